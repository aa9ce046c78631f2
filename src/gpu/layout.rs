//! Data shared by Rust and WGSL: one Rust definition per GPU-visible struct, mirrored in
//! `shaders/prelude.wgsl`, and the constants both sides use, generated from Rust into the
//! prelude ([`prelude`]) so that no number is typed twice.
//!
//! `tests/gpu_layout.rs` parses the prelude with naga and checks every struct's size and member
//! offsets against `size_of`/`offset_of!` here (no GPU needed).

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

pub use crate::bvh::BvhNode;
use crate::bvh::INVALID_INDEX;
use crate::geometry::Aabb;

/// Threads per workgroup of every 1D kernel.
pub const WORKGROUP_SIZE: u32 = 256;

/// A primitive's box as the GPU reads it: `vec3` members align to 16 bytes in WGSL, so each
/// corner carries a padding word.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuAabb {
    pub min: Vec3,
    pub pad0: u32,
    pub max: Vec3,
    pub pad1: u32,
}

const _: () = assert!(size_of::<GpuAabb>() == 32);

impl From<Aabb> for GpuAabb {
    fn from(b: Aabb) -> Self {
        Self { min: b.min, pad0: 0, max: b.max, pad1: 0 }
    }
}

/// The LBVH kernels' parameters: the Morton quantizer (computed on the host from the centroid
/// bounds, so that the codes are bit for bit the CPU's) and the primitive count.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct LbvhParams {
    pub origin: Vec3,
    pub prim_count: u32,
    pub scale: Vec3,
    pub pad: u32,
}

const _: () = assert!(size_of::<LbvhParams>() == 32);

/// The prelude every shader starts with: generated constants, then `shaders/prelude.wgsl`.
pub fn prelude() -> String {
    format!(
        "// Generated from src/gpu/layout.rs: do not edit here.\n\
         const WORKGROUP_SIZE: u32 = {WORKGROUP_SIZE}u;\n\
         const INVALID_INDEX: u32 = {INVALID_INDEX}u;\n\
         const MORTON_BITS: u32 = {}u;\n\n{}",
        crate::geometry::morton::MORTON_BITS,
        include_str!("../../shaders/prelude.wgsl")
    )
}

/// A kernel file with the prelude in front.
pub fn with_prelude(kernel: &str) -> String {
    format!("{}\n{kernel}", prelude())
}
