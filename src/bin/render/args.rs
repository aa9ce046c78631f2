//! `render`'s command line.

use std::ops::Range;
use std::path::PathBuf;

use arbor::bvh::TraceLayout;
use arbor::distributed::film_file::parse_rect;
use arbor::render::region::Rect;
use clap::{Parser, ValueEnum};

/// Render a scene (TOML) to a linear EXR image, or an 8-bit sRGB PNG when OUT ends in .png.
///
/// Animated scenes: `--frames 0..120 -o out_%04d.exr` renders a sequence (`%04d` becomes the
/// frame number), `--frame N` one frame. Without either, an output name with a frame pattern
/// renders the scene's whole frame range, and one without renders its first frame.
///
/// Split renders (docs/distributed.md): `--tile I/N`, `--crop` and `--samples` render part of
/// the image or of its samples to a partial film (EXR); `render --merge PIECE.exr... -o OUT`
/// makes the image, bit for bit the one a single render makes. An output that would overwrite
/// an input (or another output) is refused before any work. Exit codes: 0 done, 2 bad input,
/// 3 out of memory, 69 device, 74 I/O (a full disk too), 75 stopped by a signal (state
/// written), 1 other.
#[derive(Parser, Debug)]
#[command(name = "render", version, allow_negative_numbers = true)]
pub struct Args {
    /// The scene file (see docs/scene-format.md).
    #[arg(required_unless_present = "merge")]
    pub scene: Option<PathBuf>,
    /// Output image: .exr (linear float RGB) or .png (8-bit sRGB); `%04d` (or `%d`, `%0Nd`) in
    /// the name becomes the frame number. With --tile, --crop or --samples, a partial film
    /// (.exr).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Frames to render, first..one-past-last, as `0..120` (an animated scene's frames run at
    /// its `animation.fps`).
    #[arg(long, value_parser = parse_frames, conflicts_with = "frame")]
    pub frames: Option<Range<u32>>,
    /// One frame to render (at most 4294967294, the last a `--frames` range can hold).
    #[arg(long, value_parser = clap::value_parser!(u32).range(..i64::from(u32::MAX)))]
    pub frame: Option<u32>,
    /// Samples per pixel (overrides the scene's render.spp).
    #[arg(long)]
    pub spp: Option<u32>,
    /// Time budget in seconds (overrides render.time): stop after the pass that exceeds it.
    #[arg(long)]
    pub time: Option<f64>,
    /// Maximum path segments (overrides render.max_depth): 1 shows emitters, 2 adds direct light.
    #[arg(long)]
    pub max_depth: Option<u32>,
    /// Where to render.
    #[arg(long, value_enum, default_value_t = Device::Auto)]
    pub device: Device,
    /// BVH builder: auto, or a builder's name (lbvh, lbvh+prbvh, binned-sah, ploc, ...). `auto`
    /// optimises the LBVH only while that pays for itself in this render: on the CPU it starts
    /// rendering at once and optimises between passes. Default: auto on the CPU; lbvh+prbvh on
    /// the GPU, where an animated or instanced scene is rebuilt flat every frame, with lbvh
    /// unless a builder other than auto is given.
    #[arg(long)]
    pub builder: Option<String>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// The tree form traced. On the CPU: binary, wide4 or wide8 (default: wide8 where the CPU
    /// has AVX2, wide4 where it has SSE4.1 or NEON, else binary);
    /// `ARBOR_SIMD=scalar|sse4|avx2|neon` forces the instruction set. On the GPU: binary or
    /// wide8, a compressed 8-wide tree (the default; wide4 is refused). Under --device auto
    /// each device takes its own default. Every form gives the same image.
    #[arg(long, value_name = "FORM", value_parser = parse_trace)]
    pub trace: Option<TraceLayout>,
    /// Clamp fireflies: scale down any sample whose largest channel exceeds this radiance.
    /// Biased (it removes energy); off unless given.
    #[arg(long, value_name = "RADIANCE")]
    pub clamp: Option<f32>,
    /// Seed of the random streams (overrides render.seed).
    #[arg(long)]
    pub seed: Option<u64>,
    /// No progress bar and no summary.
    #[arg(long)]
    pub quiet: bool,
    /// Render tile I of N (I from 0): the image cut into a grid of N rectangles closest to
    /// square, numbered row by row from the top left. Writes a partial film.
    #[arg(long, value_name = "I/N", value_parser = parse_tile, conflicts_with = "crop")]
    pub tile: Option<(u32, u32)>,
    /// Render the rectangle of columns X0..X1 and rows Y0..Y1 (X1, Y1 excluded; row 0 at the
    /// top). Writes a partial film.
    #[arg(long, value_name = "X0,Y0,X1,Y1", value_parser = parse_crop)]
    pub crop: Option<Rect>,
    /// Render sample indices A..B-1 of every pixel (B at most the render's spp). Writes a
    /// partial film.
    #[arg(long, value_name = "A..B", value_parser = parse_samples)]
    pub samples: Option<Range<u32>>,
    /// Merge partial films into the image (-o): they must be pieces of one render that cover
    /// every pixel's samples once.
    #[arg(long, value_name = "PIECE", num_args = 1.., conflicts_with_all = ["scene", "tile", "crop", "samples", "frames", "frame", "checkpoint", "resume"])]
    pub merge: Vec<PathBuf>,
    /// Write the render's state (a partial film) this often: the output itself for a split
    /// render, else OUT.partial.exr beside the output, removed when the image is written.
    #[arg(long, value_name = "SECONDS")]
    pub checkpoint: Option<f64>,
    /// Carry on from the state a checkpoint or a signal left (start afresh where there is none).
    #[arg(long)]
    pub resume: bool,
    /// Do nothing for an output that is already complete and whole (it decodes to the end at
    /// the right size; a piece also passes its integrity check). With --merge: do nothing where
    /// the merged image is already whole.
    #[arg(long)]
    pub skip_existing: bool,
    /// Write a JSON report of what ran and what it cost to this file.
    #[arg(long, value_name = "FILE")]
    pub report: Option<PathBuf>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Device {
    Cpu,
    Gpu,
    Auto,
}

fn parse_trace(name: &str) -> Result<TraceLayout, String> {
    TraceLayout::parse(name).ok_or_else(|| format!("{name:?} is not a tree form: expected binary, wide4 or wide8"))
}

/// `A..B` with `A < B`, a range of `what` (frame, sample); `example` is shown where `s` is not
/// a range.
fn parse_range(s: &str, what: &str, example: &str) -> Result<Range<u32>, String> {
    let (a, b) = s.split_once("..").ok_or_else(|| format!("expected FIRST..END, as {example}, not {s:?}"))?;
    let a: u32 = a.trim().parse().map_err(|e| format!("first {what} {a:?}: {e}"))?;
    let b: u32 = b.trim().parse().map_err(|e| format!("end {what} {b:?}: {e}"))?;
    if b <= a {
        return Err(format!("{s}: the end ({b}) must be after the first {what} ({a})"));
    }
    Ok(a..b)
}

fn parse_frames(s: &str) -> Result<Range<u32>, String> {
    parse_range(s, "frame", "0..120")
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

fn parse_samples(s: &str) -> Result<Range<u32>, String> {
    parse_range(s, "sample", "0..64")
}
