// The binary tree's traversal (Bvh::closest_hit and Bvh::any_hit over the leaf-collapsed
// tree, triangles in leaf order), concatenated after trace.wgsl for `--trace binary`
// (src/gpu/trace.rs). One loop, `traverse`, serves closest and any hit; bvh_wide8.wgsl defines
// the same function over the compressed wide tree.

@group(0) @binding(1) var<storage, read> nodes: array<BvhNode>;

// Closest hit (any = false; Bvh::closest_hit) or any hit (any = true; Bvh::any_hit, its
// index then any hit's) in the tree whose root is node `root` (0 in a flat scene, a mesh's root
// in a two-level one), better than `best_in` (its t the limit), leaving out triangle position
// `skip` (the surface a ray leaves; INVALID_INDEX: none); `inst` and `inst_material` are the
// instance traced and its material override (0 and INVALID_INDEX in a flat scene). Near child first, the far one pushed with its entry distance
// and skipped on pop when it begins past the best hit plus the slack. Ties in t go to the lowest
// primitive id (`beats`). The stack cannot overflow: trees deeper than TRACE_STACK_SIZE + 1 are
// refused on upload.
fn traverse_tree(root_index: u32, ray: Ray, best_in: Hit, skip: u32, any: bool, inst: u32, inst_material: u32) -> Hit {
    var best = best_in;
    let t_max = best.t;
    let r = prepare_ray(ray);
    let root = nodes[root_index];
    let slack = cull_slack_in(ray, root.aabb_min, root.aabb_max);
    var limit = select(T_FAR, t_max * CULL_SCALE + slack, t_max < T_FAR || any);
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

// TwoLevel::closest_hit_skipping and any_hit_skipping over the binary top-level tree (node 0 and
// on; a leaf's `first` an instance position), near child first; at an instance's leaf the ray
// goes through its mesh's tree (`visit_instance`), then the culling limit shrinks to the best
// hit. `skip` is (instance position, triangle position).
fn traverse_instances(ray: Ray, t_max: f32, skip: vec2<u32>, any: bool) -> Hit {
    var best = no_hit(t_max);
    let r = prepare_ray(ray);
    let root = nodes[0];
    let slack = cull_slack_in(ray, root.aabb_min, root.aabb_max);
    var limit = select(T_FAR, t_max * CULL_SCALE + slack, t_max < T_FAR || any);
    if slab(root.aabb_min, root.aabb_max, r, limit) < 0.0 {
        return best;
    }
    var stack_node: array<u32, TRACE_STACK_SIZE>;
    var stack_t: array<f32, TRACE_STACK_SIZE>;
    var sp = 0u;
    var node = root;
    loop {
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
            let left = nodes[node.first];
            let right = nodes[node.first + 1u];
            let tl = slab(left.aabb_min, left.aabb_max, r, limit);
            let tr = slab(right.aabb_min, right.aabb_max, r, limit);
            if tl >= 0.0 && tr >= 0.0 {
                if sp < TRACE_STACK_SIZE {
                    stack_node[sp] = select(node.first, node.first + 1u, tl <= tr);
                    stack_t[sp] = max(tl, tr);
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
