//! LBVH: Karras, "Maximizing Parallelism in the Construction of BVHs, Octrees, and k-d Trees"
//! (HPG 2012).
//!
//! 1. Morton codes of the primitives' box centres, normalised to the centroid bounds: 21 bits
//!    per axis (see [`crate::geometry::morton`]; Karras uses 10, Meister & Bittner 2018 20).
//! 2. A parallel sort of `(code, primitive index)` pairs; sorting on the pair makes the order,
//!    and so the tree, independent of thread count, and equal to what a stable radix sort of the
//!    codes gives (the GPU build relies on that).
//! 3. The radix tree: every internal node finds its key range and split independently (section
//!    4, Figure 4). Duplicate codes are disambiguated by appending the key's index, the trick of
//!    section 4 ("augment each key with its index"): δ(i, j) = 64 + clz(i ^ j) when codes tie.
//! 4. Boxes bottom-up in parallel with atomic visit counters ([`super::parallel::bottom_up`]).
//!
//! Layout: Karras numbers internal nodes `0..n-1` and leaves `0..n`, and each node (but the root)
//! is a child of exactly one internal node. We store the two children of Karras internal node `i`
//! at slots `1 + 2i` and `2 + 2i`, and the root (internal node 0) at slot 0. Each internal node
//! then writes its own pair of slots, so step 3 needs no coordination, and the result has the
//! siblings-adjacent layout of [`Bvh`] with `2n - 1` nodes and one primitive per leaf.

use rayon::prelude::*;

use super::parallel::SharedSlice;
use super::{Bvh, BvhNode, INVALID_INDEX, refit};
use crate::geometry::Aabb;
use crate::geometry::morton::MortonQuantizer;

/// Builds an LBVH over primitives given by their boxes, one primitive per leaf.
///
/// `prim_aabbs[i]` is primitive `i`'s box; the tree's `prim_ids` refer to those indices. No
/// primitives give an empty tree; primitives with NaN boxes get a valid tree, but where they go
/// in it is unspecified.
pub fn build(prim_aabbs: &[Aabb]) -> Bvh {
    let n = prim_aabbs.len();
    assert!(n < (1 << 31), "LBVH supports fewer than 2^31 primitives, got {n}");
    if n <= 1 {
        return Bvh::single_leaf(prim_aabbs);
    }
    let (codes, prim_ids) = sorted_morton_codes(prim_aabbs);
    let (nodes, parents) = radix_tree(&codes);
    let mut bvh = Bvh { nodes, parents, prim_ids };
    refit(&mut bvh, prim_aabbs);
    bvh
}

/// Morton codes sorted ascending, and the primitive index for each.
pub fn sorted_morton_codes(prim_aabbs: &[Aabb]) -> (Vec<u64>, Vec<u32>) {
    let centroid_bounds = prim_aabbs
        .par_iter()
        .with_min_len(4096)
        .map(|b| Aabb::from_point(b.center()))
        .reduce(|| Aabb::EMPTY, Aabb::union);
    let quantizer = MortonQuantizer::new(&centroid_bounds);
    let mut keys: Vec<(u64, u32)> = prim_aabbs
        .par_iter()
        .with_min_len(4096)
        .enumerate()
        .map(|(i, b)| (quantizer.code(b.center()), i as u32))
        .collect();
    keys.par_sort_unstable();
    keys.into_par_iter().with_min_len(4096).unzip()
}

/// Karras' radix tree over sorted `codes` (at least 2), in the siblings-adjacent layout, with
/// zero boxes. Leaf `k` (the k-th code) gets `first = k`.
pub fn radix_tree(codes: &[u64]) -> (Vec<BvhNode>, Vec<u32>) {
    let n = codes.len();
    debug_assert!(n >= 2 && codes.is_sorted());
    let mut nodes = vec![BvhNode::zeroed_internal(); 2 * n - 1];
    let mut parents = vec![INVALID_INDEX; 2 * n - 1];
    nodes[0] = BvhNode::internal(Aabb::EMPTY, 1);
    parents[1] = 0;
    parents[2] = 0;
    let shared_parents = SharedSlice::new(&mut parents);
    nodes[1..].par_chunks_mut(2).with_min_len(1024).enumerate().for_each(|(i, pair)| {
        let (split, left_is_leaf, right_is_leaf) = karras_split(codes, i);
        let slot = 1 + 2 * i as u32;
        for (k, (child, is_leaf)) in [(split, left_is_leaf), (split + 1, right_is_leaf)].into_iter().enumerate() {
            pair[k] = if is_leaf {
                BvhNode::leaf(Aabb::EMPTY, child, 1)
            } else {
                // Internal node `child` keeps its children at 1 + 2 * child; they name this slot
                // as parent. Each internal node has one parent, so each pair is written once.
                let grandchildren = 1 + 2 * child as usize;
                // SAFETY: slots 1+2c and 2+2c are written only by the parent of internal node c,
                // and nothing reads `parents` until this pass ends.
                unsafe {
                    shared_parents.set(grandchildren, slot + k as u32);
                    shared_parents.set(grandchildren + 1, slot + k as u32);
                }
                BvhNode::internal(Aabb::EMPTY, grandchildren as u32)
            };
        }
    });
    (nodes, parents)
}

/// For Karras internal node `i`: the split position γ, and whether each child is a leaf
/// (Karras 2012, Figure 4).
#[inline]
fn karras_split(codes: &[u64], i: usize) -> (u32, bool, bool) {
    let n = codes.len() as i64;
    let i = i as i64;
    let delta = |j: i64| -> i32 {
        if j < 0 || j >= n {
            return -1;
        }
        let (a, b) = (codes[i as usize], codes[j as usize]);
        if a == b { 64 + (i as u32 ^ j as u32).leading_zeros() as i32 } else { (a ^ b).leading_zeros() as i32 }
    };
    // Direction of the range: towards the neighbour sharing the longer prefix.
    let d: i64 = if delta(i + 1) - delta(i - 1) >= 0 { 1 } else { -1 };
    let delta_min = delta(i - d);
    let mut l_max: i64 = 2;
    while delta(i + l_max * d) > delta_min {
        l_max *= 2;
    }
    let mut l = 0;
    let mut t = l_max / 2;
    while t >= 1 {
        if delta(i + (l + t) * d) > delta_min {
            l += t;
        }
        t /= 2;
    }
    let j = i + l * d;
    let delta_node = delta(j);
    // Binary search for the last position sharing more than the node's common prefix.
    let mut s = 0;
    let mut step = l;
    loop {
        step = (step + 1) / 2;
        if delta(i + (s + step) * d) > delta_node {
            s += step;
        }
        if step <= 1 {
            break;
        }
    }
    let split = i + s * d + d.min(0);
    (split as u32, i.min(j) == split, i.max(j) == split + 1)
}

impl BvhNode {
    fn zeroed_internal() -> Self {
        bytemuck::Zeroable::zeroed()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn duplicate_codes_split_by_index() {
        // All keys equal: the index tie-break makes a balanced radix tree over the indices.
        let codes = [7u64; 8];
        assert_eq!(karras_split(&codes, 0), (3, false, false));
        assert_eq!(karras_split(&codes, 3), (1, false, false));
        assert_eq!(karras_split(&codes, 4), (5, false, false));
    }
}
