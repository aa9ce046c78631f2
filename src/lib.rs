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
