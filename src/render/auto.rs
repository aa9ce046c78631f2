//! `--builder auto`: the tree that makes build plus render shortest, judged by the render's
//! estimated length on the device it runs on (see [`RenderScene::build_auto`]).

use std::time::Instant;

use glam::Vec2;
use rayon::prelude::*;

use super::camera::CameraModel;
use super::geometry::wants_instancing;
use super::integrator::RR_DEPTH;
use super::rng::Rng;
use super::{BuildReport, RenderScene};
use crate::bvh::Tracing;
use crate::bvh::prbvh::{self, PrbvhConfig};
use crate::bvh::{CollapseConfig, MeshBvh, collapse_leaves, lbvh};
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
    /// The CPU, whose speed the camera-ray probes measure.
    Cpu,
    /// The CPU, each tree judged by timing paths on it (see [`RenderScene::build_auto_cpu`])
    /// for a render of `samples` samples per pixel over all its frames, within `budget`
    /// seconds over all frames if it has a time budget.
    CpuPaths { samples: f64, seed: u64, max_depth: u32, budget: Option<f64> },
    /// Another device (a GPU), timed by rendering a little of the LBVH scene: `measure` returns
    /// the seconds one sample per pixel takes there and the time to leave out of the build (a
    /// kernel's compilation, paid once per process), or `None` to fall back on the CPU's
    /// estimate. `samples` is the render's samples per pixel over all its frames.
    /// `budget` is as for [`AutoDevice::CpuPaths`].
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
            AutoDevice::Cpu | AutoDevice::CpuPaths { .. } => Tracing::current(),
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
    let mesh = MeshBvh::with_tracing(collapse_leaves(bvh, &CollapseConfig::default()), triangles, tracing);
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

/// Paths [`RenderScene::cpu_seconds_per_sample`] traces: one from each cell of a 64 × 64 grid
/// over the image.
pub const TIMED_PATHS: u32 = 64 * 64;

/// The sample index of the timed paths' random numbers: no render reaches it.
const TIMING_SAMPLE: u64 = 1 << 63;

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
    /// What one probe costs beyond the camera rays: assembling and timing paths.
    probe_cost: f64,
    /// How the render was timed, for the label.
    measured: String,
    /// Time to leave out of the build's (a GPU kernel's compilation).
    excluded: std::time::Duration,
}

/// How `auto` judges a tree's render time.
#[derive(Clone, Copy)]
enum Judge {
    /// By the camera-ray probe's estimate, divided by `speedup`: that estimate for the LBVH
    /// over the time the render is taken to last (the device's measured time, or the time
    /// budget); 1 with neither.
    Camera { speedup: f64 },
    /// By timing paths on the CPU, for a render of `samples` samples per pixel.
    Paths { samples: f64, seed: u64, max_depth: u32 },
}

impl Judge {
    fn is_camera(self) -> bool {
        matches!(self, Judge::Camera { .. })
    }
}

/// Whether the CPU's `auto` times paths, for a render of `samples` samples in all (pixels ×
/// spp × frames) where one timing (3 × [`TIMED_PATHS`] paths) is estimated at
/// `timing_seconds` and the LBVH took `lbvh_seconds`: only where the timing costs at most a
/// sixteenth of the render (and of its time budget, if it has one), and no more than what is
/// at stake, a reinsertion sweep (8 LBVH builds): on a scene as small as the Cornell box a
/// timing costs more than every build together (docs/benchmarks.md, "The CPU thresholds").
fn worth_timing(samples: f64, timing_seconds: f64, lbvh_seconds: f64, budget: Option<f64>) -> bool {
    samples >= 16.0 * 3.0 * f64::from(TIMED_PATHS)
        && budget.is_none_or(|b| 16.0 * timing_seconds <= b)
        && timing_seconds <= 8.0 * lbvh_seconds
}

impl RenderScene {
    /// `--builder auto`: the tree that makes build plus render shortest for a render of about
    /// `rays` rays, among LBVH and binned SAH, each optimised by parallel reinsertion for as long
    /// as that pays for itself. Here each tree's render is estimated from its trace speed on a
    /// probe of 4096 camera rays; [`RenderScene::build_auto_cpu`], what `render` uses, times
    /// real paths instead wherever the render is long enough to afford it.
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
    pub fn build_auto(scene: &Scene, rays: f64) -> (Self, BuildReport) {
        Self::build_auto_for(scene, rays, AutoDevice::Cpu)
    }

    /// `--builder auto` for a CPU render.
    ///
    /// Each tree is judged by timing paths on it, not by the camera-ray probe: its scene is
    /// assembled and [`RenderScene::cpu_seconds_per_sample`] traces real paths from
    /// [`TIMED_PATHS`] pixels, three times (the fastest counts: the first runs on cold caches).
    /// The render's length is that time per sample times the render's samples. The camera-ray
    /// estimate it replaces counted five segments and a shadow ray for every path and priced
    /// them all as camera rays, and it compared trees by coherent rays, so it overstated both
    /// the render and the gain from a better tree (docs/benchmarks.md, "Estimates against real
    /// renders"). Timing is done only where one timing costs at most a sixteenth of the render
    /// (16 × 3 × [`TIMED_PATHS`] samples in all) and of its time budget, and no more than a
    /// reinsertion sweep (8 LBVH builds); otherwise the camera-ray estimate is kept (on the
    /// Cornell box, timing cost more than it could gain).
    ///
    /// Under a time limit (`render --time`, `settings.time` per frame) the render lasts no longer than it, and a faster
    /// tree is worth the time it saves on the samples the LBVH would render in it.
    pub fn build_auto_cpu(scene: &Scene, settings: &RenderSettings, frames: usize) -> (Self, BuildReport) {
        let device = AutoDevice::CpuPaths {
            samples: total_samples(settings, frames),
            seed: settings.seed,
            max_depth: settings.max_depth,
            budget: total_budget(settings, frames),
        };
        let rays = Self::estimated_rays(scene, settings.spp, settings.max_depth, frames);
        Self::build_auto_for(scene, rays, device)
    }

    /// [`RenderScene::build_auto`] for a render on `device`.
    ///
    /// - [`AutoDevice::CpuPaths`]: each tree is timed on paths ([`RenderScene::build_auto_cpu`]),
    ///   and the scene of the last tree timed is returned if the tree did not change after it.
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
            return Self::build_instanced(scene, &"lbvh+prbvh".parse().expect("a builder name"));
        }
        let mut t = Instant::now();
        let (triangles, material_of) = scene.world_triangles();
        let prims: Vec<_> = triangles.par_iter().map(Triangle::aabb).collect();
        let mut bvh = lbvh::build(&prims);
        let lbvh_seconds = t.elapsed().as_secs_f64();
        let tracing = device.tracing();
        let assemble = |b: &crate::bvh::Bvh| {
            Self::assemble(scene, triangles.clone(), material_of.clone(), b, Instant::now(), String::new(), tracing)
        };
        let Some(baseline) = Self::auto_baseline(scene, rays, device, &bvh, &triangles, lbvh_seconds, &assemble) else {
            let label = "auto: lbvh, a render too short to time on the device".to_owned();
            return Self::assemble(scene, triangles, material_of, &bvh, t, label, tracing);
        };
        t += baseline.excluded;
        let Baseline { judge, render_seconds, mut timed, probe_cost, measured, .. } = baseline;
        // A tree's estimated render time, and its scene where it was assembled to time paths.
        let probe = |b: &crate::bvh::Bvh| match judge {
            Judge::Camera { speedup } => {
                (rays / (probe_trace_speed(b, &triangles, &scene.camera, tracing) * speedup), None)
            }
            Judge::Paths { samples, seed, max_depth } => {
                let (rs, report) = assemble(b);
                (rs.fastest_seconds_per_sample(seed, max_depth) * samples, Some((rs, report)))
            }
        };
        let mut render_seconds = render_seconds.unwrap_or_else(|| probe(&bvh).0);
        let mut base = "lbvh";
        // The render time binned SAH saves, 16% (the dragon scene, timed paths), must repay its
        // build, 9 LBVH builds (its cost there), and its probe, with half as much again to spare.
        if 0.16 * render_seconds > 1.5 * (9.0 * lbvh_seconds + probe_cost) {
            let binned = crate::bvh::binned_sah::build(&prims, &Default::default());
            // The LBVH's scene goes first: one probed scene at a time.
            let lbvh_scene = timed.take();
            let (binned_seconds, binned_scene) = probe(&binned);
            if binned_seconds < render_seconds {
                (bvh, render_seconds, base) = (binned, binned_seconds, "binned-sah");
                timed = binned_scene;
            } else if judge.is_camera() {
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
            None => Self::assemble(scene, triangles, material_of, &bvh, t, label, tracing),
        }
    }

    /// `auto`'s first step, on `device`: how trees will be judged (camera-ray probes, or paths
    /// timed on the CPU), the render's length with the LBVH `bvh` where that step estimates it,
    /// and the LBVH's scene where it was assembled to time it. `None` where the device's render
    /// is too short to time ([`AutoDevice::Unmeasured`]): the LBVH is kept.
    fn auto_baseline(
        scene: &Scene,
        rays: f64,
        device: AutoDevice<'_>,
        bvh: &crate::bvh::Bvh,
        triangles: &[Triangle],
        lbvh_seconds: f64,
        assemble: &dyn Fn(&crate::bvh::Bvh) -> Assembled,
    ) -> Option<Baseline> {
        let mut b = Baseline {
            judge: Judge::Camera { speedup: 1.0 },
            render_seconds: None,
            timed: None,
            probe_cost: 0.0,
            measured: String::new(),
            excluded: std::time::Duration::ZERO,
        };
        let tracing = device.tracing();
        match device {
            AutoDevice::Cpu => {}
            AutoDevice::CpuPaths { samples, seed, max_depth, budget } => {
                let camera_seconds = rays / probe_trace_speed(bvh, triangles, &scene.camera, tracing);
                let pixels = f64::from(scene.camera.width) * f64::from(scene.camera.height);
                // One timing's cost (3 × TIMED_PATHS paths), priced by the camera estimate, which
                // overstates it.
                let timing_seconds = camera_seconds / samples / pixels * 3.0 * f64::from(TIMED_PATHS);
                if worth_timing(pixels * samples, timing_seconds, lbvh_seconds, budget) {
                    let start = Instant::now();
                    let lbvh_scene = assemble(bvh);
                    let per_sample = lbvh_scene.0.fastest_seconds_per_sample(seed, max_depth);
                    b.probe_cost = start.elapsed().as_secs_f64();
                    // Under a time budget, the samples the LBVH renders in it: a faster tree is
                    // worth the time it saves on those.
                    let samples = budget.map_or(samples, |b| samples.min(b / per_sample.max(1e-12)));
                    b.judge = Judge::Paths { samples, seed, max_depth };
                    b.render_seconds = Some(per_sample * samples);
                    b.measured = format!(", paths timed at {:.1} ms per sample", per_sample * 1e3);
                    b.timed = Some(lbvh_scene);
                } else {
                    let capped = budget.map_or(camera_seconds, |b| camera_seconds.min(b));
                    b.judge = Judge::Camera { speedup: camera_seconds / capped.max(1e-12) };
                    b.render_seconds = Some(capped);
                }
            }
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
                b.judge = Judge::Camera { speedup: cpu_seconds / device_seconds.max(1e-12) };
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
        let config = PrbvhConfig { collapse: None, ..Default::default() };
        // The first sweep is measured, not predicted: SAH overstates trace gains on some scenes
        // (the dragon's room), so its real gain, from a second probe, decides whether to go on
        // and calibrates the SAH-to-time factor for the sweeps after it. A sweep costs about 8
        // LBVH builds, plus its probe; none is tried when the gain to expect could not repay
        // that: 20% from the LBVH, 5% from binned SAH (the most a first sweep on binned SAH
        // gained on the dragon scene).
        let mut iterations = 0;
        let expected_gain = if base == "lbvh" { 0.2 } else { 0.05 };
        if expected_gain * *render_seconds > 8.0 * lbvh_seconds + probe_cost {
            let first = PrbvhConfig { max_iterations: config.mu, ..config };
            // The probe below assembles its own scene: one at a time.
            drop(timed.take());
            let sweep_start = Instant::now();
            let s1 = prbvh::optimize_while(bvh, &first, |_| true);
            let spent = sweep_start.elapsed().as_secs_f64();
            iterations += s1.iterations.len();
            let (after, swept_scene) = probe(bvh);
            *timed = swept_scene;
            let gained = *render_seconds - after;
            let sah_fraction = (s1.initial_sah - s1.sah_before_collapse) / s1.initial_sah;
            // A sweep that did not pay is kept all the same: its cost is spent, its SAH is lower,
            // and a timing cannot tell a gain of a few percent from its noise (on the dragon
            // scene a sweep that timed slower still rendered faster).
            if gained > spent && sah_fraction > 0.0 {
                let efficiency = (gained / *render_seconds / sah_fraction).clamp(0.05, 1.0);
                *render_seconds = after;
                let estimate = *render_seconds;
                let mut sweep: std::collections::VecDeque<(f64, f64)> = std::collections::VecDeque::new();
                let rest = prbvh::optimize_while(bvh, &config, |p| {
                    let saved = (p.previous_sah - p.sah) / p.initial_sah * estimate * efficiency;
                    sweep.push_back((saved, p.iteration_time.as_secs_f64()));
                    if sweep.len() > config.mu as usize {
                        sweep.pop_front();
                    }
                    // Judged over a whole sweep (μ iterations) only: one iteration searches a
                    // μ-th of the nodes, and the Cornell box's first one after a paying sweep
                    // found nothing, which stopped it at SAH 30.89 where a full run reaches 30.57.
                    let (saved, spent): (f64, f64) = sweep.iter().fold((0.0, 0.0), |a, s| (a.0 + s.0, a.1 + s.1));
                    sweep.len() < config.mu as usize || saved > spent
                });
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

    /// The CPU's time to trace one sample of every pixel, in seconds, estimated by tracing paths
    /// of at most `max_depth` segments from [`TIMED_PATHS`] pixels, one in each cell of a 64 ×
    /// 64 grid over the image, on all worker threads. They are real paths (bounces, shadow
    /// rays, escapes and Russian roulette as the render has them), not a count of rays at a
    /// camera ray's price. Their random numbers come from sample indices no render uses.
    pub fn cpu_seconds_per_sample(&self, seed: u64, max_depth: u32) -> f64 {
        let (w, h) = (self.width as f32 / 64.0, self.height as f32 / 64.0);
        let start = Instant::now();
        let rays: u64 = (0..TIMED_PATHS)
            .into_par_iter()
            .map(|i| {
                let mut rng = Rng::for_sample(seed, u64::from(i), TIMING_SAMPLE);
                let cell = Vec2::new((i % 64) as f32, (i / 64) as f32);
                let ray = self.camera.ray((cell + rng.next_vec2()) * Vec2::new(w, h), rng.next_vec2());
                u64::from(self.radiance(ray, &mut rng, max_depth).1)
            })
            .sum();
        std::hint::black_box(rays);
        let pixels = f64::from(self.width) * f64::from(self.height);
        start.elapsed().as_secs_f64() * pixels / f64::from(TIMED_PATHS)
    }

    /// The fastest of three [`RenderScene::cpu_seconds_per_sample`]: the first runs on cold
    /// caches.
    fn fastest_seconds_per_sample(&self, seed: u64, max_depth: u32) -> f64 {
        (0..3).map(|_| self.cpu_seconds_per_sample(seed, max_depth)).fold(f64::INFINITY, f64::min)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The timing rule: enough samples for a timing to be a sixteenth of the render, a timing
    /// no dearer than a sweep (8 LBVH builds), and, under a budget, a sixteenth of the budget.
    /// The Cornell box's case (a timing of 8 ms against LBVH builds of 0.3 ms) is not timed.
    #[test]
    fn paths_are_timed_only_where_it_pays() {
        let least = 16.0 * 3.0 * f64::from(TIMED_PATHS);
        assert!(worth_timing(least, 0.01, 0.02, None));
        assert!(!worth_timing(least - 1.0, 0.01, 0.02, None));
        assert!(worth_timing(1e9, 0.16, 0.02, None));
        assert!(!worth_timing(1e9, 0.17, 0.02, None));
        assert!(!worth_timing(1e9, 0.008, 0.0003, None));
        assert!(worth_timing(1e9, 0.01, 0.02, Some(0.16)));
        assert!(!worth_timing(1e9, 0.01, 0.02, Some(0.15)));
    }
}
