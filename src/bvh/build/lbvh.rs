//! LBVH: Karras, "Maximizing Parallelism in the Construction of BVHs, Octrees, and k-d Trees"
//! (HPG 2012).
//!
//! 1. Morton codes of the primitives' box centres, normalised to the centroid bounds: 21 bits
//!    per axis (see [`crate::geometry::morton`]; Karras uses 10, Meister & Bittner 2018 20).
//! 2. A parallel sort (rayon's pdqsort) of `(code, primitive index)` pairs; sorting on the pair
//!    makes the order, and so the tree, independent of thread count, and equal to what a stable
//!    radix sort of the codes gives (the GPU build relies on that).
//! 3. The radix tree: every internal node finds its key range and split independently (section
//!    4, Figure 4). Duplicate codes are disambiguated by appending the key's index, the trick of
//!    section 4 ("augment each key with its index"): δ(i, j) = 64 + clz(i ^ j) when codes tie.
//! 4. Boxes bottom-up in parallel with atomic visit counters (the parallel bottom-up pass of `bvh::refit`).
//!
//! One departure: runs of equal codes whose centroids differ are coded again, in the run's own
//! centroid bounds, and sorted by that second code; the radix tree then splits such a run by
//! the second code before the index ([`refine_equal_codes`]). Karras' codes are relative to the
//! bounds of all centroids, so one far outlier (a stray triangle 10^7 away from a bunny, or a
//! sky box of 10^6 around a model) put the whole model in a few cells, and the index tie-break
//! left its tree to the file's triangle order: the bunny with one stray triangle traced orders
//! of magnitude slower, and PRBVH spent many times its usual time repairing it
//! (docs/benchmarks.md, "Far outliers"). Inputs with no such run get Karras' tree unchanged;
//! elsewhere only the order inside such runs changes.
//! [`build_karras`] is the plain algorithm, which the GPU build reproduces node for node
//! (`render --device gpu` takes this module's tree where [`refinable_primitives`] is large).
//!
//! Layout: Karras numbers internal nodes `0..n-1` and leaves `0..n`, and each node (but the root)
//! is a child of exactly one internal node. We store the two children of Karras internal node `i`
//! at slots `2 + 2i` and `3 + 2i` (one cache-line pair), and the root (internal node 0) at slot 0
//! beside the padding slot 1. Each internal node then writes its own pair, so step 3 needs no
//! coordination, and the result has the layout of [`Bvh`]: `2n` slots, `2n - 1` nodes, one
//! primitive per leaf.
//!
//! Memory: first-touching fresh memory can cost as much as the build's arithmetic
//! (docs/benchmarks.md, "Fresh memory"). [`LbvhBuilder`] keeps its scratch buffers and builds
//! into an existing tree ([`LbvhBuilder::build_into`]) so that repeated builds (animation,
//! benchmarks) touch no new pages, and no buffer is zero-filled only to be overwritten.

use std::sync::atomic::AtomicU32;

use rayon::prelude::*;

use crate::bvh::parallel::SharedSlice;
use bytemuck::Zeroable;

use crate::bvh::{Bvh, BvhNode, INVALID_INDEX, LeafBoxes, Nodes, refit_with};
use crate::geometry::Aabb;
use crate::geometry::morton::MortonQuantizer;

/// Builds an LBVH over primitives given by their boxes, one primitive per leaf.
///
/// `prim_aabbs[i]` is primitive `i`'s box; the tree's `prim_ids` refer to those indices. No
/// primitives give an empty tree; primitives with NaN boxes get a valid tree, but where they go
/// in it is unspecified. The tree does not depend on the thread count.
pub fn build(prim_aabbs: &[Aabb]) -> Bvh {
    LbvhBuilder::default().build(prim_aabbs)
}

/// [`build`] without the refinement of equal-code runs: Karras' algorithm as published, the
/// tree the GPU build makes.
pub fn build_karras(prim_aabbs: &[Aabb]) -> Bvh {
    LbvhBuilder { karras_only: true, ..Default::default() }.build(prim_aabbs)
}

/// An LBVH builder that keeps its scratch memory between builds.
#[derive(Debug, Default)]
pub struct LbvhBuilder {
    /// `(code << 32) | primitive index`, sorted; then, where [`refine_equal_codes`] refined a
    /// run, `code << 64 | second code`, the radix tree's keys.
    keys: Vec<u128>,
    codes: Vec<u64>,
    leaf_slots: Vec<u32>,
    visits: Vec<AtomicU32>,
    /// Skip [`refine_equal_codes`] ([`build_karras`]).
    karras_only: bool,
}

impl LbvhBuilder {
    pub fn build(&mut self, prim_aabbs: &[Aabb]) -> Bvh {
        let mut bvh = Bvh::default();
        self.build_into(prim_aabbs, &mut bvh);
        bvh
    }

    /// Builds into `out`, reusing its arrays' memory.
    pub fn build_into(&mut self, prim_aabbs: &[Aabb], out: &mut Bvh) {
        let n = prim_aabbs.len();
        assert!(n < (1 << 31), "LBVH supports fewer than 2^31 primitives, got {n}");
        if n <= 1 {
            *out = Bvh::single_leaf(prim_aabbs);
            return;
        }
        self.sort_morton_codes(prim_aabbs, &mut out.prim_ids);
        // `keys` held the sort's (code, index) pairs; it now holds the refined keys, if any.
        if !self.karras_only && refine_equal_codes(prim_aabbs, &self.codes, &mut out.prim_ids, &mut self.keys) {
            radix_tree(&self.keys, &mut out.nodes, &mut out.parents, &mut self.leaf_slots);
        } else {
            radix_tree(&self.codes, &mut out.nodes, &mut out.parents, &mut self.leaf_slots);
        }
        // Leaf boxes first, in key order (sequential writes), then internal boxes bottom-up from
        // the leaves in key order: neighbouring walks share ancestors and cache lines.
        let (nodes, prim_ids) = (SharedSlice::new(&mut out.nodes), &out.prim_ids);
        self.leaf_slots.par_iter().with_min_len(4096).enumerate().for_each(|(k, &slot)| {
            // SAFETY: leaf slots are distinct, and only this pass touches `nodes`.
            unsafe { nodes.set(slot as usize, BvhNode::leaf(prim_aabbs[prim_ids[k] as usize], k as u32, 1)) };
        });
        refit_with(out, prim_aabbs, &self.leaf_slots, &mut self.visits, LeafBoxes::Keep);
    }

    /// Fills `self.codes` with the sorted Morton codes and `prim_ids` with the primitive of each.
    fn sort_morton_codes(&mut self, prim_aabbs: &[Aabb], prim_ids: &mut Vec<u32>) {
        let centroid_bounds = prim_aabbs
            .par_iter()
            .with_min_len(4096)
            .map(|b| Aabb::from_point(b.center()))
            .reduce(|| Aabb::EMPTY, Aabb::union);
        let quantizer = MortonQuantizer::new(&centroid_bounds);
        // (code << 32 | index): unique keys, so an unstable sort gives one order, the same as a
        // stable sort of the codes. Packed into one u128, which sorted faster than (u64, u32)
        // tuples or the rdst radix sort (docs/benchmarks.md, "The key sort").
        self.keys.clear();
        self.keys.par_extend(
            prim_aabbs
                .par_iter()
                .with_min_len(4096)
                .enumerate()
                .map(|(i, b)| ((quantizer.code(b.center()) as u128) << 32) | i as u128),
        );
        self.keys.par_sort_unstable();
        self.codes.clear();
        prim_ids.clear();
        self.keys
            .par_iter()
            .with_min_len(4096)
            .map(|&k| ((k >> 32) as u64, k as u32))
            .unzip_into_vecs(&mut self.codes, prim_ids);
    }
}

/// Codes each run of equal `codes` again, where its centroids differ, in the run's own centroid
/// bounds, and sorts the run's `prim_ids` by `(second code, index)`. Fills `keys` with
/// `code << 64 | second code` and returns true where some run was refined; returns false (and
/// leaves `keys` unspecified) where none was, and the codes alone make the tree.
///
/// Two levels give 42 bits per axis, a range of about 4·10^12: a run whose second codes tie
/// again is split by index, as Karras does.
pub fn refine_equal_codes(prim_aabbs: &[Aabb], codes: &[u64], prim_ids: &mut [u32], keys: &mut Vec<u128>) -> bool {
    let centroid = |p: u32| prim_aabbs[p as usize].center();
    let runs = refinable_runs(prim_aabbs, codes, prim_ids);
    if runs.is_empty() {
        return false;
    }
    keys.clear();
    keys.par_extend(codes.par_iter().with_min_len(4096).map(|&c| u128::from(c) << 64));
    // Disjoint slices of the runs, so that they can be sorted in parallel.
    let mut jobs = Vec::with_capacity(runs.len());
    let (mut ids, mut ks, mut at) = (&mut prim_ids[..], &mut keys[..], 0);
    for &(s, e) in &runs {
        let (_, rest_ids) = std::mem::take(&mut ids).split_at_mut(s - at);
        let (_, rest_keys) = std::mem::take(&mut ks).split_at_mut(s - at);
        let (run_ids, tail_ids) = rest_ids.split_at_mut(e - s);
        let (run_keys, tail_keys) = rest_keys.split_at_mut(e - s);
        jobs.push((run_ids, run_keys));
        (ids, ks, at) = (tail_ids, tail_keys, e);
    }
    jobs.into_par_iter().for_each(|(run_ids, run_keys)| {
        let bounds = run_ids.iter().fold(Aabb::EMPTY, |b, &p| b.grow(centroid(p)));
        let q = MortonQuantizer::new(&bounds);
        let mut sub: Vec<(u64, u32)> = run_ids.iter().map(|&p| (q.code(centroid(p)), p)).collect();
        sub.sort_unstable();
        for ((id, key), (code, p)) in run_ids.iter_mut().zip(run_keys.iter_mut()).zip(sub) {
            *id = p;
            *key |= u128::from(code);
        }
    });
    true
}

/// The runs `(start, end)` of two or more equal sorted `codes` whose centroids are not all the
/// same point: those [`refine_equal_codes`] splits.
fn refinable_runs(prim_aabbs: &[Aabb], codes: &[u64], prim_ids: &[u32]) -> Vec<(usize, usize)> {
    let n = codes.len();
    let centroid = |p: u32| prim_aabbs[p as usize].center();
    // Most meshes have no equal codes at all: nothing to allocate then.
    if !codes.par_windows(2).with_min_len(4096).any(|w| w[0] == w[1]) {
        return Vec::new();
    }
    let starts: Vec<usize> =
        (0..n).into_par_iter().with_min_len(4096).filter(|&k| k == 0 || codes[k] != codes[k - 1]).collect();
    starts
        .par_iter()
        .enumerate()
        .with_min_len(1024)
        .map(|(r, &s)| (s, starts.get(r + 1).copied().unwrap_or(n)))
        .filter(|&(s, e)| e - s >= 2 && prim_ids[s + 1..e].iter().any(|&p| centroid(p) != centroid(prim_ids[s])))
        .collect()
}

/// How many primitives lie in runs that [`refine_equal_codes`] would split, given the sorted
/// `codes` and their `prim_ids`: where it is a large share, [`build_karras`] leaves much of the
/// scene in file order.
pub fn refinable_primitives(prim_aabbs: &[Aabb], codes: &[u64], prim_ids: &[u32]) -> usize {
    refinable_runs(prim_aabbs, codes, prim_ids).iter().map(|(s, e)| e - s).sum()
}

/// Morton codes sorted ascending, and the primitive index for each.
pub fn sorted_morton_codes(prim_aabbs: &[Aabb]) -> (Vec<u64>, Vec<u32>) {
    let mut b = LbvhBuilder::default();
    let mut prim_ids = Vec::new();
    b.sort_morton_codes(prim_aabbs, &mut prim_ids);
    (b.codes, prim_ids)
}

/// The primitives in the LBVH's order: by Morton code, and inside each run of equal codes by
/// the run's own codes ([`refine_equal_codes`]). PLOC clusters in this order.
pub fn morton_order(prim_aabbs: &[Aabb]) -> Vec<u32> {
    let (codes, mut prim_ids) = sorted_morton_codes(prim_aabbs);
    refine_equal_codes(prim_aabbs, &codes, &mut prim_ids, &mut Vec::new());
    prim_ids
}

/// Karras' radix tree over sorted `codes` (at least 2), in the layout of [`Bvh`], with empty
/// boxes. Leaf `k` (the k-th code) gets `first = k`. Fills `nodes`, `parents`, and each leaf's
/// slot in key order (`leaf_slots`).
pub fn radix_tree<K: RadixKey>(codes: &[K], nodes: &mut Nodes, parents: &mut Vec<u32>, leaf_slots: &mut Vec<u32>) {
    let n = codes.len();
    debug_assert!(n >= 2 && codes.is_sorted());
    let len = 2 * n;
    parents.clear();
    parents.resize(len, INVALID_INDEX);
    leaf_slots.clear();
    leaf_slots.resize(n, 0);
    parents[2] = 0;
    parents[3] = 0;
    let shared_parents = SharedSlice::new(parents);
    let shared_leaf_slots = SharedSlice::new(leaf_slots);
    nodes.fill_pairs(n, len, |pair| {
        if pair == 0 {
            return [BvhNode::internal(Aabb::EMPTY, 2), BvhNode::zeroed()];
        }
        let i = pair - 1;
        let (split, left_is_leaf, right_is_leaf) = karras_split(codes, i);
        let slot = 2 + 2 * i as u32;
        let child = |k: u32, child: u32, is_leaf: bool| {
            if is_leaf {
                // SAFETY: each leaf has one parent, so its entry is written once.
                unsafe { shared_leaf_slots.set(child as usize, slot + k) };
                return BvhNode::leaf(Aabb::EMPTY, child, 1);
            }
            // Internal node `child` keeps its children at 2 + 2 * child; they name this slot as
            // parent. Each internal node has one parent, so each pair is written once.
            let grandchildren = 2 + 2 * child as usize;
            // SAFETY: slots 2+2c and 3+2c are written only by the parent of internal node c,
            // and nothing reads `parents` until this pass ends.
            unsafe {
                shared_parents.set(grandchildren, slot + k);
                shared_parents.set(grandchildren + 1, slot + k);
            }
            BvhNode::internal(Aabb::EMPTY, grandchildren as u32)
        };
        [child(0, split, left_is_leaf), child(1, split + 1, right_is_leaf)]
    });
}

/// A sorted key of the radix tree: a Morton code (`u64`), or a code and the second code of
/// [`refine_equal_codes`] (`u128`, the code in the high half).
pub trait RadixKey: Copy + Eq + Ord + Send + Sync {
    /// The length of the common prefix of two keys, given that they differ.
    fn common_prefix(self, other: Self) -> i32;
    /// The key's width in bits: equal keys are told apart by their indices past it.
    const BITS: i32;
}

impl RadixKey for u64 {
    #[inline]
    fn common_prefix(self, other: Self) -> i32 {
        (self ^ other).leading_zeros() as i32
    }
    const BITS: i32 = 64;
}

impl RadixKey for u128 {
    #[inline]
    fn common_prefix(self, other: Self) -> i32 {
        (self ^ other).leading_zeros() as i32
    }
    const BITS: i32 = 128;
}

/// For Karras internal node `i`: the split position γ, and whether each child is a leaf
/// (Karras 2012, Figure 4).
#[inline]
fn karras_split<K: RadixKey>(codes: &[K], i: usize) -> (u32, bool, bool) {
    let n = codes.len() as u64;
    let code_i = codes[i];
    let i = i as i64;
    // δ(i, j): common prefix length of keys i and j, -1 outside the array. A negative `j`
    // wraps to a huge unsigned value, so one comparison covers both ends.
    let delta = |j: i64| -> i32 {
        if j as u64 >= n {
            return -1;
        }
        let other = codes[j as usize];
        if other != code_i {
            code_i.common_prefix(other)
        } else {
            K::BITS + (i as u32 ^ j as u32).leading_zeros() as i32
        }
    };
    // Direction of the range: towards the neighbour sharing the longer prefix.
    let d: i64 = if delta(i + 1) >= delta(i - 1) { 1 } else { -1 };
    let delta_min = delta(i - d);
    let mut l_max: i64 = 2;
    while delta(i + l_max * d) > delta_min {
        l_max *= 2;
    }
    // Binary searches written with a conditional add, which compiles without branches.
    let mut l = 0;
    let mut t = l_max / 2;
    while t >= 1 {
        l += if delta(i + (l + t) * d) > delta_min { t } else { 0 };
        t /= 2;
    }
    let j = i + l * d;
    let delta_node = delta(j);
    // The last position sharing more than the node's common prefix.
    let mut s = 0;
    let mut step = l;
    loop {
        step = (step + 1) / 2;
        s += if delta(i + (s + step) * d) > delta_node { step } else { 0 };
        if step <= 1 {
            break;
        }
    }
    let split = i + s * d + d.min(0);
    (split as u32, i.min(j) == split, i.max(j) == split + 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tree_does_not_depend_on_the_units() {
        crate::bvh::assert_scale_invariant("lbvh", build);
    }

    /// 2000 boxes in a 10-unit cube and one box 10^7 away: Karras' codes put the cluster in a
    /// few cells and its tree in index order; the refined codes give it the tree it gets alone.
    #[test]
    fn a_far_outlier_does_not_flatten_the_tree() {
        let cluster = crate::bvh::scattered_boxes(2000, 0.3);
        let mut prims = cluster.clone();
        prims.push(Aabb::new(glam::Vec3::splat(1e7), glam::Vec3::splat(1e7 + 1.0)));
        // Interior area below the root, where the root holds the outlier beside the cluster.
        let interior = |b: &Bvh| -> f64 {
            b.nodes.iter().skip(2).filter(|n| !n.is_leaf()).map(|n| f64::from(n.aabb().half_area())).sum()
        };
        let alone = build(&cluster);
        let alone = interior(&alone) + f64::from(alone.nodes[0].aabb().half_area());
        let (refined, karras) = (build(&prims), build_karras(&prims));
        crate::bvh::validate(&refined, &prims).unwrap();
        let (r, k) = (interior(&refined), interior(&karras));
        assert!(r <= 1.1 * alone, "refined: {r} against {alone} for the cluster alone");
        assert!(k >= 3.0 * alone, "Karras: {k} against {alone}: the test no longer shows the problem");
        // Without such runs (boxes on a grid: distinct codes), the tree is Karras' own.
        let grid: Vec<Aabb> = (0..1000)
            .map(|k| {
                let c = glam::Vec3::new((k % 10) as f32, (k / 10 % 10) as f32, (k / 100) as f32);
                Aabb::new(c, c + 0.5)
            })
            .collect();
        assert!(build(&grid).nodes[..] == build_karras(&grid).nodes[..]);
    }

    #[test]
    fn splits_of_karras_figure_3() {
        // The eight 5-bit keys of Karras' Figure 3.
        let codes = [0b00001u64, 0b00010, 0b00100, 0b00101, 0b10011, 0b11000, 0b11001, 0b11110];
        let expected = [
            (3, false, false),
            (0, true, true),
            (2, true, true),
            (1, false, false),
            (4, true, false),
            (6, false, true),
            (5, true, true),
        ];
        for (i, e) in expected.into_iter().enumerate() {
            assert_eq!(karras_split(&codes, i), e, "internal node {i}");
        }
    }

    /// A u128 key with the code in its high half and equal low halves splits where the u64 code
    /// does, so refined keys change the tree only inside runs of equal codes.
    #[test]
    fn wide_keys_split_as_their_codes() {
        let codes: Vec<u64> = {
            let mut c: Vec<u64> = (0..500u64).map(|k| k.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 3).collect();
            c.extend_from_slice(&[c[7]; 5]);
            c.sort_unstable();
            c
        };
        let wide: Vec<u128> = codes.iter().map(|&c| u128::from(c) << 64).collect();
        for i in 0..codes.len() - 1 {
            assert_eq!(karras_split(&codes, i), karras_split(&wide, i), "internal node {i}");
        }
    }

    #[test]
    fn duplicate_codes_split_by_index() {
        // All keys equal: the index tie-break makes a balanced radix tree over the indices.
        let codes = [7u64; 8];
        assert_eq!(karras_split(&codes, 0), (3, false, false));
        assert_eq!(karras_split(&codes, 3), (1, false, false));
        assert_eq!(karras_split(&codes, 4), (5, false, false));
    }
}
