//! Rendering: film, materials and sampling.

pub mod bsdf;
pub mod film;
pub mod sampling;
