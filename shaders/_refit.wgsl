
// Bottom-up box refit shared by the LBVH and PRBVH kernels, appended to both files; it uses
// their `nodes`, `parents`, `visits` and `refit_boxes` bindings. The thread of a leaf climbs; at
// each node the first child's thread to arrive stops and the second computes the node's box
// (Karras 2012, section 4.2), so every box is written once, after both children's.
//
// How the boxes pass between threads. WGSL's atomics are relaxed and it has no fence, so a plain
// store made by one workgroup need not be visible to another in the same dispatch, even after
// that one has seen an atomic the first wrote later. On an H100 the second thread read stale
// boxes (its L1 cache's) and left boxes that did not hold their children; lavapipe never showed
// it. So the boxes travel in `refit_boxes`, through atomics only: REFIT_BOX_WORDS (six) words
// per node, each the complement of a float's bits, where 0 (the complement of a NaN) means "not written yet". Every
// thread publishes its box before it counts its visit at the parent. The second to arrive reads
// its sibling's words and waits on any still 0: the sibling's thread stored them before the visit
// that was seen, so the wait ends. It then clears both children's words, which leaves the buffer
// zero for the next refit. Boxes are also stored in `nodes`, which later dispatches read.

// Bounds the wait on one word, so that a broken tree cannot hang the device: the word then reads
// as a NaN, and the tree fails validation.
const REFIT_SPIN_LIMIT: u32 = 1048576u;

fn publish_box(n: u32, lo: vec3<f32>, hi: vec3<f32>) {
    let b = REFIT_BOX_WORDS * n;
    atomicStore(&refit_boxes[b], ~bitcast<u32>(lo.x));
    atomicStore(&refit_boxes[b + 1u], ~bitcast<u32>(lo.y));
    atomicStore(&refit_boxes[b + 2u], ~bitcast<u32>(lo.z));
    atomicStore(&refit_boxes[b + 3u], ~bitcast<u32>(hi.x));
    atomicStore(&refit_boxes[b + 4u], ~bitcast<u32>(hi.y));
    atomicStore(&refit_boxes[b + 5u], ~bitcast<u32>(hi.z));
}

// One published word of a sibling's box, waited for and then cleared.
fn take_word(i: u32) -> f32 {
    var w = atomicLoad(&refit_boxes[i]);
    for (var spin = 0u; w == 0u && spin < REFIT_SPIN_LIMIT; spin++) {
        w = atomicLoad(&refit_boxes[i]);
    }
    atomicStore(&refit_boxes[i], 0u);
    return bitcast<f32>(~w);
}

fn refit_from(start: u32) {
    var node = start;
    var lo = nodes[start].aabb_min;
    var hi = nodes[start].aabb_max;
    loop {
        if (node == 0u) {
            break;
        }
        publish_box(node, lo, hi);
        let p = parents[node];
        if (atomicAdd(&visits[p], 1u) == 0u) {
            break;
        }
        let first = nodes[p].first;
        let b = REFIT_BOX_WORDS * select(first, first + 1u, node == first);
        let sibling_lo = vec3<f32>(take_word(b), take_word(b + 1u), take_word(b + 2u));
        let sibling_hi = vec3<f32>(take_word(b + 3u), take_word(b + 4u), take_word(b + 5u));
        for (var k = 0u; k < REFIT_BOX_WORDS; k++) {
            atomicStore(&refit_boxes[REFIT_BOX_WORDS * node + k], 0u);
        }
        lo = min(lo, sibling_lo);
        hi = max(hi, sibling_hi);
        nodes[p].aabb_min = lo;
        nodes[p].aabb_max = hi;
        node = p;
    }
}
