//! `render`: renders a scene file to an image.
//!
//! Argument parsing and reporting only; the work is `arbor::scene` and `arbor::render`.

use std::io::IsTerminal;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use arbor::bvh::builders::Builder;
use arbor::bvh::instances::TopLevelUpdate;
use arbor::gpu::trace::{self, GpuScene, flatten};
use arbor::gpu::{AdapterPolicy, GpuContext};
use arbor::image_io::{check_output_path, frame_path, has_frame_pattern, write_image};
use arbor::render::film::Film;
use arbor::render::geometry::wants_instancing;
use arbor::render::integrator::first_frame_time;
use arbor::render::{AutoRender, BuildReport, RenderScene};
use arbor::scene::Scene;
use clap::{Parser, ValueEnum};
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
    /// BVH builder: auto, or a name bvh-bench takes (lbvh, lbvh+prbvh, binned-sah, ...). `auto`
    /// optimises the LBVH only while that pays for itself in this render's estimated time.
    /// Default lbvh+prbvh; but on the GPU an animated or instanced scene is rebuilt flat every
    /// frame, with lbvh unless a builder other than auto is given.
    #[arg(long)]
    builder: Option<String>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
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
    unsafe { arbor::gpu::quiet_device_select_layer() };
    if let Err(e) = run() {
        eprintln!("render: error: {e:#}");
        std::process::exit(1);
    }
    if let Some(e) = arbor::stdout_error() {
        eprintln!("render: error: writing to standard output: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<()> {
    let args = Args::parse();
    let builder_name = args.builder.as_deref().unwrap_or("lbvh+prbvh");
    let builder: Option<Builder> =
        if builder_name == "auto" { None } else { Some(builder_name.parse().context("--builder (or auto)")?) };
    arbor::init_threads(args.threads).map_err(anyhow::Error::msg)?;
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
    arbor::memory::check_fits(&what, film_bytes).map_err(anyhow::Error::msg)?;
    let spp = args.spp.unwrap_or(scene.render.spp);
    let max_depth = args.max_depth.unwrap_or(scene.render.max_depth);
    let seed = args.seed.unwrap_or(scene.render.seed);
    let time = args.time.or(scene.render.time_seconds);
    if spp == 0 || max_depth == 0 {
        bail!("--spp and --max-depth must be at least 1");
    }
    if args.clamp.is_some_and(|c| !(c.is_finite() && c > 0.0)) {
        bail!("--clamp must be a radiance > 0");
    }
    if time.is_some_and(|t| !(t.is_finite() && t > 0.0)) {
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

    let settings = FrameSettings { spp, max_depth, seed, time, quiet: args.quiet };
    let gpu = gpu_context(args.device, args.quiet)?;
    // The GPU renders every scene flat; the CPU all but animated and heavily instanced ones.
    if gpu.is_some() || !wants_instancing(&scene) {
        scene.check_flat_fits(&args.scene, arbor::memory::RENDER_BYTES_PER_TRIANGLE).map_err(anyhow::Error::msg)?;
    }
    if let Some(ctx) = gpu {
        return run_gpu(ctx, &scene, &args, builder.as_ref(), &settings, frames);
    }
    let (mut render_scene, build) = match &builder {
        Some(b) => RenderScene::build(&scene, b),
        None => {
            let frame_count = frames.as_ref().map_or(1, |f| f.len());
            RenderScene::build_auto_cpu(&scene, &AutoRender { spp, max_depth, frames: frame_count, seed, time })
        }
    };
    render_scene.sample_clamp = args.clamp;
    if !args.quiet {
        print_build(&args.scene, &build);
    }
    let update = TopLevelUpdate::Dynamic(Default::default());
    match frames {
        None => render_frame(&render_scene, &settings, &args.output, None)?,
        Some(frames) => {
            for f in frames {
                let t = Instant::now();
                let stats = render_scene.set_time(&scene, scene.frame_time(f), &update);
                let update_ms = stats.map(|_| t.elapsed().as_secs_f64() * 1e3);
                render_frame(&render_scene, &settings, &frame_path(&args.output, f), update_ms)?;
            }
        }
    }
    Ok(())
}

/// `--device`: the GPU context to render with, or `None` for the CPU. `gpu` takes any adapter,
/// software ones included; `auto` only a hardware GPU, and otherwise falls back to the CPU (a
/// software GPU is slower than the CPU path).
fn gpu_context(device: Device, quiet: bool) -> Result<Option<&'static GpuContext>> {
    let ctx = match device {
        Device::Cpu => return Ok(None),
        Device::Gpu => GpuContext::shared().context("--device gpu")?,
        Device::Auto => match GpuContext::new(AdapterPolicy::HardwareOnly) {
            // One context for the process's lifetime.
            Ok(ctx) => Box::leak(Box::new(ctx)),
            Err(e) => {
                if !quiet {
                    arbor::outln!("no hardware GPU ({e}): rendering on the CPU");
                }
                return Ok(None);
            }
        },
    };
    if !quiet {
        arbor::outln!("GPU: {}", ctx.describe());
    }
    Ok(Some(ctx))
}

fn print_build(scene: &Path, build: &BuildReport) {
    arbor::outln!(
        "{}: {} triangles, BVH ({}) {:.1} ms, SAH {:.2}{}",
        scene.display(),
        build.triangles,
        build.builder,
        build.build_ms,
        build.sah,
        peak_memory(build.triangles),
    );
}

/// The GPU path (`arbor::gpu::trace`). A static scene is built as for the CPU and uploaded
/// once; an animated or instanced one is flattened to one BVH per frame (the GPU traces flat
/// scenes only), reported as that frame's BVH update.
fn run_gpu(
    ctx: &GpuContext,
    scene: &Scene,
    args: &Args,
    builder: Option<&Builder>,
    settings: &FrameSettings,
    frames: Option<Range<u32>>,
) -> Result<()> {
    let upload = |rs: &mut RenderScene, report: bool| -> Result<GpuScene> {
        rs.sample_clamp = args.clamp;
        let gpu_scene = GpuScene::upload(ctx, rs).context("uploading the scene to the GPU")?;
        let t = Instant::now();
        trace::compile(ctx, &gpu_scene).context("compiling the GPU kernel")?;
        if report && !args.quiet {
            arbor::outln!(
                "GPU kernel {} ready in {:.2} s, BVH depth {}",
                gpu_scene.features.key(),
                t.elapsed().as_secs_f64(),
                gpu_scene.depth
            );
        }
        Ok(gpu_scene)
    };
    if !wants_instancing(scene) {
        // `lbvh` and `lbvh+prbvh` build on the GPU itself; other builders on the CPU.
        let on_gpu = builder.and_then(|b| {
            let name = b.to_string();
            (name == "lbvh" || name == "lbvh+prbvh").then_some(name == "lbvh+prbvh")
        });
        let built_on_gpu = match on_gpu {
            Some(optimize) => {
                arbor::gpu::build_render_scene(ctx, scene, optimize).context("building the BVH on the GPU")?
            }
            None => None,
        };
        // `auto`'s timed samples, which the first frame carries on.
        let mut timed = None;
        let (mut rs, build) = match (built_on_gpu, builder) {
            (Some(built), _) => built,
            (None, Some(b)) => RenderScene::build(scene, b),
            (None, None) => {
                let frame_count = frames.as_ref().map_or(1, |f| f.len());
                let job = AutoRender {
                    spp: settings.spp,
                    max_depth: settings.max_depth,
                    frames: frame_count,
                    seed: settings.seed,
                    time: settings.time,
                };
                let (rs, report, partial) = trace::build_auto(ctx, scene, &job, args.clamp);
                timed = partial;
                (rs, report)
            }
        };
        if !args.quiet {
            print_build(&args.scene, &build);
        }
        let gpu_scene = upload(&mut rs, true)?;
        match frames {
            None => render_frame_gpu(ctx, &gpu_scene, &rs, settings, &args.output, None, timed)?,
            Some(frames) => {
                for f in frames {
                    let output = frame_path(&args.output, f);
                    render_frame_gpu(ctx, &gpu_scene, &rs, settings, &output, None, timed.take())?;
                }
            }
        }
        return Ok(());
    }
    // A rebuild every frame: LBVH alone unless the user named a builder (PRBVH over the 1.7
    // million triangles of instanced-field.toml takes a minute on two cores; `auto` has no
    // model for per-frame builds).
    let lbvh: Builder = "lbvh".parse().expect("a builder name");
    let builder = builder.filter(|_| args.builder.is_some()).unwrap_or(&lbvh);
    let list: Vec<(Option<u32>, f32)> = match frames {
        None => vec![(None, first_frame_time(scene))],
        Some(frames) => frames.map(|f| (Some(f), scene.frame_time(f))).collect(),
    };
    for (k, (frame, time)) in list.into_iter().enumerate() {
        let (mut rs, build) = flatten(scene, time, builder);
        if !args.quiet && k == 0 {
            print_build(&args.scene, &build);
        }
        let gpu_scene = upload(&mut rs, k == 0)?;
        let output = frame.map_or_else(|| args.output.clone(), |f| frame_path(&args.output, f));
        let update_ms = (k > 0).then_some(build.build_ms);
        render_frame_gpu(ctx, &gpu_scene, &rs, settings, &output, update_ms, None)?;
    }
    Ok(())
}

/// Renders `gpu_scene` to `output` on the GPU, in passes of `trace::PASS_SPP` samples,
/// carrying on from `timed` (the samples `auto` timed) where given. The render's time includes
/// the device's time for those samples, as its ray count does.
fn render_frame_gpu(
    ctx: &GpuContext,
    gpu_scene: &GpuScene,
    rs: &RenderScene,
    s: &FrameSettings,
    output: &Path,
    update_ms: Option<f64>,
    timed: Option<trace::PartialFilm>,
) -> Result<()> {
    let bar = progress_bar(!s.quiet && std::io::stderr().is_terminal(), s.spp as u64);
    let start = Instant::now();
    let budget = s.time.map(Duration::from_secs_f64);
    let before = timed.as_ref().map_or(Duration::ZERO, |t| Duration::from_secs_f64(t.seconds()));
    let out = trace::render_from(ctx, gpu_scene, s.seed, s.max_depth, s.spp, timed, &mut |done| {
        bar.set_position(done as u64);
        budget.is_none_or(|b| before + start.elapsed() < b)
    })
    .context("rendering on the GPU")?;
    bar.finish_and_clear();
    let render_secs = out.carried.1 + start.elapsed().as_secs_f64();
    finish_frame(rs, s, output, update_ms, &out.film, out.rays as f64, render_secs, out.samples)
}

struct FrameSettings {
    spp: u32,
    max_depth: u32,
    seed: u64,
    time: Option<f64>,
    quiet: bool,
}

/// Renders the scene as it stands to `output`.
fn render_frame(render_scene: &RenderScene, s: &FrameSettings, output: &Path, update_ms: Option<f64>) -> Result<()> {
    let mut film = Film::new(render_scene.width, render_scene.height);
    let show_progress = !s.quiet && std::io::stderr().is_terminal();
    let bar = progress_bar(show_progress, s.spp as u64 * render_scene.height as u64);
    let rays = AtomicU64::new(0);
    let start = Instant::now();
    // Passes of a few samples each, so that a time budget can stop between passes and the
    // progress bar moves even when one pixel's samples take long (a row reports when it has
    // done the pass). The image depends only on the samples taken, not on where passes fall.
    let pass = if s.time.is_some() { 4 } else { 16 }.min(s.spp);
    let mut done = 0;
    while done < s.spp {
        let n = pass.min(s.spp - done);
        render_scene.render(&mut film, s.seed, s.max_depth, done..done + n, &|r| {
            let total = rays.fetch_add(r, Ordering::Relaxed) + r;
            bar.inc(n as u64);
            let secs = start.elapsed().as_secs_f64().max(1e-9);
            bar.set_message(format!("{:.1} Mrays/s", total as f64 / secs / 1e6));
        });
        done += n;
        if s.time.is_some_and(|t| start.elapsed() >= Duration::from_secs_f64(t)) {
            break;
        }
    }
    bar.finish_and_clear();
    let render_secs = start.elapsed().as_secs_f64();
    finish_frame(render_scene, s, output, update_ms, &film, rays.load(Ordering::Relaxed) as f64, render_secs, done)
}

/// Writes the image and prints the frame's summary line.
#[allow(clippy::too_many_arguments)]
fn finish_frame(
    render_scene: &RenderScene,
    s: &FrameSettings,
    output: &Path,
    update_ms: Option<f64>,
    film: &Film,
    rays: f64,
    render_secs: f64,
    done: u32,
) -> Result<()> {
    // Missing folders are made by the write (each frame's, where the pattern names folders).
    write_image(output, &film.mean())?;
    if !s.quiet {
        arbor::outln!(
            "{}: {}render {:.2} s, {:.2} Mrays/s, {done} spp{}{}",
            output.display(),
            update_ms.map_or(String::new(), |ms| format!("BVH update {ms:.2} ms, ")),
            render_secs,
            rays / render_secs.max(1e-9) / 1e6,
            match film.non_finite_count() {
                0 => String::new(),
                n => format!(", {n} non-finite samples dropped"),
            },
            peak_memory(render_scene.geometry.world_triangle_count()),
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
