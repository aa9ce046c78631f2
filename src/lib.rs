//! Arbor: a path tracer built around its bounding volume hierarchy.
//!
//! - [`geometry`]: boxes, rays, the watertight triangle test, Morton codes, meshes.
//! - [`bvh`]: the tree layout shared with the GPU, the LBVH and binned-SAH builders, SAH cost and
//!   leaf collapse, validation, and closest/any-hit traversal.
//! - [`gpu`]: the wgpu backend: context, shared layouts, GPU LBVH.
//! - [`scene`]: the TOML scene format and its loader.
//! - [`render`]: camera, film, materials (BSDFs), sampling, lights, the path tracer, and the
//!   time-against-error benchmark.
//! - [`image_io`]: EXR and PNG output; [`atomic_file`]: every file output, written atomically;
//!   [`memory`]: peak resident memory for reports.

pub mod atomic_file;
pub mod bvh;
pub mod geometry;
pub mod gpu;
pub mod image_io;
pub mod memory;
pub mod render;
pub mod scene;

/// `println!` for the command-line tools' reports, which does not panic when standard output
/// fails: a closed pipe (`| head`) is ignored, so the work, and the files it writes, go on
/// (`println!` would panic); any other failure (`> /dev/full`) is kept for [`stdout_error`],
/// which the tools check before they exit.
#[macro_export]
macro_rules! outln {
    ($($arg:tt)*) => {
        $crate::write_stdout_line(format_args!($($arg)*))
    };
}

static STDOUT_ERROR: std::sync::OnceLock<std::io::Error> = std::sync::OnceLock::new();

/// What [`outln!`] does: one line to standard output, flushed by the line.
#[doc(hidden)]
pub fn write_stdout_line(line: std::fmt::Arguments) {
    use std::io::Write as _;
    if let Err(e) = writeln!(std::io::stdout(), "{line}") {
        if e.kind() != std::io::ErrorKind::BrokenPipe {
            let _ = STDOUT_ERROR.set(e);
        }
    }
}

/// The first error [`outln!`] met writing standard output, other than a closed pipe: a report
/// that did not arrive must not end in success.
pub fn stdout_error() -> Option<&'static std::io::Error> {
    STDOUT_ERROR.get()
}

/// Most worker threads `--threads` takes: far past any core count, and below the thousands at
/// which the pool's start-up alone takes seconds (2000 threads: 16 s on 2 cores).
pub const MAX_THREADS: usize = 1024;

/// Sizes rayon's global pool from the tools' `--threads` (all cores when `None`).
pub fn init_threads(threads: Option<usize>) -> Result<(), String> {
    let Some(n) = threads else { return Ok(()) };
    if !(1..=MAX_THREADS).contains(&n) {
        return Err(format!("--threads must be 1 to {MAX_THREADS}, not {n}"));
    }
    rayon::ThreadPoolBuilder::new().num_threads(n).build_global().map_err(|e| format!("--threads: {e}"))
}
