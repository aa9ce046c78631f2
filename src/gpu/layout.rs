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

/// Words per node of the refit's `refit_boxes` buffer (`shaders/_refit.wgsl`): a box's six
/// coordinates, each passed between threads as an atomic.
pub const REFIT_BOX_WORDS: u32 = 6;

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

/// One PRBVH iteration's parameters (`shaders/prbvh.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PrbvhParams {
    /// Nodes in the tree, padding included (`2n` for `n` primitives).
    pub node_count: u32,
    /// Search sparsity μ and this iteration's phase: node `i` searches when `i % mu == phase`.
    pub mu: u32,
    pub phase: u32,
    /// Workgroups of the SAH's first stage.
    pub partial_count: u32,
    pub cost_traversal: f32,
    pub cost_intersection: f32,
    /// The power of two the search and the SAH multiply coordinates by, so that f32 areas
    /// neither overflow nor underflow (the CPU search's `search_scale`; 1 for most scenes).
    pub area_scale: f32,
    pub pad1: u32,
}

const _: () = assert!(size_of::<PrbvhParams>() == 32);

/// The prelude every shader starts with: generated constants, then `shaders/prelude.wgsl`.
pub fn prelude() -> String {
    format!(
        "// Generated from src/gpu/layout.rs: do not edit here.\n\
         const WORKGROUP_SIZE: u32 = {WORKGROUP_SIZE}u;\n\
         const INVALID_INDEX: u32 = {INVALID_INDEX}u;\n\
         const REFIT_BOX_WORDS: u32 = {REFIT_BOX_WORDS}u;\n\
         const MORTON_BITS: u32 = {}u;\n\
         const SEARCH_MAX_VISITS: u32 = {}u;\n{}\n{}",
        crate::geometry::morton::MORTON_BITS,
        crate::bvh::prbvh::MAX_VISITS,
        trace_constants(),
        include_str!("../../shaders/prelude.wgsl")
    )
}

/// A kernel file with the prelude in front.
pub fn with_prelude(kernel: &str) -> String {
    format!("{}\n{kernel}", prelude())
}

// ---------------------------------------------------------------------------------------------
// Path tracing: `src/gpu/trace.rs`, `shaders/bsdf.wgsl`, `shaders/trace.wgsl`.

/// Entries of the traversal stack of the path tracer. A stack entry is the far sibling of a node
/// on the current root-to-leaf path, so a tree of depth `d` (nodes on its longest path) needs at
/// most `d - 1`; deeper trees are refused before upload (`trace::GpuScene::upload`).
pub const TRACE_STACK_SIZE: u32 = 64;

/// The path tracer's workgroups are `TRACE_WORKGROUP x TRACE_WORKGROUP` pixels.
pub const TRACE_WORKGROUP: u32 = 8;

/// [`GpuMaterial::kind`]: absorbs everything (an emitter that does not reflect).
pub const MAT_BLACK: u32 = 0;
/// [`GpuMaterial::kind`]: Lambertian, `albedo / π`.
pub const MAT_DIFFUSE: u32 = 1;
/// [`GpuMaterial::kind`]: GGX conductor; Fresnel by [`MAT_COMPLEX_FRESNEL`].
pub const MAT_CONDUCTOR: u32 = 2;
/// [`GpuMaterial::kind`]: smooth or rough dielectric.
pub const MAT_DIELECTRIC: u32 = 3;
/// [`GpuMaterial::flags`]: the material emits `emission`.
pub const MAT_EMITS: u32 = 1;
/// [`GpuMaterial::flags`]: it emits from the back face too.
pub const MAT_TWO_SIDED: u32 = 2;
/// [`GpuMaterial::flags`]: conductor Fresnel from the complex index `albedo + i k` (else Schlick
/// with F0 = `albedo`).
pub const MAT_COMPLEX_FRESNEL: u32 = 4;

/// A triangle in leaf order, with what shading needs of its primitive: its material and the
/// area density with which light sampling picks points on it (0 for a non-light), in the
/// padding words of its `vec3` vertices.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuTriangle {
    pub v0: Vec3,
    pub material: u32,
    pub v1: Vec3,
    pub light_pdf: f32,
    pub v2: Vec3,
    pub pad: u32,
}

const _: () = assert!(size_of::<GpuTriangle>() == 48);

/// A material ([`crate::render::bsdf::Bsdf`] plus emission). `albedo` is the diffuse albedo,
/// the conductor's Schlick F0, or the real part of its complex index; `k` the imaginary part.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuMaterial {
    pub albedo: Vec3,
    /// `MAT_BLACK`, `MAT_DIFFUSE`, `MAT_CONDUCTOR` or `MAT_DIELECTRIC`.
    pub kind: u32,
    pub k: Vec3,
    /// GGX α (conductor, dielectric).
    pub alpha: f32,
    pub emission: Vec3,
    /// Index below the surface over the one above (dielectric).
    pub ior: f32,
    /// `MAT_EMITS | MAT_TWO_SIDED | MAT_COMPLEX_FRESNEL`.
    pub flags: u32,
    pub pad0: u32,
    pub pad1: u32,
    pub pad2: u32,
}

const _: () = assert!(size_of::<GpuMaterial>() == 64);

/// An emissive triangle ([`crate::render::lights::Lights`]): `cdf` is the running sum of power
/// up to and including it (the last is 1), `pdf_area` the density per unit area of sampling a
/// point on it (selection probability over area).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuLight {
    pub v0: Vec3,
    pub cdf: f32,
    pub v1: Vec3,
    pub pdf_area: f32,
    pub v2: Vec3,
    pub two_sided: u32,
    /// Unit geometric normal (the front side).
    pub normal: Vec3,
    pub pad0: u32,
    pub radiance: Vec3,
    pub pad1: u32,
}

const _: () = assert!(size_of::<GpuLight>() == 80);

/// One pixel's running sums on the device. Sums are of `sample - shift`, where `shift` is the
/// pixel's first finite sample: in f32, a pixel whose samples are all equal keeps exactly zero
/// sums and so an exactly zero variance (as the f64 film on the CPU gets), and the
/// cancellation in `Σx² − (Σx)²/n` is kept small. `rays` counts the rays the pixel's paths
/// traced.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuPixel {
    pub shift: Vec3,
    pub count: u32,
    pub sum: Vec3,
    pub non_finite: u32,
    pub sum_sq: Vec3,
    pub rays: u32,
}

const _: () = assert!(size_of::<GpuPixel>() == 48);

/// The path tracer's parameters (read from a storage buffer: see `trace::render`): the camera ([`crate::render::camera::CameraModel`]),
/// the environment, the firefly clamp (0: off), the seed as two halves, the pass's samples.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct TraceParams {
    pub cam_origin: Vec3,
    pub width: u32,
    pub cam_forward: Vec3,
    pub height: u32,
    pub cam_right: Vec3,
    pub tan_x: f32,
    pub cam_up: Vec3,
    pub tan_y: f32,
    pub environment: Vec3,
    pub lens_radius: f32,
    pub focus_distance: f32,
    pub clamp: f32,
    pub seed_lo: u32,
    pub seed_hi: u32,
    pub sample_start: u32,
    pub sample_count: u32,
    pub max_depth: u32,
    pub light_count: u32,
}

const _: () = assert!(size_of::<TraceParams>() == 112);

/// `const NAME: f32 = value;` with the shortest decimal that reads back as the same f32.
fn wgsl_f32(name: &str, value: f32) -> String {
    assert!(value.is_finite(), "{name}: WGSL constants must be finite");
    format!("const {name}: f32 = {value:?};\n")
}

/// The path tracer's constants, for [`prelude`].
fn trace_constants() -> String {
    let mut s = format!(
        "const TRACE_STACK_SIZE: u32 = {TRACE_STACK_SIZE}u;\n\
         const TRACE_WORKGROUP: u32 = {TRACE_WORKGROUP}u;\n\
         const RR_DEPTH: u32 = {}u;\n\
         const MAT_BLACK: u32 = {MAT_BLACK}u;\n\
         const MAT_DIFFUSE: u32 = {MAT_DIFFUSE}u;\n\
         const MAT_CONDUCTOR: u32 = {MAT_CONDUCTOR}u;\n\
         const MAT_DIELECTRIC: u32 = {MAT_DIELECTRIC}u;\n\
         const MAT_EMITS: u32 = {MAT_EMITS}u;\n\
         const MAT_TWO_SIDED: u32 = {MAT_TWO_SIDED}u;\n\
         const MAT_COMPLEX_FRESNEL: u32 = {MAT_COMPLEX_FRESNEL}u;\n",
        crate::render::integrator::RR_DEPTH
    );
    s += &wgsl_f32("SMOOTH_ALPHA", crate::render::bsdf::SMOOTH_ALPHA);
    s += &wgsl_f32("CULL_SCALE", crate::bvh::CULL_SCALE);
    // traverse.rs's absolute culling slack per unit of distance, CULL_ABS_ULPS ULPs of 1.
    s += &wgsl_f32("CULL_ABS_SLACK", crate::bvh::CULL_ABS_ULPS * f32::EPSILON);
    s += &wgsl_f32("ROBUST_SLAB_SCALE", crate::geometry::ROBUST_SLAB_SCALE);
    s += &wgsl_f32("SHADOW_T_MAX", crate::render::integrator::SHADOW_T_MAX);
    // γₙ = nε / (1 − nε), the rounding-error bounds of ray offsets and the triangle test.
    for n in 1..=5 {
        s += &wgsl_f32(&format!("GAMMA{n}"), crate::geometry::gamma(n));
    }
    s
}
