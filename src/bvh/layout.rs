//! Rewriting a tree's arrays in depth-first order (left subtree first), so that each subtree is
//! one run of memory, optionally merging subtrees into leaves (the leaf collapse's last step).
//!
//! Tried and rejected: re-laying the tree out between PRBVH iterations. On the dragon it made
//! each iteration slower (the pass is sequential) and the run longer (the new indices change
//! which nodes each sparse-search phase picks), so the optimisation as a whole took longer
//! (docs/benchmarks.md, "PRBVH: tried and dropped").

use bytemuck::Zeroable;

use super::{Bvh, BvhNode, INVALID_INDEX, Nodes};

/// Depth-first copy of `bvh`, `prim_ids` in leaf order; where `collapse[i]` is true, node `i`'s
/// subtree becomes one leaf holding all its primitives.
pub(crate) fn depth_first(bvh: &Bvh, collapse: &[bool]) -> Bvh {
    if bvh.nodes.len() <= 1 {
        return bvh.clone();
    }
    let as_leaf = |i: u32| bvh.nodes[i as usize].is_leaf() || collapse[i as usize];
    let mut out = Bvh {
        nodes: Nodes::with_capacity(bvh.nodes.len()),
        parents: Vec::with_capacity(bvh.nodes.len()),
        prim_ids: Vec::with_capacity(bvh.prim_ids.len()),
    };
    out.nodes.push(bvh.nodes[0]);
    out.parents.push(INVALID_INDEX);
    if !as_leaf(0) {
        out.nodes.push(BvhNode::zeroed());
        out.parents.push(INVALID_INDEX);
    }
    // (old node, its slot in the new tree)
    let mut stack = vec![(0u32, 0u32)];
    let mut leaf_stack = Vec::new();
    while let Some((old, new)) = stack.pop() {
        let node = bvh.nodes[old as usize];
        if as_leaf(old) {
            let first = out.prim_ids.len() as u32;
            gather_prims(bvh, old, &mut out.prim_ids, &mut leaf_stack);
            let count = out.prim_ids.len() as u32 - first;
            out.nodes[new as usize] = BvhNode::leaf(node.aabb(), first, count);
        } else {
            let left = out.nodes.len() as u32;
            out.nodes[new as usize].first = left;
            for k in 0..2 {
                out.nodes.push(bvh.nodes[(node.first + k) as usize]);
                out.parents.push(new);
            }
            // Right pushed first so the left subtree is laid out first.
            stack.push((node.first + 1, left + 1));
            stack.push((node.first, left));
        }
    }
    out
}

/// Appends the primitives of every leaf under `node` to `out`, left to right.
fn gather_prims(bvh: &Bvh, node: u32, out: &mut Vec<u32>, stack: &mut Vec<u32>) {
    stack.clear();
    stack.push(node);
    while let Some(i) = stack.pop() {
        let n = &bvh.nodes[i as usize];
        if n.is_leaf() {
            out.extend_from_slice(&bvh.prim_ids[n.prim_range()]);
        } else {
            stack.push(n.first + 1);
            stack.push(n.first);
        }
    }
}
