//! `render`: renders a scene file to an image.
//!
//! Argument parsing and reporting only; the work is `arbor::scene` and `arbor::render`.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use arbor::bvh::builders::Builder;
use arbor::image_io::{check_output_path, write_image};
use arbor::render::RenderScene;
use arbor::render::film::Film;
use arbor::scene::Scene;
use clap::{Parser, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};

/// Render a scene (TOML) to a linear EXR image, or an 8-bit sRGB PNG when OUT ends in .png.
#[derive(Parser, Debug)]
#[command(name = "render", version, allow_negative_numbers = true)]
struct Args {
    /// The scene file (see docs/scene-format.md).
    scene: PathBuf,
    /// Output image: .exr (linear float RGB) or .png (8-bit sRGB).
    #[arg(short, long)]
    output: PathBuf,
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
    #[arg(long, default_value = "lbvh+prbvh")]
    builder: String,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
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
    if let Err(e) = run() {
        eprintln!("render: error: {e:#}");
        std::process::exit(1);
    }
}

fn run() -> Result<()> {
    let args = Args::parse();
    if args.device == Device::Gpu {
        bail!("--device gpu: GPU rendering is not built yet; use --device cpu");
    }
    let builder: Option<Builder> =
        if args.builder == "auto" { None } else { Some(args.builder.parse().context("--builder")?) };
    if let Some(n) = args.threads {
        if n == 0 {
            bail!("--threads must be at least 1");
        }
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global().context("--threads")?;
    }
    let scene = Scene::load(&args.scene)?;
    let spp = args.spp.unwrap_or(scene.render.spp);
    let max_depth = args.max_depth.unwrap_or(scene.render.max_depth);
    let seed = args.seed.unwrap_or(scene.render.seed);
    let time = args.time.or(scene.render.time_seconds);
    if spp == 0 || max_depth == 0 {
        bail!("--spp and --max-depth must be at least 1");
    }
    if time.is_some_and(|t| !(t.is_finite() && t > 0.0)) {
        bail!("--time must be a number of seconds > 0");
    }
    // Fail on a bad output name before spending time rendering.
    check_output_path(&args.output)?;

    let (render_scene, build) = match &builder {
        Some(b) => RenderScene::build(&scene, b),
        None => {
            // Rays of the whole render: each path segment traces one ray, plus a shadow ray when
            // the scene has emitters; paths rarely run past five segments (Russian roulette).
            let per_path = max_depth.min(5) as f64 * if scene.has_emitters() { 2.0 } else { 1.0 };
            let pixels = scene.camera.width as f64 * scene.camera.height as f64;
            RenderScene::build_auto(&scene, pixels * spp as f64 * per_path)
        }
    };
    let mut film = Film::new(render_scene.width, render_scene.height);
    let show_progress = !args.quiet && std::io::stderr().is_terminal();
    let bar = progress_bar(show_progress, spp as u64 * render_scene.height as u64);
    let rays = AtomicU64::new(0);
    let start = Instant::now();
    // Passes of a few samples each, so that a time budget can stop between passes; the image
    // depends only on the samples taken, not on where the passes fall.
    let pass = if time.is_some() { 4.min(spp) } else { spp };
    let mut done = 0;
    while done < spp {
        let n = pass.min(spp - done);
        render_scene.render(&mut film, seed, max_depth, done..done + n, &|r| {
            let total = rays.fetch_add(r, Ordering::Relaxed) + r;
            bar.inc(n as u64);
            let secs = start.elapsed().as_secs_f64().max(1e-9);
            bar.set_message(format!("{:.1} Mrays/s", total as f64 / secs / 1e6));
        });
        done += n;
        if time.is_some_and(|t| start.elapsed() >= Duration::from_secs_f64(t)) {
            break;
        }
    }
    bar.finish_and_clear();
    let render_secs = start.elapsed().as_secs_f64();
    write_image(&args.output, &film.mean())?;
    if !args.quiet {
        let rays = rays.load(Ordering::Relaxed) as f64;
        println!(
            "{}: {} triangles, BVH ({}) {:.1} ms, SAH {:.2}; render {:.2} s, {:.2} Mrays/s, {done} spp{}",
            args.output.display(),
            build.triangles,
            build.builder,
            build.build_ms,
            build.sah,
            render_secs,
            rays / render_secs.max(1e-9) / 1e6,
            match film.non_finite_count() {
                0 => String::new(),
                n => format!(", {n} non-finite samples dropped"),
            }
        );
    }
    Ok(())
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
