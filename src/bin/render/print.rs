//! What `render` prints: the build's and each frame's summary lines, and the progress bar.

use std::path::Path;

use arbor::bvh::TraceLayout;
use arbor::device::{RenderedFrame, Renderer};
use arbor::render::BuildReport;
use indicatif::{ProgressBar, ProgressStyle};

use crate::cli::outln;

pub fn print_build(scene: &Path, build: &BuildReport, cpu: bool, texture_bytes: usize) {
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

/// Prints a frame's summary line.
pub fn print_frame(renderer: &Renderer, output: &Path, update_ms: Option<f64>, frame: &RenderedFrame) {
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
pub fn dropped(film: &arbor::render::film::Film) -> String {
    match film.non_finite_count() {
        0 => String::new(),
        n => format!(", {n} non-finite samples dropped"),
    }
}

/// A warning on stderr, whatever `--quiet` says, where `output`'s film dropped samples: its
/// image is darker where they fell, which a summary alone would hide.
pub fn warn_dropped(output: &std::path::Path, dropped: u64) {
    if dropped > 0 {
        eprintln!(
            "render: warning: {}: {dropped} samples dropped (non-finite, or of radiance 2^44 or more): the image \
             lacks their light",
            output.display()
        );
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

pub fn progress_bar(show: bool, rows: u64) -> ProgressBar {
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
