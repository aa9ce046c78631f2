//! Parallel reinsertion (PRBVH): Meister & Bittner, "Parallel Reinsertion for Bounding Volume
//! Hierarchy Optimization" (Eurographics 2018).
//!
//! Each iteration (section 4.4):
//! 1. **Search** (section 4.2, Algorithm 1): every candidate node finds, in parallel, the output
//!    node whose sibling it should become to decrease the total surface area most. The search
//!    climbs from the input node through its ancestors (the pivots) and walks each pivot's other
//!    subtree in pre-order using parent links only, accumulating the surface-area decrease `d`
//!    along the path and pruning a subtree when `dbound + d <= dbest`.
//! 2. **Locks** (section 4.3): a reinsertion claims the six nodes whose topology it changes
//!    (input, sibling, parent, grandparent, output, output's parent) with an atomic max of
//!    `(decrease bits << 32) | input index`: the highest decrease wins each node, ties go to the
//!    higher index. The conservative strategy also claims every node on the path between input
//!    and output, which makes the decreases of the winners add up exactly.
//! 3. **Reinsert**: the winners, which share no node, are applied in parallel.
//! 4. **Refit and SAH**: a parallel bottom-up refit (atomic visit counters), then the SAH. The
//!    refit ([`refit_above`]) visits only the ancestors of the moved nodes, counting per node its
//!    stale children instead of both: late iterations move a few hundred nodes of several
//!    hundred thousand. The SAH is not summed over every node by a parallel reduction, as the
//!    paper does, but followed from the boxes that changed (`TrackedSah`); it is the same
//!    value (tested against the full sum), exactly the same for any thread count.
//!
//! Sparse search and termination (section 4.4.1–4.4.2): node `i` searches in iteration `I` when
//! `I ≡ i (mod μ)`; when an iteration lowers the SAH by less than `ε`, `μ` drops by one, and at
//! `μ = 1` the run stops. Afterwards the leaf collapse of [`super::sah`] picks leaf sizes.
//!
//! Departures from the paper:
//! - When the output is a pivot itself (Algorithm 1, lines 30–36), the paper's candidate value
//!   `ddirect + d` leaves out the pivot's own shrink, `AREA(pivot) - AREA(bpivot)`, which line 37
//!   adds only afterwards. We add it to the candidate too, so that every value the search reports
//!   is the true decrease of that reinsertion (the brute-force test checks this).
//! - Our layout keeps siblings adjacent, so a reinsertion moves node contents rather than child
//!   links ([`reinsert`]): the sibling's content moves into the parent's slot, and the freed pair
//!   holds the output and the input under a new node in the output's slot. The grandparent and
//!   the output's parent keep their links; they are locked anyway, as the paper does.
//! - The search stops climbing once the rest of the pivot encloses the input and the bound
//!   `dbound + d` cannot beat the best found: no higher ancestor shrinks when the input leaves,
//!   so nothing further up can do better. It returns the same result (the brute-force test).
//! - Surface areas are half areas (`Aabb::half_area`): the decreases are all halved, which
//!   changes no comparison.
//! - The search reads the areas of the nodes it passes from an array kept beside the tree
//!   (`NodeAreas`), updated for the slots a reinsertion writes and the boxes the refit changes,
//!   instead of computing them: the same values, fewer instructions.
//! - A search visits at most [`MAX_VISITS`] nodes, then prunes every node it reaches: the
//!   paper's search has no bound, and where boxes overlap so that none prunes another (a pile
//!   of triangles in one square) each search walks the whole tree. Searches on meshes stay far
//!   below the bound, so their trees are the paper's.
//! - The search multiplies coordinates by a power of two where the scene's extent is beyond
//!   2^±32 (`search_scale`), so that f32 areas neither overflow nor underflow. Exact, so it
//!   changes no comparison; without it a scene of extent 1e20 has infinite areas and nothing is
//!   ever pruned.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use glam::{BVec4A, Vec3A, Vec3Swizzles, Vec4};
use rayon::prelude::*;

use super::parallel::SharedSlice;
use super::{Bvh, BvhNode, CollapseConfig, INVALID_INDEX, SahCosts, collapse_leaves};
use crate::geometry::Aabb;

/// Which nodes a reinsertion locks (section 4.3.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LockStrategy {
    /// The six nodes whose topology changes. Faster convergence and slightly lower SAH in the
    /// paper's experiments, but one iteration can raise the SAH.
    Aggressive,
    /// The six nodes and every node on the path between input and output: the SAH never rises.
    Conservative,
}

/// Options of [`optimize`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrbvhConfig {
    /// Initial search sparsity μ: node `i` searches in iteration `I` when `I ≡ i (mod μ)`.
    /// Default 9, the fastest of the paper's three presets (μ = 1, 4, 9) at nearly the same SAH
    /// (Table 1).
    pub mu: u32,
    /// When an iteration lowers the SAH by less than this, μ drops by one; at μ = 1 the run
    /// stops. Default 0.1, the paper's value (section 4.4.2).
    pub epsilon: f64,
    /// Stop after this many iterations whatever the SAH does. Default 10,000.
    pub max_iterations: u32,
    /// Default [`LockStrategy::Aggressive`], the paper's choice.
    pub strategy: LockStrategy,
    /// SAH constants for the termination test. Default cT = 3, cI = 2.
    pub costs: SahCosts,
    /// The leaf collapse applied at the end, or `None` to keep one primitive per leaf. Default
    /// `Some(CollapseConfig::default())`.
    pub collapse: Option<CollapseConfig>,
}

impl Default for PrbvhConfig {
    fn default() -> Self {
        Self {
            mu: 9,
            epsilon: 0.1,
            max_iterations: 10_000,
            strategy: LockStrategy::Aggressive,
            costs: SahCosts::default(),
            collapse: Some(CollapseConfig::default()),
        }
    }
}

/// One iteration of [`optimize`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IterationStats {
    /// μ used by this iteration.
    pub mu: u32,
    /// Nodes that searched.
    pub searched: usize,
    /// Nodes that found a positive decrease.
    pub candidates: usize,
    /// Reinsertions that won all their locks and were applied.
    pub reinsertions: usize,
    /// SAH after the iteration's refit.
    pub sah: f64,
    /// Time since `optimize` started, at the end of this iteration.
    pub elapsed: Duration,
}

/// What [`optimize`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PrbvhStats {
    pub initial_sah: f64,
    pub iterations: Vec<IterationStats>,
    /// SAH before the leaf collapse.
    pub sah_before_collapse: f64,
    /// SAH of the returned tree.
    pub final_sah: f64,
    /// Time of the reinsertion iterations (without the collapse).
    pub optimize_time: Duration,
    /// Time of the leaf collapse.
    pub collapse_time: Duration,
}

/// Optimises `bvh` by parallel reinsertion, then collapses leaves as configured.
///
/// Works on any valid tree; leaves are moved whole, so their boxes need no primitives. In debug
/// builds (and so in tests) the tree is validated after every iteration.
pub fn optimize(bvh: &mut Bvh, config: &PrbvhConfig) -> PrbvhStats {
    optimize_while(bvh, config, |_| true)
}

/// What [`optimize_while`] asks about after each iteration.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    pub initial_sah: f64,
    /// SAH before and after this iteration.
    pub previous_sah: f64,
    pub sah: f64,
    /// Time this iteration took.
    pub iteration_time: Duration,
}

/// [`optimize`], stopping early as soon as `keep_going` returns false after an iteration (the
/// μ/ε rule and the iteration cap still apply).
pub fn optimize_while(
    bvh: &mut Bvh,
    config: &PrbvhConfig,
    mut keep_going: impl FnMut(&Progress) -> bool,
) -> PrbvhStats {
    assert!(config.mu >= 1, "PRBVH needs mu >= 1");
    let start = Instant::now();
    let sah = |b: &Bvh| super::sah_cost_with(b, &config.costs);
    let mut stats = PrbvhStats { initial_sah: sah(bvh), ..Default::default() };
    let mut mu = config.mu;
    let mut previous = stats.initial_sah;
    let mut locks: Vec<AtomicU64> = Vec::new();
    let mut refit = RefitScratch::default();
    let mut tracked = TrackedSah::new(bvh, &config.costs, stats.initial_sah);
    let mut areas = NodeAreas::new(bvh);
    // A tree of fewer than three nodes has nothing to reinsert.
    let mut iteration = 0u32;
    while bvh.nodes.len() > 3 && iteration < config.max_iterations {
        let iteration_start = Instant::now();
        let (searched, candidates, applied) = iterate(bvh, iteration, mu, config.strategy, &mut locks, &areas);
        let reinsertions = applied.len();
        let moved = tracked.reinsertions(bvh, &applied);
        areas.moved(bvh, &applied);
        let refitted = refit_tracking(bvh, &changed_slots(&applied), &mut refit, Some(&tracked), areas.shared());
        #[cfg(debug_assertions)]
        debug_validate(bvh, iteration);
        #[cfg(debug_assertions)]
        areas.debug_check(bvh, iteration);
        let current = tracked.update(moved.zip(refitted), || sah(bvh));
        stats.iterations.push(IterationStats {
            mu,
            searched,
            candidates,
            reinsertions,
            sah: current,
            elapsed: start.elapsed(),
        });
        iteration += 1;
        let progress = Progress {
            initial_sah: stats.initial_sah,
            previous_sah: previous,
            sah: current,
            iteration_time: iteration_start.elapsed(),
        };
        if !keep_going(&progress) {
            break;
        }
        match next_mu(previous, current, mu, config.epsilon) {
            Some(next) => mu = next,
            None => break,
        }
        previous = current;
    }
    stats.optimize_time = start.elapsed();
    stats.sah_before_collapse = sah(bvh);
    if let Some(collapse) = &config.collapse {
        let t = Instant::now();
        *bvh = collapse_leaves(bvh, collapse);
        stats.collapse_time = t.elapsed();
    }
    stats.final_sah = sah(bvh);
    stats
}

/// The sparsity after an iteration took the SAH from `previous` to `current` at sparsity `mu`
/// (section 4.4.2): one less when it fell by less than `epsilon`, and `None` (stop) when that
/// happens at `mu = 1`. Shared with the GPU optimiser.
pub fn next_mu(previous: f64, current: f64, mu: u32, epsilon: f64) -> Option<u32> {
    if previous - current >= epsilon {
        Some(mu)
    } else if mu > 1 {
        Some(mu - 1)
    } else {
        None
    }
}

/// One search-lock-reinsert round; returns (searched, candidates, what was applied).
fn iterate(
    bvh: &mut Bvh,
    iteration: u32,
    mu: u32,
    strategy: LockStrategy,
    locks: &mut Vec<AtomicU64>,
    areas: &NodeAreas,
) -> (usize, usize, Vec<Reinsertion>) {
    let len = bvh.nodes.len();
    let phase = (iteration % mu) as usize;
    // Nodes i in 2..len with i ≡ phase (mod μ): the first is 2 + ((phase - 2) mod μ).
    let mu = mu as usize;
    let first = 2 + (phase + mu - 2 % mu) % mu;
    let searched = len.saturating_sub(first).div_ceil(mu);
    let moves = search(bvh, (0..searched).into_par_iter().with_min_len(64).map(|k| first + k * mu), areas.get());
    let applied = lock_and_apply(bvh, &moves, strategy, locks);
    (searched, moves.len(), applied)
}

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
fn refit_tracking(
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
/// node (which took about a tenth of the dragon's optimisation).
///
/// A reinsertion leaves every box in place but two: the input's old parent disappears and the
/// new internal node appears, both interior nodes (leaves move whole). The refit then changes
/// the boxes of their ancestors. So the SAH changes by `cT / SA(root)` times the sum of those
/// area changes, and `SA(root)` never changes. The changes are summed in fixed point (units of
/// 2^-60), where addition is exact and so the total does not depend on the order the threads
/// add in, nor then on the thread count. A non-finite area falls back to the full reduction.
struct TrackedSah {
    /// `cT / SA(root)` times 2^60, or 0 when the root has no area (the SAH then counts nodes,
    /// which reinsertion does not change).
    scale: f64,
    /// The SAH in units of 2^-60; `None` where it cannot be held (non-finite or beyond 10^12).
    fixed: Option<i128>,
}

impl TrackedSah {
    const ONE: f64 = (1u64 << 60) as f64;

    fn new(bvh: &Bvh, costs: &SahCosts, sah: f64) -> Self {
        let root = bvh.nodes.first().map_or(0.0, |n| super::sah::half_area_f64(&n.aabb()));
        let scale = if root > 0.0 { costs.traversal as f64 / root * Self::ONE } else { 0.0 };
        Self { scale, fixed: Self::to_fixed(sah * Self::ONE) }
    }

    /// `x` (already in units of 2^-60) rounded to an integer; `None` when not finite or beyond
    /// 2^100 (an SAH of 10^12), where sums could overflow.
    fn to_fixed(x: f64) -> Option<i128> {
        (x.is_finite() && x.abs() < 2f64.powi(100)).then(|| x.round() as i128)
    }

    /// The SAH change of an interior node's box going from `old` to `new`, in fixed point.
    fn internal_change(&self, old: &Aabb, new: &Aabb) -> Option<i128> {
        use super::sah::half_area_f64;
        Self::to_fixed((half_area_f64(new) - half_area_f64(old)) * self.scale)
    }

    /// The change of `applied`, just applied and not yet refitted: each new internal node's box
    /// appears and its input's old parent's disappears.
    fn reinsertions(&self, bvh: &Bvh, applied: &[Reinsertion]) -> Option<i128> {
        applied
            .par_iter()
            .map(|r| self.internal_change(&r.parent_box, &bvh.nodes[r.new_node() as usize].aabb()))
            .reduce(|| Some(0), |a, b| a.zip(b).and_then(|(a, b)| a.checked_add(b)))
    }

    /// Adds an iteration's change and returns the SAH; `full` recomputes it where the change
    /// could not be followed.
    fn update(&mut self, change: Option<(i128, i128)>, full: impl FnOnce() -> f64) -> f64 {
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

/// Every node's box area, as the search computes it, kept up to date between iterations so that
/// the search reads the areas of the nodes it passes instead of computing them (not in the
/// paper). Held only at unit scale (`search_scale` 1), where these are the search's own values,
/// so the trees are the same to the bit.
struct NodeAreas(Option<Vec<f32>>);

impl NodeAreas {
    fn new(bvh: &Bvh) -> Self {
        let unit = search_scale(bvh.nodes.first()) == 1.0;
        Self(unit.then(|| bvh.nodes.par_iter().with_min_len(4096).map(|n| Box4::of(n).area()).collect()))
    }

    fn get(&self) -> Option<&[f32]> {
        self.0.as_deref()
    }

    fn shared(&mut self) -> Option<SharedSlice<'_, f32>> {
        self.0.as_deref_mut().map(SharedSlice::new)
    }

    /// Updates the slots `applied` wrote (the refit updates their ancestors).
    fn moved(&mut self, bvh: &Bvh, applied: &[Reinsertion]) {
        let Some(areas) = self.shared() else { return };
        let nodes: &[BvhNode] = &bvh.nodes;
        applied.par_iter().for_each(|r| {
            for slot in r.written_slots() {
                // SAFETY: the winners' locked nodes are disjoint, and these are locked nodes (the
                // input's parent, the input and its sibling, the output).
                unsafe { areas.set(slot as usize, Box4::of(&nodes[slot as usize]).area()) };
            }
        });
    }

    /// Checks every area against its node's box.
    #[cfg(debug_assertions)]
    fn debug_check(&self, bvh: &Bvh, iteration: u32) {
        let Some(areas) = &self.0 else { return };
        for (i, (n, a)) in bvh.nodes.iter().zip(areas).enumerate() {
            let want = Box4::of(n).area();
            assert!(
                a.to_bits() == want.to_bits(),
                "PRBVH iteration {iteration}: node {i} has area {a} cached, {want} in its box"
            );
        }
    }
}

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

/// (input, output, decrease) for every searching node with a positive decrease.
/// The decreases are in the search's scaled units (`search_scale`), which order them as the
/// true ones do.
/// `areas`, where given, are the nodes' box areas ([`NodeAreas`]).
fn search(bvh: &Bvh, inputs: impl ParallelIterator<Item = usize>, areas: Option<&[f32]>) -> Vec<(u32, u32, f32)> {
    let scale = search_scale(bvh.nodes.first());
    inputs
        .filter_map(|i| {
            let (out, d) = search_scaled(bvh, i as u32, scale, areas);
            (d > 0.0).then_some((i as u32, out, d))
        })
        .collect()
}

/// Locks, checks and applies `moves`; returns the winners.
fn lock_and_apply(
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
struct Claim {
    six: [u32; 6],
    len: usize,
    path: Vec<u32>,
}

impl Claim {
    fn nodes(&self) -> impl Iterator<Item = u32> + '_ {
        self.six[..self.len].iter().chain(&self.path).copied()
    }
}

/// The nodes a reinsertion of `input` next to `output` locks.
fn locked_nodes(bvh: &Bvh, input: u32, output: u32, strategy: LockStrategy) -> Claim {
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

/// Algorithm 1: the output node `input` should become the sibling of, and the surface-area
/// decrease that gives (0 and the current sibling when nothing is better). `input` must not be
/// the root or the padding node.
pub fn find_best_output(bvh: &Bvh, input: u32) -> (u32, f32) {
    let scale = search_scale(bvh.nodes.first());
    let (out, d) = search_scaled(bvh, input, scale, None);
    (out, d / scale / scale)
}

/// The power of two the search multiplies coordinates by ([`Aabb::area_scale`] of the root):
/// without it, a scene of extent 1e20 has infinite areas, no pruning ever applies, and each
/// search visits the whole tree. Shared with the GPU optimiser, which reads its root back for it.
pub(crate) fn search_scale(root: Option<&BvhNode>) -> f32 {
    root.map_or(1.0, |r| r.aabb().area_scale())
}

/// [`find_best_output`] with coordinates multiplied by `scale`, which also scales the decrease
/// returned (by its square).
///
/// Written as two nested loops, the climb over the pivots and the pre-order walk of each
/// pivot's other subtree ([`Search::walk`]), instead of the paper's single loop with a
/// direction flag: most walks end at the subtree's root, and that case now runs straight
/// through. The arithmetic and the order of visits are the paper's, so the results are the same
/// bits.
///
/// `areas`, the nodes' box areas where known, are read instead of computed; they are used only
/// at unit scale, where they are what the search would compute.
fn search_scaled(bvh: &Bvh, input: u32, scale: f32, areas: Option<&[f32]>) -> (u32, f32) {
    // Unscaled (nearly every scene), the boxes are used as loaded.
    match (scale == 1.0, areas) {
        (true, Some(areas)) => search_with::<false, true>(bvh, input, scale, areas).0,
        (true, None) => search_with::<false, false>(bvh, input, scale, &[]).0,
        (false, _) => search_with::<true, false>(bvh, input, scale, &[]).0,
    }
}

/// [`search_scaled`], multiplying coordinates by `scale` only where `SCALED`, and reading node
/// areas from `areas` where `CACHED`; also returns the nodes visited.
#[inline(always)]
fn search_with<const SCALED: bool, const CACHED: bool>(
    bvh: &Bvh,
    input: u32,
    scale: f32,
    areas: &[f32],
) -> ((u32, f32), u32) {
    let scale = Vec3A::splat(scale);
    let mut s = Search::<SCALED, CACHED> {
        nodes: &bvh.nodes,
        parents: &bvh.parents,
        areas,
        scale,
        b_in: Box4::EMPTY,
        a_parent: 0.0,
        d_bound: 0.0,
        d: 0.0,
        d_best: 0.0,
        out_best: input ^ 1,
        growth: [0.0; KEPT],
        visits: 0,
    };
    let b_in = s.bbox(input);
    let parent = s.parents[input as usize];
    let a_parent = s.area(parent);
    (s.b_in, s.a_parent, s.d_bound) = (b_in, a_parent, a_parent - s.area_of(input, b_in));
    let mut b_pivot = Box4::EMPTY;
    let (mut child, mut pivot) = (input, parent);
    loop {
        // The pivot's other subtree, then the pivot itself as an output.
        let b_other = s.walk(child ^ 1);
        b_pivot = b_pivot.union(b_other);
        if pivot != parent {
            let a_out = s.area(pivot);
            let d_direct = a_parent - b_in.union(b_pivot).area();
            // The pivot's own shrink (see the module docs).
            let own = a_out - b_pivot.area();
            if s.d_best < d_direct + s.d + own {
                s.d_best = d_direct + s.d + own;
                s.out_best = pivot;
            }
            s.d += own;
        }
        // Once the rest of the pivot encloses the input, removing the input shrinks no higher
        // ancestor, so no output further up can beat `d_bound + d`.
        if pivot == 0 || (s.d_bound + s.d <= s.d_best && b_pivot.contains(b_in)) {
            return ((s.out_best, s.d_best), s.visits);
        }
        child = pivot;
        pivot = s.parents[pivot as usize];
    }
}

/// The state of one search of [`search_scaled`]: `d` is the surface-area decrease accumulated
/// along the path, the paper's `d`.
struct Search<'a, const SCALED: bool, const CACHED: bool> {
    /// The node array, dereferenced once (each `Nodes` dereference recomputes the slice).
    nodes: &'a [BvhNode],
    parents: &'a [u32],
    areas: &'a [f32],
    scale: Vec3A,
    b_in: Box4,
    a_parent: f32,
    d_bound: f32,
    d: f32,
    d_best: f32,
    out_best: u32,
    /// The growth added to `d` at each depth below the subtree's root, to take back on the way
    /// up without reloading the node (the paper recomputes it; the values are the same bits).
    /// Deeper than the array, it is recomputed.
    growth: [f32; KEPT],
    /// Nodes visited so far; from [`MAX_VISITS`] on, the walk prunes every node.
    visits: u32,
}

/// Most nodes one search visits as outputs: past them, the walk prunes every node it reaches.
/// Searches on meshes visited at most 283 (dragon 133, bunny 115, city:1M 270, hairball:200k
/// 283, hairball:1M 246), so this changes no tree there; on a pile of 20,000 triangles
/// overlapping in one square, where no box prunes another, searches visited up to 24,515 nodes
/// and the optimisation took 8.4 s, against 1.8 s with this bound, at a leaf-1 SAH 0.09% higher.
/// Shared with the GPU search through the WGSL prelude.
pub const MAX_VISITS: u32 = 1024;

/// Levels of growth a [`Search`] keeps.
const KEPT: usize = 64;

impl<const SCALED: bool, const CACHED: bool> Search<'_, SCALED, CACHED> {
    #[inline(always)]
    fn bbox(&self, n: u32) -> Box4 {
        let node = &self.nodes[n as usize];
        if SCALED { Box4::scaled(node, self.scale) } else { Box4::of(node) }
    }

    /// The area of node `n`'s box.
    #[inline(always)]
    fn area(&self, n: u32) -> f32 {
        if CACHED { self.areas[n as usize] } else { self.bbox(n).area() }
    }

    /// The area of node `n`, whose box `b` is at hand.
    #[inline(always)]
    fn area_of(&self, n: u32, b: Box4) -> f32 {
        if CACHED { self.areas[n as usize] } else { b.area() }
    }

    /// Walks the subtree of `root` in pre-order, pruning below a node when `d_bound + d` cannot
    /// beat the best decrease, and offering every node visited as an output. Returns the root's
    /// box; leaves `d` as the walk found it (the same value, up to the rounding the paper's
    /// add-and-subtract leaves).
    #[inline(always)]
    fn walk(&mut self, root: u32) -> Box4 {
        let b_root = self.bbox(root);
        if self.visit_at(root, b_root, 0) {
            self.d -= self.growth[0];
            return b_root;
        }
        let parents = self.parents;
        let mut out = self.nodes[root as usize].first;
        let mut depth = 1usize;
        loop {
            let b_out = self.bbox(out);
            if !self.visit_at(out, b_out, depth) {
                out = self.nodes[out as usize].first;
                depth += 1;
                continue;
            }
            // Up: take back each level's growth until a left child's right sibling is next.
            loop {
                self.d -= if depth < KEPT {
                    self.growth[depth]
                } else {
                    let b_out = self.bbox(out);
                    self.area_of(out, b_out) - self.b_in.union(b_out).area()
                };
                if depth == 0 {
                    return b_root;
                }
                if out % 2 == 0 {
                    out += 1;
                    break;
                }
                out = parents[out as usize];
                depth -= 1;
            }
        }
    }

    /// Offers node `n` (box `b`, `depth` below the subtree's root) as an output and adds its
    /// growth to `d`; returns whether the walk goes back up from it.
    #[inline(always)]
    fn visit_at(&mut self, n: u32, b: Box4, depth: usize) -> bool {
        self.visits += 1;
        let a_merged = self.b_in.union(b).area();
        let d_direct = self.a_parent - a_merged;
        if self.d_best < d_direct + self.d {
            self.d_best = d_direct + self.d;
            self.out_best = n;
        }
        let g = self.area_of(n, b) - a_merged;
        if depth < KEPT {
            self.growth[depth] = g;
        }
        self.d += g;
        self.nodes[n as usize].is_leaf() || self.d_bound + self.d <= self.d_best || self.visits >= MAX_VISITS
    }
}

/// A node's box in SIMD registers, for [`find_best_output`]: the same arithmetic as
/// [`Aabb::half_area_nonempty`] and [`Aabb::union`], in the same order, so the results are bit
/// for bit the scalar ones.
#[derive(Clone, Copy)]
struct Box4 {
    min: Vec3A,
    max: Vec3A,
}

impl Box4 {
    const EMPTY: Self = Self { min: Vec3A::INFINITY, max: Vec3A::NEG_INFINITY };

    /// The node's box with coordinates multiplied by `scale` (a power of two: exact).
    #[inline(always)]
    fn scaled(node: &BvhNode, scale: Vec3A) -> Self {
        let b = Self::of(node);
        Self { min: b.min * scale, max: b.max * scale }
    }

    /// The node's box. Each corner is one 16-byte load with its fourth lane (`first` or
    /// `prim_count`) cleared: `Vec3A::new` takes four instructions per corner, and left in
    /// place, those integer bits would be denormal floats in the arithmetic of that lane.
    #[inline(always)]
    fn of(node: &BvhNode) -> Self {
        let f = node.as_floats();
        let xyz = BVec4A::new(true, true, true, false);
        let corner = |c: &[f32]| Vec3A::from_vec4(Vec4::select(xyz, Vec4::from_slice(c), Vec4::ZERO));
        Self { min: corner(&f[..4]), max: corner(&f[4..]) }
    }

    #[inline(always)]
    fn union(self, other: Self) -> Self {
        Self { min: self.min.min(other.min), max: self.max.max(other.max) }
    }

    /// Half surface area: `(x y + y z) + z x`, as [`Aabb::half_area_nonempty`] sums it.
    #[inline(always)]
    fn area(self) -> f32 {
        let e = self.max - self.min;
        (e * e.yzx()).element_sum()
    }

    #[inline(always)]
    fn contains(self, other: Self) -> bool {
        self.min.cmple(other.min).all() && self.max.cmpge(other.max).all()
    }
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

/// Validates the tree's structure and boxes; each primitive's box is taken from its leaf.
#[cfg(debug_assertions)]
fn debug_validate(bvh: &Bvh, iteration: u32) {
    let mut prim_aabbs = vec![Aabb::EMPTY; bvh.prim_ids.len()];
    for (i, n) in bvh.nodes.iter().enumerate() {
        if n.is_leaf() && i != super::PAD_INDEX as usize {
            for &p in &bvh.prim_ids[n.prim_range()] {
                prim_aabbs[p as usize] = n.aabb();
            }
        }
    }
    if let Err(e) = super::validate(bvh, &prim_aabbs) {
        panic!("PRBVH iteration {iteration} broke the tree: {e}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// Reading the nodes' areas from [`NodeAreas`] gives every search the same output and the
    /// same decrease, to the bit, as computing them, on a fresh tree and on one that iterations
    /// have changed (whose areas the iterations kept up to date; debug builds check them all).
    #[test]
    fn cached_areas_change_no_search() {
        let boxes = crate::bvh::scattered_boxes(3000, 0.8);
        let mut bvh = crate::bvh::lbvh::build(&boxes);
        for round in 0..3 {
            let areas = NodeAreas::new(&bvh);
            let cached = areas.get().expect("unit-scale scene");
            let mut found = 0;
            for input in 2..bvh.nodes.len() as u32 {
                let plain = search_scaled(&bvh, input, 1.0, None);
                let fast = search_scaled(&bvh, input, 1.0, Some(cached));
                assert_eq!((plain.0, plain.1.to_bits()), (fast.0, fast.1.to_bits()), "round {round}, node {input}");
                found += usize::from(plain.1 > 0.0);
            }
            assert!(round == 2 || found > 0, "round {round}: the test needs searches that find something");
            let config = PrbvhConfig { max_iterations: 4, collapse: None, ..Default::default() };
            optimize(&mut bvh, &config);
        }
    }

    /// A search visits at most [`MAX_VISITS`] nodes where no box prunes another (a pile of
    /// triangles over one square, where searches would otherwise walk most of the tree), and a
    /// search that the bound stops still returns the true decrease of the output it names.
    #[test]
    fn searches_are_bounded_on_a_pile() {
        // Boxes of triangles with corners at random in the unit square.
        let mut rng = crate::render::rng::Rng::for_sample(1, 0, 0);
        let boxes: Vec<Aabb> = (0..4000)
            .map(|_| {
                let corners = [0; 3].map(|_| rng.next_vec2().extend(0.0));
                Aabb::new(corners[0].min(corners[1]).min(corners[2]), corners[0].max(corners[1]).max(corners[2]))
            })
            .collect();
        let bvh = crate::bvh::lbvh::build(&boxes);
        let mut bounded = 0;
        for input in 2..bvh.nodes.len() as u32 {
            let ((out, d), visits) = search_with::<false, false>(&bvh, input, 1.0, &[]);
            // Past the bound, the walk's way back up and the climb visit a few nodes more.
            assert!(visits < 2 * MAX_VISITS, "node {input}: {visits} visits");
            bounded += usize::from(visits >= MAX_VISITS);
            if d > 0.0 {
                let mut moved = bvh.clone();
                let before = crate::bvh::sah_cost_with(&moved, &SahCosts { traversal: 1.0, intersection: 0.0 });
                reinsert(&mut moved, input, out);
                crate::bvh::refit_sequential(&mut moved, &boxes);
                let after = crate::bvh::sah_cost_with(&moved, &SahCosts { traversal: 1.0, intersection: 0.0 });
                let root = bvh.nodes[0].aabb().half_area();
                assert!(((before - after) * root as f64 - f64::from(d)).abs() <= 1e-3 * f64::from(d).max(1.0));
            }
        }
        assert!(bounded > 0, "the pile must need the bound, or the test shows nothing");
    }

    /// The SIMD box arithmetic of the search gives the scalar `(x y + y z) + z x` bit for bit,
    /// so the search's decisions do not depend on how it is vectorised.
    #[test]
    fn simd_areas_equal_scalar_areas() {
        let scalar = Aabb::half_area_nonempty;
        let boxes = crate::bvh::scattered_boxes(500, 3.0);
        for pair in boxes.windows(2) {
            let (a, b) = (pair[0], Aabb::new(pair[1].min * Vec3::new(0.3, 1.7, -2.1), pair[1].max * 1.3));
            let node = |x: Aabb| BvhNode::leaf(x, 7, 1);
            let (p, q) = (Box4::scaled(&node(a), Vec3A::ONE), Box4::scaled(&node(b), Vec3A::ONE));
            assert_eq!(p.area().to_bits(), scalar(&a).to_bits());
            assert_eq!(p.union(q).area().to_bits(), scalar(&a.union(b)).to_bits());
            assert_eq!(p.union(q).contains(p), a.union(b).contains_box(&a));
            assert_eq!(q.contains(p), b.contains_box(&a));
        }
    }
}
