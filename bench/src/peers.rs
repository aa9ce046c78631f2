//! External builders as peers for comparison: the obvhs crate's presets, converted into Arbor's
//! layout so that they are traced by the same traversal as ours. [`register`] adds them to the
//! builder names (`obvhs-medium`, ...) through [`arbor::bvh::build::register_external`].
//!
//! The presets run with `max_prims_per_leaf = 1` (no leaf collapse of their own): callers apply
//! Arbor's leaf collapse to every builder alike. They also run with `pre_split = false`: spatial
//! pre-splits put one triangle in several leaves, which Arbor's trees do not allow (every
//! primitive sits in exactly one leaf), so the slower presets are measured without them. obvhs
//! may pad or share boxes, so the converted tree is refitted from our primitive boxes, which
//! makes it pass `validate()` exactly.

use obvhs::BvhBuildParams;
use obvhs::bvh2::Bvh2;

use arbor::bvh::build::{ExternalBuilder, register_external};
use arbor::bvh::{Bvh, BvhNode, INVALID_INDEX, refit};
use arbor::geometry::{Aabb, Triangle};

/// The obvhs presets' names, fastest first.
pub const OBVHS_PRESETS: [&str; 6] = ["fastest", "very-fast", "fast", "medium", "slow", "very-slow"];

/// Registers every obvhs preset as the builder `obvhs-PRESET`.
pub fn register() {
    // `ExternalBuilder::build` is a plain function, so each preset gets its own.
    macro_rules! preset {
        ($name:literal) => {
            register_external(ExternalBuilder {
                name: concat!("obvhs-", $name),
                build: |triangles, prim_aabbs| obvhs_build($name, triangles, prim_aabbs),
            })
        };
    }
    preset!("fastest");
    preset!("very-fast");
    preset!("fast");
    preset!("medium");
    preset!("slow");
    preset!("very-slow");
}

/// Builds with the obvhs preset `preset` (one of [`OBVHS_PRESETS`]).
pub fn obvhs_build(preset: &str, triangles: &[Triangle], prim_aabbs: &[Aabb]) -> Bvh {
    let tris = to_obvhs_triangles(triangles);
    let mut core_time = std::time::Duration::ZERO;
    let theirs = obvhs::bvh2::builder::build_bvh2_from_tris(&tris, peer_params(preset), &mut core_time);
    let mut bvh = from_bvh2(&theirs);
    refit(&mut bvh, prim_aabbs);
    bvh
}

/// Builds with obvhs's preset exactly as obvhs ships it (its own leaf size and pre-split
/// setting, no conversion to Arbor's layout), for memory comparisons. Returns the bytes it keeps
/// to trace: its copy of the triangles and every vector of its `Bvh2` (by capacity).
pub fn obvhs_native_bytes(preset: &str, triangles: &[Triangle]) -> (usize, usize) {
    let params = preset_params(preset);
    let tris = to_obvhs_triangles(triangles);
    let mut core_time = std::time::Duration::ZERO;
    let b = obvhs::bvh2::builder::build_bvh2_from_tris(&tris, params, &mut core_time);
    let bytes = |cap: usize, size: usize| cap * size;
    let bvh = bytes(b.nodes.capacity(), size_of::<obvhs::bvh2::node::Bvh2Node>())
        + bytes(b.primitive_indices.capacity(), 4)
        + bytes(b.primitive_indices_freelist.capacity(), 4)
        + bytes(b.primitives_to_nodes.capacity(), 4)
        + bytes(b.parents.capacity(), 4);
    (bytes(tris.capacity(), size_of::<obvhs::triangle::Triangle>()), bvh)
}

/// The obvhs preset `preset` as Arbor compares with it: one primitive per leaf and no spatial
/// pre-splits (see the module docs).
pub fn peer_params(preset: &str) -> BvhBuildParams {
    BvhBuildParams { max_prims_per_leaf: 1, pre_split: false, ..preset_params(preset) }
}

/// The obvhs preset `preset` names, as obvhs ships it.
fn preset_params(preset: &str) -> BvhBuildParams {
    match preset {
        "fastest" => BvhBuildParams::fastest_build(),
        "very-fast" => BvhBuildParams::very_fast_build(),
        "fast" => BvhBuildParams::fast_build(),
        "medium" => BvhBuildParams::medium_build(),
        "slow" => BvhBuildParams::slow_build(),
        "very-slow" => BvhBuildParams::very_slow_build(),
        other => panic!("unknown obvhs preset {other}"),
    }
}

/// Triangles in obvhs's type.
pub fn to_obvhs_triangles(triangles: &[Triangle]) -> Vec<obvhs::triangle::Triangle> {
    triangles.iter().map(|t| obvhs::triangle::Triangle { v0: t.v0.into(), v1: t.v1.into(), v2: t.v2.into() }).collect()
}

/// obvhs's `Bvh2` in Arbor's layout. Both keep the root at 0 and sibling pairs adjacent, and
/// obvhs packs its pairs from index 1; shifting every other index up by one opens Arbor's
/// padding slot and puts every pair at an even index.
fn from_bvh2(b: &Bvh2) -> Bvh {
    if b.nodes.is_empty() || b.primitive_indices.is_empty() {
        return Bvh::default();
    }
    let slot = |i: u32| if i == 0 { 0 } else { i + 1 };
    let mut nodes: Vec<BvhNode> = Vec::with_capacity(b.nodes.len() + 1);
    for (i, n) in b.nodes.iter().enumerate() {
        let aabb = Aabb::new(n.aabb.min.into(), n.aabb.max.into());
        nodes.push(if n.prim_count > 0 {
            BvhNode::leaf(aabb, n.first_index, n.prim_count)
        } else {
            assert!(n.first_index % 2 == 1, "obvhs put the children of node {i} at an even index");
            BvhNode::internal(aabb, slot(n.first_index))
        });
        if i == 0 && b.nodes.len() > 1 {
            nodes.push(bytemuck::Zeroable::zeroed());
        }
    }
    let mut parents = vec![INVALID_INDEX; nodes.len()];
    for (i, n) in nodes.iter().enumerate() {
        if !n.is_leaf() && i != 1 {
            parents[n.first as usize] = i as u32;
            parents[n.first as usize + 1] = i as u32;
        }
    }
    Bvh { nodes: nodes.into(), parents, prim_ids: b.primitive_indices.clone() }
}
