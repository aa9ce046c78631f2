//! The bounding volume hierarchy: layout, builders, cost, validation and traversal.

pub mod binned_sah;
pub mod lbvh;
mod node;
mod parallel;
pub mod sah;
mod traverse;
mod validate;

pub use node::{Bvh, BvhNode, INVALID_INDEX};
pub use sah::{CollapseConfig, SahCosts, collapse_leaves, sah_cost, sah_cost_with};
pub use traverse::{CULL_ABS_ULPS, CULL_SCALE, Hit, brute_force_any, brute_force_closest, hit_point_and_normal};
pub use validate::{BvhStats, ValidationError, validate};

use rayon::prelude::*;

use crate::geometry::Aabb;

/// Recomputes every box bottom-up in parallel from the primitives' boxes, keeping the topology
/// (Karras 2012, section 4; the refit step of Meister & Bittner 2018, section 5).
pub fn refit(bvh: &mut Bvh, prim_aabbs: &[Aabb]) {
    let mut boxes = vec![Aabb::EMPTY; bvh.nodes.len()];
    {
        let (nodes, prim_ids) = (&bvh.nodes, &bvh.prim_ids);
        parallel::bottom_up(
            &bvh.parents,
            |i| (!nodes[i].is_leaf()).then_some(nodes[i].first as usize),
            &mut boxes,
            |i| leaf_bounds(&prim_ids[nodes[i].prim_range()], prim_aabbs),
            |_, l, r| l.union(r),
        );
    }
    bvh.nodes.par_iter_mut().zip(boxes.par_iter()).with_min_len(4096).for_each(|(n, b)| n.set_aabb(*b));
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
