//! The BVH's data layout: plain arrays that upload to the GPU unchanged.
//!
//! ```text
//!   nodes:    [ root  pad | L0 R0 | L1 R1 | ... ]   32-byte nodes; each | ... | is one 64-byte line
//!   parents:  [ INVALID INVALID | 0 0 | ... ]        one per node
//!   prim_ids: [ 7 3 9 ... ]                          leaves index ranges of this
//! ```
//! Siblings sit next to each other, so an internal node stores only its left child `first`; the
//! right child is `first + 1`. Node 0 is the root; node 1 is padding, so that every sibling pair
//! starts at an even index, and [`Nodes`] keeps the array 64-byte aligned: both children of a
//! node are one cache line, fetched together by traversal. (Without it, glibc places large arrays
//! at 16 mod 64 and every pair straddles two lines.) The sibling of node `i >= 2` is `i ^ 1`.
//! The same layout, padding included, is what tinybvh uses for the same reason.
//!
//! What a leaf refers to is up to the caller: `prim_ids` holds indices into whatever array of
//! primitives the tree was built over (triangles for a mesh, instances for a top-level tree).

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use rayon::prelude::*;

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

    /// The node as 8 floats: `[min.xyz, first bits, max.xyz, prim_count bits]`, the form the
    /// traversal's slab test reads.
    #[inline(always)]
    pub fn as_floats(&self) -> &[f32; 8] {
        bytemuck::cast_ref(self)
    }

    /// The primitive range of a leaf, as indices into `prim_ids`.
    #[inline]
    pub fn prim_range(&self) -> std::ops::Range<usize> {
        self.first as usize..(self.first + self.prim_count) as usize
    }
}

/// Index of the padding node after the root.
pub const PAD_INDEX: u32 = 1;

/// Two sibling nodes: one 64-byte cache line.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct NodePair(pub [BvhNode; 2]);

const _: () = assert!(size_of::<NodePair>() == 64 && align_of::<NodePair>() == 64);

/// The node array: a `[BvhNode]` (through `Deref`) stored as 64-byte-aligned pairs.
#[derive(Clone, Default)]
pub struct Nodes {
    pairs: Vec<NodePair>,
    len: usize,
}

impl std::ops::Deref for Nodes {
    type Target = [BvhNode];
    fn deref(&self) -> &[BvhNode] {
        &bytemuck::cast_slice(&self.pairs)[..self.len]
    }
}

impl std::ops::DerefMut for Nodes {
    fn deref_mut(&mut self) -> &mut [BvhNode] {
        &mut bytemuck::cast_slice_mut(&mut self.pairs)[..self.len]
    }
}

impl PartialEq for Nodes {
    fn eq(&self, other: &Self) -> bool {
        **self == **other
    }
}

impl std::fmt::Debug for Nodes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

impl From<Vec<BvhNode>> for Nodes {
    fn from(v: Vec<BvhNode>) -> Self {
        let mut n = Nodes::default();
        v.into_iter().for_each(|x| n.push(x));
        n
    }
}

impl Nodes {
    pub fn with_capacity(nodes: usize) -> Self {
        Self { pairs: Vec::with_capacity(nodes.div_ceil(2)), len: 0 }
    }

    pub fn push(&mut self, node: BvhNode) {
        if self.len % 2 == 0 {
            self.pairs.truncate(self.len / 2);
            self.pairs.push(NodePair([node, BvhNode::zeroed()]));
        } else {
            self.pairs[self.len / 2].0[1] = node;
        }
        self.len += 1;
    }

    pub fn clear(&mut self) {
        self.pairs.clear();
        self.len = 0;
    }

    /// Keeps the first `len` nodes; the rest of the last pair is zeroed.
    pub fn truncate(&mut self, len: usize) {
        if len < self.len {
            self.pairs.truncate(len.div_ceil(2));
            if len % 2 == 1 {
                self.pairs[len / 2].0[1] = BvhNode::zeroed();
            }
            self.len = len;
        }
    }

    /// Replaces the contents with `pair_count` pairs made in parallel by `pair(k)`, written in
    /// place without zero-filling first, and keeps the first `len` nodes.
    pub fn fill_pairs(&mut self, pair_count: usize, len: usize, pair: impl Fn(usize) -> [BvhNode; 2] + Sync + Send) {
        assert!(len <= 2 * pair_count && len + 1 >= 2 * pair_count, "len {len} does not fit {pair_count} pairs");
        self.pairs.clear();
        self.pairs.par_extend((0..pair_count).into_par_iter().with_min_len(1024).map(|k| NodePair(pair(k))));
        self.len = len;
    }

    /// The bytes to upload: whole pairs, 64-byte aligned (a trailing half pair is zero).
    pub fn as_bytes(&self) -> &[u8] {
        bytemuck::cast_slice(&self.pairs)
    }
}

/// A binary BVH as three plain arrays.
///
/// Invariants, checked by [`crate::bvh::validate`]:
/// - `nodes.len() == parents.len()`; an empty tree has no nodes and no `prim_ids`; a tree of
///   one leaf has just the root; otherwise node 1 is the zeroed padding node, which no node
///   refers to, with `parents[1] == INVALID_INDEX`;
/// - node 0 is the root and `parents[0] == INVALID_INDEX`; for every other node `i`,
///   `parents[i]` is the internal node whose children are `i` and its sibling `i ^ 1`;
///   children always come in pairs starting at an even index;
/// - every node but the padding is reachable from the root exactly once (no cycles, no orphans);
/// - every primitive id appears in exactly one leaf's range, and the leaf ranges cover
///   `prim_ids` without overlap.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Bvh {
    pub nodes: Nodes,
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
        self.nodes.par_iter().filter(|n| n.is_leaf()).count()
    }

    /// Indices of the leaves, ascending (the start points of bottom-up passes).
    pub fn leaf_indices(&self) -> Vec<u32> {
        self.nodes.par_iter().enumerate().filter(|(_, n)| n.is_leaf()).map(|(i, _)| i as u32).collect()
    }

    /// The other child of `node`'s parent; `None` for the root (and the padding node).
    #[inline]
    pub fn sibling(node: u32) -> Option<u32> {
        (node >= 2).then_some(node ^ 1)
    }

    /// A tree holding one leaf with every primitive (also the result for a single primitive).
    pub fn single_leaf(prim_aabbs: &[Aabb]) -> Self {
        if prim_aabbs.is_empty() {
            return Self::default();
        }
        let bounds = prim_aabbs.iter().fold(Aabb::EMPTY, |b, a| b.union(*a));
        Self {
            nodes: vec![BvhNode::leaf(bounds, 0, prim_aabbs.len() as u32)].into(),
            parents: vec![INVALID_INDEX],
            prim_ids: (0..prim_aabbs.len() as u32).collect(),
        }
    }

    /// Bytes the three arrays occupy.
    pub fn memory_bytes(&self) -> usize {
        self.nodes.as_bytes().len() + size_of_val(self.parents.as_slice()) + size_of_val(self.prim_ids.as_slice())
    }
}
