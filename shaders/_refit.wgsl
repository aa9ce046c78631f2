
// Bottom-up box refit shared by the LBVH and PRBVH kernels, appended to both files; it uses
// their `nodes`, `parents` and `visits` bindings. The thread of a leaf climbs; at each node the
// first child's thread to arrive stops and the second computes the node's box (Karras 2012,
// section 4.2), so every box is written once, after both children's.
fn refit_from(start: u32) {
    var node = start;
    loop {
        if (node == 0u) {
            break;
        }
        let p = parents[node];
        if (atomicAdd(&visits[p], 1u) == 0u) {
            break;
        }
        let l = nodes[nodes[p].first];
        let r = nodes[nodes[p].first + 1u];
        nodes[p].aabb_min = min(l.aabb_min, r.aabb_min);
        nodes[p].aabb_max = max(l.aabb_max, r.aabb_max);
        node = p;
    }
}
