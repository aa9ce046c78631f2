// Shared by every Arbor kernel. Each struct mirrors one in src/gpu/layout.rs (checked by
// tests/gpu_layout.rs); the constants above this file are generated from Rust.

// A BVH node (src/bvh/node.rs): internal nodes have prim_count 0 and children first, first + 1;
// leaves hold prim_ids[first .. first + prim_count].
struct BvhNode {
    aabb_min: vec3<f32>,
    first: u32,
    aabb_max: vec3<f32>,
    prim_count: u32,
}

struct GpuAabb {
    min: vec3<f32>,
    pad0: u32,
    max: vec3<f32>,
    pad1: u32,
}

struct LbvhParams {
    origin: vec3<f32>,
    prim_count: u32,
    scale: vec3<f32>,
    pad: u32,
}

// lampshade's sort item (lampshade::KeyValue).
struct KeyValue {
    key: u32,
    value: u32,
}

// The linear thread index of a 1D kernel dispatched as a 2D grid (GpuContext::dispatch_size).
fn linear_index(gid: vec3<u32>, groups: vec3<u32>) -> u32 {
    return gid.y * groups.x * WORKGROUP_SIZE + gid.x;
}
