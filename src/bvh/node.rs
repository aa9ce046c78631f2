//! The BVH's data layout: plain arrays that upload to the GPU unchanged.
//!
//! ```text
//!   nodes:    [ root | L0 R0 | L1 R1 | ... ]     32 bytes each, siblings adjacent
//!   parents:  [ INVALID_INDEX | 0 0 | ... ]       one per node
//!   prim_ids: [ 7 3 9 ... ]                       leaves index ranges of this
//! ```
//! Siblings sit next to each other, so an internal node stores only its left child `first`; the
//! right child is `first + 1`. The root is node 0 and has no sibling; every other pair starts at
//! an odd index, so the sibling of node `i > 0` is `i + 1` when `i` is odd and `i - 1` when even.
//! Traversal reads both children of a node from 64 contiguous bytes.
//!
//! What a leaf refers to is up to the caller: `prim_ids` holds indices into whatever array of
//! primitives the tree was built over (triangles for a mesh, instances for a top-level tree).

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::geometry::Aabb;

/// "No node": the parent of the root.
pub const INVALID_INDEX: u32 = u32::MAX;

/// One node. A 32-byte layout that is also a valid WGSL struct (`vec3<f32>` followed by `u32`
/// packs into 16 bytes), so the GPU reads the same bytes.
///
/// Invariants, checked by [`crate::bvh::validate`]:
/// - internal node: `prim_count == 0`; its children are `first` and `first + 1`, both `> 0`;
/// - leaf: `prim_count > 0`; it holds `prim_ids[first .. first + prim_count]`;
/// - the box is exactly the union of its children's boxes (internal) or of its primitives'
///   boxes (leaf): tight, not merely enclosing.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct BvhNode {
    pub aabb_min: Vec3,
    /// Internal: the left child's index. Leaf: the first position in `prim_ids`.
    pub first: u32,
    pub aabb_max: Vec3,
    /// 0 for an internal node; the number of primitives in a leaf.
    pub prim_count: u32,
}

const _: () = assert!(size_of::<BvhNode>() == 32);

impl BvhNode {
    pub fn leaf(aabb: Aabb, first: u32, prim_count: u32) -> Self {
        debug_assert!(prim_count > 0, "a leaf holds at least one primitive");
        Self { aabb_min: aabb.min, first, aabb_max: aabb.max, prim_count }
    }

    pub fn internal(aabb: Aabb, left: u32) -> Self {
        Self { aabb_min: aabb.min, first: left, aabb_max: aabb.max, prim_count: 0 }
    }

    #[inline]
    pub fn is_leaf(&self) -> bool {
        self.prim_count > 0
    }

    #[inline]
    pub fn aabb(&self) -> Aabb {
        Aabb::new(self.aabb_min, self.aabb_max)
    }

    #[inline]
    pub fn set_aabb(&mut self, aabb: Aabb) {
        self.aabb_min = aabb.min;
        self.aabb_max = aabb.max;
    }

    /// The primitive range of a leaf, as indices into `prim_ids`.
    #[inline]
    pub fn prim_range(&self) -> std::ops::Range<usize> {
        self.first as usize..(self.first + self.prim_count) as usize
    }
}

/// A binary BVH as three plain arrays.
///
/// Invariants, checked by [`crate::bvh::validate`]:
/// - `nodes.len() == parents.len()`; an empty tree has no nodes and no `prim_ids`;
/// - node 0 is the root and `parents[0] == INVALID_INDEX`; for every other node `i`,
///   `parents[i]` is the internal node whose children are `i` and its sibling;
/// - every node is reachable from the root exactly once (no cycles, no orphans);
/// - every primitive id appears in exactly one leaf's range, and the leaf ranges cover
///   `prim_ids` without overlap.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Bvh {
    pub nodes: Vec<BvhNode>,
    pub parents: Vec<u32>,
    pub prim_ids: Vec<u32>,
}

impl Bvh {
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// Bounds of everything in the tree; empty for an empty tree.
    pub fn bounds(&self) -> Aabb {
        self.nodes.first().map_or(Aabb::EMPTY, BvhNode::aabb)
    }

    pub fn leaf_count(&self) -> usize {
        self.nodes.iter().filter(|n| n.is_leaf()).count()
    }

    /// The other child of `node`'s parent; `None` for the root.
    #[inline]
    pub fn sibling(node: u32) -> Option<u32> {
        match node {
            0 => None,
            i if i % 2 == 1 => Some(i + 1),
            i => Some(i - 1),
        }
    }

    /// A tree holding one leaf with every primitive (also the result for a single primitive).
    pub fn single_leaf(prim_aabbs: &[Aabb]) -> Self {
        if prim_aabbs.is_empty() {
            return Self::default();
        }
        let bounds = prim_aabbs.iter().fold(Aabb::EMPTY, |b, a| b.union(*a));
        Self {
            nodes: vec![BvhNode::leaf(bounds, 0, prim_aabbs.len() as u32)],
            parents: vec![INVALID_INDEX],
            prim_ids: (0..prim_aabbs.len() as u32).collect(),
        }
    }

    /// Bytes the three arrays occupy.
    pub fn memory_bytes(&self) -> usize {
        size_of_val(self.nodes.as_slice()) + size_of_val(self.parents.as_slice()) + size_of_val(self.prim_ids.as_slice())
    }
}
