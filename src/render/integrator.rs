//! Unidirectional path tracing with next-event estimation (one shadow ray per bounce) and
//! multiple importance sampling of light and BSDF samples with the power heuristic (Veach 1997,
//! chapter 9), Russian roulette from the fifth segment on.
//!
//! Conventions, those of the Mitsuba reference (`../shared/reference/cornell-box`): `max_depth`
//! counts path segments (1 = emitters seen directly, 2 = direct light); reflectors (diffuse,
//! conductor) are one-sided, black seen from the back of their triangle; emitters emit from the
//! front unless two-sided, and also reflect with their BSDF. An emitter reached by a BSDF sample
//! is weighted against the light sampling that could have found it, so it is neither lost nor
//! counted twice. What a scene lacks costs nothing: no emitters, no shadow rays; no
//! environment, no environment lookups.

use std::time::Instant;

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::bsdf::{Bsdf, ConductorFresnel as BsdfFresnel};
use super::camera::CameraModel;
use super::film::Film;
use super::geometry::{Flat, Geometry, Instanced, flat_lights, wants_instancing};
use super::lights::Lights;
use super::rng::Rng;
use super::sampling::{Frame, power_heuristic};
use crate::bvh::builders::Builder;
use crate::bvh::instances::TopLevelUpdate;
use crate::bvh::prbvh::{self, PrbvhConfig};
use crate::bvh::{CollapseConfig, MeshBvh, collapse_leaves, lbvh, sah_cost};
use crate::geometry::{Ray, Triangle, gamma, spawn_ray};
use crate::scene::{ConductorFresnel, Scattering, Scene};

/// Where a shadow ray's occlusion test ends, as a fraction of the way to the light's plane (see
/// `direct_light`).
pub const SHADOW_T_MAX: f32 = 1.0 - 1e-4;

/// Russian roulette starts at this many path segments (Mitsuba's `rr_depth`).
pub const RR_DEPTH: u32 = 5;

/// A material as the integrator uses it.
#[derive(Clone, Copy, Debug)]
pub struct RenderMaterial {
    /// `None`: absorbs everything.
    pub bsdf: Option<Bsdf>,
    pub emission: Option<Vec3>,
    pub two_sided: bool,
}

/// Everything a render reads: geometry and its BVH, materials, lights, camera.
pub struct RenderScene {
    pub geometry: Geometry,
    pub materials: Vec<RenderMaterial>,
    pub lights: Lights,
    pub environment: Option<Vec3>,
    pub camera: CameraModel,
    pub width: u32,
    pub height: u32,
    /// Firefly clamp, off (`None`) unless the user asks (`render --clamp`): a sample whose
    /// largest channel exceeds it is scaled down to it. Biased (energy is lost), so never a
    /// default, and no accuracy test runs with it.
    pub sample_clamp: Option<f32>,
}

/// What building the acceleration structure cost.
#[derive(Clone, Debug)]
pub struct BuildReport {
    pub build_ms: f64,
    pub sah: f64,
    pub triangles: usize,
    /// The builder used (for `auto`, what it decided).
    pub builder: String,
}

/// The device a render for [`RenderScene::build_auto_for`] runs on.
pub enum AutoDevice<'a> {
    /// The CPU, whose speed the probes measure.
    Cpu,
    /// Another device (a GPU), timed by rendering a little of the LBVH scene: `measure` returns
    /// the seconds one sample per pixel takes there and the time to leave out of the build (a
    /// kernel's compilation, paid once per process), or `None` to fall back on the CPU's
    /// estimate. `samples` is the render's samples per pixel over all its frames.
    Measured { samples: f64, measure: &'a mut dyn FnMut(&RenderScene) -> Option<(f64, std::time::Duration)> },
    /// Another device, on a render too short to be worth timing: the LBVH, not optimised.
    Unmeasured,
}

/// Rays per second of closest-hit queries on the leaf-collapsed `bvh`, measured on a 64x64 grid
/// of camera rays.
fn probe_trace_speed(bvh: &crate::bvh::Bvh, triangles: &[Triangle], camera: &crate::scene::Camera) -> f64 {
    let mesh = MeshBvh::new(collapse_leaves(bvh, &CollapseConfig::default()), triangles);
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

/// The time of a scene's first frame (0 for a static scene).
pub fn first_frame_time(scene: &Scene) -> f32 {
    scene.animation.as_ref().map_or(0.0, |a| scene.frame_time(a.frames.start))
}

impl RenderMaterial {
    pub fn from_scene(m: &crate::scene::Material) -> Self {
        let bsdf = match &m.scattering {
            Scattering::Black => None,
            Scattering::Diffuse { albedo } => Some(Bsdf::Diffuse { albedo: *albedo }),
            Scattering::Conductor { roughness, fresnel } => Some(Bsdf::Conductor {
                alpha: *roughness,
                fresnel: match fresnel {
                    ConductorFresnel::Complex { eta, k } => BsdfFresnel::Complex { eta: *eta, k: *k },
                    ConductorFresnel::BaseColor(c) => BsdfFresnel::Schlick { f0: *c },
                },
            }),
            Scattering::Dielectric { ior, roughness } => Some(Bsdf::Dielectric { alpha: *roughness, ior: *ior }),
        };
        Self { bsdf, emission: m.emission, two_sided: m.two_sided }
    }
}

impl RenderScene {
    /// Builds the scene's geometry as it is at its first frame (static scenes: as it is).
    ///
    /// A static scene is flattened to world-space triangles under one BVH built with `builder`,
    /// then the default leaf collapse. An animated or heavily instanced scene
    /// ([`wants_instancing`]) gets one such BVH per distinct mesh, in object space, under a
    /// top-level tree of its objects.
    pub fn build(scene: &Scene, builder: &Builder) -> (Self, BuildReport) {
        if wants_instancing(scene) {
            return Self::build_instanced(scene, builder);
        }
        let t = Instant::now();
        let (triangles, material_of) = scene.world_triangles();
        let prims: Vec<_> = triangles.par_iter().map(Triangle::aabb).collect();
        let built = builder.build(&triangles, &prims, &PrbvhConfig { collapse: None, ..Default::default() });
        Self::assemble(scene, triangles, material_of, &built.bvh, t, builder.to_string())
    }

    /// `--builder auto`: the tree that makes build plus render shortest for a render of about
    /// `rays` rays, among LBVH and binned SAH, each optimised by parallel reinsertion for as long
    /// as that pays for itself.
    ///
    /// 1. LBVH, and the render's length with it, estimated from its trace speed on a probe of
    ///    4096 camera rays.
    /// 2. If a quarter of that render would repay a binned-SAH build (estimated at 6 LBVH
    ///    builds, about its cost on 10⁵–10⁶ triangles here) twice over, the binned-SAH tree is
    ///    built and probed too, and the tree with the shorter estimated render is kept.
    /// 3. Parallel reinsertion on the kept tree, in sweeps (μ iterations, which search every
    ///    node once between them), if a 20% gain could repay a sweep (about 8 LBVH builds). The first sweep's gain is measured by a second probe: it goes on only if the
    ///    render got shorter by more than the sweep took, and that gain per unit of SAH gained
    ///    calibrates the rest. Each later sweep's saving is its SAH decrease, as a fraction,
    ///    times the estimated render time times that factor, and optimisation stops when the
    ///    last sweep saved less than it took. (SAH alone overstates gains: on the dragon scene
    ///    LBVH + PRBVH cut the SAH by 66% but traced 20% faster, and reinsertion on the
    ///    binned-SAH tree cost more than it returned. Judging single iterations stopped the
    ///    dragon after 5 of its ~40: one iteration searches a ninth of the nodes.)
    ///
    /// An instanced scene builds its meshes' BVHs with `lbvh+prbvh`: they are built once and
    /// serve every frame.
    pub fn build_auto(scene: &Scene, rays: f64) -> (Self, BuildReport) {
        Self::build_auto_for(scene, rays, AutoDevice::Cpu)
    }

    /// [`RenderScene::build_auto`] for a render on `device`. On another device than the CPU
    /// the CPU's probe cannot tell the render's length: it predicts the CPU's render, and an
    /// H100 rendered the dragon scene 21 times as fast as its machine's 16 cores, so `auto`
    /// spent up to 0.26 s optimising for GPU renders of 0.1 s. So the device renders a little
    /// of the LBVH scene ([`AutoDevice::Measured`]; for a GPU, `gpu::trace::build_auto`), and
    /// the render's length is its time per sample times the samples, which also corrects
    /// [`RenderScene::estimated_rays`]. The CPU probes' times are scaled to match: trees still
    /// compare by the CPU's probe, only the render's length changes. Where the LBVH is kept
    /// unoptimised, the timed scene itself is returned.
    pub fn build_auto_for(scene: &Scene, rays: f64, device: AutoDevice<'_>) -> (Self, BuildReport) {
        if wants_instancing(scene) {
            return Self::build_instanced(scene, &"lbvh+prbvh".parse().expect("a builder name"));
        }
        let mut t = Instant::now();
        let (triangles, material_of) = scene.world_triangles();
        let prims: Vec<_> = triangles.par_iter().map(Triangle::aabb).collect();
        let mut bvh = lbvh::build(&prims);
        let lbvh_seconds = t.elapsed().as_secs_f64();
        let cpu_speed = probe_trace_speed(&bvh, &triangles, &scene.camera);
        // The device's render time over the CPU probe's estimate.
        let mut speedup = 1.0;
        let mut measured = String::new();
        let mut timed_scene = None;
        match device {
            AutoDevice::Cpu => {}
            AutoDevice::Unmeasured => {
                let label = "auto: lbvh, a render too short to time on the device".to_owned();
                return Self::assemble(scene, triangles, material_of, &bvh, t, label);
            }
            AutoDevice::Measured { samples, measure } => {
                let (lbvh_scene, report) =
                    Self::assemble(scene, triangles.clone(), material_of.clone(), &bvh, Instant::now(), String::new());
                if let Some((seconds_per_sample, excluded)) = measure(&lbvh_scene) {
                    t += excluded;
                    let device_seconds = seconds_per_sample * samples;
                    speedup = rays / cpu_speed / device_seconds.max(1e-9);
                    measured = format!(", timed on the device at {:.1} ms per sample", seconds_per_sample * 1e3);
                    timed_scene = Some((lbvh_scene, report));
                }
            }
        }
        let probe = |b: &crate::bvh::Bvh| probe_trace_speed(b, &triangles, &scene.camera) * speedup;
        let mut render_seconds = rays / (cpu_speed * speedup);
        let mut base = "lbvh";
        // A quarter of the render saved (binned SAH traced the dragon 27% faster) must repay the
        // binned build, estimated at 6 LBVH builds, twice over.
        if 0.25 * render_seconds > 2.0 * 6.0 * lbvh_seconds {
            let binned = crate::bvh::binned_sah::build(&prims, &Default::default());
            let binned_seconds = rays / probe(&binned);
            if binned_seconds < render_seconds {
                (bvh, render_seconds, base) = (binned, binned_seconds, "binned-sah");
            }
        }
        let config = PrbvhConfig { collapse: None, ..Default::default() };
        // The first sweep is measured, not predicted: SAH overstates trace gains on some scenes
        // (the dragon's room), so its real gain, from a second probe, decides whether to go on
        // and calibrates the SAH-to-time factor for the sweeps after it. A sweep costs about 8
        // LBVH builds (dragon, 2 cores); none is tried when a 20% gain could not repay that.
        let mut iterations = 0;
        if 0.2 * render_seconds > 8.0 * lbvh_seconds {
            let first = PrbvhConfig { max_iterations: config.mu, ..config };
            let sweep_start = Instant::now();
            let s1 = prbvh::optimize_while(&mut bvh, &first, |_| true);
            iterations += s1.iterations.len();
            let after = rays / probe(&bvh);
            let (gained, spent) = (render_seconds - after, sweep_start.elapsed().as_secs_f64());
            let sah_fraction = (s1.initial_sah - s1.sah_before_collapse) / s1.initial_sah;
            if gained > spent && sah_fraction > 0.0 {
                let efficiency = (gained / render_seconds / sah_fraction).clamp(0.05, 1.0);
                render_seconds = after;
                let mut sweep: std::collections::VecDeque<(f64, f64)> = std::collections::VecDeque::new();
                let rest = prbvh::optimize_while(&mut bvh, &config, |p| {
                    let saved = (p.previous_sah - p.sah) / p.initial_sah * render_seconds * efficiency;
                    sweep.push_back((saved, p.iteration_time.as_secs_f64()));
                    if sweep.len() > config.mu as usize {
                        sweep.pop_front();
                    }
                    let (saved, spent): (f64, f64) = sweep.iter().fold((0.0, 0.0), |a, s| (a.0 + s.0, a.1 + s.1));
                    saved > spent
                });
                iterations += rest.iterations.len();
            }
        }
        let label = format!(
            "auto: {base}+prbvh, {iterations} iterations for a render estimated at {render_seconds:.2} s{measured}"
        );
        match timed_scene {
            Some((lbvh_scene, mut report)) if base == "lbvh" && iterations == 0 => {
                (report.builder, report.build_ms) = (label, t.elapsed().as_secs_f64() * 1e3);
                (lbvh_scene, report)
            }
            _ => Self::assemble(scene, triangles, material_of, &bvh, t, label),
        }
    }

    /// The rays a render of `scene` traces, roughly, for [`RenderScene::build_auto`]: each path
    /// segment traces one ray, plus a shadow ray when the scene has emitters, and paths rarely
    /// run past five segments (Russian roulette starts there).
    pub fn estimated_rays(scene: &Scene, spp: u32, max_depth: u32, frames: usize) -> f64 {
        let per_path = max_depth.min(RR_DEPTH) as f64 * if scene.has_emitters() { 2.0 } else { 1.0 };
        let pixels = scene.camera.width as f64 * scene.camera.height as f64;
        pixels * spp as f64 * per_path * frames as f64
    }

    /// The two-level build (see [`RenderScene::build`]).
    fn build_instanced(scene: &Scene, builder: &Builder) -> (Self, BuildReport) {
        let t = Instant::now();
        let meshes: Vec<MeshBvh> = scene.meshes.iter().map(|m| builder.build_mesh(&m.mesh.triangles())).collect();
        let materials: Vec<RenderMaterial> = scene.materials.iter().map(RenderMaterial::from_scene).collect();
        let mut instanced = Instanced::new(scene, meshes, first_frame_time(scene));
        let lights = instanced.lights(&materials);
        let geometry = Geometry::Instanced(instanced);
        let Geometry::Instanced(g) = &geometry else { unreachable!() };
        let report = BuildReport {
            build_ms: t.elapsed().as_secs_f64() * 1e3,
            sah: g.two_level.top_level().sah_estimate(&Default::default()),
            triangles: geometry.world_triangle_count(),
            builder: format!("two levels: {builder} per mesh, binned-sah over {} objects", scene.objects.len()),
        };
        (Self::with_geometry(scene, geometry, materials, lights), report)
    }

    /// The rest of a flat build from a tree with one primitive per leaf over `triangles` (built
    /// here, or on the GPU: `arbor::gpu::build_render_scene`): leaf collapse, materials, lights,
    /// camera. The report's time runs from `start`.
    pub fn assemble(
        scene: &Scene,
        triangles: Vec<Triangle>,
        material_of: Vec<u32>,
        leaf1: &crate::bvh::Bvh,
        start: Instant,
        builder: String,
    ) -> (Self, BuildReport) {
        let bvh = collapse_leaves(leaf1, &CollapseConfig::default());
        let sah = sah_cost(&bvh);
        let mesh = MeshBvh::new(bvh, &triangles);
        let materials: Vec<RenderMaterial> = scene.materials.iter().map(RenderMaterial::from_scene).collect();
        let lights = flat_lights(&triangles, &material_of, &materials);
        let report =
            BuildReport { build_ms: start.elapsed().as_secs_f64() * 1e3, sah, triangles: triangles.len(), builder };
        let geometry = Geometry::Flat(Flat { mesh, triangles, material_of });
        (Self::with_geometry(scene, geometry, materials, lights), report)
    }

    fn with_geometry(scene: &Scene, geometry: Geometry, materials: Vec<RenderMaterial>, lights: Lights) -> Self {
        Self {
            geometry,
            materials,
            lights,
            environment: scene.environment.filter(|e| e.max_element() > 0.0),
            camera: CameraModel::new(&scene.camera),
            width: scene.camera.width,
            height: scene.camera.height,
            sample_clamp: None,
        }
    }

    /// Moves an animated scene's objects to where they are at `time`, updating the top-level
    /// tree by `how`, and the lights. Returns what the update cost. A flat (static) scene does
    /// not change.
    pub fn set_time(
        &mut self,
        scene: &Scene,
        time: f32,
        how: &TopLevelUpdate,
    ) -> Option<crate::bvh::dynamic::UpdateStats> {
        let Geometry::Instanced(g) = &mut self.geometry else { return None };
        let stats = g.set_time(scene, time, how);
        if g.moves_lights(scene) {
            self.lights = g.lights(&self.materials);
        }
        Some(stats)
    }

    /// Radiance along `ray` (unit direction) for a path of at most `max_depth` segments;
    /// also returns the number of rays traced.
    pub fn radiance(&self, mut ray: Ray, rng: &mut Rng, max_depth: u32) -> (Vec3, u32) {
        let (mut l, mut beta) = (Vec3::ZERO, Vec3::ONE);
        let (mut prev_pdf, mut prev_delta) = (0.0f32, true);
        let mut rays = 0;
        for depth in 1..=max_depth {
            rays += 1;
            let Some(hit) = self.geometry.intersect(&ray) else {
                if let Some(env) = self.environment {
                    l += beta * env;
                }
                break;
            };
            let tri = &hit.triangle;
            let ng = tri.unit_normal();
            if ng == Vec3::ZERO {
                break;
            }
            let (p, p_error) = tri.point_with_error(hit.u, hit.v);
            let wo_world = -ray.dir;
            let front = ng.dot(wo_world) > 0.0;
            let material = &self.materials[hit.material as usize];
            if let Some(le) = material.emission.filter(|_| front || material.two_sided) {
                if prev_delta {
                    l += beta * le;
                } else {
                    let dist2 = (p - ray.origin).length_squared();
                    let p_light = self.lights.pdf_area(hit.light) * dist2 / ng.dot(wo_world).abs();
                    l += beta * le * power_heuristic(prev_pdf, p_light);
                }
            }
            if depth == max_depth {
                break;
            }
            let Some(bsdf) = material.bsdf else { break };
            let dielectric = matches!(bsdf, Bsdf::Dielectric { .. });
            if !dielectric && !front {
                break; // one-sided reflector seen from the back
            }
            let frame = Frame::from_normal(ng);
            let wo = frame.to_local(wo_world);
            if !self.lights.is_empty() && bsdf.has_non_delta() {
                rays += self.direct_light(&bsdf, &frame, (p, p_error), ng, wo, beta, rng, &mut l);
            }
            let Some(s) = bsdf.sample(wo, rng.next_vec2(), rng.next_f32()) else { break };
            if !(s.weight.is_finite() && s.weight.max_element() > 0.0) {
                break;
            }
            beta *= s.weight;
            prev_pdf = s.pdf;
            prev_delta = s.is_delta;
            ray = spawn_ray(p, p_error, ng, frame.to_world(s.wi).normalize());
            if depth >= RR_DEPTH {
                let q = beta.max_element().min(0.95);
                if rng.next_f32() >= q {
                    break;
                }
                beta /= q;
            }
        }
        (l, rays)
    }

    /// Next-event estimation: one light sample, MIS-weighted against the BSDF. Adds to `l` and
    /// returns the rays traced (0 or 1).
    #[allow(clippy::too_many_arguments)]
    fn direct_light(
        &self,
        bsdf: &Bsdf,
        frame: &Frame,
        (p, p_error): (Vec3, Vec3),
        ng: Vec3,
        wo: Vec3,
        beta: Vec3,
        rng: &mut Rng,
        l: &mut Vec3,
    ) -> u32 {
        let u_select = rng.next_f32();
        let u = rng.next_vec2();
        let Some(lp) = self.lights.sample(u_select, u) else { return 0 };
        let to = lp.point - p;
        let dist2 = to.length_squared();
        if dist2 <= 0.0 {
            return 0;
        }
        let wi_world = to / dist2.sqrt();
        let cos_light = lp.normal.dot(-wi_world);
        if !(cos_light > 0.0 || (lp.two_sided && cos_light < 0.0)) {
            return 0;
        }
        let wi = frame.to_local(wi_world);
        let f = bsdf.eval(wo, wi);
        if f.max_element() <= 0.0 {
            return 0;
        }
        // Neither end is moved sideways, off the line from `p` to the sampled point: that would
        // tilt the ray and shift penumbrae by the offsets (about 1% of a Cornell box placed 10⁵
        // from the origin, where one ULP is 0.4% of it). Instead the ray starts along that line
        // just far enough to clear the receiver's surface, by its error bound plus one rounding
        // of the start itself, and stops short of the light's plane by the light point's error
        // bound, both measured along the ray. It stops a further 10⁻⁴ of its length short: once
        // rounded, the two triangles of a quad light are not exactly coplanar, and a ray reaching
        // one near their shared edge can clip the other (the Cornell box's light scaled by 0.1 or
        // 10⁻⁴ lost up to 1% of its direct light that way). Both found by tests/stability.rs.
        let cos_receiver = ng.dot(wi_world).abs();
        let clear = ng.abs().dot(p_error + p.abs() * gamma(1)) / cos_receiver;
        let from = p + wi_world * clear;
        let shadow = Ray::new(from, lp.point - from);
        let length = shadow.dir.length();
        let short_of_plane = lp.normal.abs().dot(lp.point_error) / (cos_light.abs() * length);
        let t_max = (1.0 - short_of_plane) * SHADOW_T_MAX;
        if !(clear.is_finite() && clear * clear < dist2 && t_max > 0.0) || self.geometry.occluded(&shadow, t_max) {
            return 1;
        }
        let p_light = lp.pdf_area * dist2 / cos_light.abs();
        let w = power_heuristic(p_light, bsdf.pdf(wo, wi));
        *l += beta * f * wi.z.abs() * lp.radiance * (w / p_light);
        1
    }

    /// Adds samples `samples` of every pixel to `film`, rows in parallel; calls `progress` with
    /// the rays of each finished row. Returns the rays traced. The result depends only on the
    /// seed and the sample indices, not on the thread count.
    pub fn render(
        &self,
        film: &mut Film,
        seed: u64,
        max_depth: u32,
        samples: std::ops::Range<u32>,
        progress: &(dyn Fn(u64) + Sync),
    ) -> u64 {
        let width = self.width as u64;
        film.rows_mut()
            .map(|(y, row)| {
                let mut rays = 0u64;
                for (x, px) in row.iter_mut().enumerate() {
                    let pixel = y as u64 * width + x as u64;
                    for s in samples.clone() {
                        let mut rng = Rng::for_sample(seed, pixel, s as u64);
                        let film_pos = Vec2::new(x as f32, y as f32) + rng.next_vec2();
                        let ray = self.camera.ray(film_pos, rng.next_vec2());
                        let (mut l, r) = self.radiance(ray, &mut rng, max_depth);
                        if let Some(c) = self.sample_clamp {
                            // NaN stays NaN, for the film to count.
                            let m = l.max_element();
                            if m > c {
                                l *= c / m;
                            }
                        }
                        px.add(l);
                        rays += r as u64;
                    }
                }
                progress(rays);
                rays
            })
            .sum()
    }
}
