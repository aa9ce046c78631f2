//! Refit and SAH tracking after an iteration's reinsertions (section 4.4, step 4): a parallel
//! bottom-up refit of the moved nodes' ancestors only, and the SAH followed from the boxes that
//! changed instead of summed over every node (see the departures in [`super`]).

use super::reinsert::Reinsertion;
use super::search::Box4;
use crate::bvh::parallel::SharedSlice;
use crate::bvh::{Bvh, INVALID_INDEX, SahCosts};
use crate::geometry::Aabb;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering};

/// The slots whose boxes are exact after `applied` but whose ancestors' boxes are stale: for
/// each reinsertion, the input's old parent slot (now the old sibling) and the new internal node.
pub fn changed_slots(applied: &[Reinsertion]) -> Vec<u32> {
    applied.iter().flat_map(|r| [r.parent, r.new_node()]).collect()
}

/// Scratch memory of [`refit_above`], all zero between calls.
#[derive(Default)]
pub struct RefitScratch {
    /// 1 for a node whose box is stale.
    stale: Vec<AtomicU32>,
    /// A stale node's stale children not yet refitted.
    pending: Vec<AtomicU32>,
}

/// Refits the strict ancestors of `starts`, and nothing else: every box not above a start must
/// be exact already. The section 4.4 refit, restricted to the paths that changed: the stale set
/// is marked by climbing from each start until a node another climb marked, then refitted bottom
/// up with per-node counters of stale children (the Karras scheme, counting only stale ones).
/// Costs the number of stale nodes, not the tree's size: late PRBVH iterations move few nodes.
pub fn refit_above(bvh: &mut Bvh, starts: &[u32], scratch: &mut RefitScratch) {
    refit_tracking(bvh, starts, scratch, None, None);
}

/// [`refit_above`], also returning the SAH change of the refitted boxes (see [`TrackedSah`]) and
/// storing their areas in `areas` (see [`NodeAreas`]).
pub(super) fn refit_tracking(
    bvh: &mut Bvh,
    starts: &[u32],
    scratch: &mut RefitScratch,
    tracked: Option<&TrackedSah>,
    areas: Option<SharedSlice<f32>>,
) -> Option<i128> {
    let len = bvh.nodes.len();
    for v in [&mut scratch.stale, &mut scratch.pending] {
        if v.len() < len {
            v.resize_with(len, || AtomicU32::new(0));
        }
    }
    let RefitScratch { stale, pending } = &*scratch;
    let parents = &bvh.parents;
    // Mark: each climb stops where another has been, so every stale node is listed once.
    let marked: Vec<u32> = starts
        .par_iter()
        .with_min_len(64)
        .flat_map_iter(|&start| {
            let mut n = parents[start as usize];
            std::iter::from_fn(move || {
                let here = n;
                (here != INVALID_INDEX && stale[here as usize].swap(1, Ordering::Relaxed) == 0).then(|| {
                    n = parents[here as usize];
                    here
                })
            })
        })
        .collect();
    // Count each stale node's stale children; those with none start the climb.
    marked.par_iter().with_min_len(256).for_each(|&n| {
        let p = parents[n as usize];
        if p != INVALID_INDEX {
            pending[p as usize].fetch_add(1, Ordering::Relaxed);
        }
    });
    let first: Vec<u32> = marked
        .par_iter()
        .with_min_len(256)
        .copied()
        .filter(|&n| pending[n as usize].load(Ordering::Relaxed) == 0)
        .collect();
    let Bvh { nodes, parents, .. } = bvh;
    let nodes = SharedSlice::new(nodes);
    first
        .par_iter()
        .with_min_len(64)
        .map(|&start| {
            let mut change = Some(0i128);
            let mut n = start;
            loop {
                // SAFETY: node `n` is written by this thread only: it is the one that brought its
                // stale-children count to zero (or `n` had none), after those children were
                // written; the AcqRel decrement below makes their writes visible here.
                unsafe {
                    let mut node = nodes.get(n as usize);
                    let old = node.aabb();
                    let l = node.first as usize;
                    node.set_aabb(nodes.get(l).aabb().union(nodes.get(l + 1).aabb()));
                    if let Some(t) = tracked {
                        change = change.zip(t.internal_change(&old, &node.aabb())).and_then(|(a, b)| a.checked_add(b));
                    }
                    if let Some(areas) = &areas {
                        areas.set(n as usize, Box4::of(&node).area());
                    }
                    nodes.set(n as usize, node);
                }
                stale[n as usize].store(0, Ordering::Relaxed);
                n = parents[n as usize];
                if n == INVALID_INDEX || pending[n as usize].fetch_sub(1, Ordering::AcqRel) != 1 {
                    break;
                }
            }
            change
        })
        .reduce(|| Some(0), |a, b| a.zip(b).and_then(|(a, b)| a.checked_add(b)))
}

/// The SAH followed iteration by iteration from what changed, instead of a reduction over every
/// node, which took a noticeable share of the optimisation's time (docs/benchmarks.md, "The SAH
/// followed, not summed").
///
/// A reinsertion leaves every box in place but two: the input's old parent disappears and the
/// new internal node appears, both interior nodes (leaves move whole). The refit then changes
/// the boxes of their ancestors. So the SAH changes by `cT / SA(root)` times the sum of those
/// area changes, and `SA(root)` never changes. The changes are summed in fixed point (units of
/// 2^-60), where addition is exact and so the total does not depend on the order the threads
/// add in, nor then on the thread count. A non-finite area falls back to the full reduction.
pub(super) struct TrackedSah {
    /// `cT / SA(root)` times 2^60, or 0 when the root has no area (the SAH then counts nodes,
    /// which reinsertion does not change).
    scale: f64,
    /// The SAH in units of 2^-60; `None` where it cannot be held (non-finite or beyond 10^12).
    fixed: Option<i128>,
}

impl TrackedSah {
    const ONE: f64 = (1u64 << 60) as f64;

    pub(super) fn new(bvh: &Bvh, costs: &SahCosts, sah: f64) -> Self {
        let root = bvh.nodes.first().map_or(0.0, |n| crate::bvh::sah::half_area_f64(&n.aabb()));
        let scale = if root > 0.0 { costs.traversal as f64 / root * Self::ONE } else { 0.0 };
        Self { scale, fixed: Self::to_fixed(sah * Self::ONE) }
    }

    /// `x` (already in units of 2^-60) rounded to an integer; `None` when not finite or beyond
    /// 2^100 (an SAH of 10^12), where sums could overflow.
    pub(super) fn to_fixed(x: f64) -> Option<i128> {
        (x.is_finite() && x.abs() < 2f64.powi(100)).then(|| x.round() as i128)
    }

    /// The SAH change of an interior node's box going from `old` to `new`, in fixed point.
    pub(super) fn internal_change(&self, old: &Aabb, new: &Aabb) -> Option<i128> {
        use crate::bvh::sah::half_area_f64;
        Self::to_fixed((half_area_f64(new) - half_area_f64(old)) * self.scale)
    }

    /// The change of `applied`, just applied and not yet refitted: each new internal node's box
    /// appears and its input's old parent's disappears.
    pub(super) fn reinsertions(&self, bvh: &Bvh, applied: &[Reinsertion]) -> Option<i128> {
        applied
            .par_iter()
            .map(|r| self.internal_change(&r.parent_box, &bvh.nodes[r.new_node() as usize].aabb()))
            .reduce(|| Some(0), |a, b| a.zip(b).and_then(|(a, b)| a.checked_add(b)))
    }

    /// Adds an iteration's change and returns the SAH; `full` recomputes it where the change
    /// could not be followed.
    pub(super) fn update(&mut self, change: Option<(i128, i128)>, full: impl FnOnce() -> f64) -> f64 {
        match self.fixed.zip(change).and_then(|(f, (a, b))| f.checked_add(a)?.checked_add(b)) {
            Some(fixed) => {
                self.fixed = Some(fixed);
                fixed as f64 / Self::ONE
            }
            None => {
                let sah = full();
                self.fixed = Self::to_fixed(sah * Self::ONE);
                sah
            }
        }
    }
}
