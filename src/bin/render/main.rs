//! `render`: renders a scene file to an image.
//!
//! Argument parsing and reporting only; the work is `arbor::scene`, `arbor::device` and
//! `arbor::distributed` (the plan of a split render, its jobs and the merge).

mod args;
#[path = "../cli/mod.rs"]
mod cli;
mod job;
mod print;

use std::io::IsTerminal;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::{Context, Result};
use arbor::bvh::{TraceLayout, Tracing};
use arbor::device::{BuilderChoice, DeviceChoice, Forms, Renderer};
use arbor::distributed::film_file;
use arbor::distributed::overwrite::{Named, Overwrite, check_overwrites};
use arbor::distributed::{Job, JobError, Plan, PlanError, Request, Start};
use arbor::image_io::{check_output_path, write_image};
use arbor::render::film::Film;
use arbor::render::geometry::wants_instancing;
use arbor::render::pass::Progress;
use arbor::scene::{RenderSettings, Scene};
use args::{Args, Device};
use clap::Parser;
use cli::outln;
use job::{BadInput, BvhReport, FrameReport, Report, code};

fn main() {
    // SAFETY: first thing in `main`, before any other thread exists.
    #[cfg(feature = "gpu")]
    unsafe {
        arbor::gpu::quiet_device_select_layer()
    };
    let started = Instant::now();
    let signals = match job::Signals::install() {
        Ok(s) => s,
        Err(e) => {
            eprintln!("render: error: cannot handle SIGTERM and SIGINT: {e}");
            std::process::exit(code::OTHER);
        }
    };
    // clap's errors exit with 2 (bad input), its --help and --version with 0.
    let args = Args::parse();
    let mut report = Report {
        arbor_version: env!("CARGO_PKG_VERSION"),
        command: std::env::args().collect(),
        mode: if args.merge.is_empty() { "render" } else { "merge" },
        ..Default::default()
    };
    let result = if args.merge.is_empty() {
        run(&args, &signals, &mut report)
    } else {
        signals.die_on_signal();
        merge(&args, &mut report)
    };
    let mut exit = match &result {
        Ok(()) => code::OK,
        Err(e) => {
            eprintln!("render: error: {e:#}");
            job::exit_code(e)
        }
    };
    // No report where an output was refused for overwriting a file, nor over any file the run
    // read or writes (a load that failed halfway has not been checked against its files).
    let refused = result.as_ref().err().and_then(overwrite_of).is_some();
    let report_path = args.report.as_ref().filter(|r| {
        if refused {
            return false;
        }
        if report.guarded.iter().any(|p| arbor::atomic_file::replaces(r, p)) {
            eprintln!(
                "render: --report {}: not written: it would overwrite a file this run reads or writes",
                r.display()
            );
            return false;
        }
        if !replaces_only_a_report(r) {
            // A load that failed may not have come to every file it would read.
            eprintln!("render: --report {}: not written: the file there is not a report", r.display());
            return false;
        }
        true
    });
    if let Some(path) = report_path {
        report.exit_code = exit;
        report.error = result.err().map(|e| format!("{e:#}"));
        report.threads = rayon::current_num_threads();
        report.wall_seconds = started.elapsed().as_secs_f64();
        report.peak_memory_bytes = arbor::memory::peak_rss_bytes();
        let written = serde_json::to_vec_pretty(&report).map_err(std::io::Error::other).and_then(|json| {
            arbor::atomic_file::write_atomic(path, |out| std::io::Write::write_all(out, &json)).map_err(|e| match e {
                arbor::atomic_file::AtomicWriteError::Io { source, .. }
                | arbor::atomic_file::AtomicWriteError::Write(source) => source,
            })
        });
        if let Err(e) = written {
            eprintln!("render: error: --report {}: {e}", path.display());
            if exit == code::OK {
                exit = code::IO;
            }
        }
    }
    if let Some(e) = cli::stdout_error() {
        eprintln!("render: error: writing to standard output: {e}");
        if exit == code::OK {
            exit = code::OTHER;
        }
    }
    std::process::exit(exit);
}

/// Whether writing the report to `path` replaces nothing but a report: nothing is there, or a
/// stream (`/dev/stdout`), or a file that starts as a report does. A run that failed early has
/// not checked the report against every file its scene names; this keeps it off them.
fn replaces_only_a_report(path: &Path) -> bool {
    use std::io::Read as _;
    match std::fs::metadata(path) {
        Ok(m) if m.is_file() && !path.starts_with("/dev") && !path.starts_with("/proc") => {
            let mut head = [0; 64];
            let n = std::fs::File::open(path).and_then(|f| f.take(64).read(&mut head)).unwrap_or(0);
            let head = String::from_utf8_lossy(&head[..n]);
            n == 0 || head.trim_start().starts_with('{') && head.contains("\"arbor_version\"")
        }
        _ => true,
    }
}

/// The [`Overwrite`] that `error` is, if any (a [`PlanError`] wraps it in place).
fn overwrite_of(error: &anyhow::Error) -> Option<&Overwrite> {
    error.chain().find_map(|c| match c.downcast_ref::<PlanError>() {
        Some(PlanError::Overwrite(o)) => Some(o),
        _ => c.downcast_ref::<Overwrite>(),
    })
}

fn bad(message: impl Into<String>) -> anyhow::Error {
    BadInput(message.into()).into()
}

/// What the flags ask of `scene`, loaded from `scene_path`.
fn request(args: &Args, scene_path: &Path, scene: &Scene) -> Request {
    Request {
        scene: scene_path.to_path_buf(),
        output: args.output.clone(),
        settings: RenderSettings {
            spp: args.spp.unwrap_or(scene.render.spp),
            max_depth: args.max_depth.unwrap_or(scene.render.max_depth),
            seed: args.seed.unwrap_or(scene.render.seed),
            time: args.time.or(scene.render.time),
            clamp: args.clamp,
        },
        tile: args.tile,
        crop: args.crop,
        samples: args.samples.clone(),
        frames: args.frames.clone().or(args.frame.map(|n| n..n + 1)),
        checkpoint: args.checkpoint,
        resume: args.resume,
        skip_existing: args.skip_existing,
    }
}

fn run(args: &Args, signals: &job::Signals, report: &mut Report) -> Result<()> {
    let stop: &AtomicBool = &signals.stop;
    let scene_path = args.scene.as_deref().expect("clap requires a scene without --merge");
    report.scene = Some(scene_path.to_path_buf());
    // A bad name fails before any work; the default depends on the device and the scene.
    let named: Option<BuilderChoice> =
        args.builder.as_deref().map(str::parse).transpose().map_err(|e| bad(format!("--builder (or auto): {e}")))?;
    cli::init_threads(args.threads).map_err(|e| bad(e.to_string()))?;
    // The one place the trace form is chosen: every tree this render builds is given it.
    let tracing = Tracing::from_env(args.trace).map_err(|e| bad(e.to_string()))?;
    // The report is written whatever happens after, a failed load included: it must not be the
    // scene (or the output) it reports on. The scene's other files are checked once it is read.
    if let Some(r) = &args.report {
        let others = [Named::new("the scene", scene_path), Named::new("-o", &args.output)];
        check_overwrites(&[Named::new("--report", r)], None, &others)?;
    }
    let load = Instant::now();
    report.guarded.extend([scene_path.to_path_buf(), args.output.clone()]);
    let (scene, read) = arbor::memory::recording_reads(|| Scene::load(scene_path));
    report.guarded.extend(read);
    let scene = scene?;
    report.load_seconds = Some(load.elapsed().as_secs_f64());
    report.texture_bytes = Some(scene.texture_bytes() as u64);
    let plan = Plan::new(request(args, scene_path, &scene), &scene)?;
    let (settings, region) = (&plan.request.settings, &plan.region);
    report.seed = Some(settings.seed);
    report.max_depth = Some(settings.max_depth);
    report.resolution = Some([plan.width, plan.height]);
    report.tile = args.tile.map(|(i, n)| format!("{i}/{n}"));
    report.rect = Some([region.rect.x0, region.rect.y0, region.rect.x1, region.rect.y1]);
    report.samples = Some([region.samples.start, region.samples.end]);
    let frames = plan.frames(&scene)?;
    let inputs: Vec<Named> = scene.input_files().into_iter().map(|(what, path)| Named::new(what, path)).collect();
    report.guarded.extend(inputs.iter().map(|i| i.path.clone()));
    plan.check_overwrites(frames.as_ref(), &inputs, args.report.as_deref())?;
    let outputs = frames.as_ref().map_or(1, |f| f.len());
    if args.report.is_some() {
        // A line of the report for every frame, held until it is written.
        arbor::memory::check_fits(&format!("--report for {outputs} frames"), outputs as f64 * 400.0)?;
        report.keep_frames = true;
    }
    let device_choice = match args.device {
        Device::Cpu => DeviceChoice::Cpu,
        Device::Gpu => DeviceChoice::Gpu,
        Device::Auto => DeviceChoice::Auto,
    };
    let (device, note) = device_choice.select()?;
    if let Some(note) = note.filter(|_| !args.quiet) {
        outln!("{note}");
    }
    report.device = Some(device.name());
    report.adapter = device.adapter();
    let scene_hash = scene.content_hash();
    report.scene_hash = Some(scene_hash.clone());
    // A frame range moves the scene to each frame (its BVH update is reported); a still renders
    // the scene as built, at its first frame.
    let moves = frames.is_some();
    // Outputs already complete are skipped (--skip-existing); states are checked (--resume)
    // before any work. What is left is kept as runs of frames: a range may hold millions.
    let mut pending = Pending::default();
    for job in plan.jobs(frames, &scene, &scene_hash, device.name()) {
        if job.skips() {
            if !args.quiet {
                outln!("{}: complete, skipped (--skip-existing)", job.output.display());
            }
            let held = [region.samples.start, region.samples.end];
            report.push_frame(frame_report(&job, "skipped", held, None));
        } else {
            job.check_state()?;
            pending.push(job.frame);
        }
    }
    let Some(first) = pending.first() else { return Ok(()) };
    let first_time = plan.job(first, &scene, &scene_hash, device.name()).time;
    // Both devices render animated and heavily instanced scenes in two levels, the rest flat.
    // The memory checked: the binary tree alone, or with the wide form and what making it holds.
    let gpu_form = args.trace.unwrap_or(TraceLayout::Wide8);
    let binary = if device.name() == "gpu" { gpu_form } else { tracing.layout } == TraceLayout::Binary;
    if !wants_instancing(&scene) {
        scene.check_flat_fits(scene_path, arbor::memory::render_bytes_per_triangle(binary))?;
    } else {
        scene.check_instanced_fits(scene_path, arbor::memory::render_bytes_per_triangle(binary))?;
    }
    let builder = named.unwrap_or_else(|| BuilderChoice::default_for(device, &scene));
    let count = pending.count();
    // Each device takes its own default form; a form it lacks is refused, under auto too.
    #[cfg(feature = "gpu")]
    if device.name() == "gpu" {
        arbor::gpu::trace::GpuForm::of(gpu_form).map_err(|e| bad(e.to_string()))?;
    }
    let forms = Forms { cpu: tracing, gpu: gpu_form };
    let mut renderer = Renderer::new(device, &scene, &builder, forms, settings, count, first_time)?;
    let build = renderer.build_report();
    report.bvh = Some(BvhReport {
        builder: build.builder.clone(),
        triangles: build.triangles,
        build_ms: build.build_ms,
        sah: build.sah,
        trace: renderer.trace_form(),
    });
    if !args.quiet {
        print::print_build(scene_path, build, device.name() == "cpu", scene.texture_bytes());
        if let Some(note) = renderer.kernel_note() {
            outln!("{note}");
        }
    }
    // From here a signal is heard by the render, which writes its state.
    signals.loading.store(false, std::sync::atomic::Ordering::SeqCst);
    for frame in pending.frames() {
        let job = plan.job(frame, &scene, &scene_hash, device.name());
        let carried = match job.start()? {
            Start::Skip => continue,
            Start::Fresh => None,
            Start::Resume(carried) => Some(carried),
            Start::Restart(why) => {
                eprintln!("render: warning: --resume: {why}; its state is not used: rendering afresh");
                None
            }
        };
        let update_ms = if moves { renderer.set_time(&scene, job.time)? } else { None };
        render_job(args, &mut renderer, &job, carried, update_ms, stop, report)?;
    }
    if let Some(r) = renderer.refine_report().filter(|_| !args.quiet) {
        outln!("{r}");
    }
    Ok(())
}

/// The outputs left to render: runs of consecutive frames (or the still), so that a range of
/// millions of frames costs no memory per frame.
#[derive(Default)]
struct Pending {
    /// `(first frame, count)`; the still is `(None, 1)`.
    runs: Vec<(Option<u32>, u32)>,
}

impl Pending {
    fn push(&mut self, frame: Option<u32>) {
        if let (Some(f), Some((Some(first), n))) = (frame, self.runs.last_mut()) {
            if *first + *n == f {
                *n += 1;
                return;
            }
        }
        self.runs.push((frame, 1));
    }

    fn first(&self) -> Option<Option<u32>> {
        self.runs.first().map(|r| r.0)
    }

    fn count(&self) -> usize {
        self.runs.iter().map(|r| r.1 as usize).sum()
    }

    fn frames(&self) -> impl Iterator<Item = Option<u32>> + '_ {
        self.runs.iter().flat_map(|&(first, n)| (0..n).map(move |k| first.map(|f| f + k)))
    }
}

/// A line of the report's `frames` for `job`, of no rendering in this run.
fn frame_report(job: &Job, status: &'static str, held: [u32; 2], bvh_update_ms: Option<f64>) -> FrameReport {
    let output = job.output.clone();
    let (render_seconds, rays, dropped_samples) = (0.0, 0, 0);
    FrameReport {
        frame: job.frame,
        output,
        status,
        samples_done: held,
        bvh_update_ms,
        render_seconds,
        rays,
        dropped_samples,
    }
}

/// Renders and writes one job, carrying on from `carried` (`--resume`), with a progress bar.
fn render_job(
    args: &Args,
    renderer: &mut Renderer,
    job: &Job,
    carried: Option<arbor::device::RenderedFrame>,
    update_ms: Option<f64>,
    stop: &AtomicBool,
    report: &mut Report,
) -> Result<()> {
    renderer.begin_frame();
    let samples = &job.region.samples;
    let resumed = carried.is_some();
    let before = carried.as_ref().map_or((0, 0.0), |f| (f.rays, f.seconds));
    let bar = print::progress_bar(!args.quiet && std::io::stderr().is_terminal(), u64::from(samples.len() as u32));
    let progress = |p: Progress| {
        bar.set_length(p.total);
        bar.set_position(p.done);
        if p.rays > 0 {
            let secs = bar.elapsed().as_secs_f64().max(1e-9);
            bar.set_message(format!("{:.1} Mrays/s", p.rays as f64 / secs / 1e6));
        }
    };
    let frame = job.render(renderer, carried, &progress, stop);
    bar.finish_and_clear();
    let frame = frame.inspect_err(|e| {
        if let JobError::Interrupted { done, .. } = e {
            report.push_frame(frame_report(job, "interrupted", [samples.start, *done], update_ms));
        }
    })?;
    let done = samples.start + frame.samples;
    let dropped = frame.film.non_finite_count();
    report.dropped_samples += dropped;
    print::warn_dropped(&job.output, dropped);
    report.push_frame(FrameReport {
        dropped_samples: dropped,
        status: if resumed { "resumed" } else { "rendered" },
        render_seconds: frame.seconds - before.1,
        rays: frame.rays - before.0,
        ..frame_report(job, "", [samples.start, done], update_ms)
    });
    job.write(&frame)?;
    if !args.quiet {
        print::print_frame(renderer, &job.output, update_ms, &frame);
    }
    Ok(())
}

/// `render --merge`: checks the pieces and writes the image.
fn merge(args: &Args, report: &mut Report) -> Result<()> {
    check_output_path(&args.output)?;
    let pieces: Vec<Named> = args.merge.iter().map(|p| Named::new("a piece", p)).collect();
    let mut outputs = vec![Named::new("-o", &args.output)];
    outputs.extend(args.report.as_ref().map(|r| Named::new("--report", r)));
    report.guarded.extend(args.merge.iter().cloned());
    report.guarded.push(args.output.clone());
    check_overwrites(&outputs, None, &pieces)?;
    arbor::atomic_file::prepare(&args.output).with_context(|| format!("cannot write {}", args.output.display()))?;
    report.pieces.clone_from(&args.merge);
    report.keep_frames = args.report.is_some();
    let start = Instant::now();
    let skipped = if args.skip_existing {
        // The pieces' headers say the image's size; an output of that size, whole, is this merge
        // done before (a retried merge job does nothing twice).
        let infos =
            args.merge.iter().map(|p| Ok((p.clone(), film_file::piece_info(p)?))).collect::<Result<Vec<_>>>()?;
        let merged = film_file::check_pieces(&infos)?;
        arbor::image_io::is_whole_image(&args.output, merged.width, merged.height).then_some(merged)
    } else {
        None
    };
    let (info, film) = match skipped {
        Some(info) => (info, None),
        None => {
            let (info, film) = film_file::merge_files(&args.merge)?;
            write_image(&args.output, &film.mean())?;
            (info, Some(film))
        }
    };
    report.scene_hash = Some(info.scene_hash.clone());
    report.seed = Some(info.seed);
    report.max_depth = Some(info.max_depth);
    report.resolution = Some([info.width, info.height]);
    report.samples = Some([info.samples.start, info.samples.end]);
    let dropped = film.as_ref().map_or(0, Film::non_finite_count);
    report.dropped_samples = dropped;
    report.push_frame(FrameReport {
        frame: info.frame,
        output: args.output.clone(),
        status: if film.is_some() { "merged" } else { "skipped" },
        samples_done: [info.samples.start, info.samples.end],
        bvh_update_ms: None,
        render_seconds: info.seconds,
        rays: info.rays,
        dropped_samples: dropped,
    });
    let Some(film) = film else {
        if !args.quiet {
            outln!("{}: complete, skipped (--skip-existing)", args.output.display());
        }
        return Ok(());
    };
    print::warn_dropped(&args.output, dropped);
    if !args.quiet {
        outln!(
            "{}: {} pieces merged in {:.2} s: {}x{}, samples {}..{}, {:.2} s of rendering{}",
            args.output.display(),
            args.merge.len(),
            start.elapsed().as_secs_f64(),
            info.width,
            info.height,
            info.samples.start,
            info.samples.end,
            info.seconds,
            print::dropped(&film),
        );
    }
    Ok(())
}
