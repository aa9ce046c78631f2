//! Sequential reinsertion (RBVH): Bittner, Hapala & Havran, "Fast Insertion-Based Optimization of
//! Bounding Volume Hierarchies" (Computer Graphics Forum 2013), the method parallel reinsertion
//! is measured against in Meister & Bittner 2018 (section 6, Table 1).
//!
//! Batches of the least efficient internal nodes are taken out of the tree and their two
//! children put back where they cost least:
//! 1. **Select**: rank the internal nodes (not the root) by the product of three inefficiency
//!    measures, `A(N) / mean(A(children))`, `A(N) / min(A(children))` and `A(N)`, and take the
//!    worst fraction of them ([`RbvhConfig::batch`]).
//! 2. **Remove** each one, N: its sibling takes the parent's place, which frees N's slot and the
//!    parent's; N's two children are orphaned.
//! 3. **Reinsert** the orphans, larger first, each as the sibling of the node that raises the
//!    total surface area least. The search is best-first branch and bound from the root on the
//!    induced cost (the growth of the would-be ancestors), as in Bittner et al.'s insertion;
//!    a subtree is skipped once its induced cost plus the orphan's own area cannot win.
//! 4. After each batch the SAH is measured. The run stops when `patience` batches in a row did
//!    not lower the best SAH by `min_gain` (relative), and returns the best tree seen.
//!
//! Decisions where the paper leaves room, set by measurement on the bunny (docs/benchmarks.md,
//! "RBVH settings"): batches of 10% of the internal nodes; a slot taken out is not selected again
//! for 5 batches (without this, the same few inefficient but well-placed nodes are taken out
//! batch after batch and the run stalls well above the SAH it can reach); the run stops after 20
//! batches without a 0.01% gain. Smaller batches or earlier stops ended at a higher SAH. Boxes are
//! refitted along the changed paths after every removal and insertion, so each search sees an
//! exact tree. It runs on one thread, as the paper's does: a reference, not a production builder
//! (it takes many times PRBVH's time).

use std::time::{Duration, Instant};

use crate::bvh::dynamic::best_sibling;
use crate::bvh::{Bvh, BvhNode, INVALID_INDEX, SahCosts, sah_cost_with};
use crate::geometry::Aabb;

/// Options of [`optimize`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RbvhConfig {
    /// Fraction of the internal nodes taken out per batch. Default 0.1.
    pub batch: f64,
    /// Stop after this many batches in a row without a gain of `min_gain`. Default 20.
    pub patience: u32,
    /// Relative SAH gain that counts as progress. Default 1e-4.
    pub min_gain: f64,
    /// At most this many batches. Default 10,000.
    pub max_batches: u32,
    /// A slot taken out is not selected again for this many batches. Default 5.
    pub tabu: u32,
    pub costs: SahCosts,
}

impl Default for RbvhConfig {
    fn default() -> Self {
        Self { batch: 0.1, patience: 20, min_gain: 1e-4, max_batches: 10_000, tabu: 5, costs: SahCosts::default() }
    }
}

/// What [`optimize`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RbvhStats {
    pub initial_sah: f64,
    /// `(time since the start, SAH)` after each batch.
    pub batches: Vec<(Duration, f64)>,
    pub final_sah: f64,
    pub time: Duration,
}

/// Optimises `bvh` (one primitive per leaf or not; leaves move whole) by sequential
/// reinsertion; the result is the best tree seen.
pub fn optimize(bvh: &mut Bvh, config: &RbvhConfig) -> RbvhStats {
    let start = Instant::now();
    let sah = |b: &Bvh| sah_cost_with(b, &config.costs);
    let mut stats = RbvhStats { initial_sah: sah(bvh), ..Default::default() };
    let mut best = (stats.initial_sah, bvh.clone());
    // Fewer than three internal nodes: nothing to move.
    if bvh.nodes.len() >= 7 {
        let internal = (bvh.nodes.len() - 1) / 2;
        let batch = ((internal as f64 * config.batch) as usize).max(1);
        let mut stale = 0;
        // The batch in which each slot was last taken out, to keep a node that found no better
        // place from being selected again and again.
        let mut taken = vec![u32::MAX; bvh.nodes.len()];
        for round in 0..config.max_batches {
            let recent = |i: u32| taken[i as usize] != u32::MAX && round < taken[i as usize] + config.tabu;
            for n in select(bvh, batch, recent) {
                taken[n as usize] = round;
                // An earlier move of this batch may have changed what the slot holds.
                let node = bvh.nodes[n as usize];
                if n >= 2 && !node.is_leaf() {
                    remove_and_reinsert(bvh, n);
                }
            }
            let current = sah(bvh);
            stats.batches.push((start.elapsed(), current));
            if current < best.0 * (1.0 - config.min_gain) {
                stale = 0;
            } else {
                stale += 1;
            }
            if current < best.0 {
                best = (current, bvh.clone());
            }
            if stale >= config.patience {
                break;
            }
        }
    }
    *bvh = best.1;
    stats.final_sah = best.0;
    stats.time = start.elapsed();
    stats
}

/// The `count` internal nodes (not the root, not `excluded`) of highest inefficiency, worst
/// first. Areas are of boxes scaled by the root's [`Aabb::area_scale`].
fn select(bvh: &Bvh, count: usize, excluded: impl Fn(u32) -> bool) -> Vec<u32> {
    let nodes = &bvh.nodes;
    let scale = nodes[0].aabb().area_scale();
    let area = |b: Aabb| b.scaled(scale).half_area_nonempty();
    let mut ranked: Vec<(f32, u32)> = (2..nodes.len() as u32)
        .filter(|&i| !nodes[i as usize].is_leaf() && !excluded(i))
        .map(|i| {
            let n = &nodes[i as usize];
            let a = area(n.aabb());
            let (l, r) = (area(nodes[n.first as usize].aabb()), area(nodes[n.first as usize + 1].aabb()));
            let m_sum = a / (0.5 * (l + r)).max(f32::MIN_POSITIVE);
            let m_min = a / l.min(r).max(f32::MIN_POSITIVE);
            (m_sum * m_min * a, i)
        })
        .collect();
    let count = count.min(ranked.len());
    if count == 0 {
        return Vec::new();
    }
    ranked.select_nth_unstable_by(count - 1, |a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    ranked.truncate(count);
    ranked.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    ranked.into_iter().map(|(_, i)| i).collect()
}

/// Writes `node` into `slot` and points its children at it.
fn place(bvh: &mut Bvh, slot: u32, node: BvhNode) {
    bvh.nodes[slot as usize] = node;
    if !node.is_leaf() {
        bvh.parents[node.first as usize] = slot;
        bvh.parents[node.first as usize + 1] = slot;
    }
}

/// Recomputes the boxes from `node` up to the root.
fn refit_up(bvh: &mut Bvh, mut node: u32) {
    while node != INVALID_INDEX {
        let n = bvh.nodes[node as usize];
        if !n.is_leaf() {
            let b = bvh.nodes[n.first as usize].aabb().union(bvh.nodes[n.first as usize + 1].aabb());
            bvh.nodes[node as usize].set_aabb(b);
        }
        node = bvh.parents[node as usize];
    }
}

/// Takes internal node `n` (not the root) out and reinserts its two children.
fn remove_and_reinsert(bvh: &mut Bvh, n: u32) {
    let node = bvh.nodes[n as usize];
    let p = bvh.parents[n as usize];
    let s = n ^ 1;
    // The orphans, larger first.
    let (mut a, mut b) = (bvh.nodes[node.first as usize], bvh.nodes[node.first as usize + 1]);
    let scale = bvh.nodes[0].aabb().area_scale();
    let area = |b: &BvhNode| b.aabb().scaled(scale).half_area_nonempty();
    if area(&b) > area(&a) {
        std::mem::swap(&mut a, &mut b);
    }
    // The sibling takes the parent's slot; the pair {n, s} and the orphans' pair are free.
    let sibling = bvh.nodes[s as usize];
    place(bvh, p, sibling);
    refit_up(bvh, bvh.parents[p as usize]);
    let free = [n & !1, node.first];
    for (orphan, pair) in [(a, free[0]), (b, free[1])] {
        let target = best_sibling(&bvh.nodes, &orphan.aabb(), |_| false);
        let t = bvh.nodes[target as usize];
        place(bvh, pair, t);
        place(bvh, pair + 1, orphan);
        bvh.parents[pair as usize] = target;
        bvh.parents[pair as usize + 1] = target;
        bvh.nodes[target as usize] = BvhNode::internal(t.aabb().union(orphan.aabb()), pair);
        refit_up(bvh, bvh.parents[target as usize]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::{build::lbvh, validate};

    #[test]
    fn the_tree_does_not_depend_on_the_units() {
        crate::bvh::assert_scale_invariant("lbvh+rbvh", |p| {
            let mut bvh = lbvh::build(p);
            optimize(&mut bvh, &RbvhConfig::default());
            bvh
        });
    }

    fn boxes(n: usize) -> Vec<Aabb> {
        crate::bvh::scattered_boxes(n, 0.3)
    }

    #[test]
    fn keeps_trees_valid_and_never_returns_a_worse_one() {
        for n in [1, 2, 3, 4, 5, 40, 2000] {
            let prims = boxes(n);
            let mut bvh = lbvh::build(&prims);
            let before = sah_cost_with(&bvh, &SahCosts::default());
            let stats = optimize(&mut bvh, &RbvhConfig::default());
            validate(&bvh, &prims).unwrap_or_else(|e| panic!("n = {n}: {e}"));
            assert!(stats.final_sah <= before, "n = {n}: {before} -> {}", stats.final_sah);
            assert_eq!(stats.final_sah, sah_cost_with(&bvh, &SahCosts::default()));
            if n >= 40 {
                assert!(stats.final_sah < 0.97 * before, "n = {n}: only {before} -> {}", stats.final_sah);
            }
        }
    }

    #[test]
    fn every_single_reinsertion_gives_a_valid_tree() {
        let prims = boxes(60);
        let base = lbvh::build(&prims);
        for n in 2..base.nodes.len() as u32 {
            if base.nodes[n as usize].is_leaf() {
                continue;
            }
            let mut bvh = base.clone();
            remove_and_reinsert(&mut bvh, n);
            validate(&bvh, &prims).unwrap_or_else(|e| panic!("node {n}: {e}"));
        }
    }
}
