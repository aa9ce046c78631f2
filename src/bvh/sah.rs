//! SAH cost of a tree, and the leaf-collapse pass that picks leaf sizes by SAH.
//!
//! Cost: Meister & Bittner 2018, section 3, equation 2 (the unrolled recurrence):
//!
//! ```text
//!   c(root) = 1 / SA(root) * [ cT * Σ_interior SA(Ni) + cI * Σ_leaves SA(Nl) * |Nl| ]
//! ```
//!
//! with cT = 3 and cI = 2 as in the paper's section 6.
//!
//! Leaf collapse: the paper (section 6) applies "an adaptive leaf size" after optimisation, using
//! PLOC's implementation. We evaluate, bottom-up, the cheaper of keeping a subtree or replacing it
//! by one leaf holding all its primitives (allowed up to `max_leaf_size` primitives), exactly the
//! recurrence of equation 1 with a choice at each node; then rebuild the arrays in depth-first
//! order so the kept nodes are compact.

use rayon::prelude::*;

use super::layout::depth_first;
use super::parallel::{SharedSlice, bottom_up};
use super::{Bvh, BvhNode, PAD_INDEX};
use crate::geometry::Aabb;

/// The SAH's constants.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SahCosts {
    /// Cost of a traversal step, cT. Default 3 (Meister & Bittner 2018, section 6).
    pub traversal: f32,
    /// Cost of one primitive intersection, cI. Default 2.
    pub intersection: f32,
}

impl Default for SahCosts {
    fn default() -> Self {
        Self { traversal: 3.0, intersection: 2.0 }
    }
}

/// SAH cost with the default constants (cT = 3, cI = 2).
pub fn sah_cost(bvh: &Bvh) -> f64 {
    sah_cost_with(bvh, &SahCosts::default())
}

/// SAH cost by equation 2, summed in f64 by a parallel reduction. An empty tree costs 0.
///
/// When the root's surface area is zero (all primitives at one point) the ratios are 0/0; we
/// take every node as hit with probability 1, so the cost is `cT * interior + cI * primitives`.
pub fn sah_cost_with(bvh: &Bvh, costs: &SahCosts) -> f64 {
    if bvh.is_empty() {
        return 0.0;
    }
    let weight = |n: &BvhNode| -> f64 {
        if n.is_leaf() { costs.intersection as f64 * n.prim_count as f64 } else { costs.traversal as f64 }
    };
    // Every node but the padding, summed in fixed chunks and then in order, so the result does
    // not depend on the thread count (PRBVH's termination test compares successive values).
    let sum_by = |f: &(dyn Fn(&BvhNode) -> f64 + Sync)| -> f64 {
        let partial: Vec<f64> = bvh
            .nodes
            .par_chunks(4096)
            .enumerate()
            .map(|(c, chunk)| {
                chunk
                    .iter()
                    .enumerate()
                    .filter(|&(k, _)| c * 4096 + k != PAD_INDEX as usize)
                    .map(|(_, n)| f(n))
                    .sum::<f64>()
            })
            .collect();
        partial.iter().sum()
    };
    let root_area = half_area_f64(&bvh.nodes[0].aabb());
    if root_area == 0.0 {
        return sum_by(&weight);
    }
    sum_by(&|n| weight(n) * half_area_f64(&n.aabb())) / root_area
}

/// A node's half surface area in f64: for boxes of extent beyond about 1.8e19, the f32 area
/// overflows to infinity, and the cost would be infinity over infinity.
pub(crate) fn half_area_f64(b: &Aabb) -> f64 {
    if b.is_empty() {
        return 0.0;
    }
    let e = b.max.as_dvec3() - b.min.as_dvec3();
    e.x * e.y + e.y * e.z + e.z * e.x
}

/// Options of [`collapse_leaves`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CollapseConfig {
    /// Largest leaf the pass may form. Default 8: beyond that, intersecting a leaf's triangles
    /// one after another costs more than the boxes that would sort them.
    pub max_leaf_size: u32,
    /// SAH constants deciding each collapse. Default cT = 3, cI = 2.
    pub costs: SahCosts,
}

impl Default for CollapseConfig {
    fn default() -> Self {
        Self { max_leaf_size: 8, costs: SahCosts::default() }
    }
}

/// A new tree in which each subtree that SAH says is cheaper as one leaf (with at most
/// `max_leaf_size` primitives) is one leaf. Node order is depth-first, siblings adjacent. The
/// cost never increases; leaves already larger than the cap are kept as they are.
pub fn collapse_leaves(bvh: &Bvh, config: &CollapseConfig) -> Bvh {
    if bvh.nodes.len() <= 1 {
        return bvh.clone();
    }
    let collapse = collapse_decisions(bvh, config);
    depth_first(bvh, &collapse)
}

/// For every node: true where replacing its subtree by one leaf is no more expensive.
fn collapse_decisions(bvh: &Bvh, config: &CollapseConfig) -> Vec<bool> {
    let (ct, ci) = (config.costs.traversal as f64, config.costs.intersection as f64);
    // (cost in half-area units, primitive count, collapse?)
    let mut values = vec![(0.0f64, 0u32, false); bvh.nodes.len()];
    let nodes = &bvh.nodes;
    let leaves = bvh.leaf_indices();
    let out = SharedSlice::new(&mut values);
    bottom_up(&bvh.parents, &mut Vec::new(), leaves.par_iter().copied(), |i| {
        let n = &nodes[i];
        let area = half_area_f64(&n.aabb());
        let value = if n.is_leaf() {
            (ci * n.prim_count as f64 * area, n.prim_count, false)
        } else {
            // SAFETY: bottom_up visits both children before, and visits `i` once.
            let (l, r) = unsafe { (out.get(n.first as usize), out.get(n.first as usize + 1)) };
            let count = l.1 + r.1;
            let keep = ct * area + l.0 + r.0;
            let as_leaf = ci * count as f64 * area;
            if count <= config.max_leaf_size && as_leaf <= keep { (as_leaf, count, true) } else { (keep, count, false) }
        };
        // SAFETY: as above, this call owns entry `i`.
        unsafe { out.set(i, value) };
    });
    values.into_iter().map(|v| v.2).collect()
}

#[cfg(test)]
mod tests {
    use bytemuck::Zeroable;
    use glam::Vec3;

    use super::*;
    use crate::bvh::INVALID_INDEX;
    use crate::geometry::Aabb;

    fn unit(x: f32) -> Aabb {
        Aabb::new(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0))
    }

    /// root(0..3) -> [leaf a (0..1), leaf b (2..3)]: half areas 3 (unit cubes) and 7 (3x1x1).
    fn two_leaves() -> Bvh {
        Bvh {
            nodes: vec![
                BvhNode::internal(unit(0.0).union(unit(2.0)), 2),
                BvhNode::zeroed(),
                BvhNode::leaf(unit(0.0), 0, 1),
                BvhNode::leaf(unit(2.0), 1, 1),
            ]
            .into(),
            parents: vec![INVALID_INDEX, INVALID_INDEX, 0, 0],
            prim_ids: vec![0, 1],
        }
    }

    #[test]
    fn cost_of_a_known_tree() {
        // (3 * 7 + 2 * 3 + 2 * 3) / 7
        let c = sah_cost(&two_leaves());
        assert!((c - 33.0 / 7.0).abs() < 1e-12, "{c}");
        assert_eq!(sah_cost(&Bvh::default()), 0.0);
    }

    /// Boxes of extent 1e20, whose f32 areas overflow: the cost is the same as at unit scale.
    #[test]
    fn cost_does_not_overflow_at_huge_scales() {
        let mut huge = two_leaves();
        for i in [0, 2, 3] {
            let b = huge.nodes[i].aabb();
            huge.nodes[i].set_aabb(Aabb::new(b.min * 1e20, b.max * 1e20));
        }
        assert!(huge.nodes[0].aabb().half_area().is_infinite());
        let c = sah_cost(&huge);
        assert!((c - 33.0 / 7.0).abs() < 1e-9, "{c}");
    }

    #[test]
    fn collapse_when_children_overlap_fully() {
        // Two primitives with the same box: one leaf of 2 costs 2*2 = 4 < 3 + 2 + 2.
        let b = unit(0.0);
        let bvh = Bvh {
            nodes: vec![BvhNode::internal(b, 2), BvhNode::zeroed(), BvhNode::leaf(b, 0, 1), BvhNode::leaf(b, 1, 1)]
                .into(),
            parents: vec![INVALID_INDEX, INVALID_INDEX, 0, 0],
            prim_ids: vec![0, 1],
        };
        let c = collapse_leaves(&bvh, &CollapseConfig::default());
        assert_eq!(c.nodes.len(), 1);
        assert_eq!(c.nodes[0].prim_count, 2);
        assert_eq!(sah_cost(&c), 4.0);
    }

    #[test]
    fn keep_when_split_pays_and_respect_the_cap() {
        // In half-area units the split costs 3*7 + 2*3 + 2*3 = 33, one leaf 2*2*7 = 28...
        let c = collapse_leaves(&two_leaves(), &CollapseConfig::default());
        assert_eq!(c.nodes.len(), 1);
        // ...unless the cap forbids it.
        let capped = collapse_leaves(&two_leaves(), &CollapseConfig { max_leaf_size: 1, ..Default::default() });
        assert_eq!(capped, two_leaves());
        // A high intersection cost makes the split worth keeping.
        let costs = SahCosts { traversal: 1.0, intersection: 10.0 };
        let kept = collapse_leaves(&two_leaves(), &CollapseConfig { costs, ..Default::default() });
        assert_eq!(kept.nodes.len(), 4);
    }
}
