//! Structural validation of a [`Bvh`]: the invariants documented on [`Bvh`] and [`BvhNode`].
//!
//! Every builder and every tree edit is followed by `validate()` in tests (and, for the
//! optimiser, in debug builds).

use bytemuck::Zeroable;

use super::{Bvh, BvhNode, INVALID_INDEX, PAD_INDEX};
use crate::geometry::Aabb;

/// What a valid tree looks like.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BvhStats {
    pub node_count: usize,
    pub leaf_count: usize,
    /// Nodes on the longest root-to-leaf path: 0 for an empty tree, 1 for a single leaf.
    pub depth: usize,
    pub max_leaf_size: u32,
}

/// The first broken invariant found.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ValidationError {
    #[error("nodes ({nodes}) and parents ({parents}) differ in length")]
    LengthMismatch { nodes: usize, parents: usize },
    #[error("empty tree with {0} primitive ids, or primitives without a tree")]
    EmptyMismatch(usize),
    #[error("root's parent is {0}, expected INVALID_INDEX")]
    RootHasParent(u32),
    #[error("node 1, the padding after the root, is not zeroed or has a parent")]
    BadPadding,
    #[error("node {node}: child pair {child} out of range, odd, or pointing at the root or padding")]
    ChildOutOfRange { node: u32, child: u32 },
    #[error("node {child}: parent link {found}, but it is a child of {expected}")]
    ParentMismatch { child: u32, expected: u32, found: u32 },
    #[error("node {0} reached twice: the tree has a cycle or a shared subtree")]
    Revisited(u32),
    #[error("{0} nodes not reachable from the root")]
    Unreachable(usize),
    #[error("leaf {node}: primitive range {first}..{end} outside prim_ids ({len})")]
    LeafRangeOutOfBounds { node: u32, first: u32, end: u64, len: usize },
    #[error("leaf {node}: primitive id {prim} out of range ({prim_count} primitives)")]
    PrimOutOfRange { node: u32, prim: u32, prim_count: usize },
    #[error("primitive {prim} is in {count} leaves, expected exactly one")]
    PrimCount { prim: u32, count: u32 },
    #[error("prim_ids has {found} entries for {expected} primitives")]
    PrimIdsLength { expected: usize, found: usize },
    #[error("node {node}: box {found:?} is not exactly the union of its contents {expected:?}")]
    BoxNotTight { node: u32, expected: Aabb, found: Aabb },
}

/// Checks every invariant of `bvh` built over primitives with boxes `prim_aabbs`, and reports the
/// tree's shape.
///
/// - every primitive sits in exactly one leaf, and `prim_ids` holds nothing else;
/// - parent and child links agree, and the root has no parent;
/// - every box is exactly the union of its children's (or its primitives') boxes;
/// - every node is reached exactly once from the root: no cycles, no orphans, children in pairs
///   at even indices, and the padding node 1 zeroed and unreferenced.
pub fn validate(bvh: &Bvh, prim_aabbs: &[Aabb]) -> Result<BvhStats, ValidationError> {
    use ValidationError as E;
    let len = bvh.nodes.len();
    if len != bvh.parents.len() {
        return Err(E::LengthMismatch { nodes: len, parents: bvh.parents.len() });
    }
    if len == 0 {
        return match (bvh.prim_ids.len(), prim_aabbs.len()) {
            (0, 0) => Ok(BvhStats::default()),
            (ids, prims) => Err(E::EmptyMismatch(ids.max(prims))),
        };
    }
    if bvh.parents[0] != INVALID_INDEX {
        return Err(E::RootHasParent(bvh.parents[0]));
    }
    if len >= 2
        && (bvh.parents[PAD_INDEX as usize] != INVALID_INDEX || bvh.nodes[PAD_INDEX as usize] != BvhNode::zeroed())
    {
        return Err(E::BadPadding);
    }
    if bvh.prim_ids.len() != prim_aabbs.len() {
        return Err(E::PrimIdsLength { expected: prim_aabbs.len(), found: bvh.prim_ids.len() });
    }
    let mut visited = vec![false; len];
    let mut prim_seen = vec![0u32; prim_aabbs.len()];
    let mut stats = BvhStats::default();
    let mut stack = vec![(0u32, 1usize)];
    while let Some((i, depth)) = stack.pop() {
        if std::mem::replace(&mut visited[i as usize], true) {
            return Err(E::Revisited(i));
        }
        stats.node_count += 1;
        stats.depth = stats.depth.max(depth);
        let node = bvh.nodes[i as usize];
        let expected = if node.is_leaf() {
            stats.leaf_count += 1;
            stats.max_leaf_size = stats.max_leaf_size.max(node.prim_count);
            let end = node.first as u64 + node.prim_count as u64;
            if end > bvh.prim_ids.len() as u64 {
                return Err(E::LeafRangeOutOfBounds { node: i, first: node.first, end, len: bvh.prim_ids.len() });
            }
            let mut b = Aabb::EMPTY;
            for &p in &bvh.prim_ids[node.prim_range()] {
                let Some(seen) = prim_seen.get_mut(p as usize) else {
                    return Err(E::PrimOutOfRange { node: i, prim: p, prim_count: prim_aabbs.len() });
                };
                *seen += 1;
                b = b.union(prim_aabbs[p as usize]);
            }
            b
        } else {
            let left = node.first;
            if left < 2 || left % 2 == 1 || left as usize + 1 >= len {
                return Err(E::ChildOutOfRange { node: i, child: left });
            }
            for child in [left, left + 1] {
                let found = bvh.parents[child as usize];
                if found != i {
                    return Err(E::ParentMismatch { child, expected: i, found });
                }
                stack.push((child, depth + 1));
            }
            bvh.nodes[left as usize].aabb().union(bvh.nodes[left as usize + 1].aabb())
        };
        if !same_box(&expected, &node.aabb()) {
            return Err(E::BoxNotTight { node: i, expected, found: node.aabb() });
        }
    }
    let expected_nodes = if len >= 2 { len - 1 } else { len };
    if stats.node_count != expected_nodes {
        return Err(E::Unreachable(expected_nodes - stats.node_count));
    }
    if let Some((prim, &count)) = prim_seen.iter().enumerate().find(|&(_, &c)| c != 1) {
        return Err(E::PrimCount { prim: prim as u32, count });
    }
    Ok(stats)
}

/// Exact equality, with NaN equal to NaN (a primitive with NaN bounds keeps them) and 0 == -0
/// (min/max may return either zero).
fn same_box(a: &Aabb, b: &Aabb) -> bool {
    let eq = |x: f32, y: f32| x == y || (x.is_nan() && y.is_nan());
    (0..3).all(|k| eq(a.min[k], b.min[k]) && eq(a.max[k], b.max[k]))
}
