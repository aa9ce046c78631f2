//! Arbor: a path tracer built around its bounding volume hierarchy.
//!
//! - [`geometry`]: boxes, rays, the watertight triangle test, Morton codes, meshes.
//! - [`bvh`]: the tree layout shared with the GPU, the LBVH and binned-SAH builders, SAH cost and
//!   leaf collapse, validation, and closest/any-hit traversal.

pub mod bvh;
pub mod geometry;
