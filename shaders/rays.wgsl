// Ray queries (src/gpu/trace.rs, trace_rays): the path tracer's traversal on given rays, for
// bvh-bench and the tests that compare the GPU's hits with the CPU's. params.width is the
// number of rays, params.height 0 for closest hits and 1 for any hit.

// Two vec4 a ray: (origin, t_max), (direction, the triangle position to skip as bits).
@group(0) @binding(11) var<storage, read> query_rays: array<vec4<f32>>;
// One vec4 a ray: closest: (t as bits, primitive id or INVALID_INDEX, u, v as bits); any: (1
// if anything is hit, else 0, 0, 0, 0).
@group(0) @binding(12) var<storage, read_write> query_hits: array<vec4<u32>>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn trace_rays(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = gid.x + gid.y * groups.x * WORKGROUP_SIZE;
    if i >= params.width {
        return;
    }
    let a = query_rays[2u * i];
    let b = query_rays[2u * i + 1u];
    let ray = Ray(a.xyz, b.xyz);
    let skip = vec2<u32>(0u, bitcast<u32>(b.w));
    if params.height != 0u {
        query_hits[i] = vec4<u32>(select(0u, 1u, occluded(ray, a.w, skip)), 0u, 0u, 0u);
        return;
    }
    let h = closest_hit(ray, a.w, skip);
    var prim = INVALID_INDEX;
    if h.index != INVALID_INDEX {
        prim = prim_ids[h.index];
    }
    query_hits[i] = vec4<u32>(bitcast<u32>(h.t), prim, bitcast<u32>(h.u), bitcast<u32>(h.v));
}
