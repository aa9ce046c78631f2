//! Rendering: camera, random streams, film, materials, lights and the path tracer.
//!
//! - [`assembly`]: a loaded scene turned into the [`RenderScene`] the integrator reads;
//! - [`auto`]: `--builder auto`, the tree the render's length repays;
//! - [`environment`]: environment maps and their importance sampling;
//! - [`integrator`]: the path tracer, one path at a time;
//! - [`pass`]: what one call renders, as every device takes it;
//! - [`tiles`]: the CPU's loop over pixels and samples into a [`film::Film`].

pub mod assembly;
pub mod auto;
pub mod bsdf;
pub mod camera;
pub mod environment;
pub mod film;
pub mod geometry;
pub mod integrator;
pub mod lights;
pub mod material;
pub mod pass;
pub mod refine;
pub mod region;
pub mod rng;
pub mod sampling;
pub mod tiles;

pub use assembly::{BuildReport, RenderScene, first_frame_time};
pub use auto::AutoDevice;
pub use material::RenderMaterial;
