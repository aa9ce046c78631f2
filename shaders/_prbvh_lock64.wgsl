// Appended to prbvh.wgsl where the adapter has SHADER_INT64_ATOMIC_MIN_MAX: one atomicMax of
// the 64-bit key (decrease bits << 32 | index) per node decides each lock, as on the CPU.

@group(0) @binding(10) var<storage, read_write> locks64: array<atomic<u64>>;
// The same buffer, read as (low, high) words by `check64` (a separate dispatch): naga allows
// only atomicMin/atomicMax on 64-bit atomics under SHADER_INT64_ATOMIC_MIN_MAX, not loads.
@group(0) @binding(11) var<storage, read> lock_words: array<vec2<u32>>;

fn key64(i: u32) -> u64 {
    return (u64(bitcast<u32>(best_d[i])) << 32u) | u64(i);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn lock64(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = node_index(gid, groups);
    if (i >= params.node_count || !(best_d[i] > 0.0)) {
        return;
    }
    let key = key64(i);
    let ns = locked(i);
    for (var k = 0u; k < 6u; k = k + 1u) {
        if (ns[k] != INVALID_INDEX) {
            atomicMax(&locks64[ns[k]], key);
        }
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn check64(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = node_index(gid, groups);
    if (i >= params.node_count || !(best_d[i] > 0.0)) {
        return;
    }
    let key = vec2<u32>(i, bitcast<u32>(best_d[i]));
    let ns = locked(i);
    var won = 1u;
    for (var k = 0u; k < 6u; k = k + 1u) {
        if (ns[k] != INVALID_INDEX && any(lock_words[ns[k]] != key)) {
            won = 0u;
        }
    }
    winners[i] = won;
}
