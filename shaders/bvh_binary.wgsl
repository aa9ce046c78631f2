// The binary tree's traversal (Bvh::closest_hit and Bvh::any_hit over the leaf-collapsed
// tree, triangles in leaf order), concatenated after trace.wgsl for `--trace binary`
// (src/gpu/trace.rs). One loop, `traverse_tree`, serves closest and any hit in a tree; the
// top level of a two-level scene, `traverse_instances`, walks the same way with its own leaves
// (WGSL has no recursion, so the walk's steps are shared, not the loop); bvh_wide8.wgsl
// defines the same functions over the compressed wide tree.

@group(0) @binding(1) var<storage, read> nodes: array<BvhNode>;

// Far children still to visit, with the distances at which the ray enters them.
struct BinaryStack {
    node: array<u32, TRACE_STACK_SIZE>,
    t: array<f32, TRACE_STACK_SIZE>,
    sp: u32,
}

// Inner node `node`'s child to visit next, nearer first (INVALID_INDEX where the ray enters
// neither before `limit`), the other pushed with its entry distance when both are entered.
fn binary_children(node: BvhNode, r: TraceRay, limit: f32, stack: ptr<function, BinaryStack>) -> u32 {
    let left = nodes[node.first];
    let right = nodes[node.first + 1u];
    let tl = slab(left.aabb_min, left.aabb_max, r, limit);
    let tr = slab(right.aabb_min, right.aabb_max, r, limit);
    if tl >= 0.0 && tr >= 0.0 {
        if (*stack).sp < TRACE_STACK_SIZE {
            (*stack).node[(*stack).sp] = select(node.first, node.first + 1u, tl <= tr);
            (*stack).t[(*stack).sp] = max(tl, tr);
            (*stack).sp += 1u;
        }
        return select(node.first + 1u, node.first, tl <= tr);
    }
    if tl >= 0.0 {
        return node.first;
    }
    if tr >= 0.0 {
        return node.first + 1u;
    }
    return INVALID_INDEX;
}

// The nearest pushed node the ray still enters before `limit` (the others dropped), or
// INVALID_INDEX.
fn binary_pop(stack: ptr<function, BinaryStack>, limit: f32) -> u32 {
    while (*stack).sp > 0u {
        (*stack).sp -= 1u;
        if (*stack).t[(*stack).sp] <= limit {
            return (*stack).node[(*stack).sp];
        }
    }
    return INVALID_INDEX;
}

// Closest hit (any = false; Bvh::closest_hit) or any hit (any = true; Bvh::any_hit, its
// index then any hit's) in the tree whose root is node `root` (0 in a flat scene, a mesh's root
// in a two-level one), better than `best_in` (its t the limit), leaving out triangle position
// `skip` (the surface a ray leaves; INVALID_INDEX: none); `inst` and `inst_material` are the
// instance traced and its material override (0 and INVALID_INDEX in a flat scene). Near child
// first, the far one pushed with its entry distance and skipped on pop when it begins past the
// best hit plus the slack. Ties in t go to the lowest primitive id (`beats`). The stack cannot
// overflow: trees deeper than TRACE_STACK_SIZE + 1 are refused on upload.
fn traverse_tree(root: u32, ray: Ray, best_in: Hit, skip: u32, any: bool, inst: u32, inst_material: u32) -> Hit {
    var best = best_in;
    let r = prepare_ray(ray);
    let top = nodes[root];
    let slack = cull_slack_in(ray, top.aabb_min, top.aabb_max);
    var limit = select(T_FAR, best.t * CULL_SCALE + slack, best.t < T_FAR || any);
    if slab(top.aabb_min, top.aabb_max, r, limit) < 0.0 {
        return best;
    }
    var stack: BinaryStack;
    var index = root;
    loop {
        let node = nodes[index];
        var next = INVALID_INDEX;
        if node.prim_count > 0u {
            for (var i = node.first; i < node.first + node.prim_count; i++) {
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
        } else {
            next = binary_children(node, r, limit, &stack);
        }
        if next == INVALID_INDEX {
            next = binary_pop(&stack, limit);
            if next == INVALID_INDEX {
                break;
            }
        }
        index = next;
    }
    return best;
}

// TwoLevel::closest_hit_skipping and any_hit_skipping over the binary top-level tree (node 0 and
// on; a leaf's `first` an instance position), near child first; at an instance's leaf the ray
// goes through its mesh's tree (`visit_instance`), then the culling limit shrinks to the best
// hit. `skip` is (instance position, triangle position).
fn traverse_instances(ray: Ray, t_max: f32, skip: vec2<u32>, any: bool) -> Hit {
    var best = no_hit(t_max);
    let r = prepare_ray(ray);
    let top = nodes[0];
    let slack = cull_slack_in(ray, top.aabb_min, top.aabb_max);
    var limit = select(T_FAR, t_max * CULL_SCALE + slack, t_max < T_FAR || any);
    if slab(top.aabb_min, top.aabb_max, r, limit) < 0.0 {
        return best;
    }
    var stack: BinaryStack;
    var index = 0u;
    loop {
        let node = nodes[index];
        var next = INVALID_INDEX;
        if node.prim_count > 0u {
            for (var k = node.first; k < node.first + node.prim_count; k++) {
                let h = visit_instance(k, ray, best, skip, any);
                if h.index != best.index || h.instance != best.instance {
                    best = h;
                    if any {
                        return best;
                    }
                    limit = best.t * CULL_SCALE + slack;
                }
            }
        } else {
            next = binary_children(node, r, limit, &stack);
        }
        if next == INVALID_INDEX {
            next = binary_pop(&stack, limit);
            if next == INVALID_INDEX {
                break;
            }
        }
        index = next;
    }
    return best;
}
