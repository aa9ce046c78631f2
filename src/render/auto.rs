//! `--builder auto` decided before the render: the tree that makes build plus render shortest,
//! judged by the render's estimated length on the device it runs on (see
//! [`RenderScene::build_auto`]). A GPU render decides this way, timing a little of its render on
//! the GPU; a CPU render through [`crate::device::Renderer`] instead starts at once on the LBVH
//! and optimises between passes ([`super::refine`]).

use std::time::Instant;

use glam::Vec2;
use rayon::prelude::*;

use super::camera::CameraModel;
use super::geometry::wants_instancing;
use super::integrator::RR_DEPTH;
use super::{BuildReport, RenderScene};
use crate::bvh::Tracing;
use crate::bvh::build::prbvh::{self, PrbvhConfig};
use crate::bvh::{CollapseConfig, MeshBvh, build::lbvh, collapse_leaves};
use crate::geometry::{Ray, Triangle};
use crate::scene::{RenderSettings, Scene};

/// Samples per pixel over all `frames` frames of a render with `settings`.
pub fn total_samples(settings: &RenderSettings, frames: usize) -> f64 {
    f64::from(settings.spp) * frames as f64
}

/// The time limit over all `frames` frames, if the render has one.
pub fn total_budget(settings: &RenderSettings, frames: usize) -> Option<f64> {
    settings.time.map(|t| t * frames as f64)
}

/// The device a render for [`RenderScene::build_auto_for`] runs on.
pub enum AutoDevice<'a> {
    /// The CPU, whose speed the camera-ray probes measure. (`render` on the CPU does not build
    /// ahead of the render: it optimises while rendering, [`super::refine`].) The probes trace
    /// the form the render will.
    Cpu(Tracing),
    /// Another device (a GPU), timed by rendering a little of the LBVH scene: `measure` returns
    /// the seconds one sample per pixel takes there and the time to leave out of the build (a
    /// kernel's compilation, paid once per process), or `None` to fall back on the CPU's
    /// estimate. `samples` is the render's samples per pixel over all its frames.
    /// `budget` is the time limit over all frames, if the render has one.
    Measured {
        samples: f64,
        budget: Option<f64>,
        measure: &'a mut dyn FnMut(&RenderScene) -> Option<(f64, std::time::Duration)>,
    },
    /// Another device, on a render too short to be worth timing: the LBVH, not optimised.
    Unmeasured,
}

impl AutoDevice<'_> {
    /// The form the CPU keeps for a render on this device: the one it traces on the CPU, the
    /// binary tree alone for another device (which traces its own copy of it, so the camera
    /// probes that calibrate against it time the binary tree too, and no probe pays for a wide
    /// collapse).
    fn tracing(&self) -> Tracing {
        match self {
            AutoDevice::Cpu(tracing) => *tracing,
            AutoDevice::Measured { .. } | AutoDevice::Unmeasured => Tracing::gpu(),
        }
    }
}

/// Rays per second of closest-hit queries on the leaf-collapsed `bvh`, traced as `tracing` says
/// (the form the render's device traces), measured on a 64x64 grid of camera rays.
fn probe_trace_speed(
    bvh: &crate::bvh::Bvh,
    triangles: &[Triangle],
    camera: &crate::scene::Camera,
    tracing: Tracing,
) -> f64 {
    let mesh = MeshBvh::new(collapse_leaves(bvh, &CollapseConfig::default()), triangles, tracing);
    let model = CameraModel::new(camera);
    let (w, h) = (camera.width as f32 / 64.0, camera.height as f32 / 64.0);
    let rays: Vec<Ray> = (0..64 * 64)
        .map(|i| model.ray(Vec2::new(((i % 64) as f32 + 0.5) * w, ((i / 64) as f32 + 0.5) * h), Vec2::splat(0.5)))
        .collect();
    let t = Instant::now();
    let hits = rays.par_iter().filter(|r| mesh.closest_hit(r, f32::INFINITY).is_some()).count();
    std::hint::black_box(hits);
    rays.len() as f64 / t.elapsed().as_secs_f64().max(1e-9)
}

/// A tree's assembled scene and its report, kept while it is the tree `auto` holds.
type Assembled = (RenderScene, BuildReport);

/// What `auto` knows of the render on its device before it chooses a tree
/// ([`RenderScene::build_auto_for`]).
struct Baseline {
    judge: Judge,
    /// The render's estimated length with the LBVH, where the device's step estimated it.
    render_seconds: Option<f64>,
    /// The scene assembled for the last tree timed, while the tree is still that one.
    timed: Option<Assembled>,
    /// What one probe costs beyond the camera rays.
    probe_cost: f64,
    /// How the render was timed, for the label.
    measured: String,
    /// Time to leave out of the build's (a GPU kernel's compilation).
    excluded: std::time::Duration,
}

/// How `auto` judges a tree's render time: by the camera-ray probe's estimate, divided by
/// `speedup` (that estimate for the LBVH over the time the render is taken to last: the
/// device's measured time, or the time budget; 1 with neither).
#[derive(Clone, Copy)]
struct Judge {
    speedup: f64,
}

/// The share of the render a first reinsertion sweep saves on an LBVH, to expect before it is
/// measured (about what it saved on the dragon scene, which gained 20% from a whole PRBVH run).
pub const FIRST_SWEEP_GAIN: f64 = 0.2;

/// A sweep's cost in LBVH builds, to expect before it is measured (μ = 9 iterations on the
/// dragon scene).
pub const SWEEP_IN_LBVH_BUILDS: f64 = 8.0;

/// The builder `auto` gives the meshes of a two-level scene: they are built once and serve
/// every frame, so they are optimised in full.
pub(crate) fn instanced_builder() -> crate::bvh::build::Builder {
    "lbvh+prbvh".parse().expect("a builder name")
}

/// The reinsertion configuration `auto` runs: on one primitive per leaf, collapsed afterwards.
fn sweep_config() -> PrbvhConfig {
    PrbvhConfig { collapse: None, ..Default::default() }
}

/// `auto`'s first sweep on `bvh` (μ iterations, one search of every node, or fewer where
/// `abandon` says so between them: a signal), and the share of the SAH it removed.
pub(crate) fn first_sweep(bvh: &mut crate::bvh::Bvh, abandon: &dyn Fn() -> bool) -> (prbvh::PrbvhStats, f64) {
    let config = sweep_config();
    let s = prbvh::optimize_while(bvh, &PrbvhConfig { max_iterations: config.mu, ..config }, |_| !abandon());
    let sah_fraction = (s.initial_sah - s.sah_before_collapse) / s.initial_sah;
    (s, sah_fraction)
}

/// The sweeps after the first: reinsertion on `bvh` while each μ iterations save more of a
/// render of `render_seconds` than they take, the SAH removed converted to time by
/// `efficiency` (the first sweep's measured gain over its SAH share, [`sweep_efficiency`]).
///
/// Judged over a whole sweep (μ iterations) only: one iteration searches a μ-th of the nodes,
/// and the Cornell box's first one after a paying sweep found nothing, which stopped it at SAH
/// 30.89 where a full run reaches 30.57. (Where the μ/ε rule lowers μ, the window spans more
/// than one search, which only makes it slower to stop.) `abandon` stops it between iterations.
pub(crate) fn sweeps_while_they_pay(
    bvh: &mut crate::bvh::Bvh,
    render_seconds: f64,
    efficiency: f64,
    abandon: &dyn Fn() -> bool,
) -> prbvh::PrbvhStats {
    let config = sweep_config();
    let mu = config.mu as usize;
    let mut window: std::collections::VecDeque<(f64, f64)> = std::collections::VecDeque::new();
    prbvh::optimize_while(bvh, &config, |p| {
        let saved = (p.previous_sah - p.sah) / p.initial_sah * render_seconds * efficiency;
        window.push_back((saved, p.iteration_time.as_secs_f64()));
        if window.len() > mu {
            window.pop_front();
        }
        let (saved, spent) = window.iter().fold((0.0, 0.0), |a, w| (a.0 + w.0, a.1 + w.1));
        !abandon() && (window.len() < mu || saved > spent)
    })
}

/// Render time saved per unit of SAH share removed, from a sweep that saved `gain` of the
/// render and `sah_fraction` of the SAH; kept within 0.05 and 1 (SAH overstates trace gains).
pub(crate) fn sweep_efficiency(gain: f64, sah_fraction: f64) -> f64 {
    (gain / sah_fraction).clamp(0.05, 1.0)
}

impl RenderScene {
    /// `--builder auto`: the tree that makes build plus render shortest for a render of about
    /// `rays` rays, among LBVH and binned SAH, each optimised by parallel reinsertion for as long
    /// as that pays for itself. Here each tree's render is estimated from its trace speed on a
    /// probe of 4096 camera rays. (`render` on the CPU does not use this: it optimises while
    /// rendering, [`super::refine`].)
    ///
    /// 1. LBVH, and the render's length with it.
    /// 2. If 16% of that render (what binned SAH saved on the dragon scene) would repay a
    ///    binned-SAH build (estimated at 9 LBVH builds, its cost on the dragon) and its probe one
    ///    and a half times over, the binned-SAH tree is built and probed too, and the tree with
    ///    the shorter estimated render is kept.
    /// 3. Parallel reinsertion on the kept tree, in sweeps (μ iterations, which search every
    ///    node once between them), if the gain to expect (20% from the LBVH, 5% from binned
    ///    SAH) could repay a sweep (about 8 LBVH builds) and its probe. The first sweep's gain
    ///    is measured by a second probe: it goes on only if the render got shorter by more than
    ///    the sweep took, and that gain per unit of SAH gained calibrates the rest. Each later
    ///    sweep's saving is its SAH decrease, as a fraction, times the estimated render time
    ///    times that factor, and optimisation stops when the last sweep (μ iterations) saved
    ///    less than it took. (SAH alone overstates gains: on the dragon scene LBVH + PRBVH cut
    ///    the SAH far more than the trace time, and reinsertion on the binned-SAH tree cost more
    ///    than it returned. Judging single iterations stopped the dragon far too early: one
    ///    iteration searches a ninth of the nodes.)
    ///
    /// An instanced scene builds its meshes' BVHs with `lbvh+prbvh`: they are built once and
    /// serve every frame.
    pub fn build_auto(scene: &Scene, rays: f64, tracing: Tracing) -> (Self, BuildReport) {
        Self::build_auto_for(scene, rays, AutoDevice::Cpu(tracing))
    }

    /// [`RenderScene::build_auto`] for a render on `device`.
    ///
    /// - [`AutoDevice::Measured`]: on another device than the CPU the CPU's probe cannot tell the
    ///   render's length: it predicts the CPU's render, and a GPU can render many times as fast,
    ///   so `auto` optimised for long renders that were in fact short, spending more than the
    ///   render itself. So the device renders a little of the LBVH scene (for a GPU,
    ///   `gpu::trace::build_auto`), and the render's length is its time per sample times the
    ///   samples, which also corrects [`RenderScene::estimated_rays`]. The CPU probes' times are
    ///   scaled to match: trees still compare by the CPU's camera-ray probe, only the render's
    ///   length changes. Where the LBVH is kept unoptimised, the timed scene itself is returned.
    ///
    /// At most one probed scene is kept alive at a time (beside the triangles), so that `auto`
    /// does not double a large scene's peak memory.
    pub fn build_auto_for(scene: &Scene, rays: f64, device: AutoDevice<'_>) -> (Self, BuildReport) {
        if wants_instancing(scene) {
            return Self::build_instanced(scene, &instanced_builder(), device.tracing());
        }
        let mut t = Instant::now();
        let (triangles, material_of) = scene.world_triangles();
        let prims: Vec<_> = triangles.par_iter().map(Triangle::aabb).collect();
        let mut bvh = lbvh::build(&prims);
        let lbvh_seconds = t.elapsed().as_secs_f64();
        let tracing = device.tracing();
        let assemble = |b: &crate::bvh::Bvh| {
            Self::assemble(
                scene,
                (triangles.clone(), material_of.clone(), 0.0),
                b,
                Instant::now(),
                String::new(),
                tracing,
            )
        };
        let Some(baseline) = Self::auto_baseline(scene, rays, device, &bvh, &triangles, &assemble) else {
            let label = "auto: lbvh, a render too short to time on the device".to_owned();
            return Self::assemble(scene, (triangles, material_of, 0.0), &bvh, t, label, tracing);
        };
        t += baseline.excluded;
        let Baseline { judge, render_seconds, mut timed, probe_cost, measured, .. } = baseline;
        // A tree's estimated render time (no scene is assembled to judge it).
        let probe = |b: &crate::bvh::Bvh| -> (f64, Option<Assembled>) {
            (rays / (probe_trace_speed(b, &triangles, &scene.camera, tracing) * judge.speedup), None)
        };
        let mut render_seconds = render_seconds.unwrap_or_else(|| probe(&bvh).0);
        let mut base = "lbvh";
        // The render time binned SAH saves, 16% (the dragon scene, timed paths), must repay its
        // build, 9 LBVH builds (its cost there), and its probe, with half as much again to spare.
        if 0.16 * render_seconds > 1.5 * (9.0 * lbvh_seconds + probe_cost) {
            let binned = crate::bvh::build::binned_sah::build(&prims, &Default::default());
            // The LBVH's scene goes first: one probed scene at a time.
            let lbvh_scene = timed.take();
            let (binned_seconds, binned_scene) = probe(&binned);
            if binned_seconds < render_seconds {
                (bvh, render_seconds, base) = (binned, binned_seconds, "binned-sah");
                timed = binned_scene;
            } else {
                // The camera probe assembles nothing: the LBVH's scene (a GPU's timed one) stays.
                timed = lbvh_scene;
            }
        }
        let iterations =
            Self::auto_sweeps(&mut bvh, &probe, &mut render_seconds, &mut timed, base, lbvh_seconds, probe_cost);
        let label = format!(
            "auto: {base}+prbvh, {iterations} iterations for a render estimated at {render_seconds:.2} s{measured}"
        );
        match timed {
            Some((rs, mut report)) => {
                (report.builder, report.build_ms) = (label, t.elapsed().as_secs_f64() * 1e3);
                (rs, report)
            }
            None => Self::assemble(scene, (triangles, material_of, 0.0), &bvh, t, label, tracing),
        }
    }

    /// `auto`'s first step, on `device`: how trees will be judged, the render's length with the
    /// LBVH `bvh` where that step estimates it, and the LBVH's scene where it was assembled to
    /// time it. `None` where the device's render is too short to time
    /// ([`AutoDevice::Unmeasured`]): the LBVH is kept.
    fn auto_baseline(
        scene: &Scene,
        rays: f64,
        device: AutoDevice<'_>,
        bvh: &crate::bvh::Bvh,
        triangles: &[Triangle],
        assemble: &dyn Fn(&crate::bvh::Bvh) -> Assembled,
    ) -> Option<Baseline> {
        let mut b = Baseline {
            judge: Judge { speedup: 1.0 },
            render_seconds: None,
            timed: None,
            probe_cost: 0.0,
            measured: String::new(),
            excluded: std::time::Duration::ZERO,
        };
        let tracing = device.tracing();
        match device {
            AutoDevice::Cpu(_) => {}
            AutoDevice::Unmeasured => return None,
            AutoDevice::Measured { samples, budget, measure } => {
                let cpu_seconds = rays / probe_trace_speed(bvh, triangles, &scene.camera, tracing);
                let lbvh_scene = assemble(bvh);
                let mut device_seconds = cpu_seconds;
                if let Some((seconds_per_sample, excluded)) = measure(&lbvh_scene.0) {
                    b.excluded = excluded;
                    device_seconds = seconds_per_sample * samples;
                    b.measured = format!(", timed at {:.1} ms per sample", seconds_per_sample * 1e3);
                    b.timed = Some(lbvh_scene);
                }
                let device_seconds = budget.map_or(device_seconds, |b| device_seconds.min(b));
                b.judge = Judge { speedup: cpu_seconds / device_seconds.max(1e-12) };
                b.render_seconds = Some(device_seconds);
            }
        }
        Some(b)
    }

    /// `auto`'s reinsertion sweeps on `bvh` (its base builder `base`), judged by `probe`;
    /// updates the render's estimate and the scene kept for the tree, and returns the
    /// iterations run.
    fn auto_sweeps(
        bvh: &mut crate::bvh::Bvh,
        probe: &dyn Fn(&crate::bvh::Bvh) -> (f64, Option<Assembled>),
        render_seconds: &mut f64,
        timed: &mut Option<Assembled>,
        base: &str,
        lbvh_seconds: f64,
        probe_cost: f64,
    ) -> usize {
        // The first sweep is measured, not predicted: SAH overstates trace gains on some scenes
        // (the dragon's room), so its real gain, from a second probe, decides whether to go on
        // and calibrates the SAH-to-time factor for the sweeps after it. A sweep costs about
        // SWEEP_IN_LBVH_BUILDS LBVH builds, plus its probe; none is tried when the gain to
        // expect could not repay that: FIRST_SWEEP_GAIN from the LBVH, 5% from binned SAH (the
        // most a first sweep on binned SAH gained on the dragon scene).
        let mut iterations = 0;
        let expected_gain = if base == "lbvh" { FIRST_SWEEP_GAIN } else { 0.05 };
        if expected_gain * *render_seconds > SWEEP_IN_LBVH_BUILDS * lbvh_seconds + probe_cost {
            // The probe below assembles its own scene: one at a time.
            drop(timed.take());
            let sweep_start = Instant::now();
            let (s1, sah_fraction) = first_sweep(bvh, &|| false);
            let spent = sweep_start.elapsed().as_secs_f64();
            iterations += s1.iterations.len();
            let (after, swept_scene) = probe(bvh);
            *timed = swept_scene;
            let gained = *render_seconds - after;
            // A sweep that did not pay is kept all the same: its cost is spent, its SAH is lower,
            // and a timing cannot tell a gain of a few percent from its noise (on the dragon
            // scene a sweep that timed slower still rendered faster).
            if gained > spent && sah_fraction > 0.0 {
                let efficiency = sweep_efficiency(gained / *render_seconds, sah_fraction);
                *render_seconds = after;
                let rest = sweeps_while_they_pay(bvh, *render_seconds, efficiency, &|| false);
                iterations += rest.iterations.len();
                if !rest.iterations.is_empty() {
                    *timed = None;
                    // The label's estimate, for the tree as it ends.
                    *render_seconds *=
                        1.0 - (rest.initial_sah - rest.sah_before_collapse) / rest.initial_sah * efficiency;
                }
            } else {
                *render_seconds = after;
            }
        }
        iterations
    }

    /// The rays a render of `scene` traces, roughly, for [`RenderScene::build_auto`]: each path
    /// segment traces one ray, plus a shadow ray when the scene has emitters, and paths rarely
    /// run past five segments (Russian roulette starts there).
    pub fn estimated_rays(scene: &Scene, spp: u32, max_depth: u32, frames: usize) -> f64 {
        let per_path = max_depth.min(RR_DEPTH) as f64 * if scene.has_emitters() { 2.0 } else { 1.0 };
        let pixels = scene.camera.width as f64 * scene.camera.height as f64;
        pixels * spp as f64 * per_path * frames as f64
    }
}
