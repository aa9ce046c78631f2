//! PLOC: Meister & Bittner, "Parallel Locally-Ordered Clustering for Bounding Volume Hierarchy
//! Construction" (IEEE TVCG 2018).
//!
//! Bottom-up agglomerative clustering restricted to a window of the Morton order:
//! 1. The primitives, sorted by the Morton codes of their box centres (the same codes, sort and
//!    refinement of runs of equal codes as [`crate::bvh::build::lbvh`]), are the first clusters.
//! 2. Each iteration (section 4), in parallel:
//!    - every cluster finds its nearest neighbour among the `radius` clusters on either side of
//!      it, the distance being the surface area of the merged box;
//!    - clusters that are each other's nearest neighbours merge; the merged cluster takes the
//!      lower position, the higher one is removed;
//!    - the array is compacted (a parallel prefix count) and the next iteration starts.
//!
//!    Until one cluster is left. Every iteration merges at least the globally closest pair
//!    within the window, so it ends.
//! 3. Ties between distances are broken first by the pair's distance in the order, then by a
//!    hash of the pair's indices, so that "nearest" is a strict order on pairs and the result
//!    does not depend on the thread count. The hash is what keeps degenerate input fast: where
//!    many merged areas are equal (duplicated triangles, or boxes flat in two axes, whose merged
//!    boxes all have area 0), breaking ties by the lower index makes every cluster pick its left
//!    neighbour, so that one pair per iteration is mutual and the build takes O(n) iterations.
//!    With the hash, each cluster picks the adjacent pair with the lower hash, about a third of
//!    the pairs are mutual, and the build takes O(log n) iterations again.
//!
//! Layout: a merge writes its two clusters into the next free sibling pair, taken from the end
//! of the array downward in merge order (so the pairs of one iteration are contiguous), and the
//! merged cluster refers to that pair; the last cluster becomes the root in slot 0. Parent links
//! are written when a cluster is placed, so each pair's are written once.
//!
//! The radius trades quality for time: larger radii come closer to full agglomerative
//! clustering. Default 16; the PRBVH paper's comparison used 100 (Meister & Bittner 2018,
//! section 6), which `bvh-bench --builders ploc-100` measures. Each cluster computes its own `2r`
//! distances, which parallelises without shared writes (each distance is computed twice).

use bytemuck::Zeroable;
use rayon::prelude::*;

use crate::bvh::parallel::SharedSlice;
use crate::bvh::{Bvh, BvhNode, INVALID_INDEX, Nodes};
use crate::geometry::Aabb;

/// Options of [`build`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PlocConfig {
    /// How many clusters on each side a cluster looks at for its nearest neighbour. Default 16.
    pub radius: usize,
}

impl Default for PlocConfig {
    fn default() -> Self {
        Self { radius: 16 }
    }
}

/// Builds a PLOC tree over primitives given by their boxes, one primitive per leaf. Like
/// [`crate::bvh::build::lbvh::build`], the tree does not depend on the thread count.
pub fn build(prim_aabbs: &[Aabb], config: &PlocConfig) -> Bvh {
    build_counting(prim_aabbs, config).0
}

/// [`build`], also returning the number of clustering iterations.
fn build_counting(prim_aabbs: &[Aabb], config: &PlocConfig) -> (Bvh, usize) {
    let n = prim_aabbs.len();
    assert!(n < (1 << 31), "PLOC supports fewer than 2^31 primitives, got {n}");
    assert!(config.radius >= 1, "PLOC needs a radius of at least 1");
    if n <= 1 {
        return (Bvh::single_leaf(prim_aabbs), 0);
    }
    let prim_ids = crate::bvh::build::lbvh::morton_order(prim_aabbs);
    let len = 2 * n;
    let mut nodes = Nodes::default();
    nodes.fill_pairs(n, len, |_| [BvhNode::zeroed(); 2]);
    let mut parents = vec![INVALID_INDEX; len];
    // Clusters not yet placed in the tree: node records whose children (if any) are placed.
    let mut clusters: Vec<BvhNode> =
        prim_ids.par_iter().enumerate().map(|(k, &p)| BvhNode::leaf(prim_aabbs[p as usize], k as u32, 1)).collect();
    let mut next: Vec<BvhNode> = Vec::with_capacity(n);
    let mut neighbours: Vec<u32> = Vec::with_capacity(n);
    // Pairs are taken from the top: the next merge writes slots `top - 2` and `top - 1`.
    let mut top = len as u32;
    let mut iterations = 0usize;
    // Distances are computed on boxes scaled by a power of two where the scene's size would make
    // f32 areas overflow or underflow (Aabb::area_scale); the nodes keep the real boxes.
    let scale = clusters.par_iter().map(BvhNode::aabb).reduce(|| Aabb::EMPTY, Aabb::union).area_scale();
    while clusters.len() > 1 {
        iterations += 1;
        nearest_neighbours(&clusters, config.radius, scale, &mut neighbours);
        let merged = {
            let shared_nodes = SharedSlice::new(&mut nodes);
            let shared_parents = SharedSlice::new(&mut parents);
            merge(&clusters, &neighbours, top, &shared_nodes, &shared_parents, &mut next)
        };
        // The closest pair in any window is always mutual (module docs), so this cannot fail
        // unless that argument is broken; better a panic than an endless loop.
        assert!(merged > 0, "PLOC: no mutual nearest neighbours among {} clusters", clusters.len());
        top -= 2 * merged as u32;
        std::mem::swap(&mut clusters, &mut next);
    }
    debug_assert_eq!(top, 2);
    let root = clusters[0];
    nodes[0] = root;
    parents[root.first as usize] = 0;
    parents[root.first as usize + 1] = 0;
    (Bvh { nodes, parents, prim_ids }, iterations)
}

/// For each cluster, the index of its nearest neighbour within `radius` positions: the one whose
/// merged box has the smallest surface area, ties broken by [`tie_key`]. Areas are of the boxes
/// multiplied by `scale`, a power of two.
fn nearest_neighbours(clusters: &[BvhNode], radius: usize, scale: f32, out: &mut Vec<u32>) {
    let boxes: Vec<Aabb> = clusters.par_iter().with_min_len(4096).map(|c| c.aabb().scaled(scale)).collect();
    out.clear();
    out.par_extend((0..clusters.len()).into_par_iter().with_min_len(1024).map(|i| {
        let b = boxes[i];
        let (lo, hi) = (i.saturating_sub(radius), (i + radius).min(boxes.len() - 1));
        // NaN distances (from NaN boxes) count as infinite, so that every cluster has a
        // neighbour and the order stays strict.
        let mut best: Option<(f32, usize)> = None;
        for (j, other) in boxes.iter().enumerate().take(hi + 1).skip(lo) {
            if j != i {
                let d = b.union(*other).half_area_nonempty();
                let d = if d.is_nan() { f32::INFINITY } else { d };
                let better = best.is_none_or(|(bd, bj)| d < bd || (d == bd && tie_key(i, j) < tie_key(i, bj)));
                if better {
                    best = Some((d, j));
                }
            }
        }
        best.map_or(i, |(_, j)| j) as u32
    }));
}

/// The order among pairs at equal distance: nearer in the Morton order first, then by a hash of
/// the pair, then by the indices. Symmetric in `i` and `j`, so that with the distance it is a
/// strict order on pairs, which is what makes the closest pair of any window mutual.
#[inline]
fn tie_key(i: usize, j: usize) -> (usize, u64, usize) {
    let (a, b) = (i.min(j), i.max(j));
    // SplitMix64's finaliser over both indices.
    let mut h = ((a as u64) << 32 | b as u64).wrapping_add(0x9e37_79b9_7f4a_7c15);
    h = (h ^ (h >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    h = (h ^ (h >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    (b - a, h ^ (h >> 31), a)
}

/// Merges the mutual nearest neighbours of `clusters` into `next` (compacted, in order), writing
/// each merged pair to the tree below `top`; returns the number of merges.
fn merge(
    clusters: &[BvhNode],
    neighbours: &[u32],
    top: u32,
    nodes: &SharedSlice<BvhNode>,
    parents: &SharedSlice<u32>,
    next: &mut Vec<BvhNode>,
) -> usize {
    // What becomes of cluster i: kept (0), merged with a higher neighbour (1), or absorbed by
    // a lower one (2).
    let fate = |i: usize| -> u8 {
        let j = neighbours[i] as usize;
        if neighbours[j] as usize != i {
            0
        } else if i < j {
            1
        } else {
            2
        }
    };
    // Chunked prefix counts: survivors (for `next`) and merges (for pairs), per chunk.
    const CHUNK: usize = 4096;
    let counts: Vec<(usize, usize)> = (0..clusters.len().div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let range = c * CHUNK..((c + 1) * CHUNK).min(clusters.len());
            range.fold((0, 0), |(kept, merged), i| match fate(i) {
                0 => (kept + 1, merged),
                1 => (kept + 1, merged + 1),
                _ => (kept, merged),
            })
        })
        .collect();
    let mut starts = Vec::with_capacity(counts.len());
    let (mut kept_total, mut merged_total) = (0usize, 0usize);
    for &(kept, merged) in &counts {
        starts.push((kept_total, merged_total));
        kept_total += kept;
        merged_total += merged;
    }
    next.clear();
    next.resize(kept_total, BvhNode::zeroed());
    let out = SharedSlice::new(next);
    // Places a cluster's record in `slot` and points its children there.
    let place = |node: BvhNode, slot: u32| {
        // SAFETY: every slot below `top` is handed to exactly one merge, and a placed cluster's
        // children pair is the one its own merge wrote, so each parent entry is written once.
        unsafe {
            nodes.set(slot as usize, node);
            if !node.is_leaf() {
                parents.set(node.first as usize, slot);
                parents.set(node.first as usize + 1, slot);
            }
        }
    };
    starts.par_iter().enumerate().for_each(|(c, &(mut k, mut m))| {
        for i in c * CHUNK..((c + 1) * CHUNK).min(clusters.len()) {
            let cluster = match fate(i) {
                0 => clusters[i],
                1 => {
                    let other = clusters[neighbours[i] as usize];
                    let pair = top - 2 * (m as u32 + 1);
                    m += 1;
                    place(clusters[i], pair);
                    place(other, pair + 1);
                    BvhNode::internal(clusters[i].aabb().union(other.aabb()), pair)
                }
                _ => continue,
            };
            // SAFETY: survivor k of the whole array is written by the one chunk that holds it.
            unsafe { out.set(k, cluster) };
            k += 1;
        }
    });
    merged_total
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn boxes(n: usize) -> Vec<Aabb> {
        crate::bvh::scattered_boxes(n, 0.1)
    }

    #[test]
    fn the_tree_does_not_depend_on_the_units() {
        crate::bvh::assert_scale_invariant("ploc", |p| build(p, &PlocConfig::default()));
    }

    /// A far outlier puts the cluster's codes in a few cells; PLOC's window then follows the
    /// refined order, not the file order, and the cluster's tree is about the one it gets alone.
    #[test]
    fn a_far_outlier_does_not_spoil_the_window() {
        let cluster = crate::bvh::scattered_boxes(2000, 0.3);
        let mut prims = cluster.clone();
        prims.push(Aabb::new(Vec3::splat(1e7), Vec3::splat(1e7 + 1.0)));
        let interior =
            |b: &Bvh| -> f64 { b.nodes.iter().filter(|n| !n.is_leaf()).map(|n| f64::from(n.aabb().half_area())).sum() };
        let alone = interior(&build(&cluster, &PlocConfig::default()));
        let with = build(&prims, &PlocConfig::default());
        crate::bvh::validate(&with, &prims).unwrap();
        // Below the root, which holds the outlier beside the cluster's root.
        let below = interior(&with) - f64::from(with.nodes[0].aabb().half_area());
        assert!(below <= 1.1 * alone, "{below} against {alone} for the cluster alone");
    }

    #[test]
    fn builds_valid_trees() {
        for n in [0, 1, 2, 3, 17, 1000] {
            for radius in [1, 4, 16] {
                let prims = boxes(n);
                let bvh = build(&prims, &PlocConfig { radius });
                crate::bvh::validate(&bvh, &prims).unwrap_or_else(|e| panic!("n = {n}, r = {radius}: {e}"));
                assert_eq!(bvh.nodes.len(), if n <= 1 { n } else { 2 * n });
            }
        }
    }

    #[test]
    fn nan_boxes_still_give_a_tree() {
        let mut prims = boxes(50);
        for b in prims.iter_mut().step_by(3) {
            b.max.x = f32::NAN;
        }
        let bvh = build(&prims, &PlocConfig::default());
        let mut ids = bvh.prim_ids.clone();
        ids.sort_unstable();
        assert_eq!(ids, (0..50).collect::<Vec<u32>>());
        assert_eq!(bvh.leaf_count(), 50);
    }

    /// With a window covering every cluster, PLOC is exact agglomerative clustering (Walter et
    /// al. 2008: merging mutual nearest neighbours gives the same tree as always merging the
    /// globally closest pair, when merging never brings clusters closer, as for areas).
    #[test]
    fn a_full_window_equals_greedy_agglomerative_clustering() {
        for n in [5, 20, 40] {
            let prims = boxes(n);
            let bvh = build(&prims, &PlocConfig { radius: n });
            // The greedy reference: the sum of internal areas of the tree made by repeatedly
            // merging the pair with the smallest merged area.
            let mut clusters = prims.clone();
            let mut internal = 0.0f64;
            while clusters.len() > 1 {
                let mut best = (f32::INFINITY, 0, 0);
                for i in 0..clusters.len() {
                    for j in i + 1..clusters.len() {
                        let d = clusters[i].union(clusters[j]).half_area_nonempty();
                        if d < best.0 {
                            best = (d, i, j);
                        }
                    }
                }
                let (_, i, j) = best;
                let merged = clusters[i].union(clusters.swap_remove(j));
                clusters[i] = merged;
                internal += merged.half_area_nonempty() as f64;
            }
            let got: f64 = bvh
                .nodes
                .iter()
                .enumerate()
                .filter(|(k, m)| *k != 1 && !m.is_leaf())
                .map(|(_, m)| m.aabb().half_area_nonempty() as f64)
                .sum();
            assert!((got - internal).abs() <= 1e-5 * internal, "n = {n}: PLOC {got}, greedy {internal}");
        }
    }

    #[test]
    fn identical_boxes() {
        let prims = vec![Aabb::new(Vec3::ZERO, Vec3::ONE); 100];
        let bvh = build(&prims, &PlocConfig::default());
        crate::bvh::validate(&bvh, &prims).unwrap();
    }

    /// Where every merged area ties (identical boxes; boxes flat in two axes, whose merges all
    /// have area 0), clustering still takes a logarithmic number of iterations, not one per
    /// primitive. Breaking ties by the lower index instead takes n - 1 iterations here.
    #[test]
    fn ties_still_merge_many_pairs_per_iteration() {
        let n = 20_000;
        let identical = vec![Aabb::new(Vec3::ZERO, Vec3::ONE); n];
        let collinear: Vec<Aabb> =
            (0..n).map(|i| Aabb::new(Vec3::new(i as f32, 0.0, 0.0), Vec3::new(i as f32 + 1.0, 0.0, 0.0))).collect();
        for (name, prims) in [("identical", identical), ("collinear", collinear)] {
            for radius in [1, 16] {
                let (bvh, iterations) = build_counting(&prims, &PlocConfig { radius });
                crate::bvh::validate(&bvh, &prims).unwrap_or_else(|e| panic!("{name}, r = {radius}: {e}"));
                assert!(iterations <= 200, "{name}, r = {radius}: {iterations} iterations for {n} boxes");
            }
        }
    }
}
