//! The animation benchmark behind `bvh-bench --animated`: how each way of keeping a top-level
//! BVH up to date pays per frame, and what it does to the tree's quality.
//!
//! Strategies, all fed the same motion:
//! - `reinsert+prbvh`: delete the moved instances, clean, reinsert, one round of local PRBVH,
//!   with the quality monitor ([`arbor::bvh::dynamic`]);
//! - `reinsert`: the same without the local PRBVH;
//! - `rebuild`: a binned-SAH build of the top level every frame; its SAH is the "fresh build"
//!   every strategy's SAH is divided by, frame by frame;
//! - `refit`: the topology of the first frame, boxes refitted above the moved instances;
//! - `single-level`: no instancing; one dynamic BVH over every world-space triangle, where a
//!   moving instance deletes and reinserts all its triangles, with local PRBVH but without the
//!   monitor (skipped above `single_level_max_triangles` world or
//!   `single_level_max_moving_triangles` moving triangles). Its SAH is over triangles, so its
//!   ratio is taken against a fresh binned-SAH build over the triangles, every `check_every`
//!   frames and at the last.
//!
//! At the last frame every strategy traces the same primary and diffuse rays (as in `bvh-bench`'s
//! builder comparison); their closest hits must agree.

use std::time::Instant;

use glam::{Affine3A, Quat, Vec3};
use rayon::prelude::*;
use serde::Serialize;

use arbor::bvh::build::Builder;
use arbor::bvh::dynamic::instances::{Instance, TopLevelUpdate, TwoLevel};
use arbor::bvh::dynamic::{DynamicBvh, DynamicConfig};
use arbor::bvh::{MeshBvh, Tracing, build::binned_sah, sah_cost};
use arbor::geometry::{Aabb, Ray, Triangle, TriangleMesh};
use arbor::render::rng::Rng;
use arbor::scene::Scene;

use crate::rays as bench_rays;

/// Instances of a few meshes, some of which move.
pub struct AnimatedInstances {
    pub meshes: Vec<TriangleMesh>,
    /// Mesh and transform of every instance at frame 0.
    pub instances: Vec<(u32, Affine3A)>,
    /// The instances that move.
    pub moving: Vec<u32>,
    motion: Motion,
}

enum Motion {
    /// Straight lines at constant speed, bouncing off the field's walls, spinning about y.
    Drift { field: Aabb, velocity: Vec<Vec3>, spin: Vec<f32> },
    /// A scene's own animation, frame `f` at the scene's frame `frames.start + f`.
    Scene(Box<Scene>),
}

impl AnimatedInstances {
    /// `n` instances of a sphere (80 triangles) and a torus (144 triangles) scattered over a
    /// field about two units per instance wide, one to two units tall; `moving` (a fraction in
    /// [0, 1]) of them, picked at random, drift at 0.05% to 0.15% of the field's width per frame
    /// while spinning.
    pub fn procedural(n: usize, moving: f64, seed: u64) -> Self {
        let side = 2.0 * (n as f32).sqrt().max(1.0);
        let field = Aabb::new(Vec3::new(0.0, 0.0, 0.0), Vec3::new(side, 2.0, side));
        let meshes = vec![TriangleMesh::icosphere(1), TriangleMesh::torus(Vec3::ZERO, 0.7, 0.25, 12, 6)];
        let mut rng = Rng::for_sample(seed, 0, 0);
        let instances: Vec<(u32, Affine3A)> = (0..n)
            .map(|i| {
                let p = field.min + Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * field.extent();
                let rotation = Quat::from_euler(
                    glam::EulerRot::YXZ,
                    rng.next_f32() * std::f32::consts::TAU,
                    rng.next_f32() * std::f32::consts::TAU,
                    0.0,
                );
                let scale = 0.5 + 0.5 * rng.next_f32();
                ((i % 2) as u32, Affine3A::from_scale_rotation_translation(Vec3::splat(scale), rotation, p))
            })
            .collect();
        // Pick round(moving * n) movers: a partial Fisher-Yates shuffle.
        let count = ((moving.clamp(0.0, 1.0) * n as f64).round() as usize).min(n);
        let mut ids: Vec<u32> = (0..n as u32).collect();
        for k in 0..count {
            let j = k + ((rng.next_f32() as f64 * (n - k) as f64) as usize).min(n - k - 1);
            ids.swap(k, j);
        }
        let mut moving_ids = ids[..count].to_vec();
        moving_ids.sort_unstable();
        let velocity = moving_ids
            .iter()
            .map(|_| {
                let a = rng.next_f32() * std::f32::consts::TAU;
                let speed = side * (0.0005 + 0.001 * rng.next_f32());
                Vec3::new(a.cos(), 0.2 * (rng.next_f32() - 0.5), a.sin()) * speed
            })
            .collect();
        let spin = moving_ids.iter().map(|_| (rng.next_f32() - 0.5) * 0.2).collect();
        Self { meshes, instances, moving: moving_ids, motion: Motion::Drift { field, velocity, spin } }
    }

    /// A scene's objects, moving as its animation says (frame 0 is its first frame).
    pub fn from_scene(scene: &Scene) -> Self {
        let t0 = scene.frame_time(scene.animation.as_ref().map_or(0, |a| a.frames.start));
        Self {
            meshes: scene.meshes.iter().map(|m| m.mesh.clone()).collect(),
            instances: scene
                .objects
                .iter()
                .map(|o| (o.mesh as u32, Affine3A::from_mat4(o.world_from_object_at(t0))))
                .collect(),
            moving: (0..scene.objects.len() as u32).filter(|&i| scene.objects[i as usize].is_animated()).collect(),
            motion: Motion::Scene(Box::new(scene.clone())),
        }
    }

    /// The moving instances' transforms at frame `frame`.
    pub fn transforms_at(&self, frame: u32) -> Vec<(u32, Affine3A)> {
        match &self.motion {
            Motion::Drift { field, velocity, spin } => self
                .moving
                .par_iter()
                .enumerate()
                .map(|(k, &i)| {
                    let (s, r, t) = self.instances[i as usize].1.to_scale_rotation_translation();
                    let p = bounce(t + velocity[k] * frame as f32, field);
                    let r = Quat::from_rotation_y(spin[k] * frame as f32) * r;
                    (i, Affine3A::from_scale_rotation_translation(s, r, p))
                })
                .collect(),
            Motion::Scene(scene) => {
                let start = scene.animation.as_ref().map_or(0, |a| a.frames.start);
                let t = scene.frame_time(start + frame);
                self.moving
                    .iter()
                    .map(|&i| (i, Affine3A::from_mat4(scene.objects[i as usize].world_from_object_at(t))))
                    .collect()
            }
        }
    }

    /// Triangles over all instances.
    pub fn world_triangle_count(&self) -> usize {
        self.instances.iter().map(|(m, _)| self.meshes[*m as usize].indices.len()).sum()
    }
}

/// `p` folded back into `field` as if it bounced off its walls.
fn bounce(p: Vec3, field: &Aabb) -> Vec3 {
    let fold = |x: f32, lo: f32, hi: f32| {
        let w = hi - lo;
        if w <= 0.0 {
            return lo;
        }
        let u = (x - lo).rem_euclid(2.0 * w);
        lo + if u > w { 2.0 * w - u } else { u }
    };
    Vec3::new(
        fold(p.x, field.min.x, field.max.x),
        fold(p.y, field.min.y, field.max.y),
        fold(p.z, field.min.z, field.max.z),
    )
}

/// What to run.
#[derive(Clone, Debug)]
pub struct AnimBenchConfig {
    pub frames: u32,
    /// Primary rays at the last frame: `resolution²`. Default 256.
    pub resolution: u32,
    pub dynamic: DynamicConfig,
    /// Builder of each mesh's own BVH. Default `lbvh+prbvh`.
    pub mesh_builder: Builder,
    /// The single-level strategy runs only up to this many world triangles, and this many
    /// moving ones (it reinserts each moving triangle every frame). Defaults 2,000,000 and
    /// 250,000.
    pub single_level_max_triangles: usize,
    pub single_level_max_moving_triangles: usize,
    /// The form each mesh's tree is traced in. Default: the best this CPU has.
    pub tracing: Tracing,
}

impl Default for AnimBenchConfig {
    fn default() -> Self {
        Self {
            frames: 300,
            resolution: 256,
            dynamic: DynamicConfig::default(),
            mesh_builder: "lbvh+prbvh".parse().expect("a builder name"),
            single_level_max_triangles: 2_000_000,
            single_level_max_moving_triangles: 250_000,
            tracing: Tracing::best(),
        }
    }
}

/// One strategy's results. Times in milliseconds, trace speed in millions of rays per second.
#[derive(Clone, Debug, Serialize)]
pub struct StrategyReport {
    pub name: String,
    /// Median update time per frame.
    pub update_ms: f64,
    pub update_ms_mean: f64,
    pub update_ms_max: f64,
    /// SAH over the fresh build's, at the last frame and the worst over all frames.
    pub sah_ratio_final: f64,
    pub sah_ratio_max: f64,
    pub primary_mrays_final: f64,
    pub diffuse_mrays_final: f64,
    /// Quality-monitor rebuilds (dynamic strategies).
    pub rebuilds: usize,
    /// `[frame, SAH ratio]` for every frame where it was measured.
    pub sah_ratio_curve: Vec<[f64; 2]>,
}

/// Everything `bvh-bench --animated` reports.
#[derive(Clone, Debug, Serialize)]
pub struct AnimReport {
    pub instances: usize,
    pub moving: usize,
    pub frames: u32,
    pub triangles: usize,
    pub threads: usize,
    pub strategies: Vec<StrategyReport>,
    /// Rays whose closest hit differs between the two-level strategies, which trace the same
    /// object-space triangles and must agree exactly; empty when all agree.
    pub mismatches: Vec<String>,
    /// Rays where the single-level tree, over world-space copies of the triangles, hits another
    /// triangle: rounding in the transformed vertices can move a hit across a shared edge or
    /// between touching objects. Reported, not an error.
    pub single_level_differences: usize,
}

struct Track {
    name: String,
    times: Vec<f64>,
    curve: Vec<[f64; 2]>,
    rebuilds: usize,
}

impl Track {
    fn new(name: &str) -> Self {
        Self { name: name.into(), times: Vec::new(), curve: Vec::new(), rebuilds: 0 }
    }
}

/// Runs every strategy over `frames` frames of `anim`.
pub fn run(anim: &AnimatedInstances, config: &AnimBenchConfig) -> AnimReport {
    let meshes: Vec<MeshBvh> =
        anim.meshes.iter().map(|m| config.mesh_builder.build_mesh(&m.triangles(), config.tracing)).collect();
    let instances: Vec<Instance> = anim.instances.iter().map(|&(m, t)| Instance::new(m, t)).collect();
    let mut no_prbvh = config.dynamic;
    no_prbvh.prbvh_rounds = 0;
    let hows = [
        ("reinsert+prbvh", TopLevelUpdate::Dynamic(config.dynamic)),
        ("reinsert", TopLevelUpdate::Dynamic(no_prbvh)),
        ("rebuild", TopLevelUpdate::Rebuild),
        ("refit", TopLevelUpdate::Refit),
    ];
    let mut levels: Vec<TwoLevel> = hows.iter().map(|_| TwoLevel::new(meshes.clone(), instances.clone())).collect();
    let mut tracks: Vec<Track> = hows.iter().map(|(n, _)| Track::new(n)).collect();
    let moving_triangles: usize =
        anim.moving.iter().map(|&i| anim.meshes[anim.instances[i as usize].0 as usize].indices.len()).sum();
    let mut single = (anim.world_triangle_count() <= config.single_level_max_triangles
        && moving_triangles <= config.single_level_max_moving_triangles)
        .then(|| SingleLevel::new(anim, &config.dynamic));
    let mut single_track = Track::new("single-level");
    let rebuild = 2;
    for f in 1..=config.frames {
        let changes = anim.transforms_at(f);
        for (k, (_, how)) in hows.iter().enumerate() {
            let t = Instant::now();
            let stats = levels[k].set_transforms(&changes, how);
            tracks[k].times.push(t.elapsed().as_secs_f64() * 1e3);
            tracks[k].rebuilds += usize::from(stats.rebuilt && k != rebuild);
        }
        let fresh = sah_cost(levels[rebuild].top_level().bvh());
        for (k, level) in levels.iter().enumerate() {
            let ratio = if fresh > 0.0 { sah_cost(level.top_level().bvh()) / fresh } else { 1.0 };
            tracks[k].curve.push([f as f64, ratio]);
        }
        if let Some(s) = &mut single {
            let t = Instant::now();
            single_track.rebuilds += usize::from(s.update(anim, &changes));
            single_track.times.push(t.elapsed().as_secs_f64() * 1e3);
            if f % config.dynamic.check_every.max(1) == 0 || f == config.frames {
                single_track.curve.push([f as f64, s.sah_ratio()]);
            }
        }
    }
    // Trace speed at the last frame: the same rays through every structure.
    let reference = &levels[rebuild];
    let bounds = reference.top_level().bvh().bounds();
    let primary = bench_rays::primary_rays(&bounds, config.resolution, config.resolution);
    let diffuse = diffuse_rays(anim, reference, &primary);
    let key = |h: Option<(u32, u32)>| h.unwrap_or((u32::MAX, u32::MAX));
    let expected: Vec<_> = [&primary, &diffuse]
        .iter()
        .map(|rays| {
            rays.par_iter()
                .map(|r| key(reference.closest_hit(r, f32::INFINITY).map(|h| (h.instance, h.prim_id))))
                .collect::<Vec<_>>()
        })
        .collect();
    let mut mismatches = Vec::new();
    let mut single_level_differences = 0;
    let mut reports = Vec::new();
    let mut trace = |name: &str, hit: &(dyn Fn(&Ray) -> Option<(u32, u32)> + Sync)| -> [f64; 2] {
        let mut speeds = [0.0; 2];
        for (s, rays) in [&primary, &diffuse].iter().enumerate() {
            let t = Instant::now();
            let got: Vec<_> = rays.par_iter().map(|r| key(hit(r))).collect();
            speeds[s] = rays.len() as f64 / t.elapsed().as_secs_f64().max(1e-9) / 1e6;
            let differ = got.iter().zip(&expected[s]).filter(|(a, b)| a != b).count();
            if name == "single-level" {
                single_level_differences += differ;
            } else if differ > 0 {
                mismatches.push(format!(
                    "{name}: {differ} of {} {} rays hit differently",
                    rays.len(),
                    ["primary", "diffuse"][s]
                ));
            }
        }
        speeds
    };
    for (k, level) in levels.iter().enumerate() {
        let speeds = trace(&tracks[k].name, &|r| level.closest_hit(r, f32::INFINITY).map(|h| (h.instance, h.prim_id)));
        reports.push(summarize(&tracks[k], speeds));
    }
    if let Some(s) = &single {
        let speeds = trace("single-level", &|r| s.closest_hit(r));
        reports.push(summarize(&single_track, speeds));
    }
    AnimReport {
        instances: anim.instances.len(),
        moving: anim.moving.len(),
        frames: config.frames,
        triangles: anim.world_triangle_count(),
        threads: rayon::current_num_threads(),
        strategies: reports,
        mismatches,
        single_level_differences,
    }
}

fn summarize(t: &Track, speeds: [f64; 2]) -> StrategyReport {
    let mut sorted = t.times.clone();
    sorted.sort_by(f64::total_cmp);
    let median = crate::median(sorted.iter().copied());
    let ratios = t.curve.iter().map(|p| p[1]);
    StrategyReport {
        name: t.name.clone(),
        update_ms: median,
        update_ms_mean: sorted.iter().sum::<f64>() / sorted.len().max(1) as f64,
        update_ms_max: sorted.last().copied().unwrap_or(0.0),
        sah_ratio_final: t.curve.last().map_or(1.0, |p| p[1]),
        sah_ratio_max: ratios.fold(f64::NEG_INFINITY, f64::max).max(t.curve.first().map_or(1.0, |p| p[1])),
        primary_mrays_final: speeds[0],
        diffuse_mrays_final: speeds[1],
        rebuilds: t.rebuilds,
        sah_ratio_curve: t.curve.clone(),
    }
}

/// One cosine-distributed bounce off each primary hit ([`bench_rays::diffuse_rays_with`]).
fn diffuse_rays(anim: &AnimatedInstances, level: &TwoLevel, primary: &[Ray]) -> Vec<Ray> {
    bench_rays::diffuse_rays_with(primary, |ray| {
        let h = level.closest_hit(ray, f32::INFINITY)?;
        let inst = &level.instances()[h.instance as usize];
        let world = anim.meshes[inst.mesh as usize].triangle(h.prim_id as usize).transformed(&inst.world_from_object);
        let (p, err) = world.point_with_error(h.u, h.v);
        Some((p, err, world.unit_normal()))
    })
}

/// The single-level comparison: a dynamic BVH over every world-space triangle.
struct SingleLevel {
    tree: DynamicBvh,
    triangles: Vec<Triangle>,
    boxes: Vec<Aabb>,
    /// First triangle id of each instance.
    offsets: Vec<u32>,
    config: DynamicConfig,
}

impl SingleLevel {
    fn new(anim: &AnimatedInstances, config: &DynamicConfig) -> Self {
        let mut offsets = Vec::with_capacity(anim.instances.len());
        let mut triangles = Vec::new();
        for &(m, t) in &anim.instances {
            offsets.push(triangles.len() as u32);
            triangles.extend(Self::placed(&anim.meshes[m as usize], t));
        }
        let boxes: Vec<Aabb> = triangles.par_iter().map(Triangle::aabb).collect();
        Self { tree: DynamicBvh::build(&boxes), triangles, boxes, offsets, config: *config }
    }

    fn placed(mesh: &TriangleMesh, t: Affine3A) -> impl Iterator<Item = Triangle> + '_ {
        (0..mesh.indices.len()).map(move |i| mesh.triangle(i).transformed(&t))
    }

    /// Deletes and reinserts every triangle of the moved instances; returns whether the monitor
    /// rebuilt.
    fn update(&mut self, anim: &AnimatedInstances, changes: &[(u32, Affine3A)]) -> bool {
        let mut moves = Vec::new();
        for &(i, t) in changes {
            let mesh = &anim.meshes[anim.instances[i as usize].0 as usize];
            for (k, tri) in Self::placed(mesh, t).enumerate() {
                let id = self.offsets[i as usize] + k as u32;
                self.triangles[id as usize] = tri;
                self.boxes[id as usize] = tri.aabb();
                moves.push((id, self.boxes[id as usize]));
            }
        }
        let no_monitor = DynamicConfig { check_every: u32::MAX, rebuild_threshold: f64::INFINITY, ..self.config };
        self.tree.update(&moves, &self.boxes, &no_monitor).rebuilt
    }

    fn sah_ratio(&self) -> f64 {
        let fresh = sah_cost(&binned_sah::build(&self.boxes, &Default::default()));
        if fresh > 0.0 { sah_cost(self.tree.bvh()) / fresh } else { 1.0 }
    }

    /// Closest hit as (instance, triangle id in its mesh).
    fn closest_hit(&self, ray: &Ray) -> Option<(u32, u32)> {
        let h = self.tree.bvh().closest_hit_triangles(&self.triangles, ray, f32::INFINITY)?;
        let inst = self.offsets.partition_point(|&o| o <= h.prim_id) - 1;
        Some((inst as u32, h.prim_id - self.offsets[inst]))
    }
}
