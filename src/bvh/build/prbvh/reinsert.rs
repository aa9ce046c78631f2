//! Claims and reinsertion (section 4.3): each candidate move claims the nodes whose topology it
//! changes with an atomic max, and the winners, which share no node, are applied in parallel by
//! moving node contents within Arbor's sibling-adjacent layout ([`reinsert`]).

use super::LockStrategy;
use super::search::search;
use crate::bvh::parallel::SharedSlice;
use crate::bvh::{Bvh, BvhNode, INVALID_INDEX};
use crate::geometry::Aabb;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};

/// A reinsertion that was applied: `input` became the sibling of `output`. `parent` was
/// `input`'s parent before the move, and `parent_box` its box; that slot now holds the input's
/// old sibling. The slots whose contents changed are `parent`, the pair `input & !1` (the output's
/// old content and the input), and the new internal node, in `output`'s slot (or in `parent`'s
/// when the output was the input's sibling).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reinsertion {
    pub input: u32,
    pub output: u32,
    pub parent: u32,
    pub parent_box: Aabb,
}

impl Reinsertion {
    /// The slot of the new internal node: the output's, or the parent's when the output was the
    /// input's sibling (whose content moved there).
    pub fn new_node(&self) -> u32 {
        if self.output == self.input ^ 1 { self.parent } else { self.output }
    }

    /// The slots whose contents the reinsertion wrote: the parent's, the pair `input & !1`, and
    /// the new internal node's (the parent's again when the output was the sibling).
    pub fn written_slots(&self) -> [u32; 4] {
        let pair = self.input & !1;
        [self.parent, pair, pair + 1, self.new_node()]
    }
}

/// One round restricted to `candidates` (distinct nodes, none the root or the padding): each
/// searches (Algorithm 1), the locks pick winners as in [`optimize`], and the winners are applied.
/// Boxes above the moved nodes are left stale; the caller refits them. Returns what was applied.
pub fn reinsert_candidates(
    bvh: &mut Bvh,
    candidates: &[u32],
    strategy: LockStrategy,
    locks: &mut Vec<AtomicU64>,
) -> Vec<Reinsertion> {
    if bvh.nodes.len() <= 3 {
        return Vec::new();
    }
    let moves = search(bvh, candidates.par_iter().map(|&c| c as usize), None);
    lock_and_apply(bvh, &moves, strategy, locks)
}

/// Locks, checks and applies `moves`; returns the winners.
pub(super) fn lock_and_apply(
    bvh: &mut Bvh,
    moves: &[(u32, u32, f32)],
    strategy: LockStrategy,
    locks: &mut Vec<AtomicU64>,
) -> Vec<Reinsertion> {
    if moves.is_empty() {
        return Vec::new();
    }
    // Lock: the highest (decrease, index) wins each node. The locks are all zero between calls
    // (reset below, claim by claim), so a round costs what its moves claim, not the tree's size.
    locks.resize_with(locks.len().max(bvh.nodes.len()), || AtomicU64::new(0));
    let key = |&(input, _, d): &(u32, u32, f32)| ((d.to_bits() as u64) << 32) | input as u64;
    let claims: Vec<Claim> = moves.par_iter().map(|m| locked_nodes(bvh, m.0, m.1, strategy)).collect();
    moves.par_iter().zip(&claims).for_each(|(m, claim)| {
        let k = key(m);
        for n in claim.nodes() {
            locks[n as usize].fetch_max(k, Ordering::Relaxed);
        }
    });
    // Check: a reinsertion goes ahead only if it holds every lock it asked for.
    let winners: Vec<Reinsertion> = moves
        .par_iter()
        .zip(&claims)
        .filter(|(m, claim)| claim.nodes().all(|n| locks[n as usize].load(Ordering::Relaxed) == key(m)))
        .map(|(&(input, output, _), _)| {
            let parent = bvh.parents[input as usize];
            Reinsertion { input, output, parent, parent_box: bvh.nodes[parent as usize].aabb() }
        })
        .collect();
    claims.par_iter().flat_map_iter(Claim::nodes).for_each(|n| locks[n as usize].store(0, Ordering::Relaxed));
    // Reinsert the winners in parallel.
    let Bvh { nodes, parents, .. } = bvh;
    let (nodes, parents) = (SharedSlice::new(nodes), SharedSlice::new(parents));
    winners.par_iter().for_each(|r| {
        // SAFETY: winners hold disjoint lock sets, and a reinsertion reads and writes only its
        // locked nodes and the parent links of their children, which no other winner touches
        // (a child's parent is one of the locked nodes, locked by one winner only).
        unsafe { reinsert_shared(&nodes, &parents, r.input, r.output) };
    });
    winners
}

/// The nodes one reinsertion locks: the six of the aggressive strategy (fewer where some do not
/// exist), plus the path for the conservative one. Held inline, so that the aggressive
/// strategy allocates nothing per move.
pub(super) struct Claim {
    six: [u32; 6],
    len: usize,
    path: Vec<u32>,
}

impl Claim {
    pub(super) fn nodes(&self) -> impl Iterator<Item = u32> + '_ {
        self.six[..self.len].iter().chain(&self.path).copied()
    }
}

/// The nodes a reinsertion of `input` next to `output` locks.
pub(super) fn locked_nodes(bvh: &Bvh, input: u32, output: u32, strategy: LockStrategy) -> Claim {
    let parent = bvh.parents[input as usize];
    let mut claim = Claim { six: [INVALID_INDEX; 6], len: 0, path: Vec::new() };
    let six = [input, input ^ 1, parent, bvh.parents[parent as usize], output, bvh.parents[output as usize]];
    for n in six {
        if n != INVALID_INDEX {
            claim.six[claim.len] = n;
            claim.len += 1;
        }
    }
    if strategy == LockStrategy::Conservative {
        // The path: from the input's parent up to the common ancestor, and down to the output.
        let mut up = Vec::new();
        let mut n = parent;
        while n != INVALID_INDEX {
            up.push(n);
            n = bvh.parents[n as usize];
        }
        let mut n = output;
        while n != INVALID_INDEX {
            if let Some(k) = up.iter().position(|&a| a == n) {
                claim.path.extend_from_slice(&up[..=k]);
                break;
            }
            claim.path.push(n);
            n = bvh.parents[n as usize];
        }
    }
    claim
}

/// Moves `input` (with its subtree) to become the sibling of `output`, and refits nothing: the
/// new parent's box is exact, the other ancestors' boxes are stale until a refit.
///
/// `input` must not be the root or the padding node; `output` must not be `input`'s parent nor
/// lie in `input`'s subtree.
pub fn reinsert(bvh: &mut Bvh, input: u32, output: u32) {
    assert!(input >= 2 && (input as usize) < bvh.nodes.len(), "cannot reinsert node {input}");
    let Bvh { nodes, parents, .. } = bvh;
    let (nodes, parents) = (SharedSlice::new(nodes), SharedSlice::new(parents));
    // SAFETY: one thread, exclusive borrows.
    unsafe { reinsert_shared(&nodes, &parents, input, output) };
}

/// The reinsertion itself, on shared arrays:
///
/// ```text
///        G                  G                       P                 P
///        |                  |                       |                 |
///        Q        remove    S'       insert at O    O      ->         O' (new: first = e)
///       / \       ------>  / \      ------------>  / \               /  \
///  (e) N   S      (pair e free)                   .   .      (e) O    N (e + 1)
/// ```
/// Q's slot takes S's content, so G's link stays valid; the pair `e = N & !1` is then free and
/// takes O's content and N's, under a new internal node in O's slot.
///
/// # Safety
/// No other thread reads or writes, concurrently, the nodes input, its sibling, its parent,
/// output, or the parent links of their children.
unsafe fn reinsert_shared(nodes: &SharedSlice<BvhNode>, parents: &SharedSlice<u32>, input: u32, output: u32) {
    // SAFETY (whole body): the caller guarantees exclusive access to every index used here.
    unsafe {
        let (n, s) = (input as usize, (input ^ 1) as usize);
        let q = parents.get(n) as usize;
        debug_assert!(output != q as u32 && output != input, "invalid reinsertion {input} -> {output}");
        let adopt = |node: &BvhNode, slot: usize| {
            if !node.is_leaf() {
                parents.set(node.first as usize, slot as u32);
                parents.set(node.first as usize + 1, slot as u32);
            }
        };
        let n_node = nodes.get(n);
        let s_node = nodes.get(s);
        // Remove: the sibling takes the parent's place.
        nodes.set(q, s_node);
        adopt(&s_node, q);
        // Insert: the output's content and the input's go to the freed pair.
        let o = if output as usize == s { q } else { output as usize };
        let o_node = nodes.get(o);
        let e = n & !1;
        nodes.set(e, o_node);
        adopt(&o_node, e);
        nodes.set(e + 1, n_node);
        adopt(&n_node, e + 1);
        parents.set(e, o as u32);
        parents.set(e + 1, o as u32);
        nodes.set(o, BvhNode::internal(o_node.aabb().union(n_node.aabb()), e as u32));
    }
}
