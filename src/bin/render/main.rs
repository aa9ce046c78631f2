//! `render`: renders a scene file to an image.
//!
//! Argument parsing and reporting only; the work is `arbor::scene` and `arbor::device`.

#[path = "../cli/mod.rs"]
mod cli;
mod frames;

use std::io::IsTerminal;
use std::ops::Range;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use arbor::bvh::{TraceLayout, Tracing};
use arbor::device::{BuilderChoice, DeviceChoice, Progress, RenderedFrame, Renderer};
use arbor::image_io::{check_output_path, write_image};
use arbor::render::BuildReport;
use arbor::render::geometry::wants_instancing;
use arbor::scene::{RenderSettings, Scene};
use clap::{Parser, ValueEnum};
use cli::outln;
use frames::{frame_path, has_frame_pattern};
use indicatif::{ProgressBar, ProgressStyle};

/// Render a scene (TOML) to a linear EXR image, or an 8-bit sRGB PNG when OUT ends in .png.
///
/// Animated scenes: `--frames 0..120 -o out_%04d.exr` renders a sequence (`%04d` becomes the
/// frame number), `--frame N` one frame. Without either, an output name with a frame pattern
/// renders the scene's whole frame range, and one without renders its first frame.
#[derive(Parser, Debug)]
#[command(name = "render", version, allow_negative_numbers = true)]
struct Args {
    /// The scene file (see docs/scene-format.md).
    scene: PathBuf,
    /// Output image: .exr (linear float RGB) or .png (8-bit sRGB); `%04d` (or `%d`, `%0Nd`) in
    /// the name becomes the frame number.
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
    if let Err(e) = run() {
        eprintln!("render: error: {e:#}");
        std::process::exit(1);
    }
    if let Some(e) = cli::stdout_error() {
        eprintln!("render: error: writing to standard output: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<()> {
    let args = Args::parse();
    // A bad name fails before any work; the default depends on the device and the scene.
    let named: Option<BuilderChoice> =
        args.builder.as_deref().map(str::parse).transpose().context("--builder (or auto)")?;
    cli::init_threads(args.threads)?;
    // Before any tree is built: meshes take the form current when they are built.
    Tracing::from_env(args.trace)?.set_default();
    let scene = Scene::load(&args.scene)?;
    // The film's sums, the tiles' and the image written: about three times a pixel's sums.
    let pixels = f64::from(scene.camera.width) * f64::from(scene.camera.height);
    let film_bytes = pixels * 3.0 * std::mem::size_of::<arbor::render::film::PixelAccum>() as f64;
    let what = format!(
        "{}:{}: camera.resolution {}x{}: the image",
        args.scene.display(),
        scene.camera.resolution_line,
        scene.camera.width,
        scene.camera.height
    );
    arbor::memory::check_fits(&what, film_bytes)?;
    let settings = RenderSettings {
        spp: args.spp.unwrap_or(scene.render.spp),
        max_depth: args.max_depth.unwrap_or(scene.render.max_depth),
        seed: args.seed.unwrap_or(scene.render.seed),
        time: args.time.or(scene.render.time),
        clamp: args.clamp,
    };
    if settings.spp == 0 || settings.max_depth == 0 {
        bail!("--spp and --max-depth must be at least 1");
    }
    if settings.clamp.is_some_and(|c| !(c.is_finite() && c > 0.0)) {
        bail!("--clamp must be a radiance > 0");
    }
    if settings.time.is_some_and(|t| !(t.is_finite() && t > 0.0)) {
        bail!("--time must be a number of seconds > 0");
    }
    // Fail on a bad output name before spending time rendering.
    check_output_path(&args.output)?;
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
        bail!("-o {}: more than one frame pattern (%d or %0Nd) in the name", args.output.display());
    }
    arbor::atomic_file::prepare(&first).with_context(|| format!("cannot write {}", first.display()))?;
    if frames.as_ref().is_some_and(|f| f.len() > 1) && !has_frame_pattern(&args.output) {
        bail!(
            "{} frames would all go to {}: put a frame pattern such as %04d in the output name",
            frames.as_ref().map_or(0, |f| f.len()),
            args.output.display()
        );
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
    // The GPU renders every scene flat; the CPU all but animated and heavily instanced ones.
    if device.name() == "gpu" || !wants_instancing(&scene) {
        let binary = device.name() == "gpu" || Tracing::current().layout == TraceLayout::Binary;
        scene.check_flat_fits(&args.scene, arbor::memory::render_bytes_per_triangle(binary))?;
    }
    // A frame range moves the scene to each frame (its BVH update is reported); a still renders
    // the scene as built, at its first frame.
    let moves = frames.is_some();
    // (output, scene time) of every frame.
    let list: Vec<(PathBuf, f32)> = match frames {
        None => vec![(args.output.clone(), arbor::render::first_frame_time(&scene))],
        Some(frames) => frames.map(|f| (frame_path(&args.output, f), scene.frame_time(f))).collect(),
    };
    let builder = named.unwrap_or_else(|| BuilderChoice::default_for(device, &scene));
    let mut renderer = Renderer::new(device, &scene, &builder, &settings, list.len(), list[0].1)?;
    if !args.quiet {
        print_build(&args.scene, renderer.build_report(), device.name() == "cpu");
        if let Some(note) = renderer.kernel_note() {
            outln!("{note}");
        }
    }
    for (output, time) in &list {
        let update_ms = if moves { renderer.set_time(&scene, *time)? } else { None };
        let bar = progress_bar(!args.quiet && std::io::stderr().is_terminal(), u64::from(settings.spp));
        let frame = renderer.render(&settings, &|p: Progress| {
            bar.set_length(p.total);
            bar.set_position(p.done);
            if p.rays > 0 {
                let secs = bar.elapsed().as_secs_f64().max(1e-9);
                bar.set_message(format!("{:.1} Mrays/s", p.rays as f64 / secs / 1e6));
            }
        })?;
        bar.finish_and_clear();
        finish_frame(&renderer, args.quiet, output, update_ms, &frame)?;
    }
    if let Some(r) = renderer.refine_report().filter(|_| !args.quiet) {
        outln!("{r}");
    }
    Ok(())
}

fn print_build(scene: &Path, build: &BuildReport, cpu: bool) {
    // What the CPU traces; a GPU render traces its own copy of the binary tree.
    let traced = if cpu && build.tracing.layout != TraceLayout::Binary {
        format!(", traced as a {} (collapse {:.1} ms, SAH {:.2})", build.tracing, build.collapse_ms, build.traced_sah)
    } else if cpu {
        format!(", traced as a {}", build.tracing)
    } else {
        String::new()
    };
    outln!(
        "{}: {} triangles, BVH ({}) {:.1} ms, SAH {:.2}{}{}",
        scene.display(),
        build.triangles,
        build.builder,
        build.build_ms,
        build.sah,
        traced,
        peak_memory(build.triangles),
    );
}

fn parse_trace(name: &str) -> Result<TraceLayout, String> {
    TraceLayout::parse(name).ok_or_else(|| format!("{name:?} is not a tree form: expected binary, wide4 or wide8"))
}

/// Writes the image and prints the frame's summary line.
fn finish_frame(
    renderer: &Renderer,
    quiet: bool,
    output: &Path,
    update_ms: Option<f64>,
    frame: &RenderedFrame,
) -> Result<()> {
    // Missing folders are made by the write (each frame's, where the pattern names folders).
    write_image(output, &frame.film.mean())?;
    if !quiet {
        let triangles = renderer.render_scene().geometry.world_triangle_count();
        outln!(
            "{}: {}render {:.2} s, {:.2} Mrays/s, {} spp{}{}",
            output.display(),
            update_ms.map_or(String::new(), |ms| format!("BVH update {ms:.2} ms, ")),
            frame.seconds,
            frame.rays as f64 / frame.seconds.max(1e-9) / 1e6,
            frame.samples,
            match frame.film.non_finite_count() {
                0 => String::new(),
                n => format!(", {n} non-finite samples dropped"),
            },
            peak_memory(triangles),
        );
    }
    Ok(())
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
