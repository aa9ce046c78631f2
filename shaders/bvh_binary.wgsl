// The binary tree's traversal (Bvh::closest_hit and Bvh::any_hit over the leaf-collapsed
// tree, triangles in leaf order), concatenated after trace.wgsl for `--trace binary`
// (src/gpu/trace.rs). One loop, `traverse`, serves closest and any hit; bvh_wide8.wgsl defines
// the same functions over the compressed wide tree.

@group(0) @binding(1) var<storage, read> nodes: array<BvhNode>;

fn cull_slack(r: Ray) -> f32 {
    let root = nodes[0];
    return cull_slack_in(r, root.aabb_min, root.aabb_max);
}

// Closest hit (any = false; Bvh::closest_hit) or any hit (any = true; Bvh::any_hit, its
// index then any hit's) with 0 < t <= t_max, leaving out triangle position `skip` (the surface a
// ray leaves; INVALID_INDEX: none): near child first, the far one pushed with its entry distance
// and skipped on pop when it begins past the best hit plus the slack. Ties in t go to the lowest
// primitive id (`beats`). The stack cannot overflow: trees deeper than TRACE_STACK_SIZE + 1 are
// refused on upload.
fn traverse(ray: Ray, t_max: f32, skip: u32, any: bool) -> Hit {
    var best = Hit(t_max, INVALID_INDEX, 0.0, 0.0);
    let r = prepare_ray(ray);
    let slack = cull_slack(ray);
    var limit = select(T_FAR, t_max * CULL_SCALE + slack, t_max < T_FAR || any);
    let root = nodes[0];
    if slab(root.aabb_min, root.aabb_max, r, limit) < 0.0 {
        return best;
    }
    var stack_node: array<u32, TRACE_STACK_SIZE>;
    var stack_t: array<f32, TRACE_STACK_SIZE>;
    var sp = 0u;
    var node = root;
    loop {
        if node.prim_count > 0u {
            for (var i = node.first; i < node.first + node.prim_count; i++) {
                if i == skip {
                    continue;
                }
                let hit = try_triangle(i, r, best);
                if hit.index == i {
                    best = hit;
                    if any {
                        return best;
                    }
                    limit = best.t * CULL_SCALE + slack;
                }
            }
        } else {
            let left = nodes[node.first];
            let right = nodes[node.first + 1u];
            let tl = slab(left.aabb_min, left.aabb_max, r, limit);
            let tr = slab(right.aabb_min, right.aabb_max, r, limit);
            if tl >= 0.0 && tr >= 0.0 {
                if sp < TRACE_STACK_SIZE {
                    if tl <= tr {
                        stack_node[sp] = node.first + 1u;
                        stack_t[sp] = tr;
                    } else {
                        stack_node[sp] = node.first;
                        stack_t[sp] = tl;
                    }
                    sp += 1u;
                }
                if tl <= tr {
                    node = left;
                } else {
                    node = right;
                }
                continue;
            }
            if tl >= 0.0 {
                node = left;
                continue;
            }
            if tr >= 0.0 {
                node = right;
                continue;
            }
        }
        // Pop the next node still in range.
        var found = false;
        while sp > 0u {
            sp -= 1u;
            if stack_t[sp] <= limit {
                node = nodes[stack_node[sp]];
                found = true;
                break;
            }
        }
        if !found {
            break;
        }
    }
    return best;
}

fn closest_hit(ray: Ray, t_max: f32, skip: u32) -> Hit {
    return traverse(ray, t_max, skip, false);
}

fn occluded(ray: Ray, t_max: f32, skip: u32) -> bool {
    return traverse(ray, t_max, skip, true).index != INVALID_INDEX;
}
