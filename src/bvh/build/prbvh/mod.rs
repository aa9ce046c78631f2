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
//! `μ = 1` the run stops. Afterwards the leaf collapse of [`crate::bvh::sah`] picks leaf sizes.
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
//!
//! Files: this one drives the iterations (configuration, statistics, the sparse-search schedule
//! and termination); [`search`] finds each node's best output; [`reinsert`] claims and applies
//! moves; [`refit`] refits above them and follows the SAH.

mod refit;
mod reinsert;
mod search;

pub use refit::{RefitScratch, changed_slots, refit_above};
use refit::{TrackedSah, refit_tracking};
use reinsert::lock_and_apply;
pub use reinsert::{Reinsertion, reinsert, reinsert_candidates};
#[cfg(feature = "gpu")]
pub(crate) use search::search_scale;
pub use search::{MAX_VISITS, find_best_output};
use search::{NodeAreas, search};

use crate::bvh::{Bvh, CollapseConfig, SahCosts, collapse_leaves};
use rayon::prelude::*;
use std::sync::atomic::AtomicU64;
use std::time::{Duration, Instant};

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
    let sah = |b: &Bvh| crate::bvh::sah_cost_with(b, &config.costs);
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

/// Validates the tree's structure and boxes; each primitive's box is taken from its leaf.
#[cfg(debug_assertions)]
fn debug_validate(bvh: &Bvh, iteration: u32) {
    let mut prim_aabbs = vec![crate::geometry::Aabb::EMPTY; bvh.prim_ids.len()];
    for (i, n) in bvh.nodes.iter().enumerate() {
        if n.is_leaf() && i != crate::bvh::PAD_INDEX as usize {
            for &p in &bvh.prim_ids[n.prim_range()] {
                prim_aabbs[p as usize] = n.aabb();
            }
        }
    }
    if let Err(e) = crate::bvh::validate(bvh, &prim_aabbs) {
        panic!("PRBVH iteration {iteration} broke the tree: {e}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Vec3, Vec3A};

    use super::search::{Box4, search_scaled, search_with};
    use crate::bvh::BvhNode;
    use crate::geometry::Aabb;

    /// Reading the nodes' areas from [`NodeAreas`] gives every search the same output and the
    /// same decrease, to the bit, as computing them, on a fresh tree and on one that iterations
    /// have changed (whose areas the iterations kept up to date; debug builds check them all).
    #[test]
    fn cached_areas_change_no_search() {
        let boxes = crate::bvh::scattered_boxes(3000, 0.8);
        let mut bvh = crate::bvh::build::lbvh::build(&boxes);
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
        // A fixed LCG: the same boxes every run.
        let mut state = 0x853c_49e6_748f_ea9bu64;
        let mut next = move || {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let boxes: Vec<Aabb> = (0..4000)
            .map(|_| {
                let corners = [0; 3].map(|_| glam::Vec3::new(next(), next(), 0.0));
                Aabb::new(corners[0].min(corners[1]).min(corners[2]), corners[0].max(corners[1]).max(corners[2]))
            })
            .collect();
        let bvh = crate::bvh::build::lbvh::build(&boxes);
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
