//! The bounding volume hierarchy, in rooms by family:
//!
//! - here: the node layout shared with the GPU ([`Bvh`], [`BvhNode`]), SAH cost and the leaf
//!   collapse ([`sah`]), validation, refits, and the memory layouts;
//! - [`build`]: the builders (LBVH, binned SAH, PLOC, parallel and sequential reinsertion) and
//!   the builders by name;
//! - [`trace`]: traversal of the binary tree, the wide trees and their SIMD kernels, and
//!   [`MeshBvh`], a mesh's tree with the form it is traced in;
//! - [`wide_sah`]: the SAH-optimal collapse of a binary tree into a wide one (Ylitie et al.
//!   2017), which the GPU's compressed wide nodes are made from;
//! - [`dynamic`]: the BVH kept alive while its primitives move, and the two-level BVH of
//!   instances.

pub mod build;
pub mod dynamic;
mod layout;
mod node;
mod parallel;
pub mod sah;
pub mod trace;
mod validate;
pub mod wide_sah;

pub use node::{Bvh, BvhNode, INVALID_INDEX, NodePair, Nodes, PAD_INDEX};
pub use sah::{CollapseConfig, SahCosts, collapse_leaves, sah_cost, sah_cost_with};
pub use trace::{
    CULL_ABS_ULPS, CULL_SCALE, Hit, HitFilter, MeshBvh, SimdPath, Skip, SkipReject, TraceLayout, Tracing,
    brute_force_any, brute_force_closest, hit_point_and_normal,
};
pub use validate::{BvhStats, ValidationError, validate};

use std::sync::atomic::AtomicU32;

use rayon::prelude::*;

use crate::geometry::Aabb;

/// Recomputes every box bottom-up in parallel from the primitives' boxes, keeping the topology
/// (Karras 2012, section 4; the refit step of Meister & Bittner 2018, section 5).
pub fn refit(bvh: &mut Bvh, prim_aabbs: &[Aabb]) {
    let leaves = bvh.leaf_indices();
    refit_with(bvh, prim_aabbs, &leaves, &mut Vec::new(), LeafBoxes::Recompute);
}

/// Whether a refit recomputes leaf boxes or takes them as they are.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum LeafBoxes {
    Recompute,
    Keep,
}

/// [`refit`] with the leaves given, in an order that keeps neighbouring walks close in memory,
/// and a scratch buffer for the visit counters.
pub(crate) fn refit_with(
    bvh: &mut Bvh,
    prim_aabbs: &[Aabb],
    leaves: &[u32],
    visits: &mut Vec<AtomicU32>,
    leaf_boxes: LeafBoxes,
) {
    let Bvh { nodes, parents, prim_ids } = bvh;
    let nodes = parallel::SharedSlice::new(nodes);
    parallel::bottom_up(parents, visits, leaves.par_iter().copied(), |i| {
        // SAFETY: bottom_up gives this call exclusive access to node `i`, after its children's
        // visits are complete and visible.
        unsafe {
            let mut n = nodes.get(i);
            if n.is_leaf() && leaf_boxes == LeafBoxes::Keep {
                return;
            }
            let b = if n.is_leaf() {
                leaf_bounds(&prim_ids[n.prim_range()], prim_aabbs)
            } else {
                nodes.get(n.first as usize).aabb().union(nodes.get(n.first as usize + 1).aabb())
            };
            n.set_aabb(b);
            nodes.set(i, n);
        }
    });
}

/// The same as [`refit`] on one thread, children before parents in reverse pre-order: the
/// reference `refit` is tested against.
pub fn refit_sequential(bvh: &mut Bvh, prim_aabbs: &[Aabb]) {
    let mut order = Vec::with_capacity(bvh.nodes.len());
    let mut stack = if bvh.is_empty() { vec![] } else { vec![0u32] };
    while let Some(i) = stack.pop() {
        order.push(i as usize);
        let n = &bvh.nodes[i as usize];
        if !n.is_leaf() {
            stack.extend([n.first, n.first + 1]);
        }
    }
    for &i in order.iter().rev() {
        let n = bvh.nodes[i];
        let b = if n.is_leaf() {
            leaf_bounds(&bvh.prim_ids[n.prim_range()], prim_aabbs)
        } else {
            bvh.nodes[n.first as usize].aabb().union(bvh.nodes[n.first as usize + 1].aabb())
        };
        bvh.nodes[i].set_aabb(b);
    }
}

fn leaf_bounds(prims: &[u32], prim_aabbs: &[Aabb]) -> Aabb {
    prims.iter().fold(Aabb::EMPTY, |b, &p| b.union(prim_aabbs[p as usize]))
}

/// Checks that `build` makes the same tree (the same topology, primitive order and SAH) from
/// [`scattered_boxes`] as from the same boxes scaled by 2^100 and by 2^-100, where f32 areas
/// overflow and underflow: a builder's area arithmetic must not depend on the scene's units.
#[cfg(test)]
pub(crate) fn assert_scale_invariant(name: &str, build: impl Fn(&[Aabb]) -> Bvh) {
    let unit = scattered_boxes(2000, 0.3);
    let reference = build(&unit);
    for scale in [2f32.powi(100), 2f32.powi(-100)] {
        let scaled: Vec<Aabb> = unit.iter().map(|b| b.scaled(scale)).collect();
        let bvh = build(&scaled);
        validate(&bvh, &scaled).unwrap();
        let shape = |b: &Bvh| b.nodes.iter().map(|n| (n.first, n.prim_count)).collect::<Vec<_>>();
        assert!(
            shape(&bvh) == shape(&reference) && bvh.prim_ids == reference.prim_ids,
            "{name}: scale {scale:e} changed the tree"
        );
        let (a, b) = (sah_cost(&bvh), sah_cost(&reference));
        assert!((a - b).abs() <= 1e-9 * b, "{name}: SAH {a} at scale {scale:e}, {b} at unit scale");
    }
}

/// `n` small boxes scattered deterministically over a 10-unit cube, sized 0.05 to
/// `0.05 + max_extra`: test input for the builders' unit tests.
#[cfg(test)]
pub(crate) fn scattered_boxes(n: usize, max_extra: f32) -> Vec<Aabb> {
    (0..n)
        .map(|i| {
            let f = i as f32;
            let c = glam::Vec3::new((f * 0.618).fract(), (f * 0.414).fract(), (f * 0.732).fract()) * 10.0;
            Aabb::new(c, c + glam::Vec3::splat(0.05 + max_extra * (f * 0.3).fract()))
        })
        .collect()
}
