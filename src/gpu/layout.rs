//! Data shared by Rust and WGSL: one Rust definition per GPU-visible struct, and the constants
//! both sides use. The WGSL declarations of the structs and the constants are generated from
//! Rust into the prelude every shader starts with ([`prelude`]), so nothing is typed twice:
//! [`gpu_structs!`] defines each struct and lists its members (name, WGSL type and `offset_of!`)
//! for the generator.
//!
//! The layout test (`tests/gpu_layout.rs`) parses the prelude with naga and checks, for every
//! struct in [`SHARED_STRUCTS`], that WGSL's size and member offsets are Rust's and that the
//! members cover the Rust struct without gaps, so a member WGSL would lay out elsewhere (a
//! `vec3` without its padding word), or a field missing from a hand-written list ([`BvhNode`]'s),
//! fails it. No GPU needed.

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

/// A type a shared struct's member may have, and its WGSL name.
pub trait WgslType {
    const WGSL: &'static str;
}

impl WgslType for u32 {
    const WGSL: &'static str = "u32";
}

impl WgslType for f32 {
    const WGSL: &'static str = "f32";
}

impl WgslType for [u32; 12] {
    const WGSL: &'static str = "array<u32, 12>";
}

impl WgslType for [f32; 6] {
    const WGSL: &'static str = "array<f32, 6>";
}

impl WgslType for Vec3 {
    const WGSL: &'static str = "vec3<f32>";
}

/// One member of a shared struct, as Rust lays it out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Member {
    pub name: &'static str,
    pub wgsl_type: &'static str,
    pub offset: usize,
    pub size: usize,
}

/// A struct shared with WGSL: its name, size and members in declaration order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StructLayout {
    pub name: &'static str,
    pub size: usize,
    pub members: Vec<Member>,
}

impl StructLayout {
    /// The WGSL declaration.
    pub fn wgsl(&self) -> String {
        let members: String = self.members.iter().map(|m| format!("    {}: {},\n", m.name, m.wgsl_type)).collect();
        format!("struct {} {{\n{members}}}\n", self.name)
    }
}

/// A member's [`Member`] entry, for [`gpu_structs!`] and hand-written layouts.
macro_rules! member {
    ($owner:ty, $field:ident : $ty:ty) => {
        Member {
            name: stringify!($field),
            wgsl_type: <$ty as WgslType>::WGSL,
            offset: std::mem::offset_of!($owner, $field),
            size: size_of::<$ty>(),
        }
    };
}

/// Defines GPU-visible structs (`#[repr(C)]`, `Pod`) and, for each, a `layout()` giving its
/// [`StructLayout`], from which the WGSL declaration is generated.
macro_rules! gpu_structs {
    ($($(#[$meta:meta])* pub struct $name:ident { $($(#[$fmeta:meta])* pub $field:ident : $ty:ty),* $(,)? })*) => {
        $(
            $(#[$meta])*
            #[repr(C)]
            #[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
            pub struct $name {
                $($(#[$fmeta])* pub $field: $ty),*
            }

            impl $name {
                /// Its layout, for the WGSL prelude and the layout test.
                pub fn layout() -> StructLayout {
                    StructLayout {
                        name: stringify!($name),
                        size: size_of::<$name>(),
                        members: vec![$(member!($name, $field: $ty)),*],
                    }
                }
            }
        )*
    };
}

/// [`BvhNode`]'s layout: it is defined with the tree (`src/bvh/node.rs`), which knows nothing of
/// the GPU, so its members are listed here; the layout test's coverage check catches a field
/// added there and not here.
fn bvh_node_layout() -> StructLayout {
    StructLayout {
        name: "BvhNode",
        size: size_of::<BvhNode>(),
        members: vec![
            member!(BvhNode, aabb_min: Vec3),
            member!(BvhNode, first: u32),
            member!(BvhNode, aabb_max: Vec3),
            member!(BvhNode, prim_count: u32),
        ],
    }
}

/// Every struct shared with WGSL, in the order the prelude declares them.
pub const SHARED_STRUCTS: [fn() -> StructLayout; 11] = [
    bvh_node_layout,
    GpuAabb::layout,
    LbvhParams::layout,
    PrbvhParams::layout,
    CollapseParams::layout,
    GpuTriangle::layout,
    GpuInstance::layout,
    GpuMaterial::layout,
    GpuLight::layout,
    GpuPixel::layout,
    TraceParams::layout,
];

gpu_structs! {
/// A primitive's box as the GPU reads it: `vec3` members align to 16 bytes in WGSL, so each
/// corner carries a padding word.
pub struct GpuAabb {
    pub min: Vec3,
    pub pad0: u32,
    pub max: Vec3,
    pub pad1: u32,
}

/// The LBVH kernels' parameters: the Morton quantizer (computed on the host from the centroid
/// bounds, so that the codes are bit for bit the CPU's) and the primitive count.
pub struct LbvhParams {
    pub origin: Vec3,
    pub prim_count: u32,
    pub scale: Vec3,
    pub pad: u32,
}

/// One PRBVH iteration's parameters (`shaders/prbvh.wgsl`).
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

/// The GPU collapse's parameters (`shaders/collapse.wgsl`).
pub struct CollapseParams {
    /// Nodes of the binary tree, padding included (`2n`).
    pub node_count: u32,
    /// The most triangles of a leaf lane.
    pub max_leaf: u32,
    /// Wide nodes to make in this dispatch.
    pub queue_len: u32,
    pub pad: u32,
    pub cost_node: f32,
    pub cost_prim: f32,
    /// One over the root's half area, of its extents times `area_scale` (a power of two that
    /// keeps f32 areas finite).
    pub inv_root_area: f32,
    pub area_scale: f32,
}

/// A triangle in leaf order, with what shading needs of its primitive: its material, the
/// area density with which light sampling picks points on it (0 for a non-light), and whether
/// its material has a cut-out mask (1, else 0: the traversal looks up no material for it), in
/// the padding words of its `vec3` vertices.
pub struct GpuTriangle {
    pub v0: Vec3,
    pub material: u32,
    pub v1: Vec3,
    pub light_pdf: f32,
    pub v2: Vec3,
    pub cutout: u32,
}

/// One placement of a mesh in a two-level scene ([`crate::bvh::dynamic::instances::Instance`]):
/// its transforms as columns (x, y, z axes and translation; rays go into object space by
/// `to_object`, hits come out by `to_world`), the root of its mesh's tree in the concatenated
/// node buffer, its material override (`INVALID_INDEX`: the mesh's own), its first light id
/// (`INVALID_INDEX`: none of its triangles emits), whether it mirrors (1, else 0), and its id
/// (the object's index: ties between instances go to the lower id).
pub struct GpuInstance {
    pub to_object_x: Vec3,
    pub root: u32,
    pub to_object_y: Vec3,
    pub material: u32,
    pub to_object_z: Vec3,
    pub light_base: u32,
    pub to_object_t: Vec3,
    pub mirrors: u32,
    pub to_world_x: Vec3,
    pub id: u32,
    pub to_world_y: Vec3,
    pub pad1: u32,
    pub to_world_z: Vec3,
    pub pad2: u32,
    pub to_world_t: Vec3,
    pub pad3: u32,
}

/// A material ([`crate::render::bsdf::Bsdf`] plus emission). `albedo` is the diffuse albedo,
/// the conductor's Schlick F0 or the real part of its complex index, or the coated material's
/// base colour; `k` the conductor's imaginary part, or the coated material's metallic in `k.x`.
pub struct GpuMaterial {
    pub albedo: Vec3,
    /// `MAT_BLACK`, `MAT_DIFFUSE`, `MAT_CONDUCTOR`, `MAT_DIELECTRIC` or `MAT_COATED`.
    pub kind: u32,
    pub k: Vec3,
    /// GGX α (conductor, dielectric, coated).
    pub alpha: f32,
    pub emission: Vec3,
    /// Index below the surface over the one above (dielectric), or of the coat (coated).
    pub ior: f32,
    /// `MAT_EMITS | MAT_TWO_SIDED | MAT_COMPLEX_FRESNEL`.
    pub flags: u32,
    /// The base colour texture and the cut-out mask, packed
    /// ([`crate::gpu::texture::gpu_texture_ref`]; `INVALID_INDEX`: none), and the mask's
    /// cutoff.
    pub base_color_tex: u32,
    pub alpha_tex: u32,
    pub alpha_cutoff: f32,
    /// The tangent-space normal map, packed as the textures above, and the scale of its x and y.
    pub normal_tex: u32,
    pub normal_scale: f32,
    /// The texture multiplying `emission`, packed as the textures above.
    pub emission_tex: u32,
    /// The coated material's roughness and metallic textures, each with its channel
    /// ([`crate::gpu::texture::gpu_texture_channel`]).
    pub roughness_tex: u32,
    pub metallic_tex: u32,
    pub pad0: u32,
    pub pad1: u32,
    pub pad2: u32,
}

/// An emissive triangle ([`crate::render::lights::Lights`]): `cdf` is the running sum of power
/// up to and including it (the last is 1), `pdf_area` the density per unit area of sampling a
/// point on it (selection probability over area).
pub struct GpuLight {
    pub v0: Vec3,
    pub cdf: f32,
    pub v1: Vec3,
    pub pdf_area: f32,
    pub v2: Vec3,
    pub two_sided: u32,
    /// Unit geometric normal (the front side).
    pub normal: Vec3,
    /// The texture multiplying `radiance` (packed, `INVALID_INDEX`: none), at texture
    /// coordinates interpolated from `uvs` (u, v of each vertex).
    pub emission_tex: u32,
    pub radiance: Vec3,
    pub pad0: u32,
    pub uvs: [f32; 6],
    pub pad1: u32,
    pub pad2: u32,
}

/// One pixel's running sums on the device. `exact` is the film's exact sum
/// ([`crate::render::film::PixelAccum::sum`]): per channel a 128-bit two's-complement
/// fixed-point integer in four 32-bit limbs, least significant first, which makes the image of
/// any split of the samples the same. The f32 sums, which only the variance reads, are of
/// `sample - shift`, where `shift` is the pixel's first finite sample: a pixel whose samples are
/// all equal keeps exactly zero sums and so an exactly zero variance (as the CPU's film gets),
/// and the cancellation in `Σx² − (Σx)²/n` is kept small. `rays` counts the rays the pixel's
/// paths traced.
pub struct GpuPixel {
    pub shift: Vec3,
    pub count: u32,
    pub sum: Vec3,
    pub non_finite: u32,
    pub sum_sq: Vec3,
    pub rays: u32,
    pub exact: [u32; 12],
}

/// The path tracer's parameters (read from a storage buffer: see `trace::render`): the camera ([`crate::render::camera::CameraModel`]),
/// the environment, the firefly clamp (0: off), the seed as two halves, the pass's samples.
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
    /// The rectangle rendered: its top left in the image, and its size (the film's).
    pub origin_x: u32,
    pub origin_y: u32,
    pub rect_width: u32,
    pub rect_height: u32,
    /// The environment map's frame from the world's, row by row (`environment` is then the
    /// map's scale), its size in texels (0: no map), and the probability that next-event
    /// estimation samples it rather than the area lights
    /// ([`crate::render::RenderScene::environment_light`]).
    pub env_x: Vec3,
    pub env_width: u32,
    pub env_y: Vec3,
    pub env_height: u32,
    pub env_z: Vec3,
    pub env_select: f32,
}
}

const _: () = assert!(size_of::<GpuAabb>() == 32);
const _: () = assert!(size_of::<LbvhParams>() == 32);
const _: () = assert!(size_of::<PrbvhParams>() == 32);
const _: () = assert!(size_of::<CollapseParams>() == 32);
const _: () = assert!(size_of::<GpuTriangle>() == 48);
const _: () = assert!(size_of::<GpuInstance>() == 128);
const _: () = assert!(size_of::<GpuMaterial>() == 96);
const _: () = assert!(size_of::<GpuLight>() == 112);
const _: () = assert!(size_of::<GpuPixel>() == 96);
const _: () = assert!(size_of::<TraceParams>() == 176);

impl From<Aabb> for GpuAabb {
    fn from(b: Aabb) -> Self {
        Self { min: b.min, pad0: 0, max: b.max, pad1: 0 }
    }
}

/// The prelude every shader starts with: generated constants and struct declarations, then
/// `shaders/prelude.wgsl`.
pub fn prelude() -> String {
    let structs: String = SHARED_STRUCTS.iter().map(|layout| layout().wgsl()).collect::<Vec<_>>().join("\n");
    format!(
        "// Generated from src/gpu/layout.rs: do not edit here.\n\
         const WORKGROUP_SIZE: u32 = {WORKGROUP_SIZE}u;\n\
         const INVALID_INDEX: u32 = {INVALID_INDEX}u;\n\
         const REFIT_BOX_WORDS: u32 = {REFIT_BOX_WORDS}u;\n\
         const MORTON_BITS: u32 = {}u;\n\
         const SEARCH_MAX_VISITS: u32 = {}u;\n{}\n{structs}\n{}",
        crate::geometry::morton::MORTON_BITS,
        crate::bvh::build::prbvh::MAX_VISITS,
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

/// Entries of the compressed wide tree's traversal stack (`shaders/bvh_wide8.wgsl`): one group
/// of siblings per level, so a wide tree of depth `d` needs at most `d - 1`; deeper trees are
/// refused before upload.
pub const WIDE_STACK_SIZE: u32 = 32;

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
/// [`GpuMaterial::kind`]: glTF's metallic-roughness, base colour `albedo`, metallic `k.x`.
pub const MAT_COATED: u32 = 4;
/// [`GpuMaterial::flags`]: the material emits `emission`.
pub const MAT_EMITS: u32 = 1;
/// [`GpuMaterial::flags`]: it emits from the back face too.
pub const MAT_TWO_SIDED: u32 = 2;
/// [`GpuMaterial::flags`]: conductor Fresnel from the complex index `albedo + i k` (else Schlick
/// with F0 = `albedo`).
pub const MAT_COMPLEX_FRESNEL: u32 = 4;

/// `const NAME: f32 = value;` with the shortest decimal that reads back as the same f32.
fn wgsl_f32(name: &str, value: f32) -> String {
    assert!(value.is_finite(), "{name}: WGSL constants must be finite");
    format!("const {name}: f32 = {value:?};\n")
}

/// The path tracer's constants, for [`prelude`].
fn trace_constants() -> String {
    let mut s = format!(
        "const TRACE_STACK_SIZE: u32 = {TRACE_STACK_SIZE}u;\n\
         const WIDE_STACK_SIZE: u32 = {WIDE_STACK_SIZE}u;\n\
         const TRACE_WORKGROUP: u32 = {TRACE_WORKGROUP}u;\n\
         const RR_DEPTH: u32 = {}u;\n\
         const MAT_BLACK: u32 = {MAT_BLACK}u;\n\
         const MAT_DIFFUSE: u32 = {MAT_DIFFUSE}u;\n\
         const MAT_CONDUCTOR: u32 = {MAT_CONDUCTOR}u;\n\
         const MAT_DIELECTRIC: u32 = {MAT_DIELECTRIC}u;\n\
         const MAT_COATED: u32 = {MAT_COATED}u;\n\
         const MAT_EMITS: u32 = {MAT_EMITS}u;\n\
         const MAT_TWO_SIDED: u32 = {MAT_TWO_SIDED}u;\n\
         const MAT_COMPLEX_FRESNEL: u32 = {MAT_COMPLEX_FRESNEL}u;\n\
         const FILM_FRACTION_BITS: i32 = {};\n",
        crate::render::integrator::RR_DEPTH,
        crate::render::film::FRACTION_BITS,
    );
    // The film's exact sums (`render::film`): samples this large are dropped.
    s += &wgsl_f32("FILM_SAMPLE_LIMIT", 2f32.powi(crate::render::film::SAMPLE_LIMIT_LOG2));
    s += &wgsl_f32("SMOOTH_ALPHA", crate::render::bsdf::SMOOTH_ALPHA);
    s += &wgsl_f32("CULL_SCALE", crate::bvh::CULL_SCALE);
    // src/bvh/trace/mod.rs's absolute culling slack per unit of distance, CULL_ABS_ULPS ULPs of 1.
    s += &wgsl_f32("CULL_ABS_SLACK", crate::bvh::CULL_ABS_ULPS * f32::EPSILON);
    s += &wgsl_f32("ROBUST_SLAB_SCALE", crate::geometry::ROBUST_SLAB_SCALE);
    s += &wgsl_f32("SHADOW_T_MAX", crate::render::integrator::SHADOW_T_MAX);
    // γₙ = nε / (1 − nε), the rounding-error bounds of ray offsets and the triangle test.
    for n in 1..=5 {
        s += &wgsl_f32(&format!("GAMMA{n}"), crate::geometry::gamma(n));
    }
    s
}
