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

struct PrbvhParams {
    node_count: u32,
    mu: u32,
    phase: u32,
    partial_count: u32,
    cost_traversal: f32,
    cost_intersection: f32,
    area_scale: f32,
    pad1: u32,
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

// ---------------------------------------------------------------------------------------------
// Path tracing (src/gpu/trace.rs, shaders/bsdf.wgsl, shaders/trace.wgsl).

// A triangle in leaf order, with its material and light density (0 for non-lights).
struct GpuTriangle {
    v0: vec3<f32>,
    material: u32,
    v1: vec3<f32>,
    light_pdf: f32,
    v2: vec3<f32>,
    pad: u32,
}

// albedo: diffuse albedo, Schlick F0, or the real part of a complex index (k its imaginary part).
struct GpuMaterial {
    albedo: vec3<f32>,
    kind: u32,
    k: vec3<f32>,
    alpha: f32,
    emission: vec3<f32>,
    ior: f32,
    flags: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

// An emissive triangle: CDF of power up to and including it, density per unit area.
struct GpuLight {
    v0: vec3<f32>,
    cdf: f32,
    v1: vec3<f32>,
    pdf_area: f32,
    v2: vec3<f32>,
    two_sided: u32,
    normal: vec3<f32>,
    pad0: u32,
    radiance: vec3<f32>,
    pad1: u32,
}

// A pixel's running sums of (sample - shift), shift being its first finite sample.
struct GpuPixel {
    shift: vec3<f32>,
    count: u32,
    sum: vec3<f32>,
    non_finite: u32,
    sum_sq: vec3<f32>,
    rays: u32,
}

struct TraceParams {
    cam_origin: vec3<f32>,
    width: u32,
    cam_forward: vec3<f32>,
    height: u32,
    cam_right: vec3<f32>,
    tan_x: f32,
    cam_up: vec3<f32>,
    tan_y: f32,
    environment: vec3<f32>,
    lens_radius: f32,
    focus_distance: f32,
    clamp: f32,
    seed_lo: u32,
    seed_hi: u32,
    sample_start: u32,
    sample_count: u32,
    max_depth: u32,
    light_count: u32,
}
