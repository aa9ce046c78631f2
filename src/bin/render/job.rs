//! What a scheduler needs from `render`: exit codes that say whether to retry, a flag raised by
//! SIGTERM and SIGINT, and the `--report` JSON. Documented for users in docs/distributed.md.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use arbor::device::DeviceError;
use arbor::distributed::film_file::PieceError;
use arbor::distributed::overwrite::Overwrite;
use arbor::distributed::{JobError, PlanError};
use arbor::image_io::ImageError;
use arbor::memory::OutOfMemory;
use arbor::scene::{FlatSceneError, SceneError};
use serde::Serialize;

/// Exit codes, stable: a scheduler decides on them.
pub mod code {
    /// Rendered, merged, or skipped (`--skip-existing`).
    pub const OK: i32 = 0;
    /// Anything not below: a bug, or an error not classified.
    pub const OTHER: i32 = 1;
    /// Bad input (arguments, scene, pieces that do not belong together): retrying cannot help.
    pub const BAD_INPUT: i32 = 2;
    /// The render does not fit in the memory this machine or job allows: retry only with more.
    pub const NO_MEMORY: i32 = 3;
    /// No usable GPU, or the device failed or was lost: retry (elsewhere).
    pub const DEVICE: i32 = 69;
    /// Reading or writing a file failed (not a missing input): retry.
    pub const IO: i32 = 74;
    /// Stopped by SIGTERM or SIGINT after writing its state: retry with `--resume`.
    pub const INTERRUPTED: i32 = 75;
}

/// Bad input found by `render` itself (arguments that do not fit together or the scene).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct BadInput(pub String);

/// The exit code for `error`: the first cause in its chain that says.
pub fn exit_code(error: &anyhow::Error) -> i32 {
    for cause in error.chain() {
        if let Some(code) = cause_code(cause) {
            return code;
        }
    }
    code::OTHER
}

/// The exit code `cause` says, `None` where it leaves it to its own cause.
fn cause_code(cause: &(dyn std::error::Error + 'static)) -> Option<i32> {
    if let Some(e) = cause.downcast_ref::<PlanError>() {
        // The library's errors that wrap another in place (`transparent`) say what it says.
        return match e {
            PlanError::Memory(_) => Some(code::NO_MEMORY),
            PlanError::Output(e) => Some(image_code(e)),
            PlanError::State(e) => Some(piece_code(e)),
            PlanError::Unwritable { .. } => None,
            _ => Some(code::BAD_INPUT),
        };
    }
    if let Some(e) = cause.downcast_ref::<JobError>() {
        return match e {
            JobError::Interrupted { .. } => Some(code::INTERRUPTED),
            JobError::Device(_) => Some(code::DEVICE),
            JobError::Write(e) => Some(image_code(e)),
            JobError::Remove { .. } => None,
        };
    }
    if cause.is::<BadInput>() || cause.is::<clap::Error>() || cause.is::<Overwrite>() {
        return Some(code::BAD_INPUT);
    }
    if cause.is::<OutOfMemory>() {
        return Some(code::NO_MEMORY);
    }
    if cause.is::<DeviceError>() {
        return Some(code::DEVICE);
    }
    if let Some(e) = cause.downcast_ref::<FlatSceneError>() {
        // More triangles than one tree indexes is no machine's limit: the scene must change.
        return Some(match e {
            FlatSceneError::TooManyTriangles { .. } => code::BAD_INPUT,
            FlatSceneError::Memory { .. } => code::NO_MEMORY,
        });
    }
    if let Some(e) = cause.downcast_ref::<SceneError>() {
        return Some(match e {
            SceneError::Read { error, .. } => input_code(error),
            SceneError::Invalid { .. } => code::BAD_INPUT,
            SceneError::Memory { .. } => code::NO_MEMORY,
        });
    }
    if let Some(e) = cause.downcast_ref::<PieceError>() {
        return Some(piece_code(e));
    }
    if let Some(e) = cause.downcast_ref::<ImageError>() {
        return Some(image_code(e));
    }
    cause.is::<std::io::Error>().then_some(code::IO)
}

/// An input that is not there, or is a folder or a device rather than a file, or a path through
/// a file, is bad input; one too long to read in the memory available needs more; any other
/// failure to read, and any failure to write (a shared folder briefly gone), may pass.
fn input_code(e: &std::io::Error) -> i32 {
    use std::io::ErrorKind;
    match e.kind() {
        ErrorKind::NotFound | ErrorKind::IsADirectory | ErrorKind::NotADirectory | ErrorKind::InvalidInput => {
            code::BAD_INPUT
        }
        ErrorKind::OutOfMemory => code::NO_MEMORY,
        _ => code::IO,
    }
}

fn piece_code(e: &PieceError) -> i32 {
    match e {
        PieceError::Io { source, .. } => input_code(source),
        PieceError::Memory(_) => code::NO_MEMORY,
        _ => code::BAD_INPUT,
    }
}

fn image_code(e: &ImageError) -> i32 {
    match e {
        ImageError::Io { .. } => code::IO,
        ImageError::Exr { .. } | ImageError::Png { .. } => code::OTHER,
        _ => code::BAD_INPUT,
    }
}

/// How `render` answers SIGTERM (what Slurm and Kubernetes send before they kill a job) and
/// SIGINT. Installed first thing, so that a signal in the first milliseconds is not lost.
pub struct Signals {
    /// Raised by either signal: a render abandons its pass, writes its state (its last whole
    /// pass) and exits with [`code::INTERRUPTED`]. A second SIGINT ends the process at once, as an impatient Ctrl-C
    /// expects.
    pub stop: Arc<AtomicBool>,
    /// Once raised ([`Signals::die_on_signal`]), either signal ends the process at once (a
    /// merge, which has no state worth keeping).
    die: Arc<AtomicBool>,
    /// Raised while the scene loads and its BVH builds: a signal then ends the process within
    /// [`LOADING_POLL`] with [`code::INTERRUPTED`] and nothing written (there is no state yet, so
    /// a retry starts afresh), instead of at the first pass, which may be a minute away.
    pub loading: Arc<AtomicBool>,
}

/// How often a watcher looks at the stop flag while the scene loads.
const LOADING_POLL: std::time::Duration = std::time::Duration::from_millis(50);

impl Signals {
    pub fn install() -> std::io::Result<Signals> {
        use signal_hook::consts::{SIGINT, SIGTERM};
        let (stop, die) = (Arc::new(AtomicBool::new(false)), Arc::new(AtomicBool::new(false)));
        for signal in [SIGINT, SIGTERM] {
            signal_hook::flag::register_conditional_default(signal, Arc::clone(&die))?;
        }
        // Registered before the flag it reads is raised, so it sees the flag as it was before
        // this signal.
        signal_hook::flag::register_conditional_shutdown(SIGINT, 130, Arc::clone(&stop))?;
        signal_hook::flag::register(SIGINT, Arc::clone(&stop))?;
        signal_hook::flag::register(SIGTERM, Arc::clone(&stop))?;
        let loading = Arc::new(AtomicBool::new(true));
        let (watched, watching) = (Arc::clone(&stop), Arc::clone(&loading));
        std::thread::Builder::new().name("signal watcher".into()).spawn(move || {
            while watching.load(Ordering::SeqCst) {
                if stopped(&watched) && watching.load(Ordering::SeqCst) {
                    eprintln!("render: stopped by a signal while loading the scene; nothing written");
                    // `_exit`: the main thread may be inside a driver (a GPU's set-up), whose
                    // exit handlers must not run under it.
                    signal_hook::low_level::exit(code::INTERRUPTED);
                }
                std::thread::sleep(LOADING_POLL);
            }
        })?;
        Ok(Signals { stop, die, loading })
    }

    /// From now on a signal ends the process as if no handler were installed; one that came
    /// already does so now.
    pub fn die_on_signal(&self) {
        self.loading.store(false, Ordering::SeqCst);
        self.die.store(true, Ordering::SeqCst);
        if stopped(&self.stop) {
            eprintln!("render: stopped by a signal");
            std::process::exit(code::INTERRUPTED);
        }
    }
}

pub fn stopped(flag: &AtomicBool) -> bool {
    flag.load(Ordering::Relaxed)
}

/// `--report`: what ran and what it cost. Field names are stable (docs/distributed.md).
#[derive(Debug, Default, Serialize)]
pub struct Report {
    pub arbor_version: &'static str,
    pub command: Vec<String>,
    /// `render` or `merge`.
    pub mode: &'static str,
    pub scene: Option<PathBuf>,
    pub scene_hash: Option<String>,
    pub device: Option<&'static str>,
    pub adapter: Option<String>,
    pub threads: usize,
    pub seed: Option<u64>,
    pub max_depth: Option<u32>,
    pub resolution: Option<[u32; 2]>,
    /// `I/N` where `--tile` was given.
    pub tile: Option<String>,
    /// The rectangle rendered, `[x0, y0, x1, y1]` (x1, y1 exclusive).
    pub rect: Option<[u32; 4]>,
    /// The sample indices asked for, `[first, end]`.
    pub samples: Option<[u32; 2]>,
    pub load_seconds: Option<f64>,
    /// Bytes the scene's textures and environment map hold ([`arbor::scene::Scene::texture_bytes`]).
    pub texture_bytes: Option<u64>,
    pub bvh: Option<BvhReport>,
    pub frames: Vec<FrameReport>,
    /// Whether `frames` is kept (`--report` was given): a range of millions of frames holds no
    /// line per frame otherwise.
    #[serde(skip)]
    pub keep_frames: bool,
    /// The files the run read or writes, as far as it came: the report is not written over
    /// any of them, whatever error ended the run.
    #[serde(skip)]
    pub guarded: Vec<PathBuf>,
    /// Samples the outputs' films dropped, over all frames: non-finite, or of radiance 2^44 or
    /// more ([`arbor::render::film`]). Each is a hole in its pixel's mean; stderr says so too.
    pub dropped_samples: u64,
    /// `merge` only: the pieces merged.
    pub pieces: Vec<PathBuf>,
    pub wall_seconds: f64,
    pub peak_memory_bytes: Option<u64>,
    pub exit_code: i32,
    pub error: Option<String>,
}

#[derive(Debug, Serialize)]
pub struct BvhReport {
    pub builder: String,
    pub triangles: usize,
    pub build_ms: f64,
    pub sah: f64,
    /// The tree form traced on the device rendering: `binary`, `wide4` or `wide8` (`--trace`).
    pub trace: &'static str,
}

#[derive(Debug, Serialize)]
pub struct FrameReport {
    /// The animation frame, `null` for a still.
    pub frame: Option<u32>,
    pub output: PathBuf,
    /// `rendered`, `resumed` (carried on from a partial film), `skipped` (`--skip-existing`),
    /// `interrupted` (a signal; its state written) or `merged`.
    pub status: &'static str,
    /// The sample indices the output holds, `[first, end]`.
    pub samples_done: [u32; 2],
    pub bvh_update_ms: Option<f64>,
    /// Seconds rendering in this run (not those of a partial film resumed).
    pub render_seconds: f64,
    /// Rays traced in this run.
    pub rays: u64,
    /// Samples the output's film dropped (its total, a resumed state's included).
    pub dropped_samples: u64,
}

impl Report {
    /// Adds `frame` to `frames` where they are kept.
    pub fn push_frame(&mut self, frame: FrameReport) {
        if self.keep_frames {
            self.frames.push(frame);
        }
    }
}
