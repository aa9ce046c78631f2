// Shared by every Arbor kernel. The constants and the shared structs above this file are
// generated from src/gpu/layout.rs (checked by tests/gpu_layout.rs).

// lampshade's sort item (lampshade::KeyValue).
struct KeyValue {
    key: u32,
    value: u32,
}

// The linear thread index of a 1D kernel dispatched as a 2D grid (GpuContext::dispatch_size).
fn linear_index(gid: vec3<u32>, groups: vec3<u32>) -> u32 {
    return gid.y * groups.x * WORKGROUP_SIZE + gid.x;
}

