//! `--builder auto` on the CPU: the render starts at once on the LBVH, and the tree is optimised
//! by parallel reinsertion between passes, for as long as the rest of the render repays it.
//!
//! Judging a tree before the render starts is what `auto` got wrong: camera-ray probes
//! overstated renders 2.2 to 2.6 times, and timing paths beforehand was only worth it on long
//! renders. The render's own passes are measurements that cost nothing extra, and a tree can be
//! changed between passes: the image depends only on the samples taken, since every tree gives
//! the closest hit that brute force gives, bit for bit. So:
//!
//! 1. The LBVH is built, the cheapest tree, and the render starts with passes that are slices
//!    of its first sample: every k-th row, spread over the image (`Renderer`'s render loop).
//! 2. After the passes that follow the first add up to [`MIN_TIMED_SECONDS`] (the first runs
//!    on cold caches and is not timed: timing it made the estimate up to 1.7 times the render),
//!    the rest of the render is their time per sample times the samples left (in every frame
//!    still to come), or the time budget left if that is shorter. If 20% of that (what a first
//!    reinsertion sweep gains on an LBVH, [`super::auto::FIRST_SWEEP_GAIN`]) repays a sweep (μ
//!    iterations, estimated at [`super::auto::SWEEP_IN_LBVH_BUILDS`] LBVH builds, plus making
//!    the tree ready to trace), one sweep runs and the renderer takes the new tree.
//! 3. The next passes (after an untimed one: the new tree's caches are cold; then as many
//!    again) measure what the sweep bought. Where that gain, on the rest of the render, would
//!    not repay another sweep of the same cost, the optimisation ends (later sweeps gain less
//!    than the first). Otherwise, the gain per unit of SAH decrease calibrates the rest
//!    ([`super::auto::sweeps_while_they_pay`], the rule the GPU's `auto` uses too): reinsertion
//!    goes on while each μ iterations save more of the rest of the render than they take, and
//!    the renderer takes the tree a last time.
//!
//! Then the sample is finished and passes grow to the usual size. Animated and heavily
//! instanced scenes are not flattened, so this does not apply to them (their meshes' trees are
//! built once with `lbvh+prbvh`).

use std::time::Instant;

use rayon::prelude::*;

use super::auto::{FIRST_SWEEP_GAIN, SWEEP_IN_LBVH_BUILDS, first_sweep, sweep_efficiency, sweeps_while_they_pay};
use super::geometry::Geometry;
use super::{BuildReport, RenderScene};
use crate::bvh::{Bvh, CollapseConfig, MeshBvh, Tracing, build::lbvh, collapse_leaves};
use crate::geometry::Triangle;
use crate::scene::Scene;

/// The least render time a speed is measured over, in seconds: passes are added up until they
/// reach it. A single slice of a small image takes a few milliseconds, and on a shared machine
/// one such timing came out twice the render's pace.
pub const MIN_TIMED_SECONDS: f64 = 0.02;

/// Where the optimisation stands.
#[derive(Clone, Copy, Debug)]
enum State {
    /// Waiting for the LBVH's time per sample.
    Start,
    /// One sweep done; waiting for the pass that measures it.
    Swept {
        before: f64,
        sah_fraction: f64,
        cost: f64,
    },
    Done,
}

/// What `auto` did while rendering, for the summary.
#[derive(Clone, Debug, Default)]
pub struct RefineReport {
    /// The render's estimated length on the LBVH, from the timed passes after the first (all
    /// frames, or the budget), in seconds.
    pub estimate: Option<f64>,
    /// Reinsertion iterations run.
    pub iterations: usize,
    /// Seconds spent optimising and reassembling.
    pub seconds: f64,
    /// Samples per pixel rendered on the LBVH before the first decision (a fraction: the first
    /// passes are slices of a sample).
    pub after_samples: f64,
    /// The measured gain of the first sweep, as a share of a sample's time.
    pub first_gain: Option<f64>,
}

impl std::fmt::Display for RefineReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let Some(estimate) = self.estimate else { return f.write_str("auto: lbvh, nothing left to decide for") };
        if self.iterations == 0 {
            return write!(f, "auto: lbvh, not optimised for a render estimated at {estimate:.2} s");
        }
        write!(
            f,
            "auto: lbvh+prbvh, {} iterations ({:.2} s) after {:.3} spp, for a render estimated at {estimate:.2} s",
            self.iterations, self.seconds, self.after_samples
        )?;
        match self.first_gain {
            Some(g) => write!(f, "; the first sweep saved {:.0}% per sample", g * 100.0),
            None => Ok(()),
        }
    }
}

/// The optimisation a CPU render with `auto` carries out between its passes (module docs).
pub struct Refiner {
    /// The tree being optimised, one primitive per leaf (what reinsertion works on); dropped
    /// when done.
    bvh: Bvh,
    tracing: Tracing,
    lbvh_seconds: f64,
    /// Seconds to make a tree ready to trace, bounded by what the first scene's assembly took.
    retree_seconds: f64,
    state: State,
    /// The passes timed towards the current measurement: (seconds, samples per pixel).
    timed: (f64, f64),
    /// Whether the next pass runs on cold caches (the first, and the first on a new tree) and
    /// so is not timed.
    cold: bool,
    report: RefineReport,
}

impl Refiner {
    /// The LBVH's scene for `scene`, traced as `tracing` says, and the refiner that will
    /// optimise it while it renders.
    pub fn start(scene: &Scene, tracing: Tracing) -> (RenderScene, BuildReport, Refiner) {
        let t = Instant::now();
        let (triangles, material_of) = scene.world_triangles();
        let prims: Vec<_> = triangles.par_iter().map(Triangle::aabb).collect();
        let bvh = lbvh::build(&prims);
        let lbvh_seconds = t.elapsed().as_secs_f64();
        let label = "auto: lbvh, optimised while it renders where that pays".to_owned();
        let (rs, report) = RenderScene::assemble(scene, (triangles, material_of, 0.0), &bvh, t, label, tracing);
        // The whole assembly bounds what a new tree costs to trace (collapses, packing).
        let retree_seconds = (report.build_ms * 1e-3 - lbvh_seconds).max(0.0);
        let refiner = Refiner {
            bvh,
            tracing,
            lbvh_seconds,
            retree_seconds,
            state: State::Start,
            timed: (0.0, 0.0),
            cold: true,
            report: RefineReport::default(),
        };
        (rs, report, refiner)
    }

    /// Whether it still decides between passes (and wants them to be slices of a sample).
    pub fn is_active(&self) -> bool {
        !matches!(self.state, State::Done)
    }

    /// What it did.
    pub fn report(&self) -> &RefineReport {
        &self.report
    }

    /// After a pass of the render of `rs` (the scene [`Refiner::start`] made) that took
    /// `pass.0` seconds for `pass.1` samples per pixel (a fraction where passes are slices of a
    /// sample): `samples_done` is the samples per pixel taken so far in this frame, and
    /// `rest(per_sample)` the render's remaining seconds at `per_sample` seconds per sample
    /// (module docs). Passes are added up until they make [`MIN_TIMED_SECONDS`]; then it
    /// decides, and gives `rs` a better tree where that pays. Returns whether it did. The
    /// optimisation stops between its iterations where `abandon` says so (a signal), with the
    /// tree as far as it came.
    pub fn after_pass(
        &mut self,
        rs: &mut RenderScene,
        pass: (f64, f64),
        samples_done: f64,
        rest: &dyn Fn(f64) -> f64,
        abandon: &dyn Fn() -> bool,
    ) -> bool {
        if std::mem::take(&mut self.cold) {
            return false;
        }
        self.timed = (self.timed.0 + pass.0, self.timed.1 + pass.1);
        if self.timed.0 < MIN_TIMED_SECONDS {
            return false;
        }
        let per_sample = self.timed.0 / self.timed.1;
        self.timed = (0.0, 0.0);
        let changed = self.decide(rs, per_sample, samples_done, rest(per_sample), abandon);
        if !self.is_active() {
            self.finish();
        }
        changed
    }

    fn decide(
        &mut self,
        rs: &mut RenderScene,
        per_sample: f64,
        samples_done: f64,
        rest: f64,
        abandon: &dyn Fn() -> bool,
    ) -> bool {
        match self.state {
            State::Start => {
                self.report.estimate = Some(rest + per_sample * samples_done);
                self.report.after_samples = samples_done;
                let cost = SWEEP_IN_LBVH_BUILDS * self.lbvh_seconds + self.retree_seconds;
                if FIRST_SWEEP_GAIN * rest <= cost {
                    self.state = State::Done;
                    return false;
                }
                let t = Instant::now();
                // Rendering waits meanwhile: the traced tree goes first, so that it and the
                // optimisation's own memory are never held at once.
                Self::drop_tree(rs);
                let (s, sah_fraction) = first_sweep(&mut self.bvh, abandon);
                self.report.iterations += s.iterations.len();
                self.retree(rs);
                let cost = t.elapsed().as_secs_f64();
                self.report.seconds += cost;
                self.state = State::Swept { before: per_sample, sah_fraction, cost };
                // The new tree's first pass runs on cold caches.
                self.cold = true;
                true
            }
            State::Swept { before, sah_fraction, cost } => {
                self.state = State::Done;
                let gain = (before - per_sample) / before;
                self.report.first_gain = Some(gain);
                // Later sweeps gain less than the first: go on only where the first, at its
                // measured gain, would have repaid itself on the rest of the render.
                if !(gain > 0.0 && sah_fraction > 0.0 && gain * rest > cost) {
                    return false;
                }
                let t = Instant::now();
                Self::drop_tree(rs);
                let s = sweeps_while_they_pay(&mut self.bvh, rest, sweep_efficiency(gain, sah_fraction), abandon);
                self.report.iterations += s.iterations.len();
                self.retree(rs);
                self.report.seconds += t.elapsed().as_secs_f64();
                true
            }
            State::Done => false,
        }
    }

    /// Ends the decisions (the render is over) and lets the optimisation's tree go.
    pub fn finish(&mut self) {
        self.state = State::Done;
        self.bvh = Bvh::default();
    }

    /// Drops the tree `rs` traces, before an optimisation (see [`Refiner::retree`]).
    fn drop_tree(rs: &mut RenderScene) {
        if let Geometry::Flat(flat) = &mut rs.geometry {
            drop(std::mem::take(&mut flat.mesh));
        }
    }

    /// Gives `rs` (whose tree [`Refiner::drop_tree`] dropped) the tree as it now stands. Only
    /// the tree changes: the triangles, their ids and the lights stay, so the image does too.
    fn retree(&self, rs: &mut RenderScene) {
        let Geometry::Flat(flat) = &mut rs.geometry else { return };
        let leaves = collapse_leaves(&self.bvh, &CollapseConfig::default());
        flat.mesh = MeshBvh::new(leaves, &flat.triangles, self.tracing);
    }
}
