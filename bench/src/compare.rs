//! The builder comparison behind `bvh-bench`: every builder builds the same triangles, gets the
//! same leaf collapse, and traces the same primary, shadow and diffuse rays (Meister & Bittner
//! 2018, Table 1). Closest hits must be the same for every tree (traversal is exact), so each
//! ray set's checksum must agree between builders; a disagreement is reported.

use std::time::{Duration, Instant};

use rayon::prelude::*;
use serde::Serialize;

use arbor::bvh::builders::Builder;
use arbor::bvh::prbvh::PrbvhConfig;
use arbor::bvh::{CollapseConfig, MeshBvh, collapse_leaves, lbvh, sah_cost, validate};
use arbor::geometry::{Aabb, Ray, Triangle};

use crate::median;

use crate::rays as bench_rays;

/// What to measure.
#[derive(Clone, Debug)]
pub struct BenchConfig {
    pub builders: Vec<Builder>,
    /// Builds per builder, and rounds of tracing (each round traces every builder once); the
    /// median times are reported. Default 3.
    pub runs: usize,
    /// Primary rays are `resolution²`. Default 512.
    pub resolution: u32,
    pub prbvh: PrbvhConfig,
    pub collapse: CollapseConfig,
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            builders: Vec::new(),
            runs: 3,
            resolution: 512,
            prbvh: PrbvhConfig::default(),
            collapse: CollapseConfig::default(),
        }
    }
}

/// One builder's results. Times in milliseconds, trace speeds in millions of rays per second.
#[derive(Clone, Debug, Serialize)]
pub struct BuilderReport {
    pub name: String,
    /// Median build time, without optimisation.
    pub build_ms: f64,
    /// Median PRBVH time (0 without).
    pub optimize_ms: f64,
    /// Leaf collapse time.
    pub collapse_ms: f64,
    /// SAH (cT = 3, cI = 2) after leaf collapse.
    pub sah: f64,
    /// SAH with one primitive per leaf, before collapse.
    pub sah_leaf1: f64,
    pub nodes: usize,
    pub leaves: usize,
    pub depth: usize,
    /// Trace speeds in Mrays/s; `None` (null in the JSON) for a set of no rays (or one traced
    /// in no measurable time): shadow and diffuse rays start where primary rays hit, and a
    /// camera that sees nothing of a thin mesh makes none.
    pub primary_mrays: Option<f64>,
    pub shadow_mrays: Option<f64>,
    pub diffuse_mrays: Option<f64>,
    /// PRBVH iterations: `[milliseconds since the build started, leaf-1 SAH]`, starting with
    /// the unoptimised tree; one point for builders without optimisation.
    pub sah_curve: Vec<[f64; 2]>,
    /// Checksums of the hits of each ray set: equal for every builder.
    pub checksums: [u64; 3],
}

/// Everything `bvh-bench` reports.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub triangles: usize,
    pub threads: usize,
    pub rays: RayCounts,
    pub builders: Vec<BuilderReport>,
    /// Disagreements between builders' checksums; empty when all agree.
    pub mismatches: Vec<String>,
}

#[derive(Clone, Copy, Debug, Serialize)]
pub struct RayCounts {
    pub primary: usize,
    pub shadow: usize,
    pub diffuse: usize,
}

/// The ray sets, made once from an LBVH (every exact traversal gives the same hits).
struct RaySets {
    primary: Vec<Ray>,
    shadow: Vec<Ray>,
    diffuse: Vec<Ray>,
}

fn ray_sets(triangles: &[Triangle], prim_aabbs: &[Aabb], resolution: u32) -> RaySets {
    let bvh = lbvh::build(prim_aabbs);
    let bounds = bvh.bounds();
    let primary = bench_rays::primary_rays(&bounds, resolution, resolution);
    let shadow = bench_rays::shadow_rays(&bvh, triangles, &primary, bench_rays::light_position(&bounds));
    let diffuse = bench_rays::diffuse_rays(&bvh, triangles, &primary);
    RaySets { primary, shadow, diffuse }
}

/// A builder's tree that does not validate: a bug in the builder.
#[derive(Debug, thiserror::Error)]
#[error("{builder}: invalid {stage}tree: {error}")]
pub struct InvalidTree {
    pub builder: String,
    /// Which tree: "" for the built one, "collapsed " for it after leaf collapse.
    pub stage: &'static str,
    /// Part of the message, not a `source`, so that a report of the whole chain says it once.
    pub error: arbor::bvh::ValidationError,
}

/// Runs the comparison. Fails only on a tree that does not validate (a bug); checksum
/// disagreements are listed in the report.
pub fn run(triangles: &[Triangle], config: &BenchConfig) -> Result<Report, InvalidTree> {
    run_with_progress(triangles, config, |_| {})
}

/// [`run`], calling `progress` with a line saying what it starts next (a build, a round of
/// tracing): PRBVH on 10^7 triangles runs for minutes.
pub fn run_with_progress(
    triangles: &[Triangle],
    config: &BenchConfig,
    progress: impl Fn(&str),
) -> Result<Report, InvalidTree> {
    progress("tracing the reference rays");
    let prim_aabbs: Vec<Aabb> = triangles.par_iter().map(Triangle::aabb).collect();
    let rays = ray_sets(triangles, &prim_aabbs, config.resolution);
    let mut report = Report {
        triangles: triangles.len(),
        threads: rayon::current_num_threads(),
        rays: RayCounts { primary: rays.primary.len(), shadow: rays.shadow.len(), diffuse: rays.diffuse.len() },
        builders: Vec::new(),
        mismatches: Vec::new(),
    };
    // Build everything first, then trace in rounds that visit every builder in turn: on a
    // shared, noisy machine a slow spell then hits all builders alike instead of one of them.
    let mut meshes = Vec::with_capacity(config.builders.len());
    for (k, builder) in config.builders.iter().enumerate() {
        progress(&format!(
            "building {builder} ({} of {} builders, {} runs)",
            k + 1,
            config.builders.len(),
            config.runs
        ));
        let (r, mesh) = measure(builder, triangles, &prim_aabbs, config)?;
        report.builders.push(r);
        meshes.push(mesh);
    }
    let sets: [(&[Ray], f32); 3] =
        [(&rays.primary, f32::INFINITY), (&rays.shadow, 1.0), (&rays.diffuse, f32::INFINITY)];
    let mut times = vec![[const { Vec::new() }; 3]; meshes.len()];
    for round in 0..config.runs.max(1) {
        progress(&format!("tracing, round {} of {}", round + 1, config.runs.max(1)));
        for (b, mesh) in meshes.iter().enumerate() {
            for (k, &(set, t_max)) in sets.iter().enumerate() {
                let (time, checksum) = trace(mesh, set, t_max);
                times[b][k].push(time);
                if round == 0 {
                    report.builders[b].checksums[k] = checksum;
                }
            }
        }
    }
    for (r, times) in report.builders.iter_mut().zip(times) {
        let [primary, shadow, diffuse] = times.map(median_ms);
        let mrays = |count: usize, ms: f64| (count > 0 && ms > 0.0).then(|| count as f64 / ms / 1e3);
        r.primary_mrays = mrays(rays.primary.len(), primary);
        r.shadow_mrays = mrays(rays.shadow.len(), shadow);
        r.diffuse_mrays = mrays(rays.diffuse.len(), diffuse);
    }
    for r in &report.builders[1..] {
        let first = &report.builders[0];
        for (k, set) in ["primary", "shadow", "diffuse"].iter().enumerate() {
            if r.checksums[k] != first.checksums[k] {
                report.mismatches.push(format!("{set} rays: {} and {} hit different triangles", first.name, r.name));
            }
        }
    }
    Ok(report)
}

/// The median of `times` in milliseconds.
fn median_ms(times: Vec<Duration>) -> f64 {
    median(times.iter().map(|t| t.as_secs_f64() * 1e3))
}

/// Builds with `builder` `runs` times and reports everything but the trace speeds and
/// checksums, which [`run`] measures; returns the tree to trace.
fn measure(
    builder: &Builder,
    triangles: &[Triangle],
    prim_aabbs: &[Aabb],
    config: &BenchConfig,
) -> Result<(BuilderReport, MeshBvh), InvalidTree> {
    let runs = config.runs.max(1);
    let mut builds = Vec::with_capacity(runs);
    let mut optimizations = Vec::with_capacity(runs);
    let mut last = None;
    for _ in 0..runs {
        let built = builder.build(triangles, prim_aabbs, &config.prbvh);
        builds.push(built.build_time);
        optimizations.push(built.optimize_time);
        last = Some(built);
    }
    let built = last.expect("at least one run");
    validate(&built.bvh, prim_aabbs).map_err(|error| InvalidTree { builder: builder.to_string(), stage: "", error })?;
    let sah_leaf1 = sah_cost(&built.bvh);
    let build_ms = median_ms(builds);
    let initial = built.prbvh.as_ref().map(|s| s.initial_sah).or(built.rbvh.as_ref().map(|s| s.initial_sah));
    let mut sah_curve = vec![[build_ms, initial.unwrap_or(sah_leaf1)]];
    if let Some(stats) = &built.prbvh {
        sah_curve.extend(stats.iterations.iter().map(|i| [build_ms + i.elapsed.as_secs_f64() * 1e3, i.sah]));
    }
    if let Some(stats) = &built.rbvh {
        sah_curve.extend(stats.batches.iter().map(|(t, sah)| [build_ms + t.as_secs_f64() * 1e3, *sah]));
    }
    let t = Instant::now();
    let collapsed = collapse_leaves(&built.bvh, &config.collapse);
    let collapse_ms = t.elapsed().as_secs_f64() * 1e3;
    let stats = validate(&collapsed, prim_aabbs).map_err(|error| InvalidTree {
        builder: builder.to_string(),
        stage: "collapsed ",
        error,
    })?;
    let sah = sah_cost(&collapsed);
    let mesh = MeshBvh::new(collapsed, triangles);
    let report = BuilderReport {
        name: builder.to_string(),
        build_ms,
        optimize_ms: median_ms(optimizations),
        collapse_ms,
        sah,
        sah_leaf1,
        nodes: stats.node_count,
        leaves: stats.leaf_count,
        depth: stats.depth,
        primary_mrays: None,
        shadow_mrays: None,
        diffuse_mrays: None,
        sah_curve,
        checksums: [0; 3],
    };
    Ok((report, mesh))
}

/// Traces `rays` once (closest hit, or any hit when `t_max` is finite: shadow rays); returns the
/// time and a checksum of the hits.
fn trace(mesh: &MeshBvh, rays: &[Ray], t_max: f32) -> (Duration, u64) {
    let shadow = t_max.is_finite();
    let hit_code = |r: &Ray| -> u64 {
        if shadow {
            mesh.any_hit(r, t_max) as u64
        } else {
            mesh.closest_hit(r, t_max).map_or(0, |h| h.prim_id as u64 + 1)
        }
    };
    let t = Instant::now();
    let codes = rays.par_iter().with_min_len(64).map(hit_code).collect::<Vec<u64>>();
    let time = t.elapsed();
    (time, codes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &c| (h ^ c).wrapping_mul(0x0100_0000_01b3)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// A strip 10^4 long and 1 high, far thinner than a pixel of the camera that frames it:
    /// no primary ray hits, so there are no shadow or diffuse rays, and their speeds are
    /// `None` (null in the JSON), not 0 Mrays/s.
    #[test]
    fn a_mesh_the_camera_misses_has_no_secondary_speeds() {
        let triangles: Vec<Triangle> = (0..200)
            .map(|k| {
                let p = Vec3::new(k as f32 * 50.0, (k % 7) as f32 / 7.0, 0.0);
                Triangle::new(p, p + Vec3::new(0.5, 0.0, 1e-4), p + Vec3::new(0.0, 0.01, 0.0))
            })
            .collect();
        let config =
            BenchConfig { builders: vec!["lbvh".parse().unwrap()], runs: 1, resolution: 16, ..Default::default() };
        let report = run(&triangles, &config).unwrap();
        assert_eq!((report.rays.shadow, report.rays.diffuse), (0, 0));
        let b = &report.builders[0];
        assert!(b.primary_mrays.is_some_and(|v| v > 0.0));
        assert_eq!((b.shadow_mrays, b.diffuse_mrays), (None, None));
    }
}
