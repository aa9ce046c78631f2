// Parallel reinsertion (Meister & Bittner 2018, section 5): the six kernels of one iteration,
// the same algorithm as src/bvh/build/prbvh/.
//   find_best  Algorithm 1, one thread per searching node;
//   lock_max, lock_tie, check  the portable 32-bit locks (the 64-bit ones are in
//              _prbvh_lock64.wgsl, appended when the adapter has 64-bit atomics);
//   reinsert   the winners, which share no node;
//   refit      bottom-up with atomic visit counters;
//   sah_partial, sah_final  the SAH by a two-stage reduction; only it is read back.

@group(0) @binding(0) var<uniform> params: PrbvhParams;
@group(0) @binding(1) var<storage, read_write> nodes: array<BvhNode>;
@group(0) @binding(2) var<storage, read_write> parents: array<u32>;
@group(0) @binding(3) var<storage, read_write> best_out: array<u32>;
@group(0) @binding(4) var<storage, read_write> best_d: array<f32>;
@group(0) @binding(5) var<storage, read_write> lock_bits: array<atomic<u32>>;
@group(0) @binding(6) var<storage, read_write> lock_idx: array<atomic<u32>>;
@group(0) @binding(7) var<storage, read_write> winners: array<u32>;
@group(0) @binding(8) var<storage, read_write> visits: array<atomic<u32>>;
@group(0) @binding(9) var<storage, read_write> sah_sums: array<f32>;
@group(0) @binding(12) var<storage, read_write> refit_boxes: array<atomic<u32>>;

var<workgroup> wg_sum: array<f32, WORKGROUP_SIZE>;

// Half surface area, as the CPU's `area` (the decreases are all halved alike), of the box with
// its coordinates multiplied by params.area_scale: a power of two, exact, that keeps f32 areas
// from overflowing or underflowing in scenes beyond 2^±32 (1 in others), as the CPU search does.
fn area(lo: vec3<f32>, hi: vec3<f32>) -> f32 {
    let e = hi * params.area_scale - lo * params.area_scale;
    return e.x * e.y + e.y * e.z + e.z * e.x;
}

fn node_area(n: u32) -> f32 {
    return area(nodes[n].aabb_min, nodes[n].aabb_max);
}

fn is_leaf(n: u32) -> bool {
    return nodes[n].prim_count > 0u;
}

// Algorithm 1 for `input`: best output (its sibling when nothing is better) and the decrease.
fn find_best_output(input: u32) -> vec2<u32> {
    let in_lo = nodes[input].aabb_min;
    let in_hi = nodes[input].aabb_max;
    let parent = parents[input];
    let a_parent = node_area(parent);
    var pivot_lo = vec3<f32>(3.4e38);
    var pivot_hi = vec3<f32>(-3.4e38);
    let d_bound = a_parent - area(in_lo, in_hi);
    var d_best = 0.0;
    var d = 0.0;
    var out = input ^ 1u;
    var out_best = out;
    var pivot = parent;
    var down = true;
    // The CPU search's bound on visits (src/bvh/build/prbvh/, MAX_VISITS).
    var visits_left = SEARCH_MAX_VISITS;
    loop {
        let out_lo = nodes[out].aabb_min;
        let out_hi = nodes[out].aabb_max;
        let merged = area(min(in_lo, out_lo), max(in_hi, out_hi));
        if (down) {
            visits_left = visits_left - min(visits_left, 1u);
            let d_direct = a_parent - merged;
            if (d_best < d_direct + d) {
                d_best = d_direct + d;
                out_best = out;
            }
            d = d + (area(out_lo, out_hi) - merged);
            if (is_leaf(out) || d_bound + d <= d_best || visits_left == 0u) {
                down = false;
            } else {
                out = nodes[out].first;
            }
        } else {
            d = d - (area(out_lo, out_hi) - merged);
            if (pivot == parents[out]) {
                pivot_lo = min(pivot_lo, out_lo);
                pivot_hi = max(pivot_hi, out_hi);
                out = pivot;
                let a_out = node_area(out);
                if (out != parent) {
                    let d_direct = a_parent - area(min(in_lo, pivot_lo), max(in_hi, pivot_hi));
                    // The pivot's own shrink (src/bvh/build/prbvh/, module docs).
                    let own = a_out - area(pivot_lo, pivot_hi);
                    if (d_best < d_direct + d + own) {
                        d_best = d_direct + d + own;
                        out_best = out;
                    }
                    d = d + own;
                }
                if (out == 0u) {
                    break;
                }
                out = pivot ^ 1u;
                pivot = parents[out];
                down = true;
            } else if (out % 2u == 0u) {
                out = out + 1u;
                down = true;
            } else {
                out = parents[out];
            }
        }
    }
    return vec2<u32>(out_best, bitcast<u32>(d_best));
}

fn node_index(gid: vec3<u32>, groups: vec3<u32>) -> u32 {
    return linear_index(gid, groups);
}

// Node i searches when i ≡ phase (mod μ); others record no move.
@compute @workgroup_size(WORKGROUP_SIZE)
fn find_best(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = node_index(gid, groups);
    if (i >= params.node_count) {
        return;
    }
    best_d[i] = 0.0;
    winners[i] = 0u;
    if (i < 2u || i % params.mu != params.phase) {
        return;
    }
    let r = find_best_output(i);
    let d = bitcast<f32>(r.y);
    if (d > 0.0) {
        best_out[i] = r.x;
        best_d[i] = d;
    }
}

// The six nodes a reinsertion of `i` next to best_out[i] changes (INVALID_INDEX where the
// grandparent or the output's parent does not exist).
fn locked(i: u32) -> array<u32, 6> {
    let parent = parents[i];
    let out = best_out[i];
    var grand = INVALID_INDEX;
    if (parent != INVALID_INDEX) {
        grand = parents[parent];
    }
    return array<u32, 6>(i, i ^ 1u, parent, grand, out, parents[out]);
}

// 32-bit locks, pass 1: the largest decrease per node (positive floats order as their bits).
@compute @workgroup_size(WORKGROUP_SIZE)
fn lock_max(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = node_index(gid, groups);
    if (i >= params.node_count || !(best_d[i] > 0.0)) {
        return;
    }
    let bits = bitcast<u32>(best_d[i]);
    let ns = locked(i);
    for (var k = 0u; k < 6u; k = k + 1u) {
        if (ns[k] != INVALID_INDEX) {
            atomicMax(&lock_bits[ns[k]], bits);
        }
    }
}

// 32-bit locks, pass 2: among the claims with that decrease, the highest index (+1, so that 0
// means none) wins the node, as the 64-bit key (decrease, index) orders them.
@compute @workgroup_size(WORKGROUP_SIZE)
fn lock_tie(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = node_index(gid, groups);
    if (i >= params.node_count || !(best_d[i] > 0.0)) {
        return;
    }
    let bits = bitcast<u32>(best_d[i]);
    let ns = locked(i);
    for (var k = 0u; k < 6u; k = k + 1u) {
        if (ns[k] != INVALID_INDEX && atomicLoad(&lock_bits[ns[k]]) == bits) {
            atomicMax(&lock_idx[ns[k]], i + 1u);
        }
    }
}

// A reinsertion goes ahead only if it holds every lock it claimed.
@compute @workgroup_size(WORKGROUP_SIZE)
fn check(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = node_index(gid, groups);
    if (i >= params.node_count || !(best_d[i] > 0.0)) {
        return;
    }
    let bits = bitcast<u32>(best_d[i]);
    let ns = locked(i);
    var won = 1u;
    for (var k = 0u; k < 6u; k = k + 1u) {
        let n = ns[k];
        if (n != INVALID_INDEX && (atomicLoad(&lock_bits[n]) != bits || atomicLoad(&lock_idx[n]) != i + 1u)) {
            won = 0u;
        }
    }
    winners[i] = won;
}

fn adopt(node: BvhNode, slot: u32) {
    if (node.prim_count == 0u) {
        parents[node.first] = slot;
        parents[node.first + 1u] = slot;
    }
}

// The reinsertion of src/bvh/build/prbvh/ `reinsert_shared`: the sibling takes the parent's slot,
// the freed pair takes the output and the input under a new node in the output's slot.
@compute @workgroup_size(WORKGROUP_SIZE)
fn reinsert(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = node_index(gid, groups);
    if (i >= params.node_count || winners[i] == 0u) {
        return;
    }
    let output = best_out[i];
    let n = i;
    let s = i ^ 1u;
    let q = parents[n];
    let n_node = nodes[n];
    let s_node = nodes[s];
    nodes[q] = s_node;
    adopt(s_node, q);
    var o = output;
    if (output == s) {
        o = q;
    }
    let o_node = nodes[o];
    let e = n & ~1u;
    nodes[e] = o_node;
    adopt(o_node, e);
    nodes[e + 1u] = n_node;
    adopt(n_node, e + 1u);
    parents[e] = o;
    parents[e + 1u] = o;
    nodes[o] = BvhNode(min(o_node.aabb_min, n_node.aabb_min), e, max(o_node.aabb_max, n_node.aabb_max), 0u);
}

// Bottom-up refit from every leaf (the padding node, index 1, is not one).
@compute @workgroup_size(WORKGROUP_SIZE)
fn refit(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = node_index(gid, groups);
    if (i >= params.node_count || i == 1u || !is_leaf(i)) {
        return;
    }
    refit_from(i);
}

fn reduce_sum(lid: u32) {
    for (var stride = WORKGROUP_SIZE / 2u; stride > 0u; stride = stride / 2u) {
        workgroupBarrier();
        if (lid < stride) {
            wg_sum[lid] = wg_sum[lid] + wg_sum[lid + stride];
        }
    }
    workgroupBarrier();
}

// SAH, stage 1: each node's cost times its half area, summed per workgroup.
@compute @workgroup_size(WORKGROUP_SIZE)
fn sah_partial(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>,
               @builtin(local_invocation_index) lid: u32, @builtin(workgroup_id) wid: vec3<u32>) {
    let i = node_index(gid, groups);
    var v = 0.0;
    if (i < params.node_count && i != 1u) {
        var w = params.cost_traversal;
        if (is_leaf(i)) {
            w = params.cost_intersection * f32(nodes[i].prim_count);
        }
        v = w * node_area(i);
    }
    wg_sum[lid] = v;
    reduce_sum(lid);
    if (lid == 0u) {
        sah_sums[wid.y * groups.x + wid.x] = wg_sum[0];
    }
}

// SAH, stage 2: one workgroup sums the params.partial_count partials and divides by the
// root's half area into sah_sums[0].
@compute @workgroup_size(WORKGROUP_SIZE)
fn sah_final(@builtin(local_invocation_index) lid: u32) {
    var v = 0.0;
    for (var k = lid; k < params.partial_count; k = k + WORKGROUP_SIZE) {
        v = v + sah_sums[k];
    }
    wg_sum[lid] = v;
    reduce_sum(lid);
    if (lid == 0u) {
        let root = node_area(0u);
        if (root > 0.0) {
            sah_sums[0] = wg_sum[0] / root;
        } else {
            // Every box is a point: each node counts its weight alone, as on the CPU (the tree
            // has one primitive per leaf: n leaves, n - 1 internal nodes, node_count = 2n).
            let n = f32(params.node_count / 2u);
            sah_sums[0] = params.cost_traversal * (n - 1.0) + params.cost_intersection * n;
        }
    }
}
