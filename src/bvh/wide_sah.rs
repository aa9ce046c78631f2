//! The SAH-optimal collapse of a binary tree into a wide one (Ylitie, Karras & Laine 2017,
//! "Efficient Incoherent Ray Traversal on GPUs Through Compressed Wide BVHs", section 3):
//! dynamic programming over the binary tree decides, for every binary node, whether it becomes
//! a wide node, a leaf lane, or is dissolved so that its children's subtrees take lanes of an
//! ancestor, minimising the wide tree's own SAH cost rather than the binary tree's.
//!
//! For a binary node `n` with box area `A(n)` and `p(n)` primitives, `C(n, i)` is the least
//! cost of `n`'s subtree as a forest of at most `i` roots:
//!
//! ```text
//!   C(n, 1) = min( A(n) p(n) c_prim          (one leaf lane; only if p(n) <= max_leaf)
//!                , A(n) c_node + D(n, W) )   (a wide node whose W lanes share n's subtree)
//!   C(n, i) = min( C(n, i - 1), D(n, i) )    for 1 < i <= W
//!   D(n, j) = min over 0 < k < j of C(left, k) + C(right, j - k)
//! ```
//!
//! The table is filled bottom-up (children before parents) and read top-down from the root.
//! Its size is `W` costs and choices per binary node, and its time `O(n W²)`.
//!
//! Leaves of the binary tree with more than `max_leaf` primitives (a leaf-collapsed tree's, up
//! to 8) are first split at the median centroid along their widest axis until every leaf fits,
//! so that the collapse takes any tree.
//!
//! Which lane a child gets, and how lanes are stored, is the consumer's: the GPU's compressed
//! nodes (`gpu::wide`) order them by ray octant and quantise their boxes.

use rayon::prelude::*;

use crate::bvh::Bvh;
use crate::geometry::Aabb;

/// The most lanes a wide node has here.
pub const MAX_WIDTH: usize = 8;

/// The constants of the wide tree's SAH: the cost of entering a node (testing its lanes'
/// boxes) and of testing one primitive, relative to each other.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WideCosts {
    pub node: f32,
    pub prim: f32,
}

impl Default for WideCosts {
    /// A node test (eight boxes at once) against a triangle test at about a third of it: a
    /// starting balance, not yet tuned on a lent GPU.
    fn default() -> Self {
        Self { node: 1.0, prim: 0.3 }
    }
}

/// One lane of a wide node.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Lane {
    /// A wide node, by index in [`WideSah::nodes`].
    Node(u32),
    /// A leaf: `prim_ids[first .. first + count]`.
    Leaf { first: u32, count: u32 },
}

/// A wide tree chosen by [`collapse`]: node 0 is the root; every node has 1 to `width` lanes,
/// each with the exact box of what it holds.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct WideSah {
    pub nodes: Vec<Vec<(Aabb, Lane)>>,
    /// Primitive ids, each leaf's a contiguous run.
    pub prim_ids: Vec<u32>,
    /// The tree's SAH cost under the costs it was chosen with, over the root's area.
    pub cost: f64,
}

/// The binary tree the table is computed over: the input's, with its large leaves split.
struct Binary {
    aabb: Vec<Aabb>,
    /// Children, or `[NONE, NONE]` for a leaf. Children have larger indices than parents.
    children: Vec<[u32; 2]>,
    /// Each node's run of `prims`.
    first: Vec<u32>,
    count: Vec<u32>,
    prims: Vec<u32>,
}

const NONE: u32 = u32::MAX;

impl Binary {
    /// `bvh` in depth-first order (left first, so that every subtree's primitives are one run),
    /// its leaves of more than `max_leaf` primitives split at median centroids.
    fn from_bvh(bvh: &Bvh, prim_aabbs: &[Aabb], max_leaf: u32) -> Binary {
        let mut t = Binary {
            aabb: Vec::with_capacity(bvh.nodes.len()),
            children: Vec::with_capacity(bvh.nodes.len()),
            first: Vec::with_capacity(bvh.nodes.len()),
            count: Vec::with_capacity(bvh.nodes.len()),
            prims: Vec::with_capacity(bvh.prim_ids.len()),
        };
        let mut scratch: Vec<u32> = Vec::new();
        // (what, parent and which child it is)
        let mut stack = vec![(0u32, None::<(u32, usize)>)];
        while let Some((i, parent)) = stack.pop() {
            let id = t.aabb.len() as u32;
            if let Some((p, k)) = parent {
                t.children[p as usize][k] = id;
            }
            let n = &bvh.nodes[i as usize];
            if !n.is_leaf() {
                t.aabb.push(n.aabb());
                t.children.push([NONE; 2]);
                t.first.push(0);
                t.count.push(0);
                stack.push((n.first + 1, Some((id, 1))));
                stack.push((n.first, Some((id, 0))));
            } else if n.prim_count <= max_leaf {
                t.aabb.push(n.aabb());
                t.children.push([NONE; 2]);
                t.first.push(t.prims.len() as u32);
                t.count.push(n.prim_count);
                t.prims.extend_from_slice(&bvh.prim_ids[n.prim_range()]);
            } else {
                // A leaf too large, split in this node's place.
                scratch.clear();
                scratch.extend_from_slice(&bvh.prim_ids[n.prim_range()]);
                t.split(&mut scratch, prim_aabbs, max_leaf);
            }
        }
        // Inner nodes' runs, children first (they have larger indices).
        for i in (0..t.aabb.len()).rev() {
            let [l, r] = t.children[i];
            if l != NONE {
                t.first[i] = t.first[l as usize];
                t.count[i] = t.count[l as usize] + t.count[r as usize];
            }
        }
        t
    }
}

impl Binary {
    /// Appends the subtree over `ids` that splits them at median centroids until every leaf holds
    /// at most `max_leaf` primitives (one leaf where they fit), its root at the next index.
    fn split(&mut self, all: &mut [u32], prim_aabbs: &[Aabb], max_leaf: u32) {
        let t = self;
        // (run, parent and which child)
        let mut stack = vec![((0, all.len()), None::<(u32, usize)>)];
        while let Some(((a, b), parent)) = stack.pop() {
            let here = t.aabb.len() as u32;
            if let Some((p, k)) = parent {
                t.children[p as usize][k] = here;
            }
            let ids = &mut all[a..b];
            let aabb = ids.iter().fold(Aabb::EMPTY, |acc, &p| acc.union(prim_aabbs[p as usize]));
            t.aabb.push(aabb);
            t.children.push([NONE; 2]);
            if ids.len() <= max_leaf as usize {
                t.first.push(t.prims.len() as u32);
                t.count.push(ids.len() as u32);
                t.prims.extend_from_slice(ids);
                continue;
            }
            t.first.push(0);
            t.count.push(0);
            let centroids = ids.iter().fold(Aabb::EMPTY, |acc, &p| acc.grow(prim_aabbs[p as usize].center()));
            let axis = centroids.extent().max_position();
            let mid = ids.len() / 2;
            ids.select_nth_unstable_by(mid, |&x, &y| {
                let (cx, cy) = (prim_aabbs[x as usize].center()[axis], prim_aabbs[y as usize].center()[axis]);
                cx.total_cmp(&cy).then(x.cmp(&y))
            });
            // Right pushed first: the left run is laid out first.
            stack.push(((a + mid, b), Some((here, 1))));
            stack.push(((a, a + mid), Some((here, 0))));
        }
    }
}

/// Subtrees of at most this many nodes fill their part of the table as one task.
const PARALLEL_NODES: usize = 1 << 14;

/// One binary node's row of the table.
#[derive(Clone, Copy, Debug)]
struct Entry {
    /// `cost[k]` = C(n, k + 1).
    cost: [f32; MAX_WIDTH],
    /// The best `k` of D(n, j), for j in 2..=width.
    split: [u8; MAX_WIDTH + 1],
    /// Bit k: whether C(n, k + 1) is D(n, k + 1).
    dist: u8,
    /// Whether C(n, 1) is the leaf.
    leaf: bool,
}

impl Default for Entry {
    fn default() -> Self {
        Entry { cost: [f32::INFINITY; MAX_WIDTH], split: [0; MAX_WIDTH + 1], dist: 0, leaf: false }
    }
}

impl Entry {
    /// The row of a node whose leaf costs `leaf_cost` and whose own box costs `node_cost` as a
    /// wide node, from its children's costs (none for a leaf).
    fn new(
        leaf_cost: f32,
        node_cost: f32,
        children: Option<([f32; MAX_WIDTH], [f32; MAX_WIDTH])>,
        width: usize,
    ) -> Entry {
        let mut e = Entry::default();
        let Some((cl, cr)) = children else {
            e.cost = [leaf_cost; MAX_WIDTH];
            e.leaf = true;
            return e;
        };
        // D(n, j) for j in 2..=width.
        let mut d = [f32::INFINITY; MAX_WIDTH + 1];
        for j in 2..=width {
            // Some split, should every cost be infinite.
            e.split[j] = 1;
            for k in 1..j {
                let c = cl[k - 1] + cr[j - k - 1];
                if c < d[j] {
                    d[j] = c;
                    e.split[j] = k as u8;
                }
            }
        }
        let inner_cost = node_cost + d[width];
        e.leaf = leaf_cost <= inner_cost;
        e.cost[0] = leaf_cost.min(inner_cost);
        for k in 1..width {
            if d[k + 1] < e.cost[k - 1] {
                e.dist |= 1 << k;
                e.cost[k] = d[k + 1];
            } else {
                e.cost[k] = e.cost[k - 1];
            }
        }
        for k in width..MAX_WIDTH {
            e.cost[k] = e.cost[width - 1];
        }
        e
    }
}

/// A box's half area in f64: f32 areas overflow for scenes beyond about 10^19.
fn half_area(b: &Aabb) -> f64 {
    let e = b.extent().as_dvec3().max(glam::DVec3::ZERO);
    e.x * e.y + e.y * e.z + e.z * e.x
}

/// Nodes in each node's subtree, itself included.
fn subtree_sizes(children: &[[u32; 2]]) -> Vec<usize> {
    let mut size = vec![1usize; children.len()];
    for i in (0..children.len()).rev() {
        let [l, r] = children[i];
        if l != NONE {
            size[i] += size[l as usize] + size[r as usize];
        }
    }
    size
}

/// The SAH-optimal `width`-wide tree (2 to [`MAX_WIDTH`] lanes) over `bvh`'s primitives, with
/// leaf lanes of at most `max_leaf` primitives (see the module docs). `prim_aabbs` are the
/// primitives' boxes by id (for splitting large leaves). An empty tree gives no nodes.
pub fn collapse(bvh: &Bvh, prim_aabbs: &[Aabb], width: usize, max_leaf: u32, costs: WideCosts) -> WideSah {
    assert!((2..=MAX_WIDTH).contains(&width) && max_leaf >= 1, "a wide node has 2 to 8 lanes, a leaf 1+ primitives");
    if bvh.nodes.is_empty() || bvh.prim_ids.is_empty() {
        return WideSah::default();
    }
    let t = Binary::from_bvh(bvh, prim_aabbs, max_leaf);
    let n = t.aabb.len();
    // Areas over the root's, so that the costs are in units of rays entering the root.
    let root_area = half_area(&t.aabb[0]).max(f64::MIN_POSITIVE);
    let area = |i: usize| {
        let a = (half_area(&t.aabb[i]) / root_area) as f32;
        if a.is_finite() { a } else { 1.0 }
    };
    // The table, bottom-up. A subtree is a contiguous run of indices (depth-first order), so
    // subtrees of at most PARALLEL_NODES nodes fill their runs of the table in parallel, and the
    // nodes above them follow.
    let mut table = vec![Entry::default(); n];
    let size = subtree_sizes(&t.children);
    let mut roots = Vec::new();
    let mut stack = vec![0usize];
    while let Some(i) = stack.pop() {
        let [l, r] = t.children[i];
        if size[i] <= PARALLEL_NODES || l == NONE {
            roots.push(i);
        } else {
            stack.extend([r as usize, l as usize]);
        }
    }
    roots.sort_unstable();
    let fill = |i: usize, table: &mut [Entry], base: usize| {
        let [l, r] = t.children[i];
        let (cl, cr) = if l == NONE {
            (None, None)
        } else {
            (Some(table[l as usize - base].cost), Some(table[r as usize - base].cost))
        };
        let leaf_cost = if t.count[i] <= max_leaf { area(i) * t.count[i] as f32 * costs.prim } else { f32::INFINITY };
        table[i - base] = Entry::new(leaf_cost, area(i) * costs.node, cl.zip(cr), width);
    };
    {
        // Split the table into the subtrees' runs.
        let mut runs: Vec<(usize, &mut [Entry])> = Vec::with_capacity(roots.len());
        let mut rest: &mut [Entry] = &mut table;
        let mut at = 0;
        for &root in &roots {
            let (_, tail) = rest.split_at_mut(root - at);
            let (run, tail) = tail.split_at_mut(size[root]);
            runs.push((root, run));
            rest = tail;
            at = root + size[root];
        }
        runs.par_iter_mut().for_each(|(root, run)| {
            for i in (*root..*root + run.len()).rev() {
                fill(i, run, *root);
            }
        });
    }
    // The nodes above the subtrees, children first.
    let mut is_root = vec![false; n];
    roots.iter().for_each(|&i| is_root[i] = true);
    let mut above = Vec::new();
    let mut stack = vec![0usize];
    while let Some(i) = stack.pop() {
        if is_root[i] {
            continue;
        }
        above.push(i);
        let [l, r] = t.children[i];
        stack.extend([r as usize, l as usize]);
    }
    for &i in above.iter().rev() {
        fill(i, &mut table, 0);
    }
    let leaf = |i: usize| table[i].leaf;
    let split = |i: usize, j: usize| usize::from(table[i].split[j]);
    let dist = |i: usize, k: usize| table[i].dist & (1 << k) != 0;
    // Read top-down. The root is a node even where one leaf would be cheaper.
    let mut out = WideSah { prim_ids: Vec::with_capacity(t.prims.len()), ..Default::default() };
    let [l, r] = t.children[0];
    if l == NONE {
        // A tree of one leaf: a node with one leaf lane.
        out.nodes.push(vec![(t.aabb[0], Lane::Leaf { first: 0, count: t.count[0] })]);
        out.prim_ids.extend_from_slice(&t.prims);
        out.cost = f64::from(costs.node) + f64::from(table[0].cost[0]);
        return out;
    }
    let k = split(0, width);
    out.cost = f64::from(costs.node)
        + f64::from(table[l as usize].cost[k - 1])
        + f64::from(table[r as usize].cost[width - k - 1]);
    // Binary nodes that become wide nodes, in the order of their indices in `out.nodes`.
    let mut pending = vec![0usize];
    let mut next = 0;
    let mut work: Vec<(usize, usize)> = Vec::new();
    while next < pending.len() {
        let root = pending[next];
        next += 1;
        let mut lanes = Vec::with_capacity(width);
        let [l, r] = t.children[root];
        let k = split(root, width);
        work.clear();
        work.push((r as usize, width - k));
        work.push((l as usize, k));
        while let Some((i, j)) = work.pop() {
            if j >= 2 && dist(i, j - 1) {
                let [l, r] = t.children[i];
                let k = split(i, j);
                work.push((r as usize, j - k));
                work.push((l as usize, k));
            } else if j >= 2 {
                work.push((i, j - 1));
            } else if leaf(i) {
                let (first, count) = (out.prim_ids.len() as u32, t.count[i]);
                let run = t.first[i] as usize..(t.first[i] + t.count[i]) as usize;
                out.prim_ids.extend_from_slice(&t.prims[run]);
                lanes.push((t.aabb[i], Lane::Leaf { first, count }));
            } else {
                lanes.push((t.aabb[i], Lane::Node(pending.len() as u32)));
                pending.push(i);
            }
        }
        out.nodes.push(lanes);
    }
    out
}

impl WideSah {
    /// The SAH cost of the tree as built, over the root's area: `c_node` for each node entered
    /// (weighted by the area of the lane box it is entered by; 1 for the root) and `c_prim`
    /// for each primitive of each leaf lane entered (by its lane's area). Equal to
    /// [`WideSah::cost`] up to rounding: a check on the table's reading.
    pub fn sah(&self, costs: WideCosts) -> f64 {
        if self.nodes.is_empty() {
            return 0.0;
        }
        let root = self.nodes[0].iter().fold(Aabb::EMPTY, |acc, (b, _)| acc.union(*b));
        let root_area = half_area(&root).max(f64::MIN_POSITIVE);
        let mut total = f64::from(costs.node);
        for lanes in &self.nodes {
            for (b, lane) in lanes {
                let a = half_area(b) / root_area;
                total += match lane {
                    Lane::Node(_) => a * f64::from(costs.node),
                    Lane::Leaf { count, .. } => a * f64::from(*count) * f64::from(costs.prim),
                };
            }
        }
        total
    }
}
