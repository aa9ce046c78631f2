//! `render`: renders a scene file to an image.
//!
//! Argument parsing and reporting only; the work is `arbor::scene` and `arbor::device`.

#[path = "../cli/mod.rs"]
mod cli;
mod frames;
mod job;

use std::io::IsTerminal;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::{Context, Result};
use arbor::bvh::{TraceLayout, Tracing};
use arbor::device::{BuilderChoice, DeviceChoice, Progress, RenderedFrame, Renderer};
use arbor::distributed::film_file::{FilmPiece, PieceInfo, parse_rect, read_info, read_piece, write_piece};
use arbor::image_io::{check_output_path, write_image};
use arbor::render::BuildReport;
use arbor::render::geometry::wants_instancing;
use arbor::render::region::{Rect, Region, tile_rect};
use arbor::scene::{RenderSettings, Scene};
use clap::{Parser, ValueEnum};
use cli::outln;
use frames::{frame_path, has_frame_pattern};
use indicatif::{ProgressBar, ProgressStyle};
use job::{BadInput, BvhReport, FrameReport, Interrupted, Report, code};

/// Render a scene (TOML) to a linear EXR image, or an 8-bit sRGB PNG when OUT ends in .png.
///
/// Animated scenes: `--frames 0..120 -o out_%04d.exr` renders a sequence (`%04d` becomes the
/// frame number), `--frame N` one frame. Without either, an output name with a frame pattern
/// renders the scene's whole frame range, and one without renders its first frame.
///
/// Split renders (docs/distributed.md): `--tile I/N`, `--crop` and `--samples` render part of
/// the image or of its samples to a partial film (EXR); `render --merge PIECE.exr... -o OUT`
/// makes the image, bit for bit the one a single render makes. Exit codes: 0 done, 2 bad input,
/// 3 out of memory, 69 device, 74 I/O, 75 stopped by a signal (state written), 1 other.
#[derive(Parser, Debug)]
#[command(name = "render", version, allow_negative_numbers = true)]
struct Args {
    /// The scene file (see docs/scene-format.md).
    #[arg(required_unless_present = "merge")]
    scene: Option<PathBuf>,
    /// Output image: .exr (linear float RGB) or .png (8-bit sRGB); `%04d` (or `%d`, `%0Nd`) in
    /// the name becomes the frame number. With --tile, --crop or --samples, a partial film
    /// (.exr).
    #[arg(short, long)]
    output: PathBuf,
    /// Frames to render, first..one-past-last, as `0..120` (an animated scene's frames run at
    /// its `animation.fps`).
    #[arg(long, value_parser = parse_frames, conflicts_with = "frame")]
    frames: Option<Range<u32>>,
    /// One frame to render (at most 4294967294, the last a `--frames` range can hold).
    #[arg(long, value_parser = clap::value_parser!(u32).range(..i64::from(u32::MAX)))]
    frame: Option<u32>,
    /// Samples per pixel (overrides the scene's render.spp).
    #[arg(long)]
    spp: Option<u32>,
    /// Time budget in seconds (overrides render.time): stop after the pass that exceeds it.
    #[arg(long)]
    time: Option<f64>,
    /// Maximum path segments (overrides render.max_depth): 1 shows emitters, 2 adds direct light.
    #[arg(long)]
    max_depth: Option<u32>,
    /// Where to render.
    #[arg(long, value_enum, default_value_t = Device::Auto)]
    device: Device,
    /// BVH builder: auto, or a builder's name (lbvh, lbvh+prbvh, binned-sah, ploc, ...). `auto`
    /// optimises the LBVH only while that pays for itself in this render: on the CPU it starts
    /// rendering at once and optimises between passes. Default: auto on the CPU; lbvh+prbvh on
    /// the GPU, where an animated or instanced scene is rebuilt flat every frame, with lbvh
    /// unless a builder other than auto is given.
    #[arg(long)]
    builder: Option<String>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// The tree the CPU traces: binary, wide4 or wide8 (default: wide8 where the CPU has AVX2,
    /// wide4 where it has SSE4.1 or NEON, else binary). Every form gives the same image;
    /// `ARBOR_SIMD=scalar|sse4|avx2|neon` forces the instruction set.
    #[arg(long, value_name = "FORM", value_parser = parse_trace)]
    trace: Option<TraceLayout>,
    /// Clamp fireflies: scale down any sample whose largest channel exceeds this radiance.
    /// Biased (it removes energy); off unless given.
    #[arg(long, value_name = "RADIANCE")]
    clamp: Option<f32>,
    /// Seed of the random streams (overrides render.seed).
    #[arg(long)]
    seed: Option<u64>,
    /// No progress bar and no summary.
    #[arg(long)]
    quiet: bool,
    /// Render tile I of N (I from 0): the image cut into a grid of N rectangles closest to
    /// square, numbered row by row from the top left. Writes a partial film.
    #[arg(long, value_name = "I/N", value_parser = parse_tile, conflicts_with = "crop")]
    tile: Option<(u32, u32)>,
    /// Render the rectangle of columns X0..X1 and rows Y0..Y1 (X1, Y1 excluded; row 0 at the
    /// top). Writes a partial film.
    #[arg(long, value_name = "X0,Y0,X1,Y1", value_parser = parse_crop)]
    crop: Option<Rect>,
    /// Render sample indices A..B-1 of every pixel (B at most the render's spp). Writes a
    /// partial film.
    #[arg(long, value_name = "A..B", value_parser = parse_samples)]
    samples: Option<Range<u32>>,
    /// Merge partial films into the image (-o): they must be pieces of one render that cover
    /// every pixel's samples once.
    #[arg(long, value_name = "PIECE", num_args = 1.., conflicts_with_all = ["scene", "tile", "crop", "samples", "frames", "frame", "checkpoint", "resume"])]
    merge: Vec<PathBuf>,
    /// Write the render's state (a partial film) this often: the output itself for a split
    /// render, else OUT.partial.exr beside the output, removed when the image is written.
    #[arg(long, value_name = "SECONDS")]
    checkpoint: Option<f64>,
    /// Carry on from the state a checkpoint or a signal left (start afresh where there is none).
    #[arg(long)]
    resume: bool,
    /// Do nothing for an output that is already complete.
    #[arg(long)]
    skip_existing: bool,
    /// Write a JSON report of what ran and what it cost to this file.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum Device {
    Cpu,
    Gpu,
    Auto,
}

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

/// One output of a render: a frame, or the still.
struct Output {
    path: PathBuf,
    /// The scene time it shows.
    time: f32,
    /// The frame number (`None` for a still).
    frame: Option<u32>,
    /// Where its state goes: the output itself for a partial film, else `OUT.partial.exr`.
    state: PathBuf,
    /// The samples already taken (`--resume`), `None` to start afresh.
    carried: Option<FilmPiece>,
}

fn run(args: &Args, stop: &AtomicBool, report: &mut Report) -> Result<()> {
    let scene_path = args.scene.as_deref().expect("clap requires a scene without --merge");
    report.scene = Some(scene_path.to_path_buf());
    // A bad name fails before any work; the default depends on the device and the scene.
    let named: Option<BuilderChoice> =
        args.builder.as_deref().map(str::parse).transpose().map_err(|e| bad(format!("--builder (or auto): {e}")))?;
    cli::init_threads(args.threads).map_err(|e| bad(e.to_string()))?;
    // Before any tree is built: meshes take the form current when they are built.
    Tracing::from_env(args.trace).map_err(|e| bad(e.to_string()))?.set_default();
    let load = Instant::now();
    let scene = Scene::load(scene_path)?;
    report.load_seconds = Some(load.elapsed().as_secs_f64());
    report.texture_bytes = Some(scene.texture_bytes() as u64);
    let (width, height) = (scene.camera.width, scene.camera.height);
    let settings = RenderSettings {
        spp: args.spp.unwrap_or(scene.render.spp),
        max_depth: args.max_depth.unwrap_or(scene.render.max_depth),
        seed: args.seed.unwrap_or(scene.render.seed),
        time: args.time.or(scene.render.time),
        clamp: args.clamp,
    };
    if settings.spp == 0 || settings.max_depth == 0 {
        return Err(bad("--spp and --max-depth must be at least 1"));
    }
    if settings.clamp.is_some_and(|c| !(c.is_finite() && c > 0.0)) {
        return Err(bad("--clamp must be a radiance > 0"));
    }
    if settings.time.is_some_and(|t| !(t.is_finite() && t > 0.0)) {
        return Err(bad("--time must be a number of seconds > 0"));
    }
    if args.checkpoint.is_some_and(|t| !(t.is_finite() && t > 0.0)) {
        return Err(bad("--checkpoint must be a number of seconds > 0"));
    }
    let resolution =
        format!("{}:{}: camera.resolution {width}x{height}", scene_path.display(), scene.camera.resolution_line);
    // What this run renders of each frame.
    let split = args.tile.is_some() || args.crop.is_some() || args.samples.is_some();
    let rect = match (args.tile, args.crop) {
        (Some((i, n)), _) => tile_rect(i, n, width, height).ok_or_else(|| {
            bad(if i >= n {
                format!("--tile {i}/{n}: the tile number must be below {n} (tiles count from 0)")
            } else {
                format!("--tile {i}/{n}: a {width}x{height} image has no grid of {n} tiles ({resolution})")
            })
        })?,
        (None, Some(r)) if r.fits(width, height) => r,
        (None, Some(r)) => return Err(bad(format!("--crop {r}: not inside the image ({resolution})"))),
        (None, None) => Rect::full(width, height),
    };
    let samples = args.samples.clone().unwrap_or(0..settings.spp);
    if samples.end > settings.spp {
        return Err(bad(format!(
            "--samples {}..{}: past the render's {} samples per pixel (render.spp in {}, or --spp)",
            samples.start,
            samples.end,
            settings.spp,
            scene_path.display()
        )));
    }
    let region = Region { rect, samples: samples.clone() };
    report.seed = Some(settings.seed);
    report.max_depth = Some(settings.max_depth);
    report.resolution = Some([width, height]);
    report.tile = args.tile.map(|(i, n)| format!("{i}/{n}"));
    report.rect = Some([rect.x0, rect.y0, rect.x1, rect.y1]);
    report.samples = Some([samples.start, samples.end]);
    // The film's sums, the tiles' and the image written: about three times a pixel's sums.
    let film_bytes = rect.pixel_count() as f64 * 3.0 * size_of::<arbor::render::film::PixelAccum>() as f64;
    arbor::memory::check_fits(&format!("{resolution}: the image"), film_bytes)?;
    // Fail on a bad output name before spending time rendering.
    check_output_path(&args.output)?;
    if split && !args.output.to_string_lossy().to_ascii_lowercase().ends_with(".exr") {
        return Err(bad(format!(
            "-o {}: a split render (--tile, --crop or --samples) writes a partial film, an EXR: name it .exr",
            args.output.display()
        )));
    }
    let frames: Option<Range<u32>> = match (&args.frames, args.frame) {
        (Some(r), _) => Some(r.clone()),
        (None, Some(n)) => Some(n..n + 1),
        (None, None) if has_frame_pattern(&args.output) => {
            Some(scene.animation.as_ref().map_or(0..1, |a| a.frames.clone()))
        }
        (None, None) => None,
    };
    // Fail on an output that cannot be written before spending time rendering: the first frame's
    // file is tried (in the nearest folder that exists), and a name with two frame patterns, of
    // which only the first would be replaced, is refused.
    let first = frames.as_ref().map_or_else(|| args.output.clone(), |r| frame_path(&args.output, r.start));
    if frames.is_some() && has_frame_pattern(&first) {
        return Err(bad(format!("-o {}: more than one frame pattern (%d or %0Nd) in the name", args.output.display())));
    }
    arbor::atomic_file::prepare(&first).with_context(|| format!("cannot write {}", first.display()))?;
    if frames.as_ref().is_some_and(|f| f.len() > 1) && !has_frame_pattern(&args.output) {
        return Err(bad(format!(
            "{} frames would all go to {}: put a frame pattern such as %04d in the output name",
            frames.as_ref().map_or(0, |f| f.len()),
            args.output.display()
        )));
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
    // What each output's partial film says of itself.
    let piece_info = |frame: Option<u32>| PieceInfo {
        scene_hash: scene_hash.clone(),
        seed: settings.seed,
        max_depth: settings.max_depth,
        clamp: settings.clamp,
        width,
        height,
        frame,
        device: device.name().to_owned(),
        rect,
        samples: samples.clone(),
        done: samples.start,
        rays: 0,
        seconds: 0.0,
    };
    // A frame range moves the scene to each frame (its BVH update is reported); a still renders
    // the scene as built, at its first frame.
    let moves = frames.is_some();
    let all: Vec<(PathBuf, f32, Option<u32>)> = match frames {
        None => vec![(args.output.clone(), arbor::render::first_frame_time(&scene), None)],
        Some(frames) => frames.map(|f| (frame_path(&args.output, f), scene.frame_time(f), Some(f))).collect(),
    };
    // Outputs already complete are skipped (--skip-existing); states are read (--resume).
    let mut outputs = Vec::new();
    for (path, time, frame) in all {
        let expected = piece_info(frame);
        let state = if split { path.clone() } else { sidecar(&path) };
        if args.skip_existing && is_complete(&path, split, &expected) {
            if !args.quiet {
                outln!("{}: complete, skipped (--skip-existing)", path.display());
            }
            let held = [samples.start, samples.end];
            report.frames.push(FrameReport {
                frame,
                output: path,
                status: "skipped",
                samples_done: held,
                bvh_update_ms: None,
                render_seconds: 0.0,
                rays: 0,
            });
            continue;
        }
        let carried = if args.resume { resumable(&state, &expected, split)? } else { None };
        outputs.push(Output { path, time, frame, state, carried });
    }
    if outputs.is_empty() {
        return Ok(());
    }
    // The GPU renders every scene flat; the CPU all but animated and heavily instanced ones.
    if device.name() == "gpu" || !wants_instancing(&scene) {
        let binary = device.name() == "gpu" || Tracing::current().layout == TraceLayout::Binary;
        scene.check_flat_fits(scene_path, arbor::memory::render_bytes_per_triangle(binary))?;
    }
    let builder = named.unwrap_or_else(|| BuilderChoice::default_for(device, &scene));
    let mut renderer = Renderer::new(device, &scene, &builder, &settings, outputs.len(), outputs[0].time)?;
    let build = renderer.build_report();
    report.bvh = Some(BvhReport {
        builder: build.builder.clone(),
        triangles: build.triangles,
        build_ms: build.build_ms,
        sah: build.sah,
    });
    if !args.quiet {
        print_build(scene_path, build, device.name() == "cpu", scene.texture_bytes());
        if let Some(note) = renderer.kernel_note() {
            outln!("{note}");
        }
    }
    for output in outputs {
        let update_ms = if moves { renderer.set_time(&scene, output.time)? } else { None };
        renderer.begin_frame();
        let resumed = output.carried.is_some();
        let carried = output.carried.map(|p| RenderedFrame {
            samples: p.info.done - p.info.samples.start,
            rays: p.info.rays,
            seconds: p.info.seconds,
            film: p.film,
            timed_seconds: 0.0,
        });
        let before = carried.as_ref().map_or((0, 0.0), |f| (f.rays, f.seconds));
        let bar = progress_bar(!args.quiet && std::io::stderr().is_terminal(), u64::from(region.samples.len() as u32));
        let progress = |p: Progress| {
            bar.set_length(p.total);
            bar.set_position(p.done);
            if p.rays > 0 {
                let secs = bar.elapsed().as_secs_f64().max(1e-9);
                bar.set_message(format!("{:.1} Mrays/s", p.rays as f64 / secs / 1e6));
            }
        };
        let info = piece_info(output.frame);
        let frame = render_output(
            &mut renderer,
            &region,
            carried,
            &settings,
            &progress,
            args.checkpoint,
            stop,
            &info,
            &output.state,
        );
        bar.finish_and_clear();
        let frame = frame.inspect_err(|e| {
            if let Some(i) = e.downcast_ref::<Interrupted>() {
                report.frames.push(FrameReport {
                    frame: output.frame,
                    output: output.path.clone(),
                    status: "interrupted",
                    samples_done: [samples.start, i.done],
                    bvh_update_ms: update_ms,
                    render_seconds: 0.0,
                    rays: 0,
                });
            }
        })?;
        let done = samples.start + frame.samples;
        report.frames.push(FrameReport {
            frame: output.frame,
            output: output.path.clone(),
            status: if resumed { "resumed" } else { "rendered" },
            samples_done: [samples.start, done],
            bvh_update_ms: update_ms,
            render_seconds: frame.seconds - before.1,
            rays: frame.rays - before.0,
        });
        if split {
            write_piece(&output.path, &held(&info, &frame), &frame.film)?;
        } else {
            // Missing folders are made by the write (each frame's, where the pattern names folders).
            write_image(&output.path, &frame.film.mean())?;
            match std::fs::remove_file(&output.state) {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                    return Err(e).with_context(|| format!("cannot remove {}", output.state.display()));
                }
                _ => {}
            }
        }
        if !args.quiet {
            print_frame(&renderer, &output.path, update_ms, &frame);
        }
    }
    if let Some(r) = renderer.refine_report().filter(|_| !args.quiet) {
        outln!("{r}");
    }
    Ok(())
}

/// Renders one output's region, carrying on from `carried`. Every `checkpoint` seconds, and
/// when a signal raises `stop`, the render pauses after its pass and its state goes to `state`
/// (a partial film, written atomically); after a signal, the render ends there with
/// [`Interrupted`].
#[allow(clippy::too_many_arguments)]
fn render_output(
    renderer: &mut Renderer,
    region: &Region,
    mut carried: Option<RenderedFrame>,
    settings: &RenderSettings,
    progress: &(dyn Fn(Progress) + Sync),
    checkpoint: Option<f64>,
    stop: &AtomicBool,
    info: &PieceInfo,
    state: &Path,
) -> Result<RenderedFrame> {
    let wanted = region.samples.len() as u32;
    loop {
        let since = Instant::now();
        let pause = |_| job::stopped(stop) || checkpoint.is_some_and(|c| since.elapsed().as_secs_f64() >= c);
        let frame = renderer.render_region(region, carried.take(), settings, progress, &pause)?;
        let out_of_time = settings.time.is_some_and(|t| frame.seconds >= t);
        if frame.samples == wanted || out_of_time {
            return Ok(frame);
        }
        write_piece(state, &held(info, &frame), &frame.film)?;
        if job::stopped(stop) {
            let done = region.samples.start + frame.samples;
            return Err(Interrupted { state: state.to_path_buf(), done, of: region.samples.end }.into());
        }
        carried = Some(frame);
    }
}

/// What the partial film of `frame`, a render of the piece `info` describes, holds.
fn held(info: &PieceInfo, frame: &RenderedFrame) -> PieceInfo {
    PieceInfo { done: info.samples.start + frame.samples, rays: frame.rays, seconds: frame.seconds, ..info.clone() }
}

/// Where a whole render keeps its state: `OUT.partial.exr`.
fn sidecar(output: &Path) -> PathBuf {
    let mut name = output.as_os_str().to_owned();
    name.push(".partial.exr");
    PathBuf::from(name)
}

/// Whether `path` already holds this output, complete: for a partial film, a piece of this very
/// render with all its samples; for an image, any file (images are written whole, atomically).
fn is_complete(path: &Path, split: bool, expected: &PieceInfo) -> bool {
    if !split {
        return path.is_file();
    }
    matches!(read_info(path), Ok(Some(info)) if info.same_piece(expected) && info.is_complete())
}

/// The state to carry on from at `state` (`--resume`): `None` where there is none; an error
/// where it belongs to another render, or (for a partial film) is already complete.
fn resumable(state: &Path, expected: &PieceInfo, split: bool) -> Result<Option<FilmPiece>> {
    if !state.exists() {
        return Ok(None);
    }
    let piece = read_piece(state)?;
    if !piece.info.same_piece(expected) {
        let why = match expected.differs_from(&piece.info) {
            Some((what, ours, theirs)) => format!("its {what} is {theirs}, this render's {ours}"),
            None => format!(
                "it holds pixels {} and samples {:?}, this render {} and {:?}",
                piece.info.rect, piece.info.samples, expected.rect, expected.samples
            ),
        };
        return Err(bad(format!("--resume: {} is a piece of another render: {why}", state.display())));
    }
    if split && piece.info.is_complete() {
        return Err(bad(format!(
            "--resume: {} is finished (samples {}..{}): nothing to resume; --skip-existing skips finished outputs",
            state.display(),
            piece.info.samples.start,
            piece.info.samples.end
        )));
    }
    Ok(Some(piece))
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
            dropped(&film),
        );
    }
    Ok(())
}

fn print_build(scene: &Path, build: &BuildReport, cpu: bool, texture_bytes: usize) {
    // What the CPU traces; a GPU render traces its own copy of the binary tree.
    let traced = if cpu && build.tracing.layout != TraceLayout::Binary {
        format!(", traced as a {} (collapse {:.1} ms, SAH {:.2})", build.tracing, build.collapse_ms, build.traced_sah)
    } else if cpu {
        format!(", traced as a {}", build.tracing)
    } else {
        String::new()
    };
    let textures = match texture_bytes {
        0 => String::new(),
        b => format!(", textures {:.1} MB", b as f64 / 1e6),
    };
    outln!(
        "{}: {} triangles, BVH ({}) {:.1} ms, SAH {:.2}{}{}{}",
        scene.display(),
        build.triangles,
        build.builder,
        build.build_ms,
        build.sah,
        traced,
        textures,
        peak_memory(build.triangles),
    );
}

fn parse_trace(name: &str) -> Result<TraceLayout, String> {
    TraceLayout::parse(name).ok_or_else(|| format!("{name:?} is not a tree form: expected binary, wide4 or wide8"))
}

/// Prints a frame's summary line.
fn print_frame(renderer: &Renderer, output: &Path, update_ms: Option<f64>, frame: &RenderedFrame) {
    let triangles = renderer.render_scene().geometry.world_triangle_count();
    outln!(
        "{}: {}render {:.2} s, {:.2} Mrays/s, {} spp{}{}",
        output.display(),
        update_ms.map_or(String::new(), |ms| format!("BVH update {ms:.2} ms, ")),
        frame.seconds,
        frame.rays as f64 / frame.seconds.max(1e-9) / 1e6,
        frame.samples,
        dropped(&frame.film),
        peak_memory(triangles),
    );
}

/// `, N non-finite samples dropped` where the film dropped any.
fn dropped(film: &arbor::render::film::Film) -> String {
    match film.non_finite_count() {
        0 => String::new(),
        n => format!(", {n} non-finite samples dropped"),
    }
}

/// `, peak memory M MB (B bytes per triangle)` where the system reports it.
fn peak_memory(triangles: usize) -> String {
    match arbor::memory::peak_rss_bytes() {
        Some(b) if triangles < 100_000 => format!(", peak memory {:.1} MB", b as f64 / 1e6),
        Some(b) => {
            let per = b as f64 / triangles.max(1) as f64;
            // Instancing can put far more triangles in the world than bytes in memory.
            let per = if per >= 10.0 { format!("{per:.0}") } else { format!("{per:.2}") };
            format!(", peak memory {:.1} MB ({per} bytes per triangle)", b as f64 / 1e6)
        }
        None => String::new(),
    }
}

/// `A..B` with `A < B`.
fn parse_frames(s: &str) -> Result<Range<u32>, String> {
    let (a, b) = s.split_once("..").ok_or_else(|| format!("expected FIRST..END, as 0..120, not {s:?}"))?;
    let a: u32 = a.trim().parse().map_err(|e| format!("first frame {a:?}: {e}"))?;
    let b: u32 = b.trim().parse().map_err(|e| format!("end frame {b:?}: {e}"))?;
    if b <= a {
        return Err(format!("{s}: the end ({b}) must be after the first frame ({a})"));
    }
    Ok(a..b)
}

/// `I/N` with `I < N`.
fn parse_tile(s: &str) -> Result<(u32, u32), String> {
    let (i, n) = s.split_once('/').ok_or_else(|| format!("expected I/N, as 0/4, not {s:?}"))?;
    let i: u32 = i.trim().parse().map_err(|e| format!("tile {i:?}: {e}"))?;
    let n: u32 = n.trim().parse().map_err(|e| format!("tile count {n:?}: {e}"))?;
    if n == 0 || i >= n {
        return Err(format!("{s}: the tile number must be below the tile count (tiles count from 0)"));
    }
    Ok((i, n))
}

fn parse_crop(s: &str) -> Result<Rect, String> {
    parse_rect(s).ok_or_else(|| format!("expected X0,Y0,X1,Y1 with X0 < X1 and Y0 < Y1, as 0,0,256,128, not {s:?}"))
}

/// `A..B` with `A < B`.
fn parse_samples(s: &str) -> Result<Range<u32>, String> {
    let (a, b) = s.split_once("..").ok_or_else(|| format!("expected FIRST..END, as 0..64, not {s:?}"))?;
    let a: u32 = a.trim().parse().map_err(|e| format!("first sample {a:?}: {e}"))?;
    let b: u32 = b.trim().parse().map_err(|e| format!("end sample {b:?}: {e}"))?;
    if b <= a {
        return Err(format!("{s}: the end ({b}) must be after the first sample ({a})"));
    }
    Ok(a..b)
}

fn progress_bar(show: bool, rows: u64) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(rows);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {percent:>3}% eta {eta} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar
}
