// The compressed 8-wide tree's traversal (src/gpu/wide.rs has the node layout; Ylitie, Karras
// & Laine 2017, after their traversal), concatenated after trace.wgsl for `--trace wide8`. One loop,
// `traverse_tree`, serves closest and any hit; bvh_binary.wgsl defines the same function over
// the binary tree.
//
// The loop keeps two groups: the inner children of a node still to visit (their node's
// child_base, the hit bits at 24..31 in visiting order, the node's imask in 0..7) and the
// triangles of a node's hit leaves (its tri_base, a bit per triangle in 0..23). A node's hit
// children are visited nearest corner first by the ray's octant (their bit is 24 + (slot ^
// near), lowest first), the rest of the group pushed; a group costs one stack entry, so a tree
// of depth d needs at most d - 1 (deeper trees are refused on upload).

@group(0) @binding(1) var<storage, read> wide_nodes: array<vec4<u32>>;

// Node `n`'s word `w` (0..19).
fn wide_word(n: u32, w: u32) -> u32 {
    return wide_nodes[n * 5u + w / 4u][w % 4u];
}

// The quantisation grid of the root `root` spans p .. p + 255 * scale: a box holding its tree.
fn cull_slack(root: u32, r: Ray) -> f32 {
    let a = wide_nodes[root * 5u];
    let e = a.w;
    let p = bitcast<vec3<f32>>(a.xyz);
    let scale = vec3<f32>(
        bitcast<f32>((e & 0xffu) << 23u),
        bitcast<f32>(((e >> 8u) & 0xffu) << 23u),
        bitcast<f32>(((e >> 16u) & 0xffu) << 23u),
    );
    return cull_slack_in(r, p, p + 255.0 * scale);
}

// Byte `k` of a pair of words holding eight bytes.
fn byte_of(lo: u32, hi: u32, k: u32) -> u32 {
    return (select(lo, hi, k >= 4u) >> (8u * (k & 3u))) & 0xffu;
}

// Node `node`'s lanes the ray `r` enters before `limit`: its inner children's group (child
// base; hit bits at 24 + (slot ^ near), in visiting order, and the node's imask in 0..7) and its
// hit leaves' triangles (triangle base; a bit per triangle in 0..23).
fn wide_node_hits(node: u32, r: TraceRay, limit: f32, near: u32) -> vec4<u32> {
    let w0 = wide_nodes[node * 5u];
    let w1 = wide_nodes[node * 5u + 1u];
    let w2 = wide_nodes[node * 5u + 2u];
    let w3 = wide_nodes[node * 5u + 3u];
    let w4 = wide_nodes[node * 5u + 4u];
    let p = bitcast<vec3<f32>>(w0.xyz);
    let e = w0.w;
    let scale = vec3<f32>(
        bitcast<f32>((e & 0xffu) << 23u),
        bitcast<f32>(((e >> 8u) & 0xffu) << 23u),
        bitcast<f32>(((e >> 16u) & 0xffu) << 23u),
    );
    // Words 8..19: qlo x, y, z then qhi x, y, z, two words (eight bytes) each.
    let q = array<vec2<u32>, 6>(w2.xy, w2.zw, w3.xy, w3.zw, w4.xy, w4.zw);
    var hits = 0u;
    for (var k = 0u; k < 8u; k++) {
        let lane = byte_of(w1.z, w1.w, k);
        if lane == 0u {
            continue;
        }
        let lo = p + scale * vec3<f32>(
            f32(byte_of(q[0].x, q[0].y, k)),
            f32(byte_of(q[1].x, q[1].y, k)),
            f32(byte_of(q[2].x, q[2].y, k)),
        );
        let hi = p + scale * vec3<f32>(
            f32(byte_of(q[3].x, q[3].y, k)),
            f32(byte_of(q[4].x, q[4].y, k)),
            f32(byte_of(q[5].x, q[5].y, k)),
        );
        if slab(lo, hi, r, limit) >= 0.0 {
            let offset = lane & 31u;
            if offset >= 24u {
                hits |= 1u << (24u + ((offset - 24u) ^ near));
            } else {
                hits |= (lane >> 5u) << offset;
            }
        }
    }
    return vec4<u32>(w1.x, (hits & 0xff000000u) | (e >> 24u), w1.y, hits & 0x00ffffffu);
}

// Groups of inner children still to visit (see the top of the file).
struct WideStack {
    groups: array<vec2<u32>, WIDE_STACK_SIZE>,
    sp: u32,
}

// The near octant of a ray going along `dir`: a node's children are visited by their slot XOR it.
fn near_octant(dir: vec3<f32>) -> u32 {
    return (select(0u, 1u, dir.x < 0.0) | select(0u, 2u, dir.y < 0.0) | select(0u, 4u, dir.z < 0.0)) ^ 7u;
}

// The node of group `g`'s first child still to visit (nearest first by the octant `near`), the
// rest of the group pushed where any remains.
fn wide_take(g: vec2<u32>, near: u32, stack: ptr<function, WideStack>) -> u32 {
    let bit = firstTrailingBit(g.y >> 24u);
    let rest = vec2<u32>(g.x, g.y & ~(1u << (24u + bit)));
    if (rest.y & 0xff000000u) != 0u && (*stack).sp < WIDE_STACK_SIZE {
        (*stack).groups[(*stack).sp] = rest;
        (*stack).sp += 1u;
    }
    let slot = bit ^ near;
    return g.x + countOneBits(g.y & ((1u << slot) - 1u) & 0xffu);
}

// Group `g`, or where it has no child left the last one pushed; false when none is left.
fn wide_next_group(g: ptr<function, vec2<u32>>, stack: ptr<function, WideStack>) -> bool {
    if ((*g).y & 0xff000000u) != 0u {
        return true;
    }
    if (*stack).sp == 0u {
        return false;
    }
    (*stack).sp -= 1u;
    *g = (*stack).groups[(*stack).sp];
    return true;
}

// Closest hit (any = false) or any hit (any = true; its index is then any hit's) in the tree
// whose root is node `root` (0 in a flat scene, a mesh's root in a two-level one), better than
// `best_in` (its t the limit), leaving out triangle position `skip`; `inst` and
// `inst_material` are the instance traced and its material override (0 and INVALID_INDEX in a
// flat scene).
fn traverse_tree(root: u32, ray: Ray, best_in: Hit, skip: u32, any: bool, inst: u32, inst_material: u32) -> Hit {
    var best = best_in;
    let r = prepare_ray(ray);
    let slack = cull_slack(root, ray);
    var limit = select(T_FAR, best.t * CULL_SCALE + slack, best.t < T_FAR || any);
    let near = near_octant(ray.dir);
    var stack: WideStack;
    // The root as the one inner child of a group based at it, in slot 0.
    var group = vec2<u32>(root, (1u << (24u + near)) | 1u);
    loop {
        var tris = vec2<u32>(0u, 0u);
        if (group.y & 0xff000000u) != 0u {
            let visit = wide_node_hits(wide_take(group, near, &stack), r, limit, near);
            group = visit.xy;
            tris = visit.zw;
        }
        while tris.y != 0u {
            let i = tris.x + firstTrailingBit(tris.y);
            tris.y &= tris.y - 1u;
            if i == skip {
                continue;
            }
            let hit = try_triangle(i, inst, inst_material, r, best);
            if hit.index == i && hit.instance == inst {
                best = hit;
                if any {
                    return best;
                }
                limit = best.t * CULL_SCALE + slack;
            }
        }
        if !wide_next_group(&group, &stack) {
            break;
        }
    }
    return best;
}

// TwoLevel::closest_hit_skipping and any_hit_skipping over the wide top-level tree (root node 0;
// a leaf lane's "triangles" are instance positions): `traverse_tree`'s walk, each hit leaf's
// instances traced through their meshes' trees (`visit_instance`), after which the culling
// limit shrinks to the best hit. `skip` is (instance position, triangle position).
fn traverse_instances(ray: Ray, t_max: f32, skip: vec2<u32>, any: bool) -> Hit {
    var best = no_hit(t_max);
    let r = prepare_ray(ray);
    let slack = cull_slack(0u, ray);
    var limit = select(T_FAR, t_max * CULL_SCALE + slack, t_max < T_FAR || any);
    let near = near_octant(ray.dir);
    var stack: WideStack;
    var group = vec2<u32>(0u, (1u << (24u + near)) | 1u);
    loop {
        var leaves = vec2<u32>(0u, 0u);
        if (group.y & 0xff000000u) != 0u {
            let visit = wide_node_hits(wide_take(group, near, &stack), r, limit, near);
            group = visit.xy;
            leaves = visit.zw;
        }
        while leaves.y != 0u {
            let k = leaves.x + firstTrailingBit(leaves.y);
            leaves.y &= leaves.y - 1u;
            let h = visit_instance(k, ray, best, skip, any);
            if h.index != best.index || h.instance != best.instance {
                best = h;
                if any {
                    return best;
                }
                limit = best.t * CULL_SCALE + slack;
            }
        }
        if !wide_next_group(&group, &stack) {
            break;
        }
    }
    return best;
}
