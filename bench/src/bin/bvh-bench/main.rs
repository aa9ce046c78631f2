//! `bvh-bench`: compares BVH builders on one mesh by build time, SAH and trace speed; with
//! `--animated` or `--procedural-animated`, compares ways of keeping a top-level BVH up to date
//! through an animation; with `--converge`, compares the image error each builder's renders
//! reach against wall time.
//!
//! Argument parsing and reporting only; the measuring is `arbor_bench::compare`,
//! `arbor_bench::anim` and `arbor_bench::converge`.

#[path = "../../../../src/bin/cli/mod.rs"]
mod cli;

mod animated;
mod compare;
mod converge;
mod gpu;
mod memory;
mod options;
mod plot;
mod report;

use crate::animated::run_animated;
use crate::converge::run_converge;
use crate::gpu::run_gpu;
use crate::memory::{memory_child, run_memory};
use crate::options::{check_options, parse_size};
use anyhow::Result;
use arbor::bvh::build::prbvh::PrbvhConfig;
use clap::Parser;
use std::path::PathBuf;

/// Compare BVH builders: build time, SAH cost (cT = 3, cI = 2) and trace speed of primary,
/// shadow and diffuse rays, all builders tracing the same rays.
#[derive(Parser, Debug, Clone)]
#[command(name = "bvh-bench", version)]
pub(crate) struct Args {
    /// Mesh (.obj; .ply, .gltf or .glb in any case) or scene (.toml) to build over. Optional with
    /// --procedural, except for `subdivided`.
    pub(crate) input: Option<PathBuf>,
    /// Make a mesh instead: hairball:N, city:N, or subdivided:N (the input mesh split until it
    /// has at least N triangles). N may use k/M suffixes (e.g. city:2M).
    #[arg(long, value_name = "KIND:N")]
    pub(crate) procedural: Option<String>,
    /// Builders to compare, comma-separated [default: lbvh,lbvh+prbvh,binned-sah,ploc,obvhs-medium;
    /// with --converge: lbvh,lbvh+prbvh,binned-sah,auto].
    #[arg(long, value_delimiter = ',')]
    pub(crate) builders: Option<Vec<String>>,
    /// Builds and traces per builder (with --converge: whole curves); medians are reported.
    #[arg(long, default_value_t = 3)]
    pub(crate) runs: usize,
    /// Primary rays: RESOLUTION x RESOLUTION.
    #[arg(long, default_value_t = 512)]
    pub(crate) resolution: u32,
    /// PRBVH's initial search sparsity μ.
    #[arg(long, default_value_t = PrbvhConfig::default().mu)]
    pub(crate) mu: u32,
    /// PRBVH's termination threshold ε on the SAH change.
    #[arg(long, default_value_t = PrbvhConfig::default().epsilon)]
    pub(crate) epsilon: f64,
    /// Seed of procedural meshes.
    #[arg(long, default_value_t = 1)]
    pub(crate) seed: u64,
    /// Worker threads for building and tracing (default: all cores), e.g. 1 and then 2 to
    /// measure how a builder scales.
    #[arg(long)]
    pub(crate) threads: Option<usize>,
    /// Write the report as JSON.
    #[arg(long, value_name = "OUT")]
    pub(crate) json: Option<PathBuf>,
    /// Write the table as CSV.
    #[arg(long, value_name = "OUT")]
    pub(crate) csv: Option<PathBuf>,
    /// Plot SAH against build + optimisation time, iteration by iteration (.svg or .png); with
    /// an animation, the SAH ratio to a fresh build against the frame.
    #[arg(long, value_name = "OUT")]
    pub(crate) plot: Option<PathBuf>,
    /// Animation benchmark on a scene's own animation (objects with keyframes or orbits move).
    #[arg(long, value_name = "SCENE.toml", conflicts_with_all = ["input", "procedural", "procedural_animated"])]
    pub(crate) animated: Option<PathBuf>,
    /// Animation benchmark on N procedural instances (spheres and tori on a field); k/M suffixes.
    #[arg(long, value_name = "N", conflicts_with_all = ["input", "procedural"])]
    pub(crate) procedural_animated: Option<String>,
    /// Frames of the animation benchmark [default: 300].
    #[arg(long)]
    pub(crate) frames: Option<u32>,
    /// Percentage of the procedural instances that move.
    #[arg(long, value_name = "PERCENT")]
    pub(crate) moving: Option<f64>,
    /// Time against error: render the scene at doubling spp with each builder (`auto` too) and
    /// measure the error against a reference, counting the BVH build in the time.
    #[arg(long, value_name = "SCENE.toml", conflicts_with_all = ["input", "procedural", "animated", "procedural_animated"])]
    pub(crate) converge: Option<PathBuf>,
    /// Devices to render on with --converge, comma-separated: cpu, gpu [default: cpu].
    #[arg(long, value_delimiter = ',')]
    pub(crate) devices: Option<Vec<String>>,
    /// --converge: the reference image (.exr, linear), e.g. an independent renderer's; without
    /// it, the scene is rendered at --reference-spp with another seed.
    #[arg(long, value_name = "REF.exr")]
    pub(crate) reference: Option<PathBuf>,
    /// --converge: samples per pixel of the rendered reference [default: 8 x --max-spp].
    #[arg(long)]
    pub(crate) reference_spp: Option<u32>,
    /// --converge: the largest sample count; curves run 1, 2, 4, ... up to it [default: 64].
    #[arg(long)]
    pub(crate) max_spp: Option<u32>,
    /// Peak memory instead of speed: each builder builds in a fresh process, and the table gives
    /// the bytes per triangle it keeps to trace (triangles included) and the process's peak.
    #[arg(long, conflicts_with_all = ["converge", "animated", "procedural_animated"])]
    pub(crate) memory: bool,
    /// The GPU: its LBVH (checked against the CPU's tree) and PRBVH with each lock scheme the
    /// adapter has, timed over --runs beside the CPU's, the collapse into its compressed 8-wide
    /// form, then the builder comparison with every ray set also traced on the GPU through both
    /// of its forms (gpu_* fields in each builder's row). With --animated: the scene's frames on
    /// the GPU, kept in two levels (the top level updated in place, or rebuilt) and flattened
    /// and rebuilt per frame, each in both forms: per-frame update time, render speed, bytes.
    #[arg(long, conflicts_with_all = ["converge", "procedural_animated", "memory"])]
    pub(crate) gpu: bool,
    /// (internal) The process --memory runs for one builder.
    #[arg(long, hide = true)]
    pub(crate) memory_child: Option<String>,
    /// --converge: render at WIDTHxHEIGHT instead of the scene's resolution.
    #[arg(long, value_name = "WxH", value_parser = parse_size)]
    pub(crate) image_size: Option<(u32, u32)>,
}

pub(crate) fn default_builders() -> Vec<String> {
    ["lbvh", "lbvh+prbvh", "binned-sah", "ploc", "obvhs-medium"].map(String::from).to_vec()
}

fn main() {
    // SAFETY: first thing in `main`, before any other thread exists.
    unsafe { arbor::gpu::quiet_device_select_layer() };
    if let Err(e) = run() {
        eprintln!("bvh-bench: error: {e:#}");
        std::process::exit(1);
    }
    if let Some(e) = cli::stdout_error() {
        eprintln!("bvh-bench: error: writing to standard output: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<()> {
    let args = Args::parse();
    arbor_bench::peers::register();
    cli::init_threads(args.threads)?;
    // The one place the trace form is chosen: a bad ARBOR_SIMD fails here, before any tree is
    // built, and every mode is given the result.
    let tracing = arbor::bvh::Tracing::from_env(None)?;
    if let Some(builder) = &args.memory_child {
        return memory_child(&args, builder, tracing);
    }
    check_options(&args)?;
    if args.converge.is_some() {
        return run_converge(&args, tracing);
    }
    if args.memory {
        return run_memory(&args);
    }
    if args.gpu && args.animated.is_some() {
        return animated::run_animated_gpu(&args);
    }
    if args.gpu {
        return run_gpu(&args, tracing);
    }
    if args.animated.is_some() || args.procedural_animated.is_some() {
        return run_animated(&args, tracing);
    }
    compare::run(&args, tracing)
}
