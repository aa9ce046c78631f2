//! The builder comparison behind `bvh-bench`: every builder builds the same triangles, gets the
//! same leaf collapse, and traces the same primary, shadow and diffuse rays (Meister & Bittner
//! 2018, Table 1). Closest hits must be the same for every tree (traversal is exact), so each
//! ray set's checksum must agree between builders; a disagreement is reported.
//!
//! With the feature `embree`, Embree takes part as a peer ([`crate::embree`]): its own trees,
//! traced by its own traversal on the same rays, in the same rounds. Its hits are not expected
//! to be bit for bit Arbor's (see that module), so it is compared ray by ray with the reference
//! (the first of Arbor's builders listed) and the rays that hit differently are counted, not
//! treated as an error.

use std::fmt;
use std::str::FromStr;
use std::time::{Duration, Instant};

use rayon::prelude::*;
use serde::Serialize;

use arbor::bvh::build::prbvh::PrbvhConfig;
use arbor::bvh::build::{Builder, UnknownBuilder};
use arbor::bvh::{CollapseConfig, MeshBvh, TraceLayout, Tracing, build::lbvh, collapse_leaves, sah_cost, validate};
use arbor::geometry::{Aabb, Ray, Triangle};

use crate::median;

use crate::rays as bench_rays;

/// A builder in the comparison: one of Arbor's, whose tree Arbor's traversal traces, or (feature
/// `embree`) Embree at a build quality, with its own tree and traversal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BenchBuilder {
    Arbor(Builder),
    #[cfg(feature = "embree")]
    Embree(crate::embree::Quality),
}

/// A name `--builders` does not take.
#[derive(Debug, thiserror::Error)]
pub enum BuilderNameError {
    #[error(transparent)]
    Unknown(#[from] UnknownBuilder),
    #[error(
        "`{0}` is an Embree builder, and this bvh-bench was built without Embree: build it with `--features embree` (needs Embree 3: Debian package libembree-dev)"
    )]
    EmbreeNotBuilt(String),
    #[error("unknown Embree builder `{0}`; known: embree-low, embree-medium, embree-high")]
    UnknownEmbree(String),
}

/// The prefix of Embree's builder names.
pub const EMBREE_PREFIX: &str = "embree-";

impl FromStr for BenchBuilder {
    type Err = BuilderNameError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s.starts_with(EMBREE_PREFIX) {
            return embree_builder(s);
        }
        Ok(BenchBuilder::Arbor(s.parse()?))
    }
}

#[cfg(feature = "embree")]
fn embree_builder(name: &str) -> Result<BenchBuilder, BuilderNameError> {
    crate::embree::Quality::from_name(name)
        .map(BenchBuilder::Embree)
        .ok_or_else(|| BuilderNameError::UnknownEmbree(name.to_owned()))
}

#[cfg(not(feature = "embree"))]
fn embree_builder(name: &str) -> Result<BenchBuilder, BuilderNameError> {
    Err(BuilderNameError::EmbreeNotBuilt(name.to_owned()))
}

impl From<Builder> for BenchBuilder {
    fn from(b: Builder) -> Self {
        BenchBuilder::Arbor(b)
    }
}

impl fmt::Display for BenchBuilder {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BenchBuilder::Arbor(b) => b.fmt(f),
            #[cfg(feature = "embree")]
            BenchBuilder::Embree(q) => f.write_str(q.name()),
        }
    }
}

/// What to measure.
#[derive(Clone, Debug)]
pub struct BenchConfig {
    pub builders: Vec<BenchBuilder>,
    /// Builds per builder, and rounds of tracing (each round traces every builder once); the
    /// median times are reported. Default 3.
    pub runs: usize,
    /// Primary rays are `resolution²`. Default 512.
    pub resolution: u32,
    pub prbvh: PrbvhConfig,
    pub collapse: CollapseConfig,
    /// The form Arbor's trees are traced in. Default: the best this CPU has
    /// ([`Tracing::best`]); `bvh-bench` passes what `ARBOR_SIMD` says.
    pub tracing: Tracing,
    /// Also trace every ray set on this GPU, through both of the GPU's forms of each of Arbor's
    /// trees (`bvh-bench --gpu`). Default: none.
    pub gpu: Option<&'static arbor::gpu::GpuContext>,
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            builders: Vec::new(),
            runs: 3,
            resolution: 512,
            prbvh: PrbvhConfig::default(),
            collapse: CollapseConfig::default(),
            tracing: Tracing::best(),
            gpu: None,
        }
    }
}

/// One builder's results. Times in milliseconds, trace speeds in millions of rays per second.
/// Fields that only Arbor's trees have (optimisation, collapse, SAH, node counts) are `None`
/// (null in the JSON) for Embree, whose tree is opaque.
#[derive(Clone, Debug, Serialize)]
pub struct BuilderReport {
    pub name: String,
    /// Whose tree and traversal: `arbor`, or `embree` for the Embree peer.
    pub engine: &'static str,
    /// Median build time, without optimisation (Embree: `rtcCommitScene`).
    pub build_ms: f64,
    /// Median PRBVH time (0 without).
    pub optimize_ms: Option<f64>,
    /// Leaf collapse time.
    pub collapse_ms: Option<f64>,
    /// SAH (cT = 3, cI = 2) after leaf collapse.
    pub sah: Option<f64>,
    /// SAH with one primitive per leaf, before collapse.
    pub sah_leaf1: Option<f64>,
    pub nodes: Option<usize>,
    pub leaves: Option<usize>,
    pub depth: Option<usize>,
    /// Trace speeds in Mrays/s of the form `render` traces by default ([`Report::trace`]: the
    /// wide tree on the best SIMD path, for Arbor's builders); `None` (null in the JSON) for a
    /// set of no rays (or one traced in no measurable time): shadow and diffuse rays start where
    /// primary rays hit, and a camera that sees nothing of a thin mesh makes none.
    pub primary_mrays: Option<f64>,
    pub shadow_mrays: Option<f64>,
    pub diffuse_mrays: Option<f64>,
    /// The same rays through the binary tree the wide one is collapsed from (scalar code);
    /// `None` for Embree.
    pub binary_primary_mrays: Option<f64>,
    pub binary_shadow_mrays: Option<f64>,
    pub binary_diffuse_mrays: Option<f64>,
    /// Time to collapse the leaf-collapsed binary tree into the wide one and pack its triangles
    /// (part of every render's BVH time); `None` for Embree, or where the traced form is binary.
    pub wide_collapse_ms: Option<f64>,
    /// SAH (cT = 3, cI = 2 per triangle) of the wide tree traced.
    pub wide_sah: Option<f64>,
    /// With a GPU (`bvh-bench --gpu`; else `None`): the same ray sets traced on it, in Mrays/s
    /// of the device's time for the dispatch, through its compressed 8-wide tree
    /// (`arbor::gpu::wide`, made from this builder's leaf-collapsed tree) and through the
    /// binary tree itself.
    pub gpu_primary_mrays: Option<f64>,
    pub gpu_shadow_mrays: Option<f64>,
    pub gpu_diffuse_mrays: Option<f64>,
    pub gpu_binary_primary_mrays: Option<f64>,
    pub gpu_binary_shadow_mrays: Option<f64>,
    pub gpu_binary_diffuse_mrays: Option<f64>,
    /// Rays (of all three sets, in either form) whose GPU hit differs from the CPU's: the
    /// GPU's f32-only triangle test where the CPU's falls back to f64 (a ray through an edge
    /// or vertex, extreme scales).
    pub gpu_hit_mismatches: Option<usize>,
    /// Milliseconds to collapse this builder's tree into the GPU's wide form and encode it
    /// (on the CPU).
    pub gpu_wide_collapse_ms: Option<f64>,
    /// The GPU wide tree's own SAH (`arbor::bvh::wide_sah`: node 1, triangle 0.3).
    pub gpu_wide_sah: Option<f64>,
    /// PRBVH iterations: `[milliseconds since the build started, leaf-1 SAH]`, starting with
    /// the unoptimised tree; one point for builders without optimisation, none for Embree.
    pub sah_curve: Vec<[f64; 2]>,
    /// Checksums of the hits of each ray set: equal for every one of Arbor's builders.
    pub checksums: [u64; 3],
    /// Rays of each set (primary, shadow, diffuse) that hit something.
    pub hits: [usize; 3],
    /// Embree only: rays of each set whose hit (triangle, or hit against miss) differs from the
    /// reference builder's ([`Report::peer_reference`]); `None` for Arbor's builders.
    pub differing_rays: Option<[usize; 3]>,
}

impl BuilderReport {
    /// A row with its name, engine and build time, and nothing measured yet: the speeds are
    /// filled by the trace rounds, the rest by the builder's own measurement.
    fn new(name: String, engine: &'static str, build_ms: f64) -> Self {
        Self {
            name,
            engine,
            build_ms,
            optimize_ms: None,
            collapse_ms: None,
            sah: None,
            sah_leaf1: None,
            nodes: None,
            leaves: None,
            depth: None,
            primary_mrays: None,
            shadow_mrays: None,
            diffuse_mrays: None,
            binary_primary_mrays: None,
            binary_shadow_mrays: None,
            binary_diffuse_mrays: None,
            wide_collapse_ms: None,
            wide_sah: None,
            gpu_primary_mrays: None,
            gpu_shadow_mrays: None,
            gpu_diffuse_mrays: None,
            gpu_binary_primary_mrays: None,
            gpu_binary_shadow_mrays: None,
            gpu_binary_diffuse_mrays: None,
            gpu_hit_mismatches: None,
            gpu_wide_collapse_ms: None,
            gpu_wide_sah: None,
            sah_curve: Vec::new(),
            checksums: [0; 3],
            hits: [0; 3],
            differing_rays: None,
        }
    }
}

/// Everything `bvh-bench` reports.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub triangles: usize,
    pub threads: usize,
    /// The tree form Arbor's `*_mrays` are measured on: `binary`, `wide4` or `wide8`.
    pub trace: &'static str,
    /// The SIMD path that traces it: `scalar`, `sse4`, `avx2` or `neon` (`ARBOR_SIMD` forces one).
    pub simd: &'static str,
    pub rays: RayCounts,
    pub builders: Vec<BuilderReport>,
    /// Disagreements between the checksums of Arbor's builders; empty when all agree.
    pub mismatches: Vec<String>,
    /// What Embree's hits are compared with, ray by ray: the first of Arbor's builders listed,
    /// or `lbvh` (the tree the rays were made with) where none is; `None` without Embree.
    pub peer_reference: Option<String>,
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

/// The tree the ray sets are made with.
fn reference_lbvh(prim_aabbs: &[Aabb]) -> arbor::bvh::Bvh {
    lbvh::build(prim_aabbs)
}

fn ray_sets(triangles: &[Triangle], prim_aabbs: &[Aabb], resolution: u32) -> RaySets {
    let bvh = reference_lbvh(prim_aabbs);
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

/// Why the comparison could not run.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error(transparent)]
    InvalidTree(#[from] InvalidTree),
    #[cfg(feature = "embree")]
    #[error(transparent)]
    Embree(#[from] crate::embree::EmbreeError),
    #[error("on the GPU: {0}")]
    Gpu(#[from] arbor::gpu::GpuError),
}

/// A built tree, ready to trace.
enum Traced {
    /// The form traced by default, with the binary tree it comes from.
    Arbor(Box<MeshBvh>),
    #[cfg(feature = "embree")]
    Embree(crate::embree::Scene),
}

impl Traced {
    /// Traces `rays` once (closest hit, or any hit when `t_max` is finite: shadow rays); returns
    /// the time and each ray's hit code: the primitive's id + 1 for a closest hit (0 for none),
    /// 1 or 0 for a shadow ray.
    fn trace(&self, rays: &[Ray], t_max: f32) -> (Duration, Vec<u64>) {
        match self {
            Traced::Arbor(mesh) => trace_mesh(rays, t_max, |r| mesh.closest_hit(r, t_max), |r| mesh.any_hit(r, t_max)),
            #[cfg(feature = "embree")]
            Traced::Embree(scene) => trace_codes(rays, |r| {
                if t_max.is_finite() {
                    scene.any_hit(r, t_max) as u64
                } else {
                    scene.closest_hit(r, t_max).map_or(0, |(prim_id, _)| prim_id as u64 + 1)
                }
            }),
        }
    }

    /// [`Traced::trace`] through Arbor's binary tree, traced beside the wide one (`None` for
    /// Embree).
    fn trace_binary(&self, rays: &[Ray], t_max: f32) -> Option<(Duration, Vec<u64>)> {
        match self {
            Traced::Arbor(mesh) => {
                Some(trace_mesh(rays, t_max, |r| mesh.closest_hit_binary(r, t_max), |r| mesh.any_hit_binary(r, t_max)))
            }
            #[cfg(feature = "embree")]
            Traced::Embree(_) => None,
        }
    }
}

/// [`Traced::trace`] by a closest-hit and an any-hit query.
fn trace_mesh(
    rays: &[Ray],
    t_max: f32,
    closest: impl Fn(&Ray) -> Option<arbor::bvh::Hit> + Send + Sync,
    any: impl Fn(&Ray) -> bool + Send + Sync,
) -> (Duration, Vec<u64>) {
    let shadow = t_max.is_finite();
    trace_codes(rays, |r| if shadow { any(r) as u64 } else { closest(r).map_or(0, |h| h.prim_id as u64 + 1) })
}

/// Runs the comparison. Fails only on a tree that does not validate (a bug) or an Embree call
/// that fails; checksum disagreements are listed in the report.
pub fn run(triangles: &[Triangle], config: &BenchConfig) -> Result<Report, BenchError> {
    run_with_progress(triangles, config, |_| {})
}

/// [`run`], calling `progress` with a line saying what it starts next (a build, a round of
/// tracing): PRBVH on 10^7 triangles runs for minutes.
pub fn run_with_progress(
    triangles: &[Triangle],
    config: &BenchConfig,
    progress: impl Fn(&str),
) -> Result<Report, BenchError> {
    progress("tracing the reference rays");
    let prim_aabbs: Vec<Aabb> = triangles.par_iter().map(Triangle::aabb).collect();
    let rays = ray_sets(triangles, &prim_aabbs, config.resolution);
    let tracing = config.tracing;
    let mut report = Report {
        triangles: triangles.len(),
        threads: rayon::current_num_threads(),
        trace: tracing.layout.name(),
        simd: tracing.simd.name(),
        rays: RayCounts { primary: rays.primary.len(), shadow: rays.shadow.len(), diffuse: rays.diffuse.len() },
        builders: Vec::new(),
        mismatches: Vec::new(),
        peer_reference: None,
    };
    // Build everything first, then trace in rounds that visit every builder in turn: on a
    // shared, noisy machine a slow spell then hits all builders alike instead of one of them.
    let mut meshes = Vec::with_capacity(config.builders.len());
    #[cfg(feature = "embree")]
    let mut embree_device = None;
    for (k, builder) in config.builders.iter().enumerate() {
        progress(&format!(
            "building {builder} ({} of {} builders, {} runs)",
            k + 1,
            config.builders.len(),
            config.runs
        ));
        let (r, mesh) = match builder {
            BenchBuilder::Arbor(b) => measure(b, triangles, &prim_aabbs, config)?,
            #[cfg(feature = "embree")]
            BenchBuilder::Embree(quality) => {
                // One device for every Embree build, with the threads Arbor's builders get.
                let device = match &mut embree_device {
                    Some(d) => d,
                    None => embree_device.insert(crate::embree::Device::new(report.threads)?),
                };
                measure_embree(*quality, device, triangles, config)?
            }
        };
        report.builders.push(r);
        meshes.push(mesh);
    }
    let sets: [(&[Ray], f32); 3] =
        [(&rays.primary, f32::INFINITY), (&rays.shadow, 1.0), (&rays.diffuse, f32::INFINITY)];
    // Embree is compared ray by ray with the first of Arbor's builders.
    let reference = config.builders.iter().position(|b| matches!(b, BenchBuilder::Arbor(_)));
    let has_peers = report.builders.iter().any(|b| b.engine != "arbor");
    let mut first_codes: Vec<Option<[Vec<u64>; 3]>> = vec![None; meshes.len()];
    let mut times = vec![[const { Vec::new() }; 3]; meshes.len()];
    let mut binary_times = vec![[const { Vec::new() }; 3]; meshes.len()];
    for round in 0..config.runs.max(1) {
        progress(&format!("tracing, round {} of {}", round + 1, config.runs.max(1)));
        for (b, mesh) in meshes.iter().enumerate() {
            let r = &mut report.builders[b];
            // The hit codes are kept (round 0) only where Embree's are compared ray by ray, or
            // the GPU's with the CPU's.
            let keep = round == 0
                && ((has_peers && (r.engine != "arbor" || Some(b) == reference))
                    || (config.gpu.is_some() && r.engine == "arbor"));
            for (k, &(set, t_max)) in sets.iter().enumerate() {
                let (time, codes) = mesh.trace(set, t_max);
                times[b][k].push(time);
                if round == 0 {
                    r.checksums[k] = checksum(&codes);
                    r.hits[k] = codes.iter().filter(|&&c| c != 0).count();
                }
                if let Some((time, binary_codes)) = mesh.trace_binary(set, t_max) {
                    binary_times[b][k].push(time);
                    if round == 0 && binary_codes != codes {
                        let set = ["primary", "shadow", "diffuse"][k];
                        report
                            .mismatches
                            .push(format!("{set} rays: {}'s binary and wide trees hit differently", r.name));
                    }
                }
                if keep {
                    first_codes[b].get_or_insert_with(Default::default)[k] = codes;
                }
            }
        }
    }
    let mrays = |count: usize, times: &[Duration]| {
        let ms = median_ms(times.to_vec());
        (count > 0 && ms > 0.0 && !times.is_empty()).then(|| count as f64 / ms / 1e3)
    };
    let counts = [rays.primary.len(), rays.shadow.len(), rays.diffuse.len()];
    for ((r, times), binary) in report.builders.iter_mut().zip(times).zip(binary_times) {
        [r.primary_mrays, r.shadow_mrays, r.diffuse_mrays] = std::array::from_fn(|k| mrays(counts[k], &times[k]));
        [r.binary_primary_mrays, r.binary_shadow_mrays, r.binary_diffuse_mrays] =
            std::array::from_fn(|k| mrays(counts[k], &binary[k]));
    }
    if let Some(ctx) = config.gpu {
        progress("tracing on the GPU");
        for ((r, mesh), cpu) in report.builders.iter_mut().zip(&meshes).zip(&first_codes) {
            if let (Traced::Arbor(mesh), Some(cpu)) = (mesh, cpu) {
                trace_on_gpu(ctx, r, mesh, triangles, (&sets, cpu), config.runs.max(1))?;
            }
        }
    }
    if let Some(first) = reference {
        let first = &report.builders[first];
        for r in report.builders.iter().filter(|r| r.engine == "arbor") {
            for (k, set) in ["primary", "shadow", "diffuse"].iter().enumerate() {
                if r.checksums[k] != first.checksums[k] {
                    report
                        .mismatches
                        .push(format!("{set} rays: {} and {} hit different triangles", first.name, r.name));
                }
            }
        }
    }
    if has_peers {
        let (name, codes) = match reference {
            Some(b) => (report.builders[b].name.clone(), first_codes[b].take().expect("kept in round 0")),
            None => {
                // Only peers listed: compare them with the tree the rays were made with.
                let mesh = Traced::Arbor(Box::new(MeshBvh::new(reference_lbvh(&prim_aabbs), triangles, tracing)));
                ("lbvh".to_string(), sets.map(|(set, t_max)| mesh.trace(set, t_max).1))
            }
        };
        for (r, peer) in report.builders.iter_mut().zip(first_codes) {
            if let (Some(peer), "embree") = (peer, r.engine) {
                r.differing_rays = Some(std::array::from_fn(|k| differing(&codes[k], &peer[k])));
            }
        }
        report.peer_reference = Some(name);
    }
    Ok(report)
}

/// The three ray sets, each with its `t_max` (finite: any-hit queries).
type SetsWithLimits<'a> = [(&'a [Ray], f32); 3];

/// Traces the three ray sets (`sets`, with the CPU's hit codes `cpu`) on the GPU through both
/// of its forms of `mesh`'s tree, `runs` times each, and fills `r`'s GPU fields.
fn trace_on_gpu(
    ctx: &arbor::gpu::GpuContext,
    r: &mut BuilderReport,
    mesh: &MeshBvh,
    triangles: &[Triangle],
    (sets, cpu): (&SetsWithLimits<'_>, &[Vec<u64>; 3]),
    runs: usize,
) -> Result<(), BenchError> {
    use arbor::bvh::INVALID_INDEX;
    use arbor::gpu::trace::{GpuForm, GpuScene, QueryRay, trace_rays};
    let start = std::time::Instant::now();
    let prim_aabbs: Vec<Aabb> = triangles.par_iter().map(Triangle::aabb).collect();
    let wide = arbor::gpu::wide::CompressedBvh::new(&mesh.bvh, &prim_aabbs);
    r.gpu_wide_collapse_ms = Some(start.elapsed().as_secs_f64() * 1e3);
    r.gpu_wide_sah = Some(wide.cost);
    let mut wide = Some(wide);
    let mut mismatches = 0;
    for form in [GpuForm::Wide8, GpuForm::Binary] {
        // The wide tree just timed is the one traced, not made again.
        let scene = match (form, wide.take()) {
            (GpuForm::Wide8, Some(w)) => GpuScene::for_rays_compressed(ctx, w, triangles)?,
            _ => GpuScene::for_rays(ctx, &mesh.bvh, triangles, form)?,
        };
        let mut speeds = [None; 3];
        for (k, &(set, t_max)) in sets.iter().enumerate() {
            let queries: Vec<QueryRay> =
                set.iter().map(|&ray| QueryRay { ray, t_max: t_max.min(f32::MAX), skip: INVALID_INDEX }).collect();
            let any = t_max.is_finite();
            let mut times = Vec::with_capacity(runs);
            let mut codes = Vec::new();
            for _ in 0..runs {
                let (hits, seconds) = trace_rays(ctx, &scene, &queries, any)?;
                times.push(Duration::from_secs_f64(seconds));
                codes = hits
                    .iter()
                    .map(|h| match (any, h.prim) {
                        (_, INVALID_INDEX) => 0,
                        (true, _) => 1,
                        (false, p) => u64::from(p) + 1,
                    })
                    .collect();
            }
            mismatches += differing(&cpu[k], &codes);
            let ms = median_ms(times);
            speeds[k] = (!set.is_empty() && ms > 0.0).then(|| set.len() as f64 / ms / 1e3);
        }
        match form {
            GpuForm::Wide8 => [r.gpu_primary_mrays, r.gpu_shadow_mrays, r.gpu_diffuse_mrays] = speeds,
            GpuForm::Binary => {
                [r.gpu_binary_primary_mrays, r.gpu_binary_shadow_mrays, r.gpu_binary_diffuse_mrays] = speeds;
            }
        }
    }
    r.gpu_hit_mismatches = Some(mismatches);
    Ok(())
}

/// How many rays hit differently in two traces of the same rays.
fn differing(a: &[u64], b: &[u64]) -> usize {
    assert_eq!(a.len(), b.len(), "two traces of one ray set");
    a.iter().zip(b).filter(|(a, b)| a != b).count()
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
) -> Result<(BuilderReport, Traced), InvalidTree> {
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
    let traced = MeshBvh::new(collapsed, triangles, config.tracing);
    let wide = traced.tracing().layout != TraceLayout::Binary;
    let report = BuilderReport {
        optimize_ms: Some(median_ms(optimizations)),
        collapse_ms: Some(collapse_ms),
        sah: Some(sah),
        sah_leaf1: Some(sah_leaf1),
        nodes: Some(stats.node_count),
        leaves: Some(stats.leaf_count),
        depth: Some(stats.depth),
        wide_collapse_ms: wide.then(|| traced.collapse_seconds() * 1e3),
        wide_sah: wide.then(|| traced.traced_sah(&Default::default())),
        sah_curve,
        ..BuilderReport::new(builder.to_string(), "arbor", build_ms)
    };
    Ok((report, Traced::Arbor(Box::new(traced))))
}

/// Builds Embree's scene at `quality` `runs` times (the build time is `rtcCommitScene`'s) and
/// reports what applies to it; returns the last scene to trace.
#[cfg(feature = "embree")]
fn measure_embree(
    quality: crate::embree::Quality,
    device: &crate::embree::Device,
    triangles: &[Triangle],
    config: &BenchConfig,
) -> Result<(BuilderReport, Traced), crate::embree::EmbreeError> {
    let mut builds = Vec::new();
    let mut last = None;
    for _ in 0..config.runs.max(1) {
        // The previous scene is freed first, so that two are never in memory at once.
        drop(last.take());
        let (scene, time) = crate::embree::Scene::build(device, triangles, quality)?;
        builds.push(time);
        last = Some(scene);
    }
    let report = BuilderReport::new(quality.name().to_string(), "embree", median_ms(builds));
    Ok((report, Traced::Embree(last.expect("at least one run"))))
}

/// Traces `rays` once by `hit_code`, in parallel; returns the time and each ray's code.
fn trace_codes(rays: &[Ray], hit_code: impl Fn(&Ray) -> u64 + Send + Sync) -> (Duration, Vec<u64>) {
    let t = Instant::now();
    let codes = rays.par_iter().with_min_len(64).map(hit_code).collect::<Vec<u64>>();
    (t.elapsed(), codes)
}

/// A checksum (FNV-1a over the codes) of a trace's hit codes.
fn checksum(codes: &[u64]) -> u64 {
    codes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &c| (h ^ c).wrapping_mul(0x0100_0000_01b3))
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
