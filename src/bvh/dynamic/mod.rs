//! A BVH kept alive while its primitives move: moved primitives are deleted and reinserted
//! instead of rebuilding the tree.
//!
//! - **Delete** (Cozzi 2008, "Deletion Algorithm", first phase): the primitive's leaf becomes a
//!   *hole*, and its ancestors are marked dirty, walking up until a node that is already dirty or
//!   the root. Invariant: a dirty node's ancestors are all dirty. Only internal nodes (and a root
//!   that became a hole) carry the flag, as in Cozzi's post.
//! - **Clean** (second phase), once per batch: from the root, following only dirty children,
//!   post-order: a node whose children are both holes becomes a hole, a node with one hole takes
//!   its other child's place (the merge), and every other dirty node gets its box recomputed from
//!   its children. It visits exactly the dirty nodes ([`DynamicBvh::clean`] returns the count).
//!   The pairs freed by merges are then filled from the end of the array, so the node array stays
//!   dense and the tree is again a valid [`Bvh`] that every other pass (traversal, SAH, PRBVH,
//!   validation, the GPU upload) takes as it is.
//! - **Insert** (Bittner, Hapala and Havran 2013, section 4.2; the insertion cost of Goldsmith and
//!   Salmon 1987): a best-first branch-and-bound search for the node whose sibling the new leaf
//!   should become, minimising the area of the new parent plus the area the insertion adds to
//!   every ancestor. A node's subtree is skipped once the area already induced on its ancestors
//!   plus the smallest possible remainder (the leaf's own area) cannot beat the best found.
//!   Ancestors' boxes are then grown, stopping at the first that already contains the leaf.
//! - **Local PRBVH**: Meister & Bittner 2018 propose focusing reinsertion on the moving parts of
//!   an animation (section 7). [`DynamicBvh::update`] runs a few rounds of their search, locks and
//!   reinsertion ([`crate::bvh::build::prbvh::reinsert_candidates`]) over only the reinserted leaves, their
//!   parents and grandparents; the boxes the moves leave stale are marked dirty and refitted by
//!   the same clean pass, so the cost follows the number of moving objects, not the scene.
//! - **Quality monitor** (in the spirit of Lauterbach et al. 2006 and Eisemann et al. 2007): the
//!   tree's SAH is kept up to date incrementally (every write of a node adjusts running sums of
//!   internal and leaf areas, so it costs nothing per frame). Every `check_every` updates, or as
//!   soon as that estimate exceeds the last fresh build's SAH by `rebuild_threshold`, a fresh
//!   binned-SAH tree is built over the current boxes; if the kept tree's exact SAH is more than
//!   `rebuild_threshold` above the fresh one's, the fresh tree replaces it. A check that finds
//!   the tree within half the threshold doubles the interval to the next (up to 8 times
//!   `check_every`), and any other check resets it: the fresh build is the monitor's only real
//!   cost, and a healthy tree need not pay it often.
//!
//! **Interleaving** (left open by Cozzi): deletions, cleans and insertions may come in any order.
//! An insertion while the tree is dirty searches the boxes as they are (a dirty node's box still
//! contains everything below it, so it is a valid, if loose, bound), never chooses a hole as its
//! sibling, and carries the dirty flag of the node it displaces, so the invariant holds and the
//! next clean makes every box tight again. [`DynamicBvh::update`] itself orders a frame as: all
//! deletions, one clean, all insertions, local PRBVH; a tree is traversable only when clean.
//!
//! Layout: leaves hold one primitive each; a leaf's `first` is the primitive's id and `prim_ids`
//! is the identity, so a primitive's slot in `prim_ids` never moves. `leaf_of` maps each id back
//! to its leaf (Cozzi's object-to-leaf back pointer).

pub mod instances;

use std::collections::{BinaryHeap, HashSet};
use std::sync::atomic::AtomicU64;
use std::time::Instant;

use bytemuck::Zeroable;
use glam::Vec3;

use crate::bvh::build::binned_sah::{self, BinnedSahConfig};
use crate::bvh::build::prbvh::{self, LockStrategy};
use crate::bvh::{Bvh, BvhNode, INVALID_INDEX, Nodes, PAD_INDEX, SahCosts};
use crate::geometry::Aabb;

/// A deleted leaf, until the next clean removes it.
const HOLE: BvhNode =
    BvhNode { aabb_min: Vec3::INFINITY, first: INVALID_INDEX, aabb_max: Vec3::NEG_INFINITY, prim_count: 0 };

fn is_hole(n: &BvhNode) -> bool {
    n.prim_count == 0 && n.first == INVALID_INDEX
}

/// The node a subtree with box `b` should become the sibling of, in the tree under `nodes[0]`:
/// best-first branch and bound on the insertion cost (module docs), skipping nodes for which
/// `skip` holds. Never the padding. Shared with [`crate::bvh::build::rbvh`]. Areas are of boxes scaled by
/// [`Aabb::area_scale`] of the root and `b`, so that they neither overflow nor underflow.
pub(crate) fn best_sibling(nodes: &[BvhNode], b: &Aabb, skip: impl Fn(&BvhNode) -> bool) -> u32 {
    let scale = nodes[0].aabb().union(*b).area_scale();
    let area = |a: Aabb| a.scaled(scale).half_area();
    let area_b = area(*b);
    // Min-heap on the induced cost: non-negative floats order like their bits.
    let mut heap = BinaryHeap::new();
    heap.push(std::cmp::Reverse((0f32.to_bits(), 0u32)));
    let (mut best_cost, mut best) = (f32::INFINITY, 0u32);
    while let Some(std::cmp::Reverse((induced_bits, n))) = heap.pop() {
        let induced = f32::from_bits(induced_bits);
        if induced + area_b >= best_cost {
            break;
        }
        let node = nodes[n as usize];
        if skip(&node) {
            continue;
        }
        let merged = area(node.aabb().union(*b));
        let cost = merged + induced;
        if cost < best_cost {
            (best_cost, best) = (cost, n);
        }
        if !node.is_leaf() {
            let child_induced = (induced + merged - area(node.aabb())).max(0.0);
            if child_induced + area_b < best_cost {
                heap.push(std::cmp::Reverse((child_induced.to_bits(), node.first)));
                heap.push(std::cmp::Reverse((child_induced.to_bits(), node.first + 1)));
            }
        }
    }
    best
}

/// Options of [`DynamicBvh::update`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DynamicConfig {
    /// Rounds of local PRBVH after the insertions. Default 1: on `scenes/instanced-field.toml` a
    /// second round cost more time for no lower SAH. 0 turns it off.
    pub prbvh_rounds: u32,
    pub prbvh_strategy: LockStrategy,
    /// Compare with a fresh build every this many updates. Default 30.
    pub check_every: u32,
    /// Rebuild when the tree's SAH exceeds a fresh build's by more than this fraction. Default
    /// 0.03.
    pub rebuild_threshold: f64,
    /// When more than this fraction of the primitives moves in one update, build afresh instead:
    /// reinsertion costs several times a build's per-primitive cost, as measured by
    /// `bvh-bench --procedural-animated` (docs/benchmarks.md, "Animation"). Default 0.25.
    pub rebuild_fraction: f64,
    pub costs: SahCosts,
}

impl Default for DynamicConfig {
    fn default() -> Self {
        Self {
            prbvh_rounds: 1,
            prbvh_strategy: LockStrategy::Aggressive,
            check_every: 30,
            rebuild_threshold: 0.03,
            rebuild_fraction: 0.25,
            costs: SahCosts::default(),
        }
    }
}

/// What one [`DynamicBvh::update`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct UpdateStats {
    /// Primitives deleted and reinserted.
    pub moved: usize,
    /// Dirty nodes the clean passes visited.
    pub clean_visits: usize,
    /// Local PRBVH reinsertions applied.
    pub reinsertions: usize,
    /// The tree's SAH afterwards, from the running sums.
    pub sah_estimate: f64,
    /// The fresh build's SAH, when the monitor built one this update.
    pub fresh_sah: Option<f64>,
    /// Whether the monitor replaced the tree by the fresh build.
    pub rebuilt: bool,
    pub seconds: f64,
    /// Of `seconds`, the local PRBVH rounds'.
    pub prbvh_seconds: f64,
    /// The share of the tree's SAH the local PRBVH rounds removed.
    pub prbvh_sah_drop: f64,
}

/// A binary BVH over primitive boxes, one primitive per leaf, that supports deletion, batched
/// cleanup and insertion (see the module docs).
#[derive(Debug)]
pub struct DynamicBvh {
    bvh: Bvh,
    dirty: Vec<bool>,
    leaf_of: Vec<u32>,
    /// Running sums of half areas: internal nodes, and leaves times their primitive count.
    area_internal: f64,
    area_leaves: f64,
    locks: Vec<AtomicU64>,
    /// Quality monitor: updates since the last fresh build, that build's SAH, and the factor
    /// (1 to 8) the check interval is stretched by while checks find the tree healthy.
    updates_since_check: u32,
    fresh_sah: f64,
    interval_scale: u32,
}

impl DynamicBvh {
    /// A tree of the primitives `boxes` (ids `0..boxes.len()`), built by binned SAH.
    pub fn build(boxes: &[Aabb]) -> Self {
        Self::from_bvh(&fresh_build(boxes), boxes.len())
    }

    /// Takes over a valid tree with one primitive per leaf, over ids below `capacity`.
    pub fn from_bvh(bvh: &Bvh, capacity: usize) -> Self {
        let mut nodes: Nodes = bvh.nodes.to_vec().into();
        let mut leaf_of = vec![INVALID_INDEX; capacity];
        for (i, n) in nodes.iter_mut().enumerate() {
            if n.is_leaf() && i != PAD_INDEX as usize {
                assert!(n.prim_count == 1, "a dynamic BVH holds one primitive per leaf");
                n.first = bvh.prim_ids[n.first as usize];
                leaf_of[n.first as usize] = i as u32;
            }
        }
        let mut s = Self {
            dirty: vec![false; nodes.len()],
            bvh: Bvh { nodes, parents: bvh.parents.clone(), prim_ids: (0..capacity as u32).collect() },
            leaf_of,
            area_internal: 0.0,
            area_leaves: 0.0,
            locks: Vec::new(),
            updates_since_check: 0,
            fresh_sah: 0.0,
            interval_scale: 1,
        };
        s.resync_areas();
        s.fresh_sah = s.sah_estimate(&SahCosts::default());
        s
    }

    /// The tree. Between a deletion and the next clean it holds holes and stale boxes and must
    /// not be traversed.
    pub fn bvh(&self) -> &Bvh {
        &self.bvh
    }

    /// Whether deletions or insertions are waiting for a clean.
    pub fn is_dirty(&self) -> bool {
        self.dirty.first().copied().unwrap_or(false)
    }

    /// Number of dirty nodes (what the next clean will visit).
    pub fn dirty_count(&self) -> usize {
        self.dirty.iter().filter(|&&d| d).count()
    }

    /// Whether primitive `prim` is in the tree.
    pub fn contains(&self, prim: u32) -> bool {
        self.leaf_of.get(prim as usize).is_some_and(|&l| l != INVALID_INDEX)
    }

    /// Primitives in the tree.
    pub fn prim_count(&self) -> usize {
        self.leaf_of.iter().filter(|&&l| l != INVALID_INDEX).count()
    }

    pub fn is_empty(&self) -> bool {
        self.bvh.nodes.is_empty() || is_hole(&self.bvh.nodes[0])
    }

    /// Half-area contributions of node `i`: (internal, leaves).
    fn contribution(i: usize, n: &BvhNode) -> (f64, f64) {
        if i == PAD_INDEX as usize || is_hole(n) {
            (0.0, 0.0)
        } else if n.is_leaf() {
            (0.0, n.aabb().half_area() as f64 * n.prim_count as f64)
        } else {
            (n.aabb().half_area() as f64, 0.0)
        }
    }

    /// Writes node `i`, keeping the area sums.
    fn set(&mut self, i: usize, n: BvhNode) {
        let (a, b) = Self::contribution(i, &self.bvh.nodes[i]);
        let (c, d) = Self::contribution(i, &n);
        self.area_internal += c - a;
        self.area_leaves += d - b;
        self.bvh.nodes[i] = n;
    }

    /// Writes `n` into slot `i` and points its children (or its primitive) back at `i`.
    fn place(&mut self, i: usize, n: BvhNode) {
        self.set(i, n);
        if is_hole(&n) {
            return;
        }
        if n.is_leaf() {
            self.leaf_of[n.first as usize] = i as u32;
        } else {
            self.bvh.parents[n.first as usize] = i as u32;
            self.bvh.parents[n.first as usize + 1] = i as u32;
        }
    }

    /// Recomputes the area sums from scratch (they drift by rounding over many updates).
    pub fn resync_areas(&mut self) {
        (self.area_internal, self.area_leaves) = self.exact_areas();
    }

    fn exact_areas(&self) -> (f64, f64) {
        let (mut a, mut b) = (0.0, 0.0);
        for (i, n) in self.bvh.nodes.iter().enumerate() {
            let (c, d) = Self::contribution(i, n);
            a += c;
            b += d;
        }
        (a, b)
    }

    /// The SAH (equation 2 of Meister & Bittner 2018) from the running area sums: O(1).
    pub fn sah_estimate(&self, costs: &SahCosts) -> f64 {
        if self.is_empty() {
            return 0.0;
        }
        let sum = costs.traversal as f64 * self.area_internal + costs.intersection as f64 * self.area_leaves;
        let root = self.bvh.nodes[0].aabb().half_area() as f64;
        if root > 0.0 { sum / root } else { sum }
    }

    /// Deletes primitive `prim`'s leaf and marks its ancestors dirty. Returns false if it was not
    /// in the tree.
    pub fn remove(&mut self, prim: u32) -> bool {
        if !self.contains(prim) {
            return false;
        }
        let slot = self.leaf_of[prim as usize];
        self.leaf_of[prim as usize] = INVALID_INDEX;
        self.set(slot as usize, HOLE);
        if slot == 0 {
            self.dirty[0] = true;
        } else {
            self.mark_dirty_from(self.bvh.parents[slot as usize]);
        }
        true
    }

    /// Gives primitive `prim`'s leaf the box `b` and marks its ancestors dirty, keeping the
    /// topology: the next clean refits exactly the boxes above the changed leaves.
    pub fn refit_leaf(&mut self, prim: u32, b: Aabb) {
        assert!(self.contains(prim), "primitive {prim} is not in the tree");
        let slot = self.leaf_of[prim as usize] as usize;
        let mut n = self.bvh.nodes[slot];
        n.set_aabb(b);
        self.set(slot, n);
        let parent = self.bvh.parents[slot];
        self.mark_dirty_from(parent);
    }

    /// Marks `node` and its ancestors dirty, stopping at the first that already is.
    fn mark_dirty_from(&mut self, mut node: u32) {
        while node != INVALID_INDEX && !self.dirty[node as usize] {
            self.dirty[node as usize] = true;
            node = self.bvh.parents[node as usize];
        }
    }

    /// Inserts primitive `prim` with box `b` (see the module docs). Panics if it is already in
    /// the tree.
    pub fn insert(&mut self, prim: u32, b: Aabb) {
        assert!(!self.contains(prim), "primitive {prim} is already in the tree");
        if prim as usize >= self.leaf_of.len() {
            self.leaf_of.resize(prim as usize + 1, INVALID_INDEX);
            self.bvh.prim_ids = (0..self.leaf_of.len() as u32).collect();
        }
        let leaf = BvhNode::leaf(b, prim, 1);
        if self.bvh.nodes.is_empty() {
            self.bvh.nodes.push(HOLE);
            self.bvh.parents.push(INVALID_INDEX);
            self.dirty.push(false);
        }
        if is_hole(&self.bvh.nodes[0]) {
            // The tree emptied and has not been cleaned: the leaf becomes the root.
            self.place(0, leaf);
            self.dirty[0] = false;
            return;
        }
        let o = self.find_insertion(&b) as usize;
        if self.bvh.nodes.len() == 1 {
            self.bvh.nodes.push(BvhNode::zeroed());
            self.bvh.parents.push(INVALID_INDEX);
            self.dirty.push(false);
        }
        let e = self.bvh.nodes.len();
        for _ in 0..2 {
            self.bvh.nodes.push(HOLE);
            self.bvh.parents.push(o as u32);
            self.dirty.push(false);
        }
        let displaced = self.bvh.nodes[o];
        self.place(e, displaced);
        self.dirty[e] = self.dirty[o];
        self.place(e + 1, leaf);
        self.set(o, BvhNode::internal(displaced.aabb().union(b), e as u32));
        let mut a = self.bvh.parents[o];
        while a != INVALID_INDEX {
            let mut n = self.bvh.nodes[a as usize];
            if n.aabb().contains_box(&b) {
                break;
            }
            n.set_aabb(n.aabb().union(b));
            self.set(a as usize, n);
            a = self.bvh.parents[a as usize];
        }
    }

    /// The node the new leaf `b` should become the sibling of ([`best_sibling`]). Never a hole
    /// or the padding.
    fn find_insertion(&self, b: &Aabb) -> u32 {
        best_sibling(&self.bvh.nodes, b, is_hole)
    }

    /// The batched clean (module docs); returns the number of nodes visited, which is the number
    /// of dirty nodes.
    pub fn clean(&mut self) -> usize {
        if !self.is_dirty() {
            return 0;
        }
        let mut visits = 0;
        let mut freed = Vec::new();
        let mut stack = vec![(0u32, false)];
        while let Some((n, expanded)) = stack.pop() {
            let node = self.bvh.nodes[n as usize];
            if is_hole(&node) || node.is_leaf() {
                // Only the root gets here: a single leaf, or a deleted one.
                visits += 1;
                self.dirty[n as usize] = false;
                continue;
            }
            let f = node.first as usize;
            if !expanded {
                stack.push((n, true));
                for c in [f, f + 1] {
                    let child = &self.bvh.nodes[c];
                    if self.dirty[c] && !child.is_leaf() && !is_hole(child) {
                        stack.push((c as u32, false));
                    }
                }
                continue;
            }
            visits += 1;
            let (l, r) = (self.bvh.nodes[f], self.bvh.nodes[f + 1]);
            match (is_hole(&l), is_hole(&r)) {
                (true, true) => {
                    self.set(n as usize, HOLE);
                    freed.push(f as u32);
                }
                (true, false) | (false, true) => {
                    let (k, kept) = if is_hole(&l) { (f + 1, r) } else { (f, l) };
                    self.set(k, HOLE);
                    self.place(n as usize, kept);
                    freed.push(f as u32);
                }
                (false, false) => {
                    let mut m = node;
                    m.set_aabb(l.aabb().union(r.aabb()));
                    self.set(n as usize, m);
                }
            }
            self.dirty[n as usize] = false;
        }
        self.compact(freed);
        visits
    }

    /// Fills the freed pairs (each given by its first slot) with pairs from the end of the array
    /// and truncates it, fixing the links into and out of every moved pair.
    fn compact(&mut self, freed: Vec<u32>) {
        if is_hole(&self.bvh.nodes[0]) {
            self.bvh.nodes.clear();
            self.bvh.parents.clear();
            self.dirty.clear();
            (self.area_internal, self.area_leaves) = (0.0, 0.0);
            return;
        }
        let mut free: HashSet<u32> = freed.iter().map(|&f| f / 2).collect();
        let mut sorted: Vec<u32> = free.iter().copied().collect();
        sorted.sort_unstable();
        let mut last = (self.bvh.nodes.len() / 2).saturating_sub(1) as u32;
        for f in sorted {
            while last > 0 && free.contains(&last) {
                last -= 1;
            }
            if f >= last {
                break;
            }
            self.move_pair(last as usize, f as usize);
            free.remove(&f);
            last -= 1;
        }
        while last > 0 && free.contains(&last) {
            last -= 1;
        }
        let len = if last == 0 && self.bvh.nodes[0].is_leaf() { 1 } else { 2 * (last as usize + 1) };
        self.bvh.nodes.truncate(len);
        self.bvh.parents.truncate(len);
        self.dirty.truncate(len);
    }

    /// Moves pair `from` (a pair index) into the free pair `to`.
    fn move_pair(&mut self, from: usize, to: usize) {
        for k in 0..2 {
            let (src, dst) = (2 * from + k, 2 * to + k);
            let node = self.bvh.nodes[src];
            self.set(src, HOLE);
            self.place(dst, node);
            self.bvh.parents[dst] = self.bvh.parents[src];
            self.dirty[dst] = self.dirty[src];
            self.dirty[src] = false;
        }
        let p = self.bvh.parents[2 * to] as usize;
        self.bvh.nodes[p].first = 2 * to as u32;
    }

    /// One frame: deletes every primitive in `moves` and reinserts it with its new box, cleans,
    /// runs the local PRBVH rounds and the quality monitor (module docs); or, when more than
    /// `rebuild_fraction` of the primitives move, builds afresh. `boxes` holds every
    /// primitive's current box (the monitor's fresh build reads it; ids not in the tree are
    /// ignored only if their box is empty). The tree is clean afterwards.
    pub fn update(&mut self, moves: &[(u32, Aabb)], boxes: &[Aabb], config: &DynamicConfig) -> UpdateStats {
        let start = Instant::now();
        let mut stats = UpdateStats { moved: moves.len(), ..Default::default() };
        if moves.len() as f64 > config.rebuild_fraction * self.prim_count() as f64 {
            let fresh = fresh_build(boxes);
            *self = Self { locks: std::mem::take(&mut self.locks), ..Self::from_bvh(&fresh, boxes.len()) };
            stats.rebuilt = true;
            stats.fresh_sah = Some(self.fresh_sah);
            stats.sah_estimate = self.sah_estimate(&config.costs);
            stats.seconds = start.elapsed().as_secs_f64();
            return stats;
        }
        for &(p, _) in moves {
            self.remove(p);
        }
        stats.clean_visits += self.clean();
        for &(p, b) in moves {
            self.insert(p, b);
        }
        if config.prbvh_rounds > 0 {
            let prbvh_start = Instant::now();
            let before = self.sah_estimate(&config.costs);
            for _ in 0..config.prbvh_rounds {
                let applied = self.local_prbvh(moves.iter().map(|m| m.0), config.prbvh_strategy);
                stats.reinsertions += applied;
                stats.clean_visits += self.clean();
                if applied == 0 {
                    break;
                }
            }
            if before > 0.0 {
                stats.prbvh_sah_drop = (before - self.sah_estimate(&config.costs)) / before;
            }
            stats.prbvh_seconds = prbvh_start.elapsed().as_secs_f64();
        }
        self.updates_since_check += 1;
        let estimate = self.sah_estimate(&config.costs);
        if self.updates_since_check >= config.check_every.saturating_mul(self.interval_scale)
            || estimate > self.fresh_sah * (1.0 + config.rebuild_threshold)
        {
            let fresh = fresh_build(boxes);
            let fresh_sah = crate::bvh::sah_cost_with(&fresh, &config.costs);
            self.resync_areas();
            let kept = self.sah_estimate(&config.costs);
            // A healthy tree is checked less often (up to 8 times the interval); the running
            // estimate still triggers a check as soon as the SAH grows.
            let scale = if kept <= fresh_sah * (1.0 + config.rebuild_threshold / 2.0) {
                (self.interval_scale * 2).min(8)
            } else {
                1
            };
            if kept > fresh_sah * (1.0 + config.rebuild_threshold) {
                *self = Self { locks: std::mem::take(&mut self.locks), ..Self::from_bvh(&fresh, boxes.len()) };
                stats.rebuilt = true;
            }
            self.interval_scale = scale;
            self.fresh_sah = fresh_sah;
            self.updates_since_check = 0;
            stats.fresh_sah = Some(fresh_sah);
        }
        stats.sah_estimate = self.sah_estimate(&config.costs);
        stats.seconds = start.elapsed().as_secs_f64();
        stats
    }

    /// One local PRBVH round over the leaves of `prims`, their parents and grandparents; marks
    /// the stale boxes dirty for the next clean. Returns the reinsertions applied.
    fn local_prbvh(&mut self, prims: impl Iterator<Item = u32>, strategy: LockStrategy) -> usize {
        let mut candidates = Vec::new();
        for p in prims {
            let mut n = self.leaf_of[p as usize];
            for _ in 0..3 {
                if n == INVALID_INDEX || n < 2 {
                    break;
                }
                candidates.push(n);
                n = self.bvh.parents[n as usize];
            }
        }
        candidates.sort_unstable();
        candidates.dedup();
        let applied = prbvh::reinsert_candidates(&mut self.bvh, &candidates, strategy, &mut self.locks);
        for r in &applied {
            let new_node = r.new_node() as usize;
            // The contents moved between slots keep their boxes; the input's old parent left
            // the tree and the new internal node joined it.
            self.area_internal += self.bvh.nodes[new_node].aabb().half_area() as f64 - r.parent_box.half_area() as f64;
            // The leaves among the written slots moved (the new internal node is written too).
            for slot in r.written_slots() {
                let n = self.bvh.nodes[slot as usize];
                if n.is_leaf() {
                    self.leaf_of[n.first as usize] = slot;
                }
            }
        }
        // Mark after every move is applied: the parent links are final.
        for r in &applied {
            let new_node = r.new_node();
            for from in [self.bvh.parents[r.parent as usize], self.bvh.parents[new_node as usize]] {
                self.mark_dirty_from(from);
            }
        }
        applied.len()
    }

    /// Checks every structural invariant, including holes and dirty flags, against the boxes the
    /// primitives were inserted with: links and pairs, reachability, one leaf per primitive in the
    /// tree and `leaf_of` pointing at it, holes only under dirty nodes, dirty nodes' ancestors
    /// dirty, every box containing its children's and equal to their union unless dirty, and the
    /// running area sums. A clean tree holding every primitive also passes [`crate::bvh::validate`].
    pub fn validate(&self, boxes: &[Aabb]) -> Result<(), DynamicValidationError> {
        use DynamicValidationError as E;
        let nodes = &self.bvh.nodes;
        let parents = &self.bvh.parents;
        if nodes.len() != parents.len() || nodes.len() != self.dirty.len() {
            return Err(E::LengthMismatch);
        }
        for (p, &l) in self.leaf_of.iter().enumerate() {
            if l != INVALID_INDEX {
                let n = nodes.get(l as usize).ok_or(E::LeafOfOutOfRange { prim: p, leaf: l })?;
                if !n.is_leaf() || n.first != p as u32 || is_hole(n) {
                    return Err(E::LeafOfWrong { prim: p, leaf: l });
                }
            }
        }
        if nodes.is_empty() {
            return if self.prim_count() == 0 { Ok(()) } else { Err(E::EmptyWithPrimitives) };
        }
        if nodes.len() > 1 && (nodes[1] != BvhNode::zeroed() || parents[1] != INVALID_INDEX || self.dirty[1]) {
            return Err(E::BadPadding);
        }
        if parents[0] != INVALID_INDEX {
            return Err(E::RootHasParent);
        }
        let mut seen = vec![false; nodes.len()];
        let mut leaves = 0;
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            if std::mem::replace(&mut seen[i], true) {
                return Err(E::Revisited(i));
            }
            let n = nodes[i];
            let parent_dirty = i == 0 || self.dirty[parents[i] as usize];
            if self.dirty[i] && !parent_dirty {
                return Err(E::DirtyUnderClean { node: i, parent: parents[i] });
            }
            if is_hole(&n) {
                if !(parent_dirty && (i != 0 || self.dirty[0])) {
                    return Err(E::HoleUnderClean(i));
                }
                continue;
            }
            if n.is_leaf() {
                if self.dirty[i] && i != 0 {
                    return Err(E::DirtyLeaf(i));
                }
                let p = n.first as usize;
                if n.prim_count != 1 || self.leaf_of.get(p) != Some(&(i as u32)) {
                    return Err(E::LeafNotMapped { node: i, prim: p });
                }
                if boxes.get(p).is_none_or(|b| *b != n.aabb()) {
                    return Err(E::LeafBox { node: i, prim: p });
                }
                leaves += 1;
                continue;
            }
            let f = n.first as usize;
            if f % 2 != 0 || f < 2 || f + 1 >= nodes.len() {
                return Err(E::ChildOutOfRange { node: i, child: f });
            }
            if parents[f] != i as u32 || parents[f + 1] != i as u32 {
                return Err(E::ParentLinks(i));
            }
            let union = nodes[f].aabb().union(nodes[f + 1].aabb());
            if !n.aabb().contains_box(&union) {
                return Err(E::BoxNotContaining(i));
            }
            if !self.dirty[i] && n.aabb() != union {
                return Err(E::CleanBoxNotUnion(i));
            }
            stack.extend([f, f + 1]);
        }
        if let Some(i) = (0..nodes.len()).find(|&i| i != PAD_INDEX as usize && !seen[i]) {
            return Err(E::Unreachable(i));
        }
        if leaves != self.prim_count() {
            return Err(E::LeafCount { leaves, prims: self.prim_count() });
        }
        let (internal, leaf) = self.exact_areas();
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-6 * a.abs().max(b.abs()).max(1e-30);
        if !close(internal, self.area_internal) || !close(leaf, self.area_leaves) {
            return Err(E::AreaDrift { running: (self.area_internal, self.area_leaves), exact: (internal, leaf) });
        }
        if !self.is_dirty() && self.prim_count() == self.leaf_of.len() {
            crate::bvh::validate(&self.bvh, boxes)?;
        }
        Ok(())
    }
}

/// What [`DynamicBvh::validate`] finds wrong: the first broken invariant.
#[derive(Debug, thiserror::Error)]
pub enum DynamicValidationError {
    #[error("nodes, parents and dirty flags differ in length")]
    LengthMismatch,
    #[error("primitive {prim}: leaf {leaf} out of range")]
    LeafOfOutOfRange { prim: usize, leaf: u32 },
    #[error("primitive {prim}: leaf_of says {leaf}, which does not hold it")]
    LeafOfWrong { prim: usize, leaf: u32 },
    #[error("empty tree with primitives")]
    EmptyWithPrimitives,
    #[error("padding node is not zeroed")]
    BadPadding,
    #[error("root has a parent")]
    RootHasParent,
    #[error("node {0} reached twice")]
    Revisited(usize),
    #[error("node {node} is dirty but its parent {parent} is not")]
    DirtyUnderClean { node: usize, parent: u32 },
    #[error("hole {0} under a clean node")]
    HoleUnderClean(usize),
    #[error("leaf {0} is marked dirty")]
    DirtyLeaf(usize),
    #[error("leaf {node}: primitive {prim} does not map back to it")]
    LeafNotMapped { node: usize, prim: usize },
    #[error("leaf {node}: box differs from primitive {prim}'s")]
    LeafBox { node: usize, prim: usize },
    #[error("node {node}: child pair {child} out of range")]
    ChildOutOfRange { node: usize, child: usize },
    #[error("node {0}: children's parent links disagree")]
    ParentLinks(usize),
    #[error("node {0}: box does not contain its children")]
    BoxNotContaining(usize),
    #[error("node {0}: clean but its box is not the union of its children's")]
    CleanBoxNotUnion(usize),
    #[error("node {0} is not reachable")]
    Unreachable(usize),
    #[error("{leaves} leaves for {prims} primitives")]
    LeafCount { leaves: usize, prims: usize },
    #[error("running area sums {running:?} drifted from the tree's {exact:?}")]
    AreaDrift { running: (f64, f64), exact: (f64, f64) },
    /// A clean tree holding every primitive fails the static tree's validation.
    #[error(transparent)]
    Tree(#[from] crate::bvh::ValidationError),
}

/// The build the monitor compares with and falls back to: binned SAH, one primitive per leaf.
fn fresh_build(boxes: &[Aabb]) -> Bvh {
    binned_sah::build(boxes, &BinnedSahConfig::default())
}
