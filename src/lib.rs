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

/// `println!` for the command-line tools' reports, ignoring a closed standard output (`| head`):
/// the work, and the files it writes, go on; `println!` would panic.
#[macro_export]
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($arg)*);
    }};
}
