// LBVH on the GPU (Karras 2012), the same algorithm and the same tree as src/bvh/build/lbvh.rs:
// centroid bounds, 63-bit Morton codes split in two u32 halves (sorted by two stable passes of
// lampshade's radix sort: low half, then high half), the radix tree with each internal node's
// children written as one sibling pair, and boxes bottom-up with atomic visit counters.

@group(0) @binding(0) var<uniform> params: LbvhParams;
@group(0) @binding(1) var<storage, read> prim_aabbs: array<GpuAabb>;
@group(0) @binding(2) var<storage, read_write> partial_bounds: array<GpuAabb>;
@group(0) @binding(3) var<storage, read_write> hi_codes: array<u32>;
@group(0) @binding(4) var<storage, read_write> lo_codes: array<u32>;
@group(0) @binding(5) var<storage, read_write> keys: array<KeyValue>;
@group(0) @binding(6) var<storage, read> sorted: array<KeyValue>;
@group(0) @binding(7) var<storage, read_write> prim_ids: array<u32>;
@group(0) @binding(8) var<storage, read_write> code_hi: array<u32>;
@group(0) @binding(9) var<storage, read_write> code_lo: array<u32>;
@group(0) @binding(10) var<storage, read_write> nodes: array<BvhNode>;
@group(0) @binding(11) var<storage, read_write> parents: array<u32>;
@group(0) @binding(12) var<storage, read_write> leaf_slots: array<u32>;
@group(0) @binding(13) var<storage, read_write> visits: array<atomic<u32>>;
@group(0) @binding(14) var<storage, read_write> centroids: array<vec4<f32>>;
@group(0) @binding(15) var<storage, read_write> refit_boxes: array<atomic<u32>>;

var<workgroup> wg_min: array<vec3<f32>, WORKGROUP_SIZE>;
var<workgroup> wg_max: array<vec3<f32>, WORKGROUP_SIZE>;

// Halve before adding, as Aabb::center does, so that the result is the CPU's bit for bit.
fn centroid(b: GpuAabb) -> vec3<f32> {
    return b.min * 0.5 + b.max * 0.5;
}

// Tree reduction of wg_min/wg_max into element 0. Called in uniform control flow.
fn reduce_workgroup(lid: u32) {
    for (var stride = WORKGROUP_SIZE / 2u; stride > 0u; stride = stride / 2u) {
        workgroupBarrier();
        if (lid < stride) {
            wg_min[lid] = min(wg_min[lid], wg_min[lid + stride]);
            wg_max[lid] = max(wg_max[lid], wg_max[lid + stride]);
        }
    }
    workgroupBarrier();
}

const BIG: f32 = 3.40282347e38;

// Centroids, and their bounds, stage 1: one partial box per workgroup (partial_bounds[workgroup]).
@compute @workgroup_size(WORKGROUP_SIZE)
fn bounds_partial(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>,
                  @builtin(local_invocation_index) lid: u32, @builtin(workgroup_id) wid: vec3<u32>) {
    let i = linear_index(gid, groups);
    var lo = vec3<f32>(BIG);
    var hi = vec3<f32>(-BIG);
    if (i < params.prim_count) {
        let c = centroid(prim_aabbs[i]);
        // Stored, and read back by `morton`: a kernel boundary that no compiler reassociates
        // across (lavapipe's LLVM folds `min*0.5 + max*0.5 - origin` into one fused expression,
        // which rounds differently from the CPU).
        centroids[i] = vec4<f32>(c, 0.0);
        lo = c;
        hi = c;
    }
    wg_min[lid] = lo;
    wg_max[lid] = hi;
    reduce_workgroup(lid);
    if (lid == 0u) {
        let w = wid.y * groups.x + wid.x;
        partial_bounds[w] = GpuAabb(wg_min[0], 0u, wg_max[0], 0u);
    }
}

// Centroid bounds, stage 2: one workgroup folds params.pad partial boxes into partial_bounds[0].
@compute @workgroup_size(WORKGROUP_SIZE)
fn bounds_final(@builtin(local_invocation_index) lid: u32) {
    var lo = vec3<f32>(BIG);
    var hi = vec3<f32>(-BIG);
    for (var k = lid; k < params.pad; k = k + WORKGROUP_SIZE) {
        lo = min(lo, partial_bounds[k].min);
        hi = max(hi, partial_bounds[k].max);
    }
    wg_min[lid] = lo;
    wg_max[lid] = hi;
    reduce_workgroup(lid);
    if (lid == 0u) {
        partial_bounds[0] = GpuAabb(wg_min[0], 0u, wg_max[0], 0u);
    }
}

// Grid coordinate of one axis, as MortonQuantizer::code: truncation, NaN to 0, clamped.
fn quantize(v: f32) -> u32 {
    let cells_max = (1u << MORTON_BITS) - 1u;
    if (!(v >= 0.0)) {
        return 0u;
    }
    if (v >= 4294967040.0) {
        return cells_max;
    }
    return min(u32(v), cells_max);
}

// Morton code (bit 3k+2 from x's bit k, 3k+1 from y, 3k from z), as (high, low) halves.
@compute @workgroup_size(WORKGROUP_SIZE)
fn morton(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = linear_index(gid, groups);
    if (i >= params.prim_count) {
        return;
    }
    // The scale is a power of two, so however this is fused, it rounds once, as the CPU does.
    let q = (centroids[i].xyz - params.origin) * params.scale;
    let g = vec3<u32>(quantize(q.x), quantize(q.y), quantize(q.z));
    var hi = 0u;
    var lo = 0u;
    for (var b = 0u; b < MORTON_BITS; b = b + 1u) {
        let bits = array<u32, 3>((g.z >> b) & 1u, (g.y >> b) & 1u, (g.x >> b) & 1u);
        for (var a = 0u; a < 3u; a = a + 1u) {
            let pos = 3u * b + a;
            if (pos < 32u) {
                lo = lo | (bits[a] << pos);
            } else {
                hi = hi | (bits[a] << (pos - 32u));
            }
        }
    }
    hi_codes[i] = hi;
    lo_codes[i] = lo;
    keys[i] = KeyValue(lo, i);
}

// Between the two sort passes: the high halves, in the order the low halves sorted to.
@compute @workgroup_size(WORKGROUP_SIZE)
fn gather_hi(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let k = linear_index(gid, groups);
    if (k >= params.prim_count) {
        return;
    }
    let p = sorted[k].value;
    keys[k] = KeyValue(hi_codes[p], p);
}

// After both passes: primitive ids and full codes in key order.
@compute @workgroup_size(WORKGROUP_SIZE)
fn unpack(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let k = linear_index(gid, groups);
    if (k >= params.prim_count) {
        return;
    }
    let p = sorted[k].value;
    prim_ids[k] = p;
    code_hi[k] = hi_codes[p];
    code_lo[k] = lo_codes[p];
}

// δ(i, j) of Karras: the common prefix of keys i and j, -1 outside; ties broken by the index.
fn delta(i: i32, j: i32) -> i32 {
    let n = i32(params.prim_count);
    if (j < 0 || j >= n) {
        return -1;
    }
    let xh = code_hi[i] ^ code_hi[j];
    if (xh != 0u) {
        return i32(countLeadingZeros(xh));
    }
    let xl = code_lo[i] ^ code_lo[j];
    if (xl != 0u) {
        return 32 + i32(countLeadingZeros(xl));
    }
    return 64 + i32(countLeadingZeros(u32(i) ^ u32(j)));
}

fn leaf_node(k: u32) -> BvhNode {
    let b = prim_aabbs[prim_ids[k]];
    return BvhNode(b.min, k, b.max, 1u);
}

// The radix tree (Karras 2012, Figure 4): internal node i writes its children at slots 2 + 2i
// and 3 + 2i, leaves with their primitive's box; thread 0 also writes the root and padding.
@compute @workgroup_size(WORKGROUP_SIZE)
fn radix_tree(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let iu = linear_index(gid, groups);
    if (iu + 1u >= params.prim_count) {
        return;
    }
    let i = i32(iu);
    var d = 1;
    if (delta(i, i + 1) < delta(i, i - 1)) {
        d = -1;
    }
    let delta_min = delta(i, i - d);
    var l_max = 2;
    while (delta(i, i + l_max * d) > delta_min) {
        l_max = l_max * 2;
    }
    var l = 0;
    for (var t = l_max / 2; t >= 1; t = t / 2) {
        if (delta(i, i + (l + t) * d) > delta_min) {
            l = l + t;
        }
    }
    let j = i + l * d;
    let delta_node = delta(i, j);
    var s = 0;
    var step = l;
    loop {
        step = (step + 1) / 2;
        if (delta(i, i + (s + step) * d) > delta_node) {
            s = s + step;
        }
        if (step <= 1) {
            break;
        }
    }
    let split = u32(i + s * d + min(d, 0));
    let left_is_leaf = min(i, j) == i32(split);
    let right_is_leaf = max(i, j) == i32(split) + 1;
    let slot = 2u + 2u * iu;
    if (iu == 0u) {
        nodes[0] = BvhNode(vec3<f32>(0.0), 2u, vec3<f32>(0.0), 0u);
        nodes[1] = BvhNode(vec3<f32>(0.0), 0u, vec3<f32>(0.0), 0u);
        parents[0] = INVALID_INDEX;
        parents[1] = INVALID_INDEX;
        parents[2] = 0u;
        parents[3] = 0u;
    }
    for (var k = 0u; k < 2u; k = k + 1u) {
        let child = split + k;
        var is_leaf = left_is_leaf;
        if (k == 1u) {
            is_leaf = right_is_leaf;
        }
        if (is_leaf) {
            leaf_slots[child] = slot + k;
            nodes[slot + k] = leaf_node(child);
        } else {
            let grandchildren = 2u + 2u * child;
            parents[grandchildren] = slot + k;
            parents[grandchildren + 1u] = slot + k;
            nodes[slot + k] = BvhNode(vec3<f32>(0.0), grandchildren, vec3<f32>(0.0), 0u);
        }
    }
}

// Boxes bottom-up from every leaf (`_refit.wgsl`).
@compute @workgroup_size(WORKGROUP_SIZE)
fn refit(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let k = linear_index(gid, groups);
    if (k >= params.prim_count) {
        return;
    }
    refit_from(leaf_slots[k]);
}
