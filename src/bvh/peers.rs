//! External builders as peers for comparison (feature `peers`): the obvhs crate's presets,
//! converted into Arbor's layout so that they are traced by the same traversal as ours.
//!
//! The presets run with `max_prims_per_leaf = 1` (no leaf collapse of their own): callers apply
//! Arbor's leaf collapse to every builder alike. obvhs may pad or share boxes, so the converted
//! tree is refitted from our primitive boxes, which makes it pass `validate()` exactly.

use obvhs::BvhBuildParams;
use obvhs::bvh2::Bvh2;

use super::{Bvh, BvhNode, INVALID_INDEX, Nodes, refit};
use crate::geometry::{Aabb, Triangle};

/// Builds with the obvhs preset `preset` (one of [`super::builders::OBVHS_PRESETS`]).
pub fn obvhs_build(preset: &str, triangles: &[Triangle], prim_aabbs: &[Aabb]) -> Bvh {
    let mut params = match preset {
        "fastest" => BvhBuildParams::fastest_build(),
        "very-fast" => BvhBuildParams::very_fast_build(),
        "fast" => BvhBuildParams::fast_build(),
        "medium" => BvhBuildParams::medium_build(),
        "slow" => BvhBuildParams::slow_build(),
        "very-slow" => BvhBuildParams::very_slow_build(),
        other => panic!("unknown obvhs preset {other}"),
    };
    params.max_prims_per_leaf = 1;
    let tris: Vec<obvhs::triangle::Triangle> = triangles
        .iter()
        .map(|t| obvhs::triangle::Triangle { v0: t.v0.into(), v1: t.v1.into(), v2: t.v2.into() })
        .collect();
    let mut core_time = std::time::Duration::ZERO;
    let theirs = obvhs::bvh2::builder::build_bvh2_from_tris(&tris, params, &mut core_time);
    let mut bvh = from_bvh2(&theirs);
    refit(&mut bvh, prim_aabbs);
    bvh
}

/// obvhs's `Bvh2` (root 0, children adjacent) in Arbor's layout (root 0, padding 1, pairs at
/// even slots), depth first.
fn from_bvh2(b: &Bvh2) -> Bvh {
    if b.nodes.is_empty() || b.primitive_indices.is_empty() {
        return Bvh::default();
    }
    let node = |n: &obvhs::bvh2::node::Bvh2Node, first: u32| -> BvhNode {
        let aabb = Aabb::new(n.aabb.min.into(), n.aabb.max.into());
        if n.prim_count > 0 { BvhNode::leaf(aabb, first, n.prim_count) } else { BvhNode::internal(aabb, first) }
    };
    let mut out = Bvh { nodes: Nodes::with_capacity(b.nodes.len() + 1), parents: Vec::new(), prim_ids: Vec::new() };
    out.nodes.push(node(&b.nodes[0], 0));
    out.parents.push(INVALID_INDEX);
    if b.nodes[0].prim_count == 0 {
        out.nodes.push(bytemuck::Zeroable::zeroed());
        out.parents.push(INVALID_INDEX);
    }
    // (their index, our slot)
    let mut stack = vec![(0usize, 0usize)];
    while let Some((theirs, ours)) = stack.pop() {
        let n = &b.nodes[theirs];
        if n.prim_count > 0 {
            let first = out.prim_ids.len() as u32;
            let range = n.first_index as usize..(n.first_index + n.prim_count) as usize;
            out.prim_ids.extend_from_slice(&b.primitive_indices[range]);
            out.nodes[ours] = node(n, first);
        } else {
            let left = out.nodes.len();
            out.nodes[ours] = node(n, left as u32);
            for k in 0..2 {
                out.nodes.push(BvhNode::zeroed_leaf());
                out.parents.push(ours as u32);
                stack.push((n.first_index as usize + k, left + k));
            }
        }
    }
    out
}

impl BvhNode {
    fn zeroed_leaf() -> Self {
        bytemuck::Zeroable::zeroed()
    }
}
