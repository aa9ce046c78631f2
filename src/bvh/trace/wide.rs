//! Wide BVHs for tracing: 4 or 8 children per node, collapsed from a binary tree.
//!
//! The builders, PRBVH and the dynamic BVH work on the binary tree ([`Bvh`]); a wide tree is
//! derived from it for tracing, as Embree and tinybvh derive theirs. The collapse is the
//! largest-area pull-up of Wald, Benthin & Boulos 2008 ("Getting Rid of Packets", section 3):
//! a wide node starts with its binary node's two children, and the child of largest surface area
//! that is not a leaf is replaced by its own two children until the node has `N` children or
//! only leaves. Opening the largest child first removes the boxes rays are most likely to enter,
//! which is what the SAH charges a node for. It is a single top-down pass, linear in the tree's
//! size; the optimal collapse by dynamic programming (Ylitie et al. 2017) costs a table per node
//! and is left for when a measurement shows the greedy one falling short.
//!
//! Layout (structure of arrays, one lane per child, so that one node's boxes load as six
//! vectors of `N` floats):
//!
//! ```text
//!   WideNode<4>: min_x[4] min_y[4] min_z[4] max_x[4] max_y[4] max_z[4] child[4] count[4]
//!                 16 B each, 128 B in all: two 64-byte lines
//!   WideNode<8>: the same with 8 lanes, 32 B each, 256 B in all: four lines
//! ```
//! A lane is a leaf when `count > 0` (it holds `prim_ids[child .. child + count]`, the binary
//! leaf's range, so leaf-ordered triangles serve both trees), an inner node when `count == 0`
//! (`child` indexes `nodes`), and empty when `child == INVALID_INDEX`. Lanes are filled from
//! the first, so the first empty lane ends a node. Node 0 is the root. The nodes are 64-byte
//! aligned, so no node straddles more lines than its size needs.
//!
//! Traversal tests each lane with the same conservative slab test as the binary tree
//! ([`crate::geometry::intersect_ray_packed`]'s arithmetic, Ize 2013), visits hit lanes near to
//! far, and culls with the same slack, so closest hits equal brute force exactly as the binary
//! tree's do (ties to the lowest primitive id).

use crate::geometry::{Aabb, Ray, RayInv, Triangle, WatertightRay};

use crate::bvh::trace::{Stack, closest_in_leaf, cull_limit, cull_slack, triangle_by_id};
use crate::bvh::{Bvh, Hit, INVALID_INDEX, SahCosts};

/// One wide node: `N` child boxes, structure of arrays (see the module docs).
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WideNode<const N: usize> {
    pub min_x: [f32; N],
    pub min_y: [f32; N],
    pub min_z: [f32; N],
    pub max_x: [f32; N],
    pub max_y: [f32; N],
    pub max_z: [f32; N],
    /// Inner lane: the child's index in `nodes`. Leaf lane: the first position in `prim_ids`.
    /// Empty lane: [`INVALID_INDEX`].
    pub child: [u32; N],
    /// 0 for an inner or empty lane; the number of primitives of a leaf lane.
    pub count: [u32; N],
}

const _: () = assert!(size_of::<WideNode<4>>() == 128);
const _: () = assert!(size_of::<WideNode<8>>() == 256);

impl<const N: usize> WideNode<N> {
    /// A node whose every lane is empty.
    fn empty() -> Self {
        Self {
            min_x: [f32::INFINITY; N],
            min_y: [f32::INFINITY; N],
            min_z: [f32::INFINITY; N],
            max_x: [f32::NEG_INFINITY; N],
            max_y: [f32::NEG_INFINITY; N],
            max_z: [f32::NEG_INFINITY; N],
            child: [INVALID_INDEX; N],
            count: [0; N],
        }
    }

    /// The box of lane `i`.
    #[inline]
    pub fn lane_box(&self, i: usize) -> Aabb {
        Aabb::new(
            glam::Vec3::new(self.min_x[i], self.min_y[i], self.min_z[i]),
            glam::Vec3::new(self.max_x[i], self.max_y[i], self.max_z[i]),
        )
    }

    fn set_lane(&mut self, i: usize, b: Aabb, child: u32, count: u32) {
        (self.min_x[i], self.min_y[i], self.min_z[i]) = (b.min.x, b.min.y, b.min.z);
        (self.max_x[i], self.max_y[i], self.max_z[i]) = (b.max.x, b.max.y, b.max.z);
        (self.child[i], self.count[i]) = (child, count);
    }

    /// Lanes in use: the first empty lane ends the node.
    #[inline]
    pub fn lanes(&self) -> usize {
        self.child.iter().position(|&c| c == INVALID_INDEX).unwrap_or(N)
    }

    /// Lane `i`'s entry distance if the ray enters its box before `t_max`: the arithmetic of
    /// [`crate::geometry::intersect_ray_packed`], lane by lane.
    #[inline(always)]
    pub(crate) fn intersect_lane(&self, i: usize, ray: &RayInv, t_max: f32) -> Option<f32> {
        let pick = |neg: bool, min: &[f32; N], max: &[f32; N]| if neg { (max[i], min[i]) } else { (min[i], max[i]) };
        let (nx, fx) = pick(ray.negative.x, &self.min_x, &self.max_x);
        let (ny, fy) = pick(ray.negative.y, &self.min_y, &self.max_y);
        let (nz, fz) = pick(ray.negative.z, &self.min_z, &self.max_z);
        let near_x = (nx - ray.origin.x) * ray.inv_dir.x;
        let near_y = (ny - ray.origin.y) * ray.inv_dir.y;
        let near_z = (nz - ray.origin.z) * ray.inv_dir.z;
        let far_x = (fx - ray.origin.x) * ray.inv_dir.x;
        let far_y = (fy - ray.origin.y) * ray.inv_dir.y;
        let far_z = (fz - ray.origin.z) * ray.inv_dir.z;
        crate::geometry::slab_interval(near_x, near_y, near_z, far_x, far_y, far_z, t_max)
    }
}

/// Entries a traversal keeps before spilling to the heap: a path of depth `d` leaves at most
/// `d × (N − 1)` entries, and collapsed trees are shallow.
const STACK_SIZE: usize = 128;

/// A wide BVH of `N`-child nodes over the primitives of the binary tree it was collapsed from.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct WideBvh<const N: usize> {
    pub nodes: Vec<WideNode<N>>,
    /// The binary tree's `prim_ids`: leaf lanes index ranges of it.
    pub prim_ids: Vec<u32>,
}

/// The 4-wide form (SSE, NEON).
pub type Bvh4 = WideBvh<4>;
/// The 8-wide form (AVX2).
pub type Bvh8 = WideBvh<8>;

/// What [`WideBvh::validate`] finds wrong: the first broken invariant.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum WideValidationError {
    #[error("node {node}: lane {lane} follows an empty lane")]
    LaneAfterEmpty { node: usize, lane: usize },
    #[error("node {node}: no lane in use")]
    EmptyNode { node: usize },
    #[error("node {node}, lane {lane}: child {child} out of range")]
    ChildOutOfRange { node: usize, lane: usize, child: u32 },
    #[error("node {0} is referenced {1} times, expected once (the root never)")]
    References(usize, u32),
    #[error("node {node}, lane {lane}: primitive range {first}..{end} outside prim_ids ({len})")]
    LeafRange { node: usize, lane: usize, first: u32, end: u64, len: usize },
    #[error("prim_ids position {0} is in {1} leaves, expected exactly one")]
    Position(usize, u32),
    #[error("node {node}, lane {lane}: box {found:?} is not exactly the union of its contents {expected:?}")]
    Box { node: usize, lane: usize, found: Aabb, expected: Aabb },
    #[error("node {node}, lane {lane}: primitive id {prim} out of range")]
    PrimOutOfRange { node: usize, lane: usize, prim: u32 },
    #[error("node {node}, lane {lane}: triangle packets {first}..{end} outside the {len} packets")]
    PacketRange { node: usize, lane: usize, first: u32, end: u64, len: usize },
    #[error("primitive {0} is in {1} packet lanes, expected exactly one")]
    Primitive(u32, u32),
    #[error("node {node}, lane {lane}: packed triangle of primitive {prim} has box {found:?}, expected {expected:?}")]
    PackedTriangle { node: usize, lane: usize, prim: u32, found: Aabb, expected: Aabb },
}

impl<const N: usize> WideBvh<N> {
    /// Collapses `bvh` (any builder's, after the leaf collapse or not) into `N`-wide nodes by
    /// the largest-area pull-up (see the module docs). Leaves stay the binary tree's leaves.
    pub fn from_binary(bvh: &Bvh) -> Self {
        let nodes =
            collapse(bvh, |_, n| n.is_leaf().then_some((n.first, n.prim_count)), |n, _| (n.first, n.prim_count));
        Self { nodes, prim_ids: bvh.prim_ids.clone() }
    }

    /// The box of everything in the tree.
    pub fn bounds(&self) -> Aabb {
        nodes_bounds(&self.nodes)
    }

    /// Bytes of the nodes and `prim_ids`, by length.
    pub fn memory_bytes(&self) -> usize {
        size_of_val(self.nodes.as_slice()) + size_of_val(self.prim_ids.as_slice())
    }

    /// The SAH cost of the wide tree: `cT` for every node a ray enters (weighted by the area of
    /// the box it enters it by, the root's for the root) plus `cI` per primitive of every leaf
    /// entered, over the root's area, as [`crate::bvh::sah_cost`] charges the binary tree.
    pub fn sah(&self, costs: &SahCosts) -> f64 {
        nodes_sah(&self.nodes, costs)
    }

    /// Checks every invariant: lanes filled from the first, every node but the root referenced
    /// exactly once, every `prim_ids` position in exactly one leaf, and every lane's box exactly
    /// the union of its contents (its child node's lanes, or its primitives' boxes, taken from
    /// `prim_aabbs` by primitive id).
    pub fn validate(&self, prim_aabbs: &[Aabb]) -> Result<(), WideValidationError> {
        use WideValidationError as E;
        let mut positions = vec![0u32; self.prim_ids.len()];
        validate_nodes(&self.nodes, |node, lane, first, count| {
            let end = u64::from(first) + u64::from(count);
            if end > self.prim_ids.len() as u64 {
                return Err(E::LeafRange { node, lane, first, end, len: self.prim_ids.len() });
            }
            let range = first as usize..end as usize;
            let mut b = Aabb::EMPTY;
            for (seen, &prim) in positions[range.clone()].iter_mut().zip(&self.prim_ids[range]) {
                *seen += 1;
                b = b.union(*prim_aabbs.get(prim as usize).ok_or(E::PrimOutOfRange { node, lane, prim })?);
            }
            Ok(b)
        })?;
        if let Some((pos, &c)) = positions.iter().enumerate().find(|(_, c)| **c != 1) {
            return Err(E::Position(pos, c));
        }
        Ok(())
    }

    /// Closest primitive hit by `ray` with `0 < t <= t_max`, ties going to the lowest id: the
    /// contract of [`Bvh::closest_hit`], whose `intersect` it takes.
    pub fn closest_hit<H>(
        &self,
        ray: &Ray,
        t_max: f32,
        mut intersect: impl FnMut(u32, u32, f32) -> Option<(f32, H)>,
    ) -> Option<(u32, f32, H)> {
        let inv = ray.inv();
        let mut best: Option<(u32, f32, H)> = None;
        let slack = cull_slack(&self.bounds(), ray);
        let mut limit = cull_limit(t_max, slack);
        self.traverse(&inv, &mut limit, |first, count, prim_ids, limit| {
            closest_in_leaf(first..first + count, prim_ids, (t_max, slack), &mut best, limit, &mut intersect);
            false
        });
        best
    }

    /// Whether any primitive is hit with `0 < t <= t_max`; stops at the first one found. The
    /// contract of [`Bvh::any_hit`].
    pub fn any_hit(&self, ray: &Ray, t_max: f32, mut intersect: impl FnMut(u32, u32, f32) -> bool) -> bool {
        let inv = ray.inv();
        let mut limit = cull_limit(t_max, cull_slack(&self.bounds(), ray));
        let mut found = false;
        self.traverse(&inv, &mut limit, |first, count, prim_ids, _| {
            found = (first..first + count).any(|pos| intersect(pos, prim_ids[pos as usize], t_max));
            found
        });
        found
    }

    /// The shared loop: calls `leaf(first, count, prim_ids, &mut limit)` for every leaf whose
    /// box the ray enters before `limit`, nearer boxes first; stops when `leaf` returns true.
    #[inline(always)]
    fn traverse(&self, ray: &RayInv, limit: &mut f32, mut leaf: impl FnMut(u32, u32, &[u32], &mut f32) -> bool) {
        if self.nodes.is_empty() {
            return;
        }
        // Entries still to visit; the nearest on top.
        let mut stack = Stack::<Entry, STACK_SIZE>::new();
        stack.push(Entry::default());
        let mut dist = [0.0f32; N];
        while let Some(Entry { child, count, t }) = stack.pop() {
            if t > *limit {
                continue;
            }
            if count > 0 {
                if leaf(child, count, &self.prim_ids, limit) {
                    return;
                }
                continue;
            }
            let node = &self.nodes[child as usize];
            let mut mask = 0;
            for (i, d) in dist.iter_mut().enumerate().take(node.lanes()) {
                if let Some(t) = node.intersect_lane(i, ray, *limit) {
                    (*d, mask) = (t, mask | 1 << i);
                }
            }
            let (hits, n) = far_to_near(node, mask, &dist);
            for &e in &hits[..n] {
                stack.push(e);
            }
        }
    }

    /// Closest triangle hit with the watertight test, over `triangles` indexed by primitive id:
    /// the same answer as [`Bvh::closest_hit_triangles`] on the tree it was collapsed from.
    pub fn closest_hit_triangles(&self, triangles: &[Triangle], ray: &Ray, t_max: f32) -> Option<Hit> {
        let wr = WatertightRay::new(ray);
        self.closest_hit(ray, t_max, triangle_by_id(triangles, &wr)).map(Hit::from_traversal)
    }

    /// Whether any triangle of `triangles` (indexed by primitive id) is hit with
    /// `0 < t <= t_max`.
    pub fn any_hit_triangles(&self, triangles: &[Triangle], ray: &Ray, t_max: f32) -> bool {
        let wr = WatertightRay::new(ray);
        self.any_hit(ray, t_max, |_, prim, t_max| triangles[prim as usize].intersect(&wr, t_max).is_some())
    }
}

/// The largest-area pull-up (module docs) over `bvh`, shared by every wide form:
/// `leaf(index, node)` says whether a binary node ends the descent as one leaf lane (and with
/// what range), and `place(node, range)` gives
/// that lane's `(child, count)` (it may store the leaf's contents elsewhere as a side effect;
/// it is called once per leaf lane, depth first). `leaf` must hold for every binary leaf.
pub(crate) fn collapse<const N: usize>(
    bvh: &Bvh,
    mut leaf: impl FnMut(u32, &crate::bvh::BvhNode) -> Option<(u32, u32)>,
    mut place: impl FnMut(&crate::bvh::BvhNode, (u32, u32)) -> (u32, u32),
) -> Vec<WideNode<N>> {
    const { assert!(N >= 2, "a wide node holds at least two children") };
    // Dereferenced once: each `Nodes` dereference rebuilds the slice.
    let nodes: &[crate::bvh::BvhNode] = &bvh.nodes;
    let Some(root) = nodes.first() else { return Vec::new() };
    // About one wide node per N - 1 binary inner nodes.
    let mut wide = Vec::with_capacity(nodes.len() / (2 * (N - 1)) + 1);
    wide.push(WideNode::empty());
    if let Some(range) = leaf(0, root) {
        let (child, count) = place(root, range);
        wide[0].set_lane(0, root.aabb(), child, count);
        return wide;
    }
    // (binary node, its wide node), depth first: each wide node gathers the binary node's
    // subtree.
    let mut stack = vec![(0u32, 0usize)];
    while let Some((b, w)) = stack.pop() {
        let first = nodes[b as usize].first;
        // The lanes' binary nodes, the leaf range of each leaf lane, and the half area of each
        // inner one (-1 for a leaf).
        let mut children = [0u32; N];
        let mut ranges = [None; N];
        let mut areas = [-1.0f32; N];
        let mut add =
            |c: u32, at: usize, children: &mut [u32; N], ranges: &mut [Option<(u32, u32)>; N], areas: &mut [f32; N]| {
                let n = &nodes[c as usize];
                children[at] = c;
                ranges[at] = leaf(c, n);
                areas[at] = if ranges[at].is_some() { -1.0 } else { n.aabb().half_area() };
            };
        add(first, 0, &mut children, &mut ranges, &mut areas);
        add(first + 1, 1, &mut children, &mut ranges, &mut areas);
        let mut len = 2;
        while len < N {
            // The inner child of largest area; ties to the first, so the result does not
            // depend on anything but the tree.
            let mut widest = None;
            for k in 0..len {
                if areas[k] >= 0.0 && widest.is_none_or(|j: usize| areas[k] > areas[j]) {
                    widest = Some(k);
                }
            }
            let Some(k) = widest else { break };
            let grand = nodes[children[k] as usize].first;
            add(grand, k, &mut children, &mut ranges, &mut areas);
            add(grand + 1, len, &mut children, &mut ranges, &mut areas);
            len += 1;
        }
        for lane in 0..len {
            let n = &nodes[children[lane] as usize];
            if let Some(range) = ranges[lane] {
                let (child, count) = place(n, range);
                wide[w].set_lane(lane, n.aabb(), child, count);
            } else {
                let index = wide.len();
                wide.push(WideNode::empty());
                wide[w].set_lane(lane, n.aabb(), index as u32, 0);
                stack.push((children[lane], index));
            }
        }
    }
    wide
}

/// A wide traversal's stack entry: a node (`count == 0`) or a leaf (`child`, `count` as in its
/// lane), with the distance its box is entered at.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Entry {
    pub child: u32,
    pub count: u32,
    pub t: f32,
}

/// The lanes of `node` in `mask`, with their entry distances `dist`, farthest first (so that
/// pushed in this order, the nearest is popped first), and how many there are. Shared by the
/// wide traversals, so that all visit lanes alike.
#[inline(always)]
pub(crate) fn far_to_near<const N: usize>(node: &WideNode<N>, mut mask: u32, dist: &[f32; N]) -> ([Entry; N], usize) {
    let mut hits = [Entry::default(); N];
    let mut n = 0;
    while mask != 0 {
        let i = mask.trailing_zeros() as usize;
        mask &= mask - 1;
        let e = Entry { child: node.child[i], count: node.count[i], t: dist[i] };
        // Insertion by entry distance; equal distances keep lane order.
        let mut j = n;
        while j > 0 && hits[j - 1].t < e.t {
            hits[j] = hits[j - 1];
            j -= 1;
        }
        hits[j] = e;
        n += 1;
    }
    (hits, n)
}

/// The box of everything under `nodes[0]`.
pub(crate) fn nodes_bounds<const N: usize>(nodes: &[WideNode<N>]) -> Aabb {
    nodes.first().map_or(Aabb::EMPTY, |n| (0..n.lanes()).fold(Aabb::EMPTY, |b, i| b.union(n.lane_box(i))))
}

/// [`WideBvh::sah`] over any wide nodes: a leaf lane's cost is its primitive count.
pub(crate) fn nodes_sah<const N: usize>(nodes: &[WideNode<N>], costs: &SahCosts) -> f64 {
    let root_area = f64::from(nodes_bounds(nodes).half_area());
    if nodes.is_empty() || root_area <= 0.0 {
        return 0.0;
    }
    let mut cost = f64::from(costs.traversal) * root_area;
    for n in nodes {
        for i in 0..n.lanes() {
            let area = f64::from(n.lane_box(i).half_area());
            cost += area
                * if n.count[i] > 0 {
                    f64::from(costs.intersection) * f64::from(n.count[i])
                } else {
                    f64::from(costs.traversal)
                };
        }
    }
    cost / root_area
}

/// The invariants every wide tree keeps, whatever its leaves point to: lanes filled from the
/// first, every node but the root referenced exactly once, every lane's box exactly the union of
/// its contents. `leaf(node, lane, first, count)` checks a leaf lane's contents and returns their
/// box.
pub(crate) fn validate_nodes<const N: usize>(
    nodes: &[WideNode<N>],
    mut leaf: impl FnMut(usize, usize, u32, u32) -> Result<Aabb, WideValidationError>,
) -> Result<(), WideValidationError> {
    use WideValidationError as E;
    let mut references = vec![0u32; nodes.len()];
    for (k, n) in nodes.iter().enumerate() {
        let lanes = n.lanes();
        if lanes == 0 {
            return Err(E::EmptyNode { node: k });
        }
        if let Some(lane) = (lanes..N).find(|&i| n.child[i] != INVALID_INDEX || n.count[i] != 0) {
            return Err(E::LaneAfterEmpty { node: k, lane });
        }
        for lane in 0..lanes {
            let (child, count) = (n.child[lane], n.count[lane]);
            let expected = if count > 0 {
                leaf(k, lane, child, count)?
            } else {
                let c = nodes.get(child as usize).ok_or(E::ChildOutOfRange { node: k, lane, child })?;
                references[child as usize] += 1;
                (0..c.lanes()).fold(Aabb::EMPTY, |b, i| b.union(c.lane_box(i)))
            };
            let found = n.lane_box(lane);
            if found != expected {
                return Err(E::Box { node: k, lane, found, expected });
            }
        }
    }
    if let Some((k, &r)) = references.iter().enumerate().find(|&(k, &r)| r != u32::from(k != 0)) {
        return Err(E::References(k, r));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::{CollapseConfig, build::lbvh, collapse_leaves, sah_cost_with};

    fn tree(n: usize) -> (Vec<Aabb>, Bvh) {
        let boxes = crate::bvh::scattered_boxes(n, 0.8);
        let bvh = collapse_leaves(&lbvh::build(&boxes), &CollapseConfig::default());
        (boxes, bvh)
    }

    /// Every tree size from one leaf up collapses to a valid 4- and 8-wide tree holding every
    /// primitive once, with lanes of the expected node sizes.
    #[test]
    fn collapsed_trees_are_valid() {
        for n in [1, 2, 3, 5, 17, 1000] {
            let (boxes, bvh) = tree(n);
            let w4 = Bvh4::from_binary(&bvh);
            let w8 = Bvh8::from_binary(&bvh);
            w4.validate(&boxes).unwrap_or_else(|e| panic!("{n} boxes, 4 wide: {e}"));
            w8.validate(&boxes).unwrap_or_else(|e| panic!("{n} boxes, 8 wide: {e}"));
            assert_eq!(w4.bounds(), bvh.bounds());
            assert!(w8.nodes.len() <= w4.nodes.len() && w4.nodes.len() <= bvh.nodes.len().max(1));
        }
        assert_eq!(Bvh4::from_binary(&Bvh::default()), Bvh4::default());
    }

    /// A wide tree's SAH is below its binary tree's: it charges a subset of the binary tree's
    /// inner nodes (those that head a wide node) and the same leaves.
    #[test]
    fn collapsing_lowers_the_sah() {
        let (_, bvh) = tree(5000);
        let costs = SahCosts::default();
        let binary = sah_cost_with(&bvh, &costs);
        let (w4, w8) = (Bvh4::from_binary(&bvh).sah(&costs), Bvh8::from_binary(&bvh).sah(&costs));
        assert!(w4 < binary && w8 < binary, "binary {binary}, 4 wide {w4}, 8 wide {w8}");
    }

    /// The check fails on a broken tree: a box grown by one ULP, a leaf lane pointing past
    /// `prim_ids`, and a node referenced twice.
    #[test]
    fn validate_rejects_broken_trees() {
        let (boxes, bvh) = tree(200);
        let good = Bvh4::from_binary(&bvh);
        let mut grown = good.clone();
        grown.nodes[0].max_x[0] = grown.nodes[0].max_x[0].next_up();
        assert!(matches!(grown.validate(&boxes), Err(WideValidationError::Box { node: 0, lane: 0, .. })));
        let mut leaf = good.clone();
        let (k, lane) = leaf
            .nodes
            .iter()
            .enumerate()
            .find_map(|(k, n)| (0..n.lanes()).find(|&i| n.count[i] > 0).map(|i| (k, i)))
            .expect("a leaf lane");
        leaf.nodes[k].child[lane] = leaf.prim_ids.len() as u32;
        assert!(matches!(leaf.validate(&boxes), Err(WideValidationError::LeafRange { .. })));
        let mut shared = good;
        let inner = (0..shared.nodes[0].lanes()).filter(|&i| shared.nodes[0].count[i] == 0).collect::<Vec<_>>();
        assert!(inner.len() >= 2, "the root needs two inner lanes for this case");
        shared.nodes[0].child[inner[1]] = shared.nodes[0].child[inner[0]];
        assert!(shared.validate(&boxes).is_err());
    }
}
