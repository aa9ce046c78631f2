//! The search (section 4.2, Algorithm 1): every candidate node finds the output node whose
//! sibling it should become to decrease the total surface area most, walking the tree by parent
//! links with the paper's pruning, bounded by [`MAX_VISITS`] (see the departures in [`super`]).

use super::reinsert::Reinsertion;
use crate::bvh::parallel::SharedSlice;
use crate::bvh::{Bvh, BvhNode};
use glam::{BVec4A, Vec3A, Vec3Swizzles, Vec4};
use rayon::prelude::*;

/// Every node's box area, as the search computes it, kept up to date between iterations so that
/// the search reads the areas of the nodes it passes instead of computing them (not in the
/// paper). Held only at unit scale (`search_scale` 1), where these are the search's own values,
/// so the trees are the same to the bit.
pub(super) struct NodeAreas(Option<Vec<f32>>);

impl NodeAreas {
    pub(super) fn new(bvh: &Bvh) -> Self {
        let unit = search_scale(bvh.nodes.first()) == 1.0;
        Self(unit.then(|| bvh.nodes.par_iter().with_min_len(4096).map(|n| Box4::of(n).area()).collect()))
    }

    pub(super) fn get(&self) -> Option<&[f32]> {
        self.0.as_deref()
    }

    pub(super) fn shared(&mut self) -> Option<SharedSlice<'_, f32>> {
        self.0.as_deref_mut().map(SharedSlice::new)
    }

    /// Updates the slots `applied` wrote (the refit updates their ancestors).
    pub(super) fn moved(&mut self, bvh: &Bvh, applied: &[Reinsertion]) {
        let Some(areas) = self.shared() else { return };
        let nodes: &[BvhNode] = &bvh.nodes;
        applied.par_iter().for_each(|r| {
            for slot in r.written_slots() {
                // SAFETY: the winners' locked nodes are disjoint, and these are locked nodes (the
                // input's parent, the input and its sibling, the output).
                unsafe { areas.set(slot as usize, Box4::of(&nodes[slot as usize]).area()) };
            }
        });
    }

    /// Checks every area against its node's box.
    #[cfg(debug_assertions)]
    pub(super) fn debug_check(&self, bvh: &Bvh, iteration: u32) {
        let Some(areas) = &self.0 else { return };
        for (i, (n, a)) in bvh.nodes.iter().zip(areas).enumerate() {
            let want = Box4::of(n).area();
            assert!(
                a.to_bits() == want.to_bits(),
                "PRBVH iteration {iteration}: node {i} has area {a} cached, {want} in its box"
            );
        }
    }
}

/// (input, output, decrease) for every searching node with a positive decrease.
/// The decreases are in the search's scaled units (`search_scale`), which order them as the
/// true ones do.
/// `areas`, where given, are the nodes' box areas ([`NodeAreas`]).
pub(super) fn search(
    bvh: &Bvh,
    inputs: impl ParallelIterator<Item = usize>,
    areas: Option<&[f32]>,
) -> Vec<(u32, u32, f32)> {
    let scale = search_scale(bvh.nodes.first());
    inputs
        .filter_map(|i| {
            let (out, d) = search_scaled(bvh, i as u32, scale, areas);
            (d > 0.0).then_some((i as u32, out, d))
        })
        .collect()
}

/// Algorithm 1: the output node `input` should become the sibling of, and the surface-area
/// decrease that gives (0 and the current sibling when nothing is better). `input` must not be
/// the root or the padding node.
pub fn find_best_output(bvh: &Bvh, input: u32) -> (u32, f32) {
    let scale = search_scale(bvh.nodes.first());
    let (out, d) = search_scaled(bvh, input, scale, None);
    (out, d / scale / scale)
}

/// The power of two the search multiplies coordinates by ([`Aabb::area_scale`] of the root):
/// without it, a scene of extent 1e20 has infinite areas, no pruning ever applies, and each
/// search visits the whole tree. Shared with the GPU optimiser, which reads its root back for it.
pub(crate) fn search_scale(root: Option<&BvhNode>) -> f32 {
    root.map_or(1.0, |r| r.aabb().area_scale())
}

/// [`find_best_output`] with coordinates multiplied by `scale`, which also scales the decrease
/// returned (by its square).
///
/// Written as two nested loops, the climb over the pivots and the pre-order walk of each
/// pivot's other subtree ([`Search::walk`]), instead of the paper's single loop with a
/// direction flag: most walks end at the subtree's root, and that case now runs straight
/// through. The arithmetic and the order of visits are the paper's, so the results are the same
/// bits.
///
/// `areas`, the nodes' box areas where known, are read instead of computed; they are used only
/// at unit scale, where they are what the search would compute.
pub(super) fn search_scaled(bvh: &Bvh, input: u32, scale: f32, areas: Option<&[f32]>) -> (u32, f32) {
    // Unscaled (nearly every scene), the boxes are used as loaded.
    match (scale == 1.0, areas) {
        (true, Some(areas)) => search_with::<false, true>(bvh, input, scale, areas).0,
        (true, None) => search_with::<false, false>(bvh, input, scale, &[]).0,
        (false, _) => search_with::<true, false>(bvh, input, scale, &[]).0,
    }
}

/// [`search_scaled`], multiplying coordinates by `scale` only where `SCALED`, and reading node
/// areas from `areas` where `CACHED`; also returns the nodes visited.
#[inline(always)]
pub(super) fn search_with<const SCALED: bool, const CACHED: bool>(
    bvh: &Bvh,
    input: u32,
    scale: f32,
    areas: &[f32],
) -> ((u32, f32), u32) {
    let scale = Vec3A::splat(scale);
    let mut s = Search::<SCALED, CACHED> {
        nodes: &bvh.nodes,
        parents: &bvh.parents,
        areas,
        scale,
        b_in: Box4::EMPTY,
        a_parent: 0.0,
        d_bound: 0.0,
        d: 0.0,
        d_best: 0.0,
        out_best: input ^ 1,
        growth: [0.0; KEPT],
        visits: 0,
    };
    let b_in = s.bbox(input);
    let parent = s.parents[input as usize];
    let a_parent = s.area(parent);
    (s.b_in, s.a_parent, s.d_bound) = (b_in, a_parent, a_parent - s.area_of(input, b_in));
    let mut b_pivot = Box4::EMPTY;
    let (mut child, mut pivot) = (input, parent);
    loop {
        // The pivot's other subtree, then the pivot itself as an output.
        let b_other = s.walk(child ^ 1);
        b_pivot = b_pivot.union(b_other);
        if pivot != parent {
            let a_out = s.area(pivot);
            let d_direct = a_parent - b_in.union(b_pivot).area();
            // The pivot's own shrink (see the module docs).
            let own = a_out - b_pivot.area();
            if s.d_best < d_direct + s.d + own {
                s.d_best = d_direct + s.d + own;
                s.out_best = pivot;
            }
            s.d += own;
        }
        // Once the rest of the pivot encloses the input, removing the input shrinks no higher
        // ancestor, so no output further up can beat `d_bound + d`.
        if pivot == 0 || (s.d_bound + s.d <= s.d_best && b_pivot.contains(b_in)) {
            return ((s.out_best, s.d_best), s.visits);
        }
        child = pivot;
        pivot = s.parents[pivot as usize];
    }
}

/// The state of one search of [`search_scaled`]: `d` is the surface-area decrease accumulated
/// along the path, the paper's `d`.
pub(super) struct Search<'a, const SCALED: bool, const CACHED: bool> {
    /// The node array, dereferenced once (each `Nodes` dereference recomputes the slice).
    nodes: &'a [BvhNode],
    parents: &'a [u32],
    areas: &'a [f32],
    scale: Vec3A,
    b_in: Box4,
    a_parent: f32,
    d_bound: f32,
    d: f32,
    d_best: f32,
    out_best: u32,
    /// The growth added to `d` at each depth below the subtree's root, to take back on the way
    /// up without reloading the node (the paper recomputes it; the values are the same bits).
    /// Deeper than the array, it is recomputed.
    growth: [f32; KEPT],
    /// Nodes visited so far; from [`MAX_VISITS`] on, the walk prunes every node.
    visits: u32,
}

/// Most nodes one search visits as outputs: past them, the walk prunes every node it reaches.
/// Searches on real and procedural meshes stay well below it, so it changes no tree there. On a
/// pile of triangles overlapping in one square, where no box prunes another, a search would
/// otherwise walk most of the tree; there the bound cuts the optimisation's time several-fold for
/// a negligible rise in SAH (docs/benchmarks.md, "The bound on each search"). Shared with the GPU
/// search through the WGSL prelude.
pub const MAX_VISITS: u32 = 1024;

/// Levels of growth a [`Search`] keeps.
pub(super) const KEPT: usize = 64;

impl<const SCALED: bool, const CACHED: bool> Search<'_, SCALED, CACHED> {
    #[inline(always)]
    pub(super) fn bbox(&self, n: u32) -> Box4 {
        let node = &self.nodes[n as usize];
        if SCALED { Box4::scaled(node, self.scale) } else { Box4::of(node) }
    }

    /// The area of node `n`'s box.
    #[inline(always)]
    pub(super) fn area(&self, n: u32) -> f32 {
        if CACHED { self.areas[n as usize] } else { self.bbox(n).area() }
    }

    /// The area of node `n`, whose box `b` is at hand.
    #[inline(always)]
    pub(super) fn area_of(&self, n: u32, b: Box4) -> f32 {
        if CACHED { self.areas[n as usize] } else { b.area() }
    }

    /// Walks the subtree of `root` in pre-order, pruning below a node when `d_bound + d` cannot
    /// beat the best decrease, and offering every node visited as an output. Returns the root's
    /// box; leaves `d` as the walk found it (the same value, up to the rounding the paper's
    /// add-and-subtract leaves).
    #[inline(always)]
    pub(super) fn walk(&mut self, root: u32) -> Box4 {
        let b_root = self.bbox(root);
        if self.visit_at(root, b_root, 0) {
            self.d -= self.growth[0];
            return b_root;
        }
        let parents = self.parents;
        let mut out = self.nodes[root as usize].first;
        let mut depth = 1usize;
        loop {
            let b_out = self.bbox(out);
            if !self.visit_at(out, b_out, depth) {
                out = self.nodes[out as usize].first;
                depth += 1;
                continue;
            }
            // Up: take back each level's growth until a left child's right sibling is next.
            loop {
                self.d -= if depth < KEPT {
                    self.growth[depth]
                } else {
                    let b_out = self.bbox(out);
                    self.area_of(out, b_out) - self.b_in.union(b_out).area()
                };
                if depth == 0 {
                    return b_root;
                }
                if out % 2 == 0 {
                    out += 1;
                    break;
                }
                out = parents[out as usize];
                depth -= 1;
            }
        }
    }

    /// Offers node `n` (box `b`, `depth` below the subtree's root) as an output and adds its
    /// growth to `d`; returns whether the walk goes back up from it.
    #[inline(always)]
    pub(super) fn visit_at(&mut self, n: u32, b: Box4, depth: usize) -> bool {
        self.visits += 1;
        let a_merged = self.b_in.union(b).area();
        let d_direct = self.a_parent - a_merged;
        if self.d_best < d_direct + self.d {
            self.d_best = d_direct + self.d;
            self.out_best = n;
        }
        let g = self.area_of(n, b) - a_merged;
        if depth < KEPT {
            self.growth[depth] = g;
        }
        self.d += g;
        self.nodes[n as usize].is_leaf() || self.d_bound + self.d <= self.d_best || self.visits >= MAX_VISITS
    }
}

/// A node's box in SIMD registers, for [`find_best_output`]: the same arithmetic as
/// [`Aabb::half_area_nonempty`] and [`Aabb::union`], in the same order, so the results are bit
/// for bit the scalar ones.
#[derive(Clone, Copy)]
pub(super) struct Box4 {
    min: Vec3A,
    max: Vec3A,
}

impl Box4 {
    const EMPTY: Self = Self { min: Vec3A::INFINITY, max: Vec3A::NEG_INFINITY };

    /// The node's box with coordinates multiplied by `scale` (a power of two: exact).
    #[inline(always)]
    pub(super) fn scaled(node: &BvhNode, scale: Vec3A) -> Self {
        let b = Self::of(node);
        Self { min: b.min * scale, max: b.max * scale }
    }

    /// The node's box. Each corner is one 16-byte load with its fourth lane (`first` or
    /// `prim_count`) cleared: `Vec3A::new` takes four instructions per corner, and left in
    /// place, those integer bits would be denormal floats in the arithmetic of that lane.
    #[inline(always)]
    pub(super) fn of(node: &BvhNode) -> Self {
        let f = node.as_floats();
        let xyz = BVec4A::new(true, true, true, false);
        let corner = |c: &[f32]| Vec3A::from_vec4(Vec4::select(xyz, Vec4::from_slice(c), Vec4::ZERO));
        Self { min: corner(&f[..4]), max: corner(&f[4..]) }
    }

    #[inline(always)]
    pub(super) fn union(self, other: Self) -> Self {
        Self { min: self.min.min(other.min), max: self.max.max(other.max) }
    }

    /// Half surface area: `(x y + y z) + z x`, as [`Aabb::half_area_nonempty`] sums it.
    #[inline(always)]
    pub(super) fn area(self) -> f32 {
        let e = self.max - self.min;
        (e * e.yzx()).element_sum()
    }

    #[inline(always)]
    pub(super) fn contains(self, other: Self) -> bool {
        self.min.cmple(other.min).all() && self.max.cmpge(other.max).all()
    }
}
