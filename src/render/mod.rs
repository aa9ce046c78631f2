//! Rendering: camera, random streams, film, materials, lights and the path tracer.

pub mod bsdf;
pub mod camera;
pub mod converge;
pub mod film;
pub mod geometry;
pub mod integrator;
pub mod lights;
pub mod rng;
pub mod sampling;

pub use integrator::{AutoDevice, AutoRender, BuildReport, RenderScene};
