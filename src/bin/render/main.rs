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
use arbor::device::{BuilderChoice, DeviceChoice, Renderer};
use arbor::distributed::{Job, JobError, Plan, Request, Start};
use arbor::image_io::{check_output_path, write_image};
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
        run(&args, &signals.stop, &mut report)
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
    if let Some(path) = &args.report {
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

fn run(args: &Args, stop: &AtomicBool, report: &mut Report) -> Result<()> {
    let scene_path = args.scene.as_deref().expect("clap requires a scene without --merge");
    report.scene = Some(scene_path.to_path_buf());
    // A bad name fails before any work; the default depends on the device and the scene.
    let named: Option<BuilderChoice> =
        args.builder.as_deref().map(str::parse).transpose().map_err(|e| bad(format!("--builder (or auto): {e}")))?;
    cli::init_threads(args.threads).map_err(|e| bad(e.to_string()))?;
    // The one place the trace form is chosen: every tree this render builds is given it.
    let tracing = Tracing::from_env(args.trace).map_err(|e| bad(e.to_string()))?;
    let load = Instant::now();
    let scene = Scene::load(scene_path)?;
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
    // Outputs already complete are skipped (--skip-existing); states are read (--resume).
    let mut jobs = Vec::new();
    for job in plan.jobs(frames, &scene, &scene_hash, device.name()) {
        match job.start()? {
            Start::Skip => {
                if !args.quiet {
                    outln!("{}: complete, skipped (--skip-existing)", job.output.display());
                }
                let held = [region.samples.start, region.samples.end];
                report.frames.push(frame_report(&job, "skipped", held, None));
            }
            Start::Fresh => jobs.push((job, None)),
            Start::Resume(carried) => jobs.push((job, Some(carried))),
        }
    }
    if jobs.is_empty() {
        return Ok(());
    }
    // The GPU renders every scene flat; the CPU all but animated and heavily instanced ones.
    let binary = device.name() == "gpu" || tracing.layout == TraceLayout::Binary;
    if device.name() == "gpu" || !wants_instancing(&scene) {
        scene.check_flat_fits(scene_path, arbor::memory::render_bytes_per_triangle(binary))?;
    } else {
        scene.check_instanced_fits(scene_path, arbor::memory::render_bytes_per_triangle(binary))?;
    }
    let builder = named.unwrap_or_else(|| BuilderChoice::default_for(device, &scene));
    let mut renderer = Renderer::new(device, &scene, &builder, tracing, settings, jobs.len(), jobs[0].0.time)?;
    let build = renderer.build_report();
    report.bvh = Some(BvhReport {
        builder: build.builder.clone(),
        triangles: build.triangles,
        build_ms: build.build_ms,
        sah: build.sah,
    });
    if !args.quiet {
        print::print_build(scene_path, build, device.name() == "cpu", scene.texture_bytes());
        if let Some(note) = renderer.kernel_note() {
            outln!("{note}");
        }
    }
    for (job, carried) in jobs {
        let update_ms = if moves { renderer.set_time(&scene, job.time)? } else { None };
        render_job(args, &mut renderer, &job, carried, update_ms, stop, report)?;
    }
    if let Some(r) = renderer.refine_report().filter(|_| !args.quiet) {
        outln!("{r}");
    }
    Ok(())
}

/// A line of the report's `frames` for `job`, of no rendering in this run.
fn frame_report(job: &Job, status: &'static str, held: [u32; 2], bvh_update_ms: Option<f64>) -> FrameReport {
    let output = job.output.clone();
    FrameReport { frame: job.frame, output, status, samples_done: held, bvh_update_ms, render_seconds: 0.0, rays: 0 }
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
            report.frames.push(frame_report(job, "interrupted", [samples.start, *done], update_ms));
        }
    })?;
    let done = samples.start + frame.samples;
    report.frames.push(FrameReport {
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
    arbor::atomic_file::prepare(&args.output).with_context(|| format!("cannot write {}", args.output.display()))?;
    report.pieces.clone_from(&args.merge);
    let start = Instant::now();
    let (info, film) = arbor::distributed::film_file::merge_files(&args.merge)?;
    write_image(&args.output, &film.mean())?;
    report.scene_hash = Some(info.scene_hash.clone());
    report.seed = Some(info.seed);
    report.max_depth = Some(info.max_depth);
    report.resolution = Some([info.width, info.height]);
    report.samples = Some([info.samples.start, info.samples.end]);
    report.frames.push(FrameReport {
        frame: info.frame,
        output: args.output.clone(),
        status: "merged",
        samples_done: [info.samples.start, info.samples.end],
        bvh_update_ms: None,
        render_seconds: info.seconds,
        rays: info.rays,
    });
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
