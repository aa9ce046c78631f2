//! `bvh-bench`: compares BVH builders on one mesh by build time, SAH and trace speed; with
//! `--animated` or `--procedural-animated`, compares ways of keeping a top-level BVH up to date
//! through an animation; with `--converge`, compares the image error each builder's renders
//! reach against wall time.
//!
//! Argument parsing and reporting only; the measuring is `arbor_bench::compare`,
//! `arbor_bench::anim` and `arbor_bench::converge`.

#[path = "../../src/bin/cli/mod.rs"]
mod cli;

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use arbor::atomic_file::{self, AtomicWriteError};
use arbor::bvh::builders::Builder;
use arbor::bvh::prbvh::PrbvhConfig;
use arbor::geometry::{TriangleMesh, procedural};
use arbor::scene::RenderSettings;
use arbor_bench::anim::{self as anim_bench, AnimBenchConfig, AnimatedInstances};
use arbor_bench::compare::{self as bench, BenchConfig, Report};
use clap::Parser;
use cli::outln;
use indicatif::ProgressBar;

/// Compare BVH builders: build time, SAH cost (cT = 3, cI = 2) and trace speed of primary,
/// shadow and diffuse rays, all builders tracing the same rays.
#[derive(Parser, Debug)]
#[command(name = "bvh-bench", version)]
struct Args {
    /// Mesh (.obj) or scene (.toml) to build over. Optional with --procedural, except for
    /// `subdivided`.
    input: Option<PathBuf>,
    /// Make a mesh instead: hairball:N, city:N, or subdivided:N (the input mesh split until it
    /// has at least N triangles). N may use k/M suffixes (e.g. city:2M).
    #[arg(long, value_name = "KIND:N")]
    procedural: Option<String>,
    /// Builders to compare, comma-separated [default: lbvh,lbvh+prbvh,binned-sah,ploc,obvhs-medium;
    /// with --converge: lbvh,lbvh+prbvh,binned-sah,auto].
    #[arg(long, value_delimiter = ',')]
    builders: Option<Vec<String>>,
    /// Builds and traces per builder (with --converge: whole curves); medians are reported.
    #[arg(long, default_value_t = 3)]
    runs: usize,
    /// Primary rays: RESOLUTION x RESOLUTION.
    #[arg(long, default_value_t = 512)]
    resolution: u32,
    /// PRBVH's initial search sparsity μ.
    #[arg(long, default_value_t = PrbvhConfig::default().mu)]
    mu: u32,
    /// PRBVH's termination threshold ε on the SAH change.
    #[arg(long, default_value_t = PrbvhConfig::default().epsilon)]
    epsilon: f64,
    /// Seed of procedural meshes.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Worker threads for building and tracing (default: all cores), e.g. 1 and then 2 to
    /// measure how a builder scales.
    #[arg(long)]
    threads: Option<usize>,
    /// Write the report as JSON.
    #[arg(long, value_name = "OUT")]
    json: Option<PathBuf>,
    /// Write the table as CSV.
    #[arg(long, value_name = "OUT")]
    csv: Option<PathBuf>,
    /// Plot SAH against build + optimisation time, iteration by iteration (.svg or .png); with
    /// an animation, the SAH ratio to a fresh build against the frame.
    #[arg(long, value_name = "OUT")]
    plot: Option<PathBuf>,
    /// Animation benchmark on a scene's own animation (objects with keyframes or orbits move).
    #[arg(long, value_name = "SCENE.toml", conflicts_with_all = ["input", "procedural", "procedural_animated"])]
    animated: Option<PathBuf>,
    /// Animation benchmark on N procedural instances (spheres and tori on a field); k/M suffixes.
    #[arg(long, value_name = "N", conflicts_with_all = ["input", "procedural"])]
    procedural_animated: Option<String>,
    /// Frames of the animation benchmark [default: 300].
    #[arg(long)]
    frames: Option<u32>,
    /// Percentage of the procedural instances that move.
    #[arg(long, value_name = "PERCENT")]
    moving: Option<f64>,
    /// Time against error: render the scene at doubling spp with each builder (`auto` too) and
    /// measure the error against a reference, counting the BVH build in the time.
    #[arg(long, value_name = "SCENE.toml", conflicts_with_all = ["input", "procedural", "animated", "procedural_animated"])]
    converge: Option<PathBuf>,
    /// Devices to render on with --converge, comma-separated: cpu, gpu [default: cpu].
    #[arg(long, value_delimiter = ',')]
    devices: Option<Vec<String>>,
    /// --converge: the reference image (.exr, linear), e.g. an independent renderer's; without
    /// it, the scene is rendered at --reference-spp with another seed.
    #[arg(long, value_name = "REF.exr")]
    reference: Option<PathBuf>,
    /// --converge: samples per pixel of the rendered reference [default: 8 x --max-spp].
    #[arg(long)]
    reference_spp: Option<u32>,
    /// --converge: the largest sample count; curves run 1, 2, 4, ... up to it [default: 64].
    #[arg(long)]
    max_spp: Option<u32>,
    /// Peak memory instead of speed: each builder builds in a fresh process, and the table gives
    /// the bytes per triangle it keeps to trace (triangles included) and the process's peak.
    #[arg(long, conflicts_with_all = ["converge", "animated", "procedural_animated"])]
    memory: bool,
    /// GPU builds instead of the CPU builders: the GPU LBVH (checked against the CPU's tree) and
    /// GPU PRBVH with each lock scheme the adapter has, timed over --runs, beside the CPU
    /// optimiser on the same input.
    #[arg(long, conflicts_with_all = ["converge", "animated", "procedural_animated", "memory"])]
    gpu: bool,
    /// (internal) The process --memory runs for one builder.
    #[arg(long, hide = true)]
    memory_child: Option<String>,
    /// --converge: render at WIDTHxHEIGHT instead of the scene's resolution.
    #[arg(long, value_name = "WxH", value_parser = parse_size)]
    image_size: Option<(u32, u32)>,
}

fn default_builders() -> Vec<String> {
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
    if let Some(builder) = &args.memory_child {
        return memory_child(&args, builder);
    }
    check_options(&args)?;
    if args.converge.is_some() {
        return run_converge(&args);
    }
    if args.memory {
        return run_memory(&args);
    }
    if args.gpu {
        return run_gpu(&args);
    }
    if args.animated.is_some() || args.procedural_animated.is_some() {
        return run_animated(&args);
    }
    let builders = args
        .builders
        .clone()
        .unwrap_or_else(default_builders)
        .iter()
        .map(|b| b.trim().parse::<Builder>())
        .collect::<Result<Vec<_>, _>>()
        .context("--builders")?;
    let (name, mesh) = load_input(&args)?;
    let triangles = mesh.triangles();
    eprintln!("{name}: {} triangles, {} threads", triangles.len(), rayon::current_num_threads());
    let config = BenchConfig {
        builders,
        runs: args.runs,
        resolution: args.resolution,
        prbvh: PrbvhConfig { mu: args.mu, epsilon: args.epsilon, ..Default::default() },
        ..Default::default()
    };
    // On a terminal, a spinner says what runs: large meshes take minutes.
    let spinner = if std::io::stderr().is_terminal() { ProgressBar::new_spinner() } else { ProgressBar::hidden() };
    spinner.enable_steady_tick(std::time::Duration::from_millis(200));
    let report = bench::run_with_progress(&triangles, &config, |what| spinner.set_message(what.to_owned()));
    spinner.finish_and_clear();
    let report = report.map_err(anyhow::Error::msg)?;
    print_table(&report);
    let series: Vec<Series> =
        report.builders.iter().map(|b| (b.name.clone(), b.sah_curve.iter().map(|p| (p[0], p[1])).collect())).collect();
    let plot = (format!("SAH against time: {name}"), ("build + optimisation time (ms)", "SAH, one primitive per leaf"));
    write_outputs(&args, &report, |f| write_csv(f, &report), plot, &series, false)?;
    if !report.mismatches.is_empty() {
        bail!("builders disagree on hits:\n  {}", report.mismatches.join("\n  "));
    }
    Ok(())
}

/// Most runs a benchmark may repeat, and the largest --resolution: beyond them a mistyped number
/// would run for days or ask for more memory than any machine has.
const MAX_RUNS: usize = 10_000;
const MAX_RESOLUTION: u32 = 8192;

/// Checks of the options all modes share, before any work: numbers in range, builders listed
/// once, and the output files writable (`atomic_file::prepare`).
fn check_options(args: &Args) -> Result<()> {
    if !(1..=MAX_RUNS).contains(&args.runs) {
        bail!("--runs must be from 1 to {MAX_RUNS}, not {}", args.runs);
    }
    if !(1..=MAX_RESOLUTION).contains(&args.resolution) {
        bail!("--resolution must be from 1 to {MAX_RESOLUTION}, not {}", args.resolution);
    }
    if args.mu == 0 {
        bail!("--mu must be at least 1");
    }
    if !(args.epsilon.is_finite() && args.epsilon >= 0.0) {
        bail!("--epsilon must be a finite number >= 0, not {}", args.epsilon);
    }
    if let Some(names) = &args.builders {
        // By the name each builds as: `prbvh` is `lbvh+prbvh`.
        let mut seen = std::collections::HashMap::new();
        for name in names.iter().map(|n| n.trim()) {
            let canonical = name.parse::<Builder>().map_or(name.to_string(), |b| b.to_string());
            if let Some(first) = seen.insert(canonical.clone(), name) {
                if first == name {
                    bail!("--builders: `{name}` is listed twice");
                }
                bail!("--builders: `{first}` and `{name}` are the same builder, `{canonical}`");
            }
        }
    }
    if let Some(devices) = &args.devices {
        let mut seen = std::collections::HashSet::new();
        if let Some(twice) = devices.iter().map(|d| d.trim()).find(|d| !seen.insert(*d)) {
            bail!("--devices: `{twice}` is listed twice");
        }
    }
    check_mode_options(args)?;
    if let Some(plot) = &args.plot {
        plot_format(plot)?;
    }
    let outputs = [("--json", &args.json), ("--csv", &args.csv), ("--plot", &args.plot)];
    let inputs = [
        ("the input", &args.input),
        ("--converge", &args.converge),
        ("--animated", &args.animated),
        ("--reference", &args.reference),
    ];
    for (k, &(flag, out)) in outputs.iter().enumerate() {
        let Some(out) = out else { continue };
        for &(name, input) in &inputs {
            if input.as_deref().is_some_and(|i| atomic_file::replaces(out, i)) {
                bail!("{flag} {}: that is the file of {name}, which the report would replace", out.display());
            }
        }
        for &(other_flag, other) in &outputs[k + 1..] {
            if other.as_deref().is_some_and(|o| atomic_file::replaces(out, o)) {
                bail!("{flag} and {other_flag} name the same file, {}: one would replace the other", out.display());
            }
        }
        atomic_file::prepare(out).with_context(|| format!("cannot write {}", out.display()))?;
    }
    Ok(())
}

/// Options that belong to another mode than the one run are errors, not silently ignored.
fn check_mode_options(args: &Args) -> Result<()> {
    let converge = args.converge.is_some();
    let animation = args.animated.is_some() || args.procedural_animated.is_some();
    let mode_only: [(bool, &str, bool, &str); 8] = [
        (args.devices.is_some(), "--devices", converge, "--converge"),
        (args.reference.is_some(), "--reference", converge, "--converge"),
        (args.reference_spp.is_some(), "--reference-spp", converge, "--converge"),
        (args.max_spp.is_some(), "--max-spp", converge, "--converge"),
        (args.image_size.is_some(), "--image-size", converge, "--converge"),
        (args.frames.is_some(), "--frames", animation, "--animated and --procedural-animated"),
        (args.moving.is_some(), "--moving", args.procedural_animated.is_some(), "--procedural-animated"),
        (
            args.builders.is_some(),
            "--builders",
            !args.gpu && !animation,
            "the builder comparison, --converge and --memory",
        ),
    ];
    for (given, option, applies, mode) in mode_only {
        if given && !applies {
            bail!("{option} applies to {mode}");
        }
    }
    if args.memory && args.plot.is_some() {
        bail!("--memory has no plot");
    }
    if args.gpu && (args.plot.is_some() || args.csv.is_some()) {
        bail!("--gpu writes a table and --json only (no --csv or --plot)");
    }
    if let Some(path) = &args.converge {
        if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("obj")) {
            bail!("--converge {}: renders a scene (.toml), not a mesh", path.display());
        }
    }
    Ok(())
}

/// Writes the report as JSON, the table as CSV and the plot, for each option given.
fn write_outputs(
    args: &Args,
    report: &impl serde::Serialize,
    csv: impl FnOnce(&mut dyn Write) -> Result<()>,
    (title, labels): (String, (&str, &str)),
    series: &[Series],
    log: bool,
) -> Result<()> {
    if let Some(path) = &args.json {
        write_atomic(path, |f| write_json(f, report))?;
    }
    if let Some(path) = &args.csv {
        write_atomic(path, csv)?;
    }
    if let Some(path) = &args.plot {
        write_plot(path, &title, labels, series, log)?;
    }
    Ok(())
}

/// `--animated` / `--procedural-animated`.
fn run_animated(args: &Args) -> Result<()> {
    let frames = args.frames.unwrap_or(300);
    if frames == 0 {
        bail!("--frames must be at least 1");
    }
    let (name, anim) = match (&args.animated, &args.procedural_animated) {
        (Some(path), _) => {
            let scene = arbor::scene::Scene::load(path)?;
            if !scene.is_animated() {
                bail!("{}: nothing in the scene moves (no keyframes or orbiting scatter)", path.display());
            }
            (path.display().to_string(), AnimatedInstances::from_scene(&scene))
        }
        (None, Some(n)) => {
            let spec = n;
            let n = parse_count(n).with_context(|| format!("--procedural-animated: bad instance count `{n}`"))?;
            // About 1.6 kB per instance at the peak (200k instances, 2 frames).
            arbor::memory::check_fits(&format!("--procedural-animated {spec}"), n as f64 * 2000.0)?;
            let moving = args.moving.unwrap_or(10.0);
            if !(0.0..=100.0).contains(&moving) {
                bail!("--moving must be a percentage from 0 to 100, not {moving}");
            }
            (format!("{n} instances, {moving}% moving"), AnimatedInstances::procedural(n, moving / 100.0, args.seed))
        }
        (None, None) => unreachable!("checked by the caller"),
    };
    eprintln!(
        "{name}: {} instances ({} moving), {} triangles, {} frames, {} threads",
        anim.instances.len(),
        anim.moving.len(),
        anim.world_triangle_count(),
        frames,
        rayon::current_num_threads()
    );
    let config = AnimBenchConfig { frames, resolution: args.resolution.min(256), ..Default::default() };
    let report = anim_bench::run(&anim, &config);
    outln!(
        "{} instances, {} moving, {} triangles, {} frames, {} threads",
        report.instances,
        report.moving,
        report.triangles,
        report.frames,
        report.threads
    );
    outln!(
        "{:<16} {:>10} {:>10} {:>10} {:>10} {:>10} {:>9} {:>9} {:>9}",
        "strategy",
        "update ms",
        "mean ms",
        "max ms",
        "SAH final",
        "SAH max",
        "rebuilds",
        "primary",
        "diffuse"
    );
    for s in &report.strategies {
        let v = strategy_values(s);
        outln!(
            "{:<16} {:>10.3} {:>10.3} {:>10.3} {:>10.3} {:>10.3} {:>9} {:>9.2} {:>9.2}",
            s.name,
            v[0],
            v[1],
            v[2],
            v[3],
            v[4],
            v[5],
            v[6],
            v[7]
        );
    }
    outln!(
        "(update: median per frame; SAH as a ratio to a fresh binned-SAH build; trace speeds in Mrays/s at the last frame)"
    );
    if report.single_level_differences > 0 {
        outln!(
            "({} rays hit another triangle through the single-level tree's world-space copies: rounding at shared edges)",
            report.single_level_differences
        );
    }
    let series: Vec<Series> = report
        .strategies
        .iter()
        .map(|s| (s.name.clone(), s.sah_ratio_curve.iter().map(|p| (p[0], p[1])).collect()))
        .collect();
    let plot = (format!("SAH ratio over the animation: {name}"), ("frame", "SAH / fresh build's SAH"));
    write_outputs(
        args,
        &report,
        |f| {
            writeln!(f, "name,{}", STRATEGY_COLUMNS.join(","))?;
            for s in &report.strategies {
                let v = strategy_values(s).map(|x| x.to_string());
                writeln!(f, "{},{}", s.name, v.join(","))?;
            }
            Ok(())
        },
        plot,
        &series,
        false,
    )?;
    if !report.mismatches.is_empty() {
        bail!("strategies disagree on hits:\n  {}", report.mismatches.join("\n  "));
    }
    Ok(())
}

/// The numeric columns of a strategy, in the table's and the CSV's order.
const STRATEGY_COLUMNS: [&str; 8] = [
    "update_ms",
    "update_ms_mean",
    "update_ms_max",
    "sah_ratio_final",
    "sah_ratio_max",
    "rebuilds",
    "primary_mrays_final",
    "diffuse_mrays_final",
];

fn strategy_values(s: &anim_bench::StrategyReport) -> [f64; 8] {
    [
        s.update_ms,
        s.update_ms_mean,
        s.update_ms_max,
        s.sah_ratio_final,
        s.sah_ratio_max,
        s.rebuilds as f64,
        s.primary_mrays_final,
        s.diffuse_mrays_final,
    ]
}

/// `--converge`.
fn run_converge(args: &Args) -> Result<()> {
    use arbor::device::{BuilderChoice, Device, DeviceChoice};
    use arbor_bench::converge::{self, ConvergeConfig};
    let path = args.converge.as_ref().expect("checked by the caller");
    let mut devices = Vec::new();
    for d in args.devices.as_deref().unwrap_or(&["cpu".to_string()]) {
        devices.push(match d.trim() {
            "cpu" => Device::Cpu,
            "gpu" => DeviceChoice::Gpu.select().context("--devices gpu")?.0,
            other => bail!("--devices: unknown device `{other}`; known: cpu, gpu"),
        });
    }
    let names = args
        .builders
        .clone()
        .unwrap_or_else(|| ["lbvh", "lbvh+prbvh", "binned-sah", "auto"].map(String::from).to_vec());
    let choices =
        names.iter().map(|b| b.trim().parse::<BuilderChoice>()).collect::<Result<Vec<_>, _>>().context("--builders")?;
    let max_spp = args.max_spp.unwrap_or(64);
    if max_spp == 0 {
        bail!("--max-spp must be at least 1");
    }
    let mut scene = arbor::scene::Scene::load(path)?;
    if let Some((w, h)) = args.image_size {
        (scene.camera.width, scene.camera.height) = (w, h);
    }
    let render = RenderSettings { spp: max_spp, time: None, clamp: None, ..scene.render };
    let config = ConvergeConfig { render, ..Default::default() };
    let (w, h) = (scene.camera.width, scene.camera.height);
    let (reference, reference_info) = match &args.reference {
        Some(file) => {
            let image = arbor::image_io::read_exr(file)?;
            if (image.width, image.height) != (w, h) {
                bail!(
                    "--reference {}: {}x{} pixels, but the render is {w}x{h} (see --image-size)",
                    file.display(),
                    image.width,
                    image.height
                );
            }
            (image, serde_json::json!({"source": "file", "path": file.display().to_string()}))
        }
        None => {
            let spp = args.reference_spp.unwrap_or(max_spp.saturating_mul(8));
            if spp == 0 {
                bail!("--reference-spp must be at least 1");
            }
            let seed = config.render.seed ^ 0x5eed_0f5e;
            eprintln!("rendering the reference: {w}x{h}, {spp} spp ...");
            let (image, secs) = converge::render_reference(&scene, spp, config.render.max_depth, seed)?;
            eprintln!("  {secs:.1} s");
            (image, serde_json::json!({"source": "rendered", "spp": spp, "seed": seed, "time_s": secs}))
        }
    };
    eprintln!(
        "{}: {w}x{h}, max depth {}, {} threads",
        path.display(),
        config.render.max_depth,
        rayon::current_num_threads()
    );
    // Runs interleave the builders, so that a slow spell of a shared machine falls on all.
    let mut runs = Vec::new();
    for run in 0..args.runs {
        let mut curves = Vec::new();
        for &device in &devices {
            for choice in &choices {
                let curve = converge::measure_curve(&scene, choice, device, &reference, &config, &mut |p| {
                    eprintln!(
                        "  run {}: {choice} on {} {} spp: {:.3} s, rel MSE {:.4e}",
                        run + 1,
                        device.name(),
                        p.spp,
                        p.time_s,
                        p.rel_mse
                    );
                })?;
                curves.push(curve);
            }
        }
        runs.push(curves);
    }
    let curves = converge::median_of_runs(runs);
    outln!(
        "{:<14} {:>6} {:>6} {:>10} {:>10} {:>12} {:>10}",
        "builder",
        "device",
        "spp",
        "time s",
        "build s",
        "rel MSE",
        "MAE"
    );
    for c in &curves {
        for p in &c.points {
            outln!(
                "{:<14} {:>6} {:>6} {:>10.3} {:>10.3} {:>12.4e} {:>10.4e}",
                c.builder,
                c.device,
                p.spp,
                p.time_s,
                p.build_s,
                p.rel_mse,
                p.mae
            );
        }
    }
    if args.runs > 1 {
        outln!("(times: the median of {} runs)", args.runs);
    }
    let auto = converge::compare_auto(&curves);
    for a in &auto {
        outln!(
            "{}: auto against the best fixed builder at equal time ({:.3} to {:.3} s): worst rel MSE ratio {:.3} at {:.3} s ({} best there), worst MAE ratio {:.3}",
            a.device,
            a.compared_from_s,
            a.compared_to_s,
            a.worst_ratio_rel_mse,
            a.worst_at_time_s,
            a.best_fixed_there,
            a.worst_ratio_mae
        );
    }
    let not_compared = converge::auto_not_compared(&curves);
    for (device, why) in &not_compared {
        outln!("{device}: auto not compared with the fixed builders: {why}");
    }
    let non_finite: u64 = curves.iter().flat_map(|c| &c.points).map(|p| p.non_finite).sum();
    let report = serde_json::json!({
        "scene": path.display().to_string(),
        "width": w,
        "height": h,
        "max_depth": config.render.max_depth,
        "threads": rayon::current_num_threads(),
        "reference": reference_info,
        "curves": curves,
        "auto": auto,
        "auto_not_compared": not_compared
            .iter()
            .map(|(device, why)| serde_json::json!({"device": device, "reason": why}))
            .collect::<Vec<_>>(),
    });
    let series: Vec<Series> = curves
        .iter()
        .map(|c| (format!("{} ({})", c.builder, c.device), c.points.iter().map(|p| (p.time_s, p.rel_mse)).collect()))
        .collect();
    let name = path.file_name().map_or(path.display().to_string(), |n| n.to_string_lossy().into_owned());
    let plot = (format!("Error against time: {name}"), ("wall time incl. BVH build (s)", "relative MSE"));
    let csv = |f: &mut dyn Write| -> Result<()> {
        writeln!(f, "builder,device,spp,time_s,build_s,rel_mse,mae,non_finite")?;
        for c in &curves {
            for p in &c.points {
                writeln!(
                    f,
                    "{},{},{},{},{},{},{},{}",
                    c.builder, c.device, p.spp, p.time_s, p.build_s, p.rel_mse, p.mae, p.non_finite
                )?;
            }
        }
        Ok(())
    };
    write_outputs(args, &report, csv, plot, &series, true)?;
    if non_finite > 0 {
        bail!("{non_finite} NaN or infinite samples were dropped: a bug");
    }
    Ok(())
}

/// What one builder's process reports to `--memory`.
#[derive(serde::Serialize, serde::Deserialize)]
struct MemoryReport {
    name: String,
    triangles: usize,
    build_ms: f64,
    /// Bytes the built structure keeps to trace: nodes, indices and its copy of the triangles.
    kept_bytes: u64,
    /// The process's peak resident memory: the mesh, its triangles and the build.
    peak_bytes: u64,
    kept_bytes_per_triangle: f64,
    peak_bytes_per_triangle: f64,
}

/// `--gpu`: GPU LBVH and PRBVH times, beside the CPU's on the same input.
fn run_gpu(args: &Args) -> Result<()> {
    use arbor::bvh::prbvh::{self, PrbvhConfig};
    use arbor::gpu::prbvh::{self as gpu_prbvh, LockScheme};
    use std::time::Instant;
    let ctx = arbor::gpu::GpuContext::shared()?;
    let (name, mesh) = load_input(args)?;
    let prims: Vec<arbor::geometry::Aabb> = mesh.triangles().iter().map(arbor::geometry::Triangle::aabb).collect();
    if prims.len() < 2 {
        bail!("{name}: --gpu needs at least 2 triangles");
    }
    eprintln!("{name}: {} triangles on {}", prims.len(), ctx.describe());
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let config = PrbvhConfig { mu: args.mu, epsilon: args.epsilon, collapse: None, ..Default::default() };
    let mut rows = Vec::new();
    let (mut cpu_ms, mut gpu_ms, mut upload_ms) = (Vec::new(), Vec::new(), Vec::new());
    let mut cpu_tree = None;
    let mut gpu_tree = None;
    // A first, untimed build compiles the pipelines (seconds on lavapipe).
    arbor::gpu::lbvh::build(ctx, &prims)?;
    for _ in 0..args.runs {
        let t = Instant::now();
        // Karras' algorithm as published, which the GPU builds (the CPU's default also refines
        // runs of equal codes).
        cpu_tree = Some(arbor::bvh::lbvh::build_karras(&prims));
        cpu_ms.push(t.elapsed().as_secs_f64() * 1e3);
        let (tree, times) = arbor::gpu::lbvh::build(ctx, &prims)?;
        gpu_ms.push(times.build.as_secs_f64() * 1e3);
        upload_ms.push(times.upload.as_secs_f64() * 1e3);
        gpu_tree = Some(tree);
    }
    let (cpu_tree, gpu_tree) = (cpu_tree.expect("runs >= 1"), gpu_tree.expect("runs >= 1"));
    let same = cpu_tree.nodes[..] == gpu_tree.nodes[..] && cpu_tree.prim_ids == gpu_tree.prim_ids;
    rows.push(serde_json::json!({"stage": "lbvh", "device": "cpu", "ms": median(cpu_ms), "sah": arbor::bvh::sah_cost(&cpu_tree)}));
    rows.push(serde_json::json!({"stage": "lbvh", "device": "gpu", "ms": median(gpu_ms), "upload_ms": median(upload_ms), "sah": arbor::bvh::sah_cost(&gpu_tree), "same_tree_as_cpu": same}));
    let mut times = Vec::new();
    let mut sah = 0.0;
    for _ in 0..args.runs {
        let mut tree = cpu_tree.clone();
        let stats = prbvh::optimize(&mut tree, &config);
        times.push(stats.optimize_time.as_secs_f64() * 1e3);
        sah = stats.sah_before_collapse;
    }
    rows.push(serde_json::json!({"stage": "prbvh", "device": "cpu", "ms": median(times), "sah": sah}));
    let mut schemes = vec![LockScheme::Portable32];
    if LockScheme::best_for(ctx) == LockScheme::Atomic64 {
        schemes.push(LockScheme::Atomic64);
    }
    for scheme in schemes {
        let mut times = Vec::new();
        let mut iterations = 0;
        let warm = PrbvhConfig { max_iterations: 1, ..config };
        gpu_prbvh::optimize(ctx, &cpu_tree, &warm, scheme)?;
        for _ in 0..args.runs {
            let (_, stats) = gpu_prbvh::optimize(ctx, &cpu_tree, &config, scheme)?;
            times.push(stats.optimize_time.as_secs_f64() * 1e3);
            sah = stats.sah_before_collapse;
            iterations = stats.iterations.len();
        }
        let lock = if scheme == LockScheme::Atomic64 { "64-bit" } else { "32-bit" };
        rows.push(serde_json::json!({"stage": "prbvh", "device": "gpu", "locks": lock, "ms": median(times), "sah": sah, "iterations": iterations}));
    }
    outln!(
        "{} triangles; {}; medians of {} runs (GPU times exclude pipeline compilation, upload and readback)",
        prims.len(),
        ctx.describe(),
        args.runs
    );
    outln!("{:<8} {:<6} {:<8} {:>12} {:>10}", "stage", "device", "locks", "ms", "SAH");
    for r in &rows {
        outln!(
            "{:<8} {:<6} {:<8} {:>12.2} {:>10.2}",
            r["stage"].as_str().unwrap_or(""),
            r["device"].as_str().unwrap_or(""),
            r["locks"].as_str().unwrap_or("-"),
            r["ms"].as_f64().unwrap_or(0.0),
            r["sah"].as_f64().unwrap_or(0.0)
        );
    }
    if !same {
        bail!("the GPU LBVH differs from the CPU LBVH on {name}");
    }
    let report =
        serde_json::json!({"triangles": prims.len(), "adapter": ctx.describe(), "runs": args.runs, "rows": rows});
    if let Some(path) = &args.json {
        write_atomic(path, |f| write_json(f, &report))?;
    }
    Ok(())
}

/// `--memory`: each builder in a fresh process, so that no peak hides another.
fn run_memory(args: &Args) -> Result<()> {
    let names = args.builders.clone().unwrap_or_else(default_builders);
    for n in &names {
        n.trim().parse::<Builder>().context("--builders")?;
    }
    let exe = std::env::current_exe().context("finding bvh-bench's own executable")?;
    let mut reports = Vec::new();
    for name in &names {
        let mut cmd = std::process::Command::new(&exe);
        cmd.args(args.input.iter()).args(["--seed", &args.seed.to_string(), "--memory-child", name.trim()]);
        if let Some(p) = &args.procedural {
            cmd.args(["--procedural", p]);
        }
        if let Some(n) = args.threads {
            cmd.args(["--threads", &n.to_string()]);
        }
        let out = cmd.stderr(std::process::Stdio::inherit()).output().context("running a --memory process")?;
        if !out.status.success() {
            bail!("--memory: the process building with {name} failed ({})", out.status);
        }
        let r: MemoryReport = serde_json::from_slice(&out.stdout).context("reading a --memory process's report")?;
        reports.push(r);
    }
    let triangles = reports.first().map_or(0, |r| r.triangles);
    outln!("{triangles} triangles; each builder in its own process");
    outln!(
        "{:<26} {:>10} {:>12} {:>12} {:>14} {:>14}",
        "builder",
        "build ms",
        "kept MB",
        "peak MB",
        "kept B/tri",
        "peak B/tri"
    );
    for r in &reports {
        outln!(
            "{:<26} {:>10.1} {:>12.1} {:>12.1} {:>14.1} {:>14.1}",
            r.name,
            r.build_ms,
            r.kept_bytes as f64 / 1e6,
            r.peak_bytes as f64 / 1e6,
            r.kept_bytes_per_triangle,
            r.peak_bytes_per_triangle
        );
    }
    outln!(
        "(kept: what tracing needs, triangles included; peak: the whole process, mesh and input triangles included)"
    );
    let report = serde_json::json!({ "triangles": triangles, "builders": reports });
    let csv = |f: &mut dyn Write| -> Result<()> {
        writeln!(f, "name,build_ms,kept_bytes,peak_bytes,kept_bytes_per_triangle,peak_bytes_per_triangle")?;
        for r in &reports {
            writeln!(
                f,
                "{},{},{},{},{},{}",
                r.name, r.build_ms, r.kept_bytes, r.peak_bytes, r.kept_bytes_per_triangle, r.peak_bytes_per_triangle
            )?;
        }
        Ok(())
    };
    write_outputs(args, &report, csv, (String::new(), ("", "")), &[], false)
}

/// One builder's `--memory` process: builds what tracing needs and prints a [`MemoryReport`].
/// Ours: the leaf-collapsed BVH and its leaf-ordered triangles (the renderer's `MeshBvh`).
/// obvhs: its `Bvh2` and triangles, built exactly as its preset ships.
fn memory_child(args: &Args, name: &str) -> Result<()> {
    let builder: Builder = name.parse().context("--memory-child")?;
    let (_, mesh) = load_input(args)?;
    let triangles = mesh.triangles();
    drop(mesh);
    let t = std::time::Instant::now();
    let kept = match builder.to_string().strip_prefix("obvhs-") {
        Some(preset) => {
            let (tris, bvh) = arbor_bench::peers::obvhs_native_bytes(preset, &triangles);
            tris + bvh
        }
        _ => {
            let m = builder.build_mesh(&triangles);
            m.bvh.memory_bytes() + size_of_val(m.triangles.as_slice())
        }
    } as u64;
    let build_ms = t.elapsed().as_secs_f64() * 1e3;
    let peak = arbor::memory::peak_rss_bytes().context("--memory needs /proc/self/status (Linux)")?;
    let n = triangles.len().max(1) as f64;
    let r = MemoryReport {
        name: builder.to_string(),
        triangles: triangles.len(),
        build_ms,
        kept_bytes: kept,
        peak_bytes: peak,
        kept_bytes_per_triangle: kept as f64 / n,
        peak_bytes_per_triangle: peak as f64 / n,
    };
    outln!("{}", serde_json::to_string(&r)?);
    Ok(())
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(|| format!("expected WIDTHxHEIGHT, as 128x128, not {s:?}"))?;
    let w: u32 = w.trim().parse().map_err(|e| format!("width {w:?}: {e}"))?;
    let h: u32 = h.trim().parse().map_err(|e| format!("height {h:?}: {e}"))?;
    if w == 0 || h == 0 || w > 65_536 || h > 65_536 {
        return Err(format!("{s}: each side must be 1 to 65536 pixels"));
    }
    Ok((w, h))
}

/// The mesh and a name for it; an error where it has no triangles, which no mode can measure.
fn load_input(args: &Args) -> Result<(String, TriangleMesh)> {
    let (name, mesh) = load_any_input(args)?;
    if mesh.indices.is_empty() {
        bail!("{}: no triangles", args.input.as_ref().map_or(name, |p| p.display().to_string()));
    }
    Ok((name, mesh))
}

/// [`load_input`], empty meshes included.
fn load_any_input(args: &Args) -> Result<(String, TriangleMesh)> {
    let input = match &args.input {
        Some(path) if path.extension().is_some_and(|e| e == "toml") => {
            // A scene: every object's triangles in world space, as the renderer builds over them.
            let scene = arbor::scene::Scene::load(path)?;
            scene.check_flat_fits(path, arbor::memory::BENCH_BYTES_PER_TRIANGLE)?;
            let (triangles, _) = scene.world_triangles();
            let mesh = TriangleMesh {
                positions: triangles.iter().flat_map(|t| [t.v0, t.v1, t.v2]).collect(),
                indices: (0..triangles.len() as u32).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect(),
            };
            Some((path.file_name().map_or(path.display().to_string(), |n| n.to_string_lossy().into_owned()), mesh))
        }
        Some(path) => {
            let mesh = TriangleMesh::load_obj(path)?;
            Some((path.file_name().map_or(path.display().to_string(), |n| n.to_string_lossy().into_owned()), mesh))
        }
        None => None,
    };
    let Some(spec) = &args.procedural else {
        return input.context("give a mesh (.obj) or --procedural KIND:N");
    };
    let (kind, count) = spec.split_once(':').context("--procedural: expected KIND:N, e.g. city:1M")?;
    let n = parse_count(count).with_context(|| format!("--procedural: bad triangle count `{count}`"))?;
    arbor::memory::check_fits(&format!("--procedural {spec}"), n as f64 * arbor::memory::BENCH_BYTES_PER_TRIANGLE)?;
    let mesh = match kind {
        "hairball" => procedural::hairball(n, args.seed),
        "city" => procedural::city(n, args.seed),
        "subdivided" => {
            let (_, base) = input.as_ref().context("--procedural subdivided:N needs an input mesh to subdivide")?;
            procedural::subdivide(base, n)
        }
        other => bail!("--procedural: unknown kind `{other}`; known: hairball, city, subdivided"),
    };
    let name = match &input {
        Some((base, _)) if kind == "subdivided" => format!("{base} subdivided"),
        _ => kind.to_string(),
    };
    Ok((name, mesh))
}

fn parse_count(s: &str) -> Result<usize> {
    let (digits, scale) = match s.chars().last() {
        Some('k' | 'K') => (&s[..s.len() - 1], 1_000.0),
        Some('m' | 'M') => (&s[..s.len() - 1], 1_000_000.0),
        _ => (s, 1.0),
    };
    let v: f64 = digits.parse()?;
    let n = v * scale;
    if !(n.is_finite() && n >= 1.0) {
        bail!("must be at least 1");
    }
    if n.fract() != 0.0 {
        bail!("must be a whole number");
    }
    // Beyond this no machine holds the mesh; `check_fits` judges the counts below it.
    if n > 1e12 {
        bail!("must be at most 10^12");
    }
    Ok(n as usize)
}

fn print_table(r: &Report) {
    outln!(
        "{} triangles, {} threads; rays: {} primary, {} shadow, {} diffuse",
        r.triangles,
        r.threads,
        r.rays.primary,
        r.rays.shadow,
        r.rays.diffuse
    );
    outln!(
        "{:<26} {:>10} {:>12} {:>10} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9}",
        "builder",
        "build ms",
        "optimize ms",
        "SAH leaf1",
        "SAH",
        "nodes",
        "leaves",
        "primary",
        "shadow",
        "diffuse"
    );
    let speed = |v: Option<f64>| v.map_or_else(|| "n/a".to_string(), |v| format!("{v:.2}"));
    for b in &r.builders {
        outln!(
            "{:<26} {:>10.1} {:>12.1} {:>10.2} {:>8.2} {:>9} {:>9} {:>9} {:>9} {:>9}",
            b.name,
            b.build_ms,
            b.optimize_ms,
            b.sah_leaf1,
            b.sah,
            b.nodes,
            b.leaves,
            speed(b.primary_mrays),
            speed(b.shadow_mrays),
            speed(b.diffuse_mrays)
        );
    }
    outln!("(trace speeds in Mrays/s; SAH after Arbor's leaf collapse, max 8 per leaf)");
    if r.rays.shadow == 0 {
        outln!(
            "(no primary ray hit the mesh, so there are no shadow or diffuse rays: n/a, null in the JSON; a thin or flat mesh seen edge-on)"
        );
    }
}

fn write_csv(f: &mut dyn Write, r: &Report) -> Result<()> {
    writeln!(
        f,
        "name,build_ms,optimize_ms,collapse_ms,sah,sah_leaf1,nodes,leaves,depth,primary_mrays,shadow_mrays,diffuse_mrays"
    )?;
    for b in &r.builders {
        writeln!(
            f,
            "{},{},{},{},{},{},{},{},{},{},{},{}",
            b.name,
            b.build_ms,
            b.optimize_ms,
            b.collapse_ms,
            b.sah,
            b.sah_leaf1,
            b.nodes,
            b.leaves,
            b.depth,
            csv_speed(b.primary_mrays),
            csv_speed(b.shadow_mrays),
            csv_speed(b.diffuse_mrays)
        )?;
    }
    Ok(())
}

/// `value` as pretty JSON, ending in a newline as text files do.
fn write_json(f: &mut dyn Write, value: &impl serde::Serialize) -> Result<()> {
    serde_json::to_writer_pretty(&mut *f, value)?;
    writeln!(f)?;
    Ok(())
}

/// A trace speed in the CSV: empty where there were no rays.
fn csv_speed(v: Option<f64>) -> String {
    v.map_or_else(String::new, |v| v.to_string())
}

/// Writes `path` atomically (see `arbor::atomic_file`).
fn write_atomic(path: &Path, write: impl FnOnce(&mut dyn Write) -> Result<()>) -> Result<()> {
    atomic_file::write_atomic(path, |f| write(f))
        .map_err(atomic_error)
        .with_context(|| format!("writing {}", path.display()))
}

fn atomic_error(e: AtomicWriteError<anyhow::Error>) -> anyhow::Error {
    match e {
        AtomicWriteError::Io { what, source } => anyhow::Error::new(source).context(what),
        AtomicWriteError::Write(e) => e,
    }
}

#[derive(Clone, Copy, PartialEq)]
enum PlotFormat {
    Svg,
    Png,
}

fn plot_format(path: &Path) -> Result<PlotFormat> {
    match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("svg") => Ok(PlotFormat::Svg),
        Some("png") => Ok(PlotFormat::Png),
        _ => bail!("--plot {}: the name must end in .svg or .png", path.display()),
    }
}

/// Fonts plotters may use for labels, first found wins.
const FONT_PATHS: [&str; 3] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
];

/// A named curve of (x, y) points.
type Series = (String, Vec<(f64, f64)>);

fn write_plot(path: &Path, title: &str, labels: (&str, &str), series: &[Series], log: bool) -> Result<()> {
    use plotters::prelude::*;
    let font = FONT_PATHS
        .iter()
        .find_map(|p| std::fs::read(p).ok())
        .context("the plot needs the DejaVu Sans font (Debian package fonts-dejavu-core)")?;
    // plotters keeps registered fonts for the whole process.
    plotters::style::register_font("sans-serif", FontStyle::Normal, Box::leak(font.into_boxed_slice()))
        .map_err(|_| anyhow::anyhow!("DejaVu Sans could not be read as a font"))?;
    // plotters creates the file itself and picks PNG by the extension, which the temporary keeps.
    let format = plot_format(path)?;
    atomic_file::replace_via_temp(path, |tmp| {
        match format {
            PlotFormat::Svg => {
                draw_chart(SVGBackend::new(tmp, (900, 600)).into_drawing_area(), title, labels, series, log)
            }
            PlotFormat::Png => {
                draw_chart(BitMapBackend::new(tmp, (900, 600)).into_drawing_area(), title, labels, series, log)
            }
        }
        .map_err(AtomicWriteError::Write)
    })
    .map_err(atomic_error)
    .with_context(|| format!("writing {}", path.display()))
}

/// A logarithmic axis's range around `lo..=hi` (both positive), with a fifth of a decade of
/// margin. plotters labels a logarithmic axis from the powers of ten inside it (then their
/// multiples), so a range that holds none is widened to the nearer one, with a margin so that
/// its label is not on the edge.
fn log_range(lo: f64, hi: f64) -> std::ops::Range<f64> {
    let (lo, hi) = (lo * 0.8, hi * 1.25);
    // The first power of ten clear of the bottom, and the last one clear of it from below.
    let above = 10f64.powf((lo * 1.1).log10().ceil());
    let below = 10f64.powf((lo / 1.1).log10().floor());
    if above * 1.1 <= hi {
        return lo..hi;
    }
    if lo / below <= above / hi { below * 0.8..hi } else { lo..above * 1.25 }
}

/// A linear axis's range around `lo..=hi` with 3% of margin; a single value (a zero error, a
/// constant SAH) gets a range around it instead of an empty one.
fn linear_range(lo: f64, hi: f64) -> (f64, f64) {
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    if hi > lo {
        let pad = (hi - lo) * 0.03;
        // An axis of values that are all positive starts at zero or above, never below it.
        let bottom = if lo >= 0.0 { (lo - pad).max(0.0) } else { lo - pad };
        return (bottom, hi + pad);
    }
    let pad = if lo == 0.0 { 1.0 } else { lo.abs() * 0.05 };
    (if lo >= 0.0 { (lo - pad).max(0.0) } else { lo - pad }, hi + pad)
}

/// A tick label with at most four significant digits and no binary-to-decimal noise
/// (0.30000000000000004 is written 0.3), in scientific notation outside 1e-3..1e6.
fn tick_label(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let magnitude = v.abs().log10().floor() as i32;
    if !(-3..6).contains(&magnitude) {
        let s = format!("{v:.3e}");
        let (mantissa, exponent) = s.split_once('e').unwrap_or((&s, "0"));
        return format!("{}e{exponent}", trim_zeros(mantissa));
    }
    let decimals = (3 - magnitude).max(0) as usize;
    trim_zeros(&format!("{v:.decimals$}")).to_string()
}

/// "1.500" -> "1.5", "2.000" -> "2"; text without a decimal point is kept.
fn trim_zeros(s: &str) -> &str {
    if s.contains('.') { s.trim_end_matches('0').trim_end_matches('.') } else { s }
}

/// One curve per series, with points marked; log-log axes when every value is positive and
/// `log` is asked for, otherwise a logarithmic x axis when it spans more than a factor of 30.
fn draw_chart<DB: plotters::prelude::DrawingBackend>(
    root: plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    (x_desc, y_desc): (&str, &str),
    series: &[Series],
    log: bool,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    use plotters::prelude::*;
    let err = |e: &dyn std::fmt::Display| anyhow::anyhow!("{e}");
    let points: Vec<&(f64, f64)> = series.iter().flat_map(|s| &s.1).collect();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut builder = ChartBuilder::on(&root);
    builder.caption(title, ("sans-serif", 22)).margin(12).x_label_area_size(40).y_label_area_size(70);
    // The same drawing for both coordinate systems, whose chart types differ.
    macro_rules! draw {
        ($chart:expr) => {{
            let mut chart = $chart.map_err(|e| err(&e))?;
            chart
                .configure_mesh()
                .x_desc(x_desc)
                .y_desc(y_desc)
                .x_label_formatter(&|v| tick_label(*v))
                .y_label_formatter(&|v| tick_label(*v))
                .draw()
                .map_err(|e| err(&e))?;
            for (k, (name, pts)) in series.iter().enumerate() {
                let color = Palette99::pick(k).to_rgba();
                // Markers only where the curve is sparse enough to show them.
                let marks = if pts.len() <= 60 { pts.clone() } else { Vec::new() };
                chart
                    .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))
                    .map_err(|e| err(&e))?
                    .label(name.clone())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(2)));
                chart.draw_series(marks.iter().map(|&p| Circle::new(p, 3, color.filled()))).map_err(|e| err(&e))?;
            }
            chart
                .configure_series_labels()
                // Error and SAH fall with time, so the upper right is where curves are least.
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(|e| err(&e))?;
        }};
    }
    if log && points.iter().all(|p| p.0 > 0.0 && p.1 > 0.0) && !points.is_empty() {
        let (x_min, x_max) = points.iter().fold((f64::INFINITY, 0.0f64), |a, p| (a.0.min(p.0), a.1.max(p.0)));
        let (y_min, y_max) = points.iter().fold((f64::INFINITY, 0.0f64), |a, p| (a.0.min(p.1), a.1.max(p.1)));
        draw!(builder.build_cartesian_2d(log_range(x_min, x_max).log_scale(), log_range(y_min, y_max).log_scale()));
    } else {
        let x_min = points.iter().map(|p| p.0).fold(f64::INFINITY, f64::min);
        let x_max = points.iter().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max);
        let x_max = if x_max > 0.0 { x_max } else { 1.0 };
        let (y_min, y_max) = linear_range(
            points.iter().map(|p| p.1).fold(f64::INFINITY, f64::min),
            points.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max),
        );
        if x_min > 0.0 && x_max > 30.0 * x_min {
            // Times spanning orders of magnitude (a sequential optimiser beside a parallel one).
            draw!(builder.build_cartesian_2d((x_min * 0.8..x_max * 1.25).log_scale(), y_min..y_max));
        } else {
            draw!(builder.build_cartesian_2d(0.0..x_max * 1.05, y_min..y_max));
        }
    }
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_labels_are_short_and_exact_looking() {
        assert_eq!(tick_label(0.1 + 0.2), "0.3");
        assert_eq!(tick_label(0.30000000000000004), "0.3");
        assert_eq!(tick_label(2.0), "2");
        assert_eq!(tick_label(1.5), "1.5");
        assert_eq!(tick_label(130.87), "130.9");
        assert_eq!(tick_label(0.0125), "0.0125");
        assert_eq!(tick_label(0.00012346), "1.235e-4");
        assert_eq!(tick_label(2.5e7), "2.5e7");
        assert_eq!(tick_label(-0.25), "-0.25");
        assert_eq!(tick_label(0.0), "0");
    }

    #[test]
    fn a_log_axis_always_holds_a_power_of_ten_away_from_its_ends() {
        let powers = |r: std::ops::Range<f64>| {
            (-20..20).filter(|&k| r.start < 10f64.powi(k) * 0.9 && 10f64.powi(k) * 1.1 < r.end).count()
        };
        for (lo, hi) in [(0.3, 0.5), (0.011, 0.019), (2.0, 3.0), (70.0, 95.0), (1e-6, 1e-3), (5.0, 5.0)] {
            let r = log_range(lo, hi);
            assert!(r.start <= lo && r.end >= hi, "{lo}..{hi} -> {r:?}");
            assert!(powers(r.clone()) >= 1, "{lo}..{hi} -> {r:?}");
            assert!(r.end / r.start < hi / lo * 20.0, "{lo}..{hi} -> {r:?} squeezes the curve");
        }
    }

    #[test]
    fn a_linear_axis_is_never_empty() {
        for (lo, hi) in [(0.0, 0.0), (5.0, 5.0), (-2.0, -2.0), (1.0, 3.0), (f64::INFINITY, f64::NEG_INFINITY)] {
            let (a, b) = linear_range(lo, hi);
            assert!(a < b, "{lo}..{hi} -> {a}..{b}");
            if lo.is_finite() {
                assert!(a <= lo && b >= hi, "{lo}..{hi} -> {a}..{b}");
            }
        }
        assert_eq!(linear_range(0.0, 0.0).0, 0.0, "zero errors stay on an axis that starts at zero");
    }
}
