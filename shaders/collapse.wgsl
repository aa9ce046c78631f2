// The collapse into the compressed 8-wide tree on the GPU (src/gpu/wide.rs, collapse_on_device):
// the SAH table of src/bvh/wide_sah.rs bottom-up over the GPU's binary tree (one primitive a
// leaf), then the wide nodes top-down, one dispatch per level, encoded as CompressedBvh::new
// encodes them. Two entry points: `collapse_costs` and `collapse_expand`.

@group(0) @binding(0) var<storage, read> params: CollapseParams;
@group(0) @binding(1) var<storage, read> nodes: array<BvhNode>;
@group(0) @binding(2) var<storage, read> parents: array<u32>;
@group(0) @binding(3) var<storage, read_write> visits: array<atomic<u32>>;
// Each node's table passed to its parent's thread: eight costs and the primitive count, as the
// complement of their bits (0: not written yet), through atomics only (see _refit.wgsl).
@group(0) @binding(4) var<storage, read_write> published: array<atomic<u32>>;
// Each node's choices: x = the best split k of D(n, j) in three bits at 3 (j - 2), and bit
// 21 + k whether C(n, k + 1) is D(n, k + 1); y = bit 0 whether C(n, 1) is the leaf, and the
// node's primitive count above it.
@group(0) @binding(5) var<storage, read_write> decisions: array<vec2<u32>>;
// Wide nodes to make at this level: (binary node, index of the wide node), and the next level's.
@group(0) @binding(6) var<storage, read> queue_in: array<vec2<u32>>;
@group(0) @binding(7) var<storage, read_write> queue_out: array<vec2<u32>>;
// Wide nodes allocated, triangle positions allocated, entries of queue_out.
@group(0) @binding(8) var<storage, read_write> counters: array<atomic<u32>>;
@group(0) @binding(9) var<storage, read_write> out_nodes: array<vec4<u32>>;
@group(0) @binding(10) var<storage, read_write> out_prims: array<u32>;
@group(0) @binding(11) var<storage, read> prim_ids: array<u32>;

const WIDTH: u32 = 8u;
const TABLE_WORDS: u32 = 9u;
const COLLAPSE_SPIN_LIMIT: u32 = 1048576u;
const F32_MAX: f32 = 3.40282347e38;

// A box's half area over the root's, on extents scaled by params.area_scale (no overflow).
fn area(n: u32) -> f32 {
    let e = max(nodes[n].aabb_max - nodes[n].aabb_min, vec3<f32>(0.0)) * params.area_scale;
    return (e.x * e.y + e.y * e.z + e.z * e.x) * params.inv_root_area;
}

struct Table {
    cost: array<f32, 8>,
    choices: vec2<u32>,
}

fn leaf_cost(n: u32, count: u32) -> f32 {
    if count > params.max_leaf {
        return F32_MAX;
    }
    return area(n) * f32(count) * params.cost_prim;
}

// wide_sah.rs's Entry::new for node n from its children's costs.
fn inner_table(n: u32, count: u32, cl: array<f32, 8>, cr: array<f32, 8>) -> Table {
    var t: Table;
    var d: array<f32, 9>;
    var x = 0u;
    for (var j = 2u; j <= WIDTH; j++) {
        d[j] = F32_MAX;
        var best_k = 1u;
        var best = F32_MAX;
        for (var k = 1u; k < j; k++) {
            let c = min(cl[k - 1u] + cr[j - k - 1u], F32_MAX);
            if c < best {
                best = c;
                best_k = k;
            }
        }
        d[j] = best;
        x |= best_k << (3u * (j - 2u));
    }
    let leaf = leaf_cost(n, count);
    let inner = min(area(n) * params.cost_node + d[WIDTH], F32_MAX);
    var y = 0u;
    if leaf <= inner {
        y = 1u;
    }
    t.cost[0] = min(leaf, inner);
    for (var k = 1u; k < WIDTH; k++) {
        if d[k + 1u] < t.cost[k - 1u] {
            x |= 1u << (21u + k);
            t.cost[k] = d[k + 1u];
        } else {
            t.cost[k] = t.cost[k - 1u];
        }
    }
    t.choices = vec2<u32>(x, y);
    return t;
}

fn publish(n: u32, cost: array<f32, 8>, count: u32) {
    let b = TABLE_WORDS * n;
    for (var k = 0u; k < 8u; k++) {
        atomicStore(&published[b + k], ~bitcast<u32>(cost[k]));
    }
    atomicStore(&published[b + 8u], ~count);
}

fn take(i: u32) -> u32 {
    var w = atomicLoad(&published[i]);
    for (var spin = 0u; w == 0u && spin < COLLAPSE_SPIN_LIMIT; spin++) {
        w = atomicLoad(&published[i]);
    }
    atomicStore(&published[i], 0u);
    return ~w;
}

// Bottom-up from every leaf: the second child's thread to arrive at a node computes its table.
@compute @workgroup_size(WORKGROUP_SIZE)
fn collapse_costs(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = gid.x + gid.y * groups.x * WORKGROUP_SIZE;
    if i >= params.node_count || i == 1u || nodes[i].prim_count == 0u {
        return;
    }
    var node = i;
    var count = nodes[i].prim_count;
    var cost: array<f32, 8>;
    let c = leaf_cost(i, count);
    for (var k = 0u; k < 8u; k++) {
        cost[k] = c;
    }
    decisions[i] = vec2<u32>(0u, 1u | (count << 1u));
    loop {
        if node == 0u {
            break;
        }
        publish(node, cost, count);
        let p = parents[node];
        if atomicAdd(&visits[p], 1u) == 0u {
            break;
        }
        let first = nodes[p].first;
        let sibling = select(first, first + 1u, node == first);
        var other: array<f32, 8>;
        for (var k = 0u; k < 8u; k++) {
            other[k] = bitcast<f32>(take(TABLE_WORDS * sibling + k));
        }
        count += take(TABLE_WORDS * sibling + 8u);
        for (var k = 0u; k < TABLE_WORDS; k++) {
            atomicStore(&published[TABLE_WORDS * node + k], 0u);
        }
        var t: Table;
        if node == first {
            t = inner_table(p, count, cost, other);
        } else {
            t = inner_table(p, count, other, cost);
        }
        decisions[p] = vec2<u32>(t.choices.x, t.choices.y | (count << 1u));
        cost = t.cost;
        node = p;
    }
}

fn split_of(n: u32, j: u32) -> u32 {
    return (decisions[n].x >> (3u * (j - 2u))) & 7u;
}

fn dist_of(n: u32, k: u32) -> bool {
    return ((decisions[n].x >> (21u + k)) & 1u) != 0u;
}

fn is_leaf_choice(n: u32) -> bool {
    return nodes[n].prim_count > 0u || (decisions[n].y & 1u) != 0u;
}

fn biased_exponent(lo: f32, hi: f32) -> u32 {
    let extent = hi - lo;
    var e = -126;
    if extent > 0.0 {
        e = clamp(i32(ceil(log2(extent / 255.0))), -126, 127);
    }
    // Checked in the decoder's arithmetic; log2 may be a little off either way.
    while e > -126 && lo + 255.0 * bitcast<f32>(u32(e + 126) << 23u) >= hi {
        e -= 1;
    }
    while e < 127 && lo + 255.0 * bitcast<f32>(u32(e + 127) << 23u) < hi {
        e += 1;
    }
    return u32(e + 127);
}

fn quantize_lo(lo: f32, s: f32, x: f32) -> u32 {
    var q = u32(clamp(floor((x - lo) / s), 0.0, 255.0));
    while q > 0u && lo + f32(q) * s > x {
        q -= 1u;
    }
    return q;
}

fn quantize_hi(lo: f32, s: f32, x: f32) -> u32 {
    var q = u32(clamp(ceil((x - lo) / s), 0.0, 255.0));
    while q < 255u && lo + f32(q) * s < x {
        q += 1u;
    }
    return q;
}

// One wide node per thread: its lanes from the table, slots by octant, boxes quantised, children
// and triangle positions allocated, the next level's wide nodes queued.
@compute @workgroup_size(WORKGROUP_SIZE)
fn collapse_expand(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let q_index = gid.x + gid.y * groups.x * WORKGROUP_SIZE;
    if q_index >= params.queue_len {
        return;
    }
    let entry = queue_in[q_index];
    let root = entry.x;
    let at = entry.y;
    // The lanes, as CompressedBvh::new reads the table (wide_sah::collapse).
    var lane_node: array<u32, 8>;
    var lanes = 0u;
    var stack: array<vec2<u32>, 16>;
    var sp = 0u;
    let first = nodes[root].first;
    let k0 = split_of(root, WIDTH);
    stack[0] = vec2<u32>(first + 1u, WIDTH - k0);
    stack[1] = vec2<u32>(first, k0);
    sp = 2u;
    while sp > 0u {
        sp -= 1u;
        let w = stack[sp];
        let i = w.x;
        let j = w.y;
        if j >= 2u && nodes[i].prim_count == 0u && dist_of(i, j - 1u) {
            let f = nodes[i].first;
            let k = split_of(i, j);
            stack[sp] = vec2<u32>(f + 1u, j - k);
            stack[sp + 1u] = vec2<u32>(f, k);
            sp += 2u;
        } else if j >= 2u {
            stack[sp] = vec2<u32>(i, j - 1u);
            sp += 1u;
        } else if lanes < 8u {
            lane_node[lanes] = i;
            lanes += 1u;
        }
    }
    // The node's box and each lane's slot (wide.rs's assign_slots).
    var lo = vec3<f32>(F32_MAX);
    var hi = vec3<f32>(-F32_MAX);
    for (var l = 0u; l < lanes; l++) {
        lo = min(lo, nodes[lane_node[l]].aabb_min);
        hi = max(hi, nodes[lane_node[l]].aabb_max);
    }
    let centre = (lo + hi) * 0.5;
    var slot_lane: array<u32, 8>;
    for (var s = 0u; s < 8u; s++) {
        slot_lane[s] = INVALID_INDEX;
    }
    var placed = 0u;
    for (var round = 0u; round < lanes; round++) {
        var best = -F32_MAX;
        var pick_l = INVALID_INDEX;
        var pick_s = 0u;
        for (var l = 0u; l < lanes; l++) {
            if (placed & (1u << l)) != 0u {
                continue;
            }
            let n = lane_node[l];
            let d = (nodes[n].aabb_min + nodes[n].aabb_max) * 0.5 - centre;
            for (var s = 0u; s < 8u; s++) {
                if slot_lane[s] != INVALID_INDEX {
                    continue;
                }
                let c = select(d.x, -d.x, (s & 1u) != 0u) + select(d.y, -d.y, (s & 2u) != 0u)
                    + select(d.z, -d.z, (s & 4u) != 0u);
                if pick_l == INVALID_INDEX || c > best {
                    best = c;
                    pick_l = l;
                    pick_s = s;
                }
            }
        }
        slot_lane[pick_s] = pick_l;
        placed |= 1u << pick_l;
    }
    let ex = biased_exponent(lo.x, hi.x);
    let ey = biased_exponent(lo.y, hi.y);
    let ez = biased_exponent(lo.z, hi.z);
    let scale = vec3<f32>(bitcast<f32>(ex << 23u), bitcast<f32>(ey << 23u), bitcast<f32>(ez << 23u));
    // Inner lanes and triangles, counted first to allocate them.
    var inner = 0u;
    var tris = 0u;
    for (var l = 0u; l < lanes; l++) {
        if is_leaf_choice(lane_node[l]) {
            tris += decisions[lane_node[l]].y >> 1u;
        } else {
            inner += 1u;
        }
    }
    let child_base = atomicAdd(&counters[0], inner);
    let tri_base = atomicAdd(&counters[1], tris);
    var imask = 0u;
    var meta_words = vec2<u32>(0u, 0u);
    var q_words: array<u32, 12>;
    var next_child = child_base;
    var offset = 0u;
    for (var s = 0u; s < 8u; s++) {
        let word = s / 4u;
        let shift = 8u * (s % 4u);
        let l = slot_lane[s];
        if l == INVALID_INDEX {
            // Empty: an inverted box, no bits.
            q_words[word] |= 255u << shift;
            q_words[2u + word] |= 255u << shift;
            q_words[4u + word] |= 255u << shift;
            continue;
        }
        let n = lane_node[l];
        let b_lo = nodes[n].aabb_min;
        let b_hi = nodes[n].aabb_max;
        q_words[word] |= quantize_lo(lo.x, scale.x, b_lo.x) << shift;
        q_words[2u + word] |= quantize_lo(lo.y, scale.y, b_lo.y) << shift;
        q_words[4u + word] |= quantize_lo(lo.z, scale.z, b_lo.z) << shift;
        q_words[6u + word] |= quantize_hi(lo.x, scale.x, b_hi.x) << shift;
        q_words[8u + word] |= quantize_hi(lo.y, scale.y, b_hi.y) << shift;
        q_words[10u + word] |= quantize_hi(lo.z, scale.z, b_hi.z) << shift;
        var lane_meta = 0u;
        if is_leaf_choice(n) {
            // Its primitives, left to right (at most WIDE_MAX_LEAF leaves below it).
            var count = 0u;
            var walk: array<u32, 8>;
            var wp = 1u;
            walk[0] = n;
            while wp > 0u {
                wp -= 1u;
                let m = walk[wp];
                if nodes[m].prim_count > 0u {
                    for (var p = 0u; p < nodes[m].prim_count; p++) {
                        out_prims[tri_base + offset + count] = prim_ids[nodes[m].first + p];
                        count += 1u;
                    }
                } else if wp + 2u <= 8u {
                    walk[wp] = nodes[m].first + 1u;
                    walk[wp + 1u] = nodes[m].first;
                    wp += 2u;
                }
            }
            lane_meta = (((1u << count) - 1u) << 5u) | offset;
            offset += count;
        } else {
            imask |= 1u << s;
            lane_meta = 0x20u | (24u + s);
            let q = atomicAdd(&counters[2], 1u);
            queue_out[q] = vec2<u32>(n, next_child);
            next_child += 1u;
        }
        if word == 0u {
            meta_words.x |= lane_meta << shift;
        } else {
            meta_words.y |= lane_meta << shift;
        }
    }
    let base = at * 5u;
    out_nodes[base] = vec4<u32>(bitcast<u32>(lo.x), bitcast<u32>(lo.y), bitcast<u32>(lo.z), ex | (ey << 8u) | (ez << 16u) | (imask << 24u));
    out_nodes[base + 1u] = vec4<u32>(child_base, tri_base, meta_words.x, meta_words.y);
    out_nodes[base + 2u] = vec4<u32>(q_words[0], q_words[1], q_words[2], q_words[3]);
    out_nodes[base + 3u] = vec4<u32>(q_words[4], q_words[5], q_words[6], q_words[7]);
    out_nodes[base + 4u] = vec4<u32>(q_words[8], q_words[9], q_words[10], q_words[11]);
}
