//! Path tracing on the GPU: the CPU integrator ([`RenderScene::radiance`] and its next-event
//! estimation), kernel for kernel the same, in `shaders/bsdf.wgsl` + `shaders/trace.wgsl`.
//!
//! **A megakernel, not a wavefront.** One thread per pixel traces whole paths, looping over a
//! pass's samples. A wavefront tracer (a kernel per stage, ray and hit queues between them)
//! keeps SIMD lanes full when paths diverge, which pays on wide hardware GPUs; it costs a
//! dispatch and a round trip of every path's state through memory per stage and bounce. On
//! lavapipe a dispatch with its submission is expensive (docs/benchmarks.md, "Lavapipe costs")
//! and "device memory" is the same RAM, so the queues buy nothing there; and a megakernel is one
//! kernel to write, to check against the CPU, and to specialize per scene, which also trims
//! divergence between material kinds on real GPUs.
//!
//! **Specialization.** Each scene gets a shader variant: `HAS_DIELECTRIC`, `HAS_CONDUCTOR`,
//! `HAS_COATED`, `HAS_ENVIRONMENT`, `HAS_LIGHTS`, `HAS_THIN_LENS`, `HAS_SHADING_NORMALS`,
//! `HAS_ENV_MAP`, `HAS_TEXTURES`, `HAS_CUTOUTS` and `HAS_INSTANCES` are generated as `const`
//! bools in front of the source ([`Features`]), and code behind a false one (a material's BSDF,
//! the environment, next-event estimation and shadow rays, the thin lens, vertex normals, the
//! environment map's sampling, texture lookups, the traversal's cut-out test, the top level) is
//! removed by the compiler. The pipeline
//! cache key names the variant. `ARBOR_GPU_NO_SPECIALIZE=1` compiles every scene with all
//! features, for measuring what specialization saves.
//!
//! **Scene.** [`GpuScene::upload`] takes a flat [`RenderScene`] (one BVH over world-space
//! triangles, leaf-collapsed, triangles in leaf order as in [`MeshBvh`](crate::bvh::MeshBvh)); material ids, stored by
//! original triangle id on the CPU, are mapped to leaf order through `prim_ids`. An instanced or
//! animated scene keeps its two levels: every mesh's tree and object-space triangles end to end
//! in the same buffers, the instances and the top-level tree beside them, which
//! [`GpuScene::update_instances`] uploads again after each frame's update (docs/design/gpu.md,
//! "Two levels"); [`flatten`] remains for comparing against. A buffer larger than the
//! adapter's largest storage binding (128 MiB on lavapipe: about 2.8 million triangles) is
//! refused with [`GpuError::BufferTooLarge`], naming the limit; nothing is split.
//!
//! **Traversal stack.** Fixed, [`TRACE_STACK_SIZE`] entries: each entry is the far sibling of a
//! node on the current path, so a tree of depth `d` needs at most `d - 1`. The tree's depth is
//! measured before upload, and a tree deeper than `TRACE_STACK_SIZE + 1` is refused with an error
//! naming both (after leaf collapse the example scenes' LBVH trees are 10 to 26 deep, and that
//! of the 1.7 million triangles of `instanced-field.toml`, flattened, 29 to 31).
//!
//! **Samples.** Each pass dispatches [`PASS_SPP`] samples per pixel (a submission short enough
//! for a display GPU's watchdog), accumulating into per-pixel sums on the device; the film is
//! read back once, at the end, into a [`Film`] with the same per-pixel statistics as the CPU's.
//! The sum is the film's exact fixed-point sum, kept in four 32-bit limbs a channel, so that any
//! split of a render's samples or pixels merges to the same image (docs/distributed.md); the
//! variance comes from f32 sums of `sample - first sample` ([`GpuPixel`]), which keep a constant
//! pixel's variance exactly 0. A render may cover a rectangle of the image only: the random
//! streams and the camera take the image's pixel, the film the rectangle's.
//!
//! **Departures from the CPU integrator** (none changes the expected image):
//! - random numbers: a 32-bit PCG (RXS-M-XS) stream per (seed, pixel, sample), seeded by a hash
//!   of the triple, not the CPU's 64-bit PCG32; images agree statistically, not bit for bit;
//! - the watertight test's fallback, where an edge function is zero, subnormal or not finite,
//!   or `T` or 1/det leaves f32's normal range, is not f64, which WGSL lacks portably: the
//!   sheared coordinates are rescaled by powers of two (exact) and the test rerun in f32, with
//!   Kahan's difference of products (correctly signed) for edge functions that are exactly 0;
//! - WGSL's `sin`, `cos`, division and `sqrt` may be less accurate than Rust's, a few ULPs, and
//!   the compiler may fuse a product and a sum (instance transforms included) where Rust rounds
//!   twice.
//!
//! Everything else is the CPU's, step for step: thin-lens camera rays, the slab test and box
//! culling slack of the traversal, the watertight test's f32 path with its conservative `t`, error-bound
//! ray offsets and shadow rays kept on the line to the light sample, every BSDF (Lambert, GGX
//! conductors with height-correlated Smith, visible-normal sampling, complex or Schlick
//! Fresnel, smooth and rough dielectrics, the coated metallic-roughness mixture), emitters front-only or two-sided, lights chosen by
//! power through the CDF, next-event estimation with the power heuristic and the `prev_delta`
//! rule, Russian roulette from `RR_DEPTH`, the firefly clamp, and non-finite samples counted and
//! dropped; shading normals and their two rules; environment maps, sampled from the same CDF
//! arrays ([`env_map_data`]) and weighted by MIS as on the CPU; textures read from the same
//! texel words and sRGB table ([`gpu_texture_data`]), and cut-outs tested in both traversals.

use std::time::Instant;

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::context::{GpuContext, GpuError};
use super::layout::{
    BvhNode, GpuInstance, GpuLight, GpuMaterial, GpuPixel, GpuTriangle, MAT_BLACK, MAT_COATED, MAT_COMPLEX_FRESNEL,
    MAT_CONDUCTOR, MAT_DIELECTRIC, MAT_DIFFUSE, MAT_EMITS, MAT_TWO_SIDED, TRACE_STACK_SIZE, TRACE_WORKGROUP,
    TraceParams, WIDE_STACK_SIZE, with_prelude,
};
use super::texture::{gpu_texture_channel, gpu_texture_data, gpu_texture_ref};
use crate::bvh::build::Builder;
use crate::bvh::build::prbvh::PrbvhConfig;
use crate::bvh::{Bvh, INVALID_INDEX};
use crate::geometry::{Aabb, Triangle};
use crate::render::bsdf::{Bsdf, ConductorFresnel};
use crate::render::film::{Film, PixelAccum};
use crate::render::geometry::Geometry;
use crate::render::pass::{Pass, Progress};
use crate::render::region::{Rect, Region};
use crate::render::{BuildReport, RenderMaterial, RenderScene};
use crate::scene::{RenderSettings, Scene};
use crate::texture::environment::EnvironmentMap;

/// The shader files concatenated (after the variant's constants and the prelude) into the
/// path tracer, in order: then the form's traversal ([`GpuForm::shader_file`]) and the ray
/// queries. `tests/gpu_layout.rs` validates them together, every variant in both forms.
pub const SHADER_FILES: [&str; 5] = ["bsdf.wgsl", "trace.wgsl", "bvh_binary.wgsl", "bvh_wide8.wgsl", "rays.wgsl"];

/// The tree form the GPU traces (`render --trace`): the binary tree, or the compressed 8-wide
/// tree ([`super::wide`]), the default. The CPU's `wide4` has no GPU form.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum GpuForm {
    Binary,
    #[default]
    Wide8,
}

impl GpuForm {
    /// The GPU form of a CPU layout name: `binary` and `wide8`; `wide4` is refused.
    pub fn of(layout: crate::bvh::TraceLayout) -> Result<GpuForm, GpuError> {
        match layout {
            crate::bvh::TraceLayout::Binary => Ok(GpuForm::Binary),
            crate::bvh::TraceLayout::Wide8 => Ok(GpuForm::Wide8),
            crate::bvh::TraceLayout::Wide4 => {
                Err(GpuError::Other("--trace wide4 is a CPU form: the GPU traces binary or wide8 (its default)".into()))
            }
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            GpuForm::Binary => "binary",
            GpuForm::Wide8 => "wide8",
        }
    }

    /// Words of one node of its tree.
    fn node_words(self) -> usize {
        match self {
            GpuForm::Binary => size_of::<BvhNode>() / 4,
            GpuForm::Wide8 => super::wide::WIDE_NODE_WORDS,
        }
    }

    /// The WGSL file of its traversal.
    fn shader_file(self) -> &'static str {
        match self {
            GpuForm::Binary => include_str!("../../shaders/bvh_binary.wgsl"),
            GpuForm::Wide8 => include_str!("../../shaders/bvh_wide8.wgsl"),
        }
    }
}

/// Samples per pixel per pass.
pub const PASS_SPP: u32 = 4;

/// About how long one submission of a pass (a band of its rows) runs: short enough that a
/// signal is acted on within a scheduler's grace period with room to spare, long enough that
/// a submission's fixed cost (milliseconds on lavapipe) stays small beside it.
const BAND_SECONDS: f64 = 0.25;

/// The first pass's band, before the pace is known: 64 rows.
const FIRST_BAND_ROWS: u32 = 8 * TRACE_WORKGROUP;

/// What a scene needs of the path tracer: each `false` removes that code from its variant.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Features {
    pub dielectric: bool,
    pub conductor: bool,
    /// The coated (metallic-roughness) material.
    pub coated: bool,
    pub environment: bool,
    /// Emitters to sample: next-event estimation and shadow rays.
    pub lights: bool,
    pub thin_lens: bool,
    /// Vertex normals to shade with.
    pub shading_normals: bool,
    /// An environment map, sampled for next-event estimation.
    pub env_map: bool,
    /// Image textures.
    pub textures: bool,
    /// Cut-out masks, tested in the traversal (only with `textures`). Apart from `textures`,
    /// since the test slows the traversal loop even where no triangle is masked.
    pub cutouts: bool,
    /// Two levels: meshes in object space under a top-level tree of instances. Not a feature
    /// to widen: it says what the scene's buffers are, and a render compiles the variant its
    /// scene's geometry names, whatever this says.
    pub instances: bool,
}

impl Features {
    /// No feature: what ray queries need of the path tracer's source.
    pub const NONE: Features = Features {
        dielectric: false,
        conductor: false,
        coated: false,
        environment: false,
        lights: false,
        thin_lens: false,
        shading_normals: false,
        env_map: false,
        textures: false,
        cutouts: false,
        instances: false,
    };

    /// Every feature: a variant that renders any scene (with its geometry's `instances`).
    pub const ALL: Features = Features {
        dielectric: true,
        conductor: true,
        coated: true,
        environment: true,
        lights: true,
        thin_lens: true,
        shading_normals: true,
        env_map: true,
        textures: true,
        cutouts: true,
        instances: false,
    };

    /// What `scene` uses.
    pub fn of(scene: &RenderScene) -> Features {
        let has = |f: fn(&Bsdf) -> bool| scene.materials.iter().any(|m| m.bsdf.as_ref().is_some_and(f));
        Features {
            dielectric: has(|b| matches!(b, Bsdf::Dielectric { .. })),
            conductor: has(|b| matches!(b, Bsdf::Conductor { .. })),
            coated: has(|b| matches!(b, Bsdf::Coated { .. })),
            environment: scene.environment.is_some(),
            lights: !scene.lights.is_empty(),
            thin_lens: scene.camera.parts().lens_radius != 0.0,
            shading_normals: match &scene.geometry {
                Geometry::Flat(f) => !f.normals.is_empty(),
                Geometry::Instanced(g) => g.mesh_normals().iter().any(|n| !n.is_empty()),
            },
            env_map: scene.environment_light().is_some(),
            textures: scene.materials.iter().any(RenderMaterial::is_textured),
            cutouts: scene.materials.iter().any(|m| m.alpha.is_some()),
            instances: matches!(scene.geometry, Geometry::Instanced(_)),
        }
    }

    /// The pipeline cache key of this variant.
    pub fn key(&self) -> String {
        let b = |x: bool| u8::from(x);
        format!(
            "trace[dielectric={} conductor={} coated={} environment={} lights={} thin_lens={} shading_normals={} env_map={} textures={} cutouts={} instances={}]",
            b(self.dielectric),
            b(self.conductor),
            b(self.coated),
            b(self.environment),
            b(self.lights),
            b(self.thin_lens),
            b(self.shading_normals),
            b(self.env_map),
            b(self.textures),
            b(self.cutouts),
            b(self.instances)
        )
    }

    /// Every combination (cut-outs only with textures), for tests that validate each variant;
    /// two levels with each combination of the features the traversal and the hit's shading
    /// read (lights, shading normals, textures, cut-outs) and the rest off.
    pub fn every() -> Vec<Features> {
        let flat = Self::every_flat();
        let two_level = flat
            .iter()
            .filter(|f| !(f.dielectric || f.conductor || f.coated || f.environment || f.thin_lens || f.env_map))
            .map(|&f| Features { instances: true, ..f });
        flat.iter().copied().chain(two_level).collect()
    }

    fn every_flat() -> Vec<Features> {
        (0..1024u32)
            .filter(|m| m & 512 == 0 || m & 128 != 0)
            .map(|m| Features {
                dielectric: m & 1 != 0,
                conductor: m & 2 != 0,
                environment: m & 4 != 0,
                lights: m & 8 != 0,
                thin_lens: m & 16 != 0,
                shading_normals: m & 32 != 0,
                env_map: m & 64 != 0,
                textures: m & 128 != 0,
                coated: m & 256 != 0,
                cutouts: m & 512 != 0,
                instances: false,
            })
            .collect()
    }
}

/// The path tracer's WGSL for the variant `features` tracing `form`: prelude, `HAS_*`
/// constants, then [`SHADER_FILES`] (of the two traversals, the form's).
pub fn shader_source(features: Features, form: GpuForm) -> String {
    let flags = format!(
        "const HAS_DIELECTRIC: bool = {};\nconst HAS_CONDUCTOR: bool = {};\nconst HAS_COATED: bool = {};\n\
         const HAS_ENVIRONMENT: bool = {};\n\
         const HAS_LIGHTS: bool = {};\nconst HAS_THIN_LENS: bool = {};\nconst HAS_SHADING_NORMALS: bool = {};\n\
         const HAS_ENV_MAP: bool = {};\nconst HAS_TEXTURES: bool = {};\nconst HAS_CUTOUTS: bool = {};\n\
         const HAS_INSTANCES: bool = {};\n",
        features.dielectric,
        features.conductor,
        features.coated,
        features.environment,
        features.lights,
        features.thin_lens,
        features.shading_normals,
        features.env_map,
        features.textures,
        features.textures && features.cutouts,
        features.instances
    );
    with_prelude(&format!(
        "{flags}\n{}\n{}\n{}\n{}",
        include_str!("../../shaders/bsdf.wgsl"),
        include_str!("../../shaders/trace.wgsl"),
        form.shader_file(),
        include_str!("../../shaders/rays.wgsl")
    ))
}

/// Whether `ARBOR_GPU_NO_SPECIALIZE` asks for the all-features variant.
fn specialization_disabled() -> bool {
    std::env::var("ARBOR_GPU_NO_SPECIALIZE").is_ok_and(|v| !v.is_empty() && v != "0")
}

/// A scene on the device, ready to render.
pub struct GpuScene {
    /// The tree in its form: binary nodes, or compressed wide nodes.
    nodes: wgpu::Buffer,
    /// Triangles in the form's order (the binary tree's leaf order, or the wide tree's).
    triangles: wgpu::Buffer,
    /// The primitive id of each triangle position.
    prim_ids: wgpu::Buffer,
    /// Bound where a kernel's layout has a binding it does not use (read-only, read-write).
    unused: (wgpu::Buffer, wgpu::Buffer),
    materials: wgpu::Buffer,
    lights: wgpu::Buffer,
    /// Each triangle's three vertex normals (nine floats, leaf order; zero: none), or one
    /// zero float where the scene has none.
    normals: wgpu::Buffer,
    /// The environment map and its distribution ([`env_map_data`]), or one zero float.
    env_map: wgpu::Buffer,
    /// The textures ([`gpu_texture_data`]) and each triangle's texture coordinates (six floats,
    /// leaf order), or one zero word each.
    textures: wgpu::Buffer,
    uvs: wgpu::Buffer,
    /// Camera, environment, clamp and light count; seed and samples are set per render.
    params: TraceParams,
    /// The variant to compile: [`Features::of`] the scene, or all of them under
    /// `ARBOR_GPU_NO_SPECIALIZE=1`. May be widened (never narrowed) before rendering.
    pub features: Features,
    pub width: u32,
    pub height: u32,
    /// Nodes on the tree's longest root-to-leaf path.
    pub depth: usize,
    /// The form traced.
    pub form: GpuForm,
    /// Bytes of the tree's nodes and triangle order.
    pub tree_bytes: usize,
    /// The tree's SAH cost in its form: [`crate::bvh::sah_cost`] for the binary tree, the wide
    /// tree's own ([`super::wide::CompressedBvh::cost`]); NaN for a wide tree the GPU made.
    pub tree_sah: f64,
    /// A scene for ray queries ([`GpuScene::for_rays`]): each primitive's triangle position;
    /// empty for a render's.
    position_of: Vec<u32>,
    /// A two-level scene's instances, top-level tree and light densities; `None` for a flat one.
    two_level: Option<TwoLevelBuffers>,
}

/// What a two-level scene holds on the device beside its meshes' trees and triangles, the part
/// [`GpuScene::update_instances`] rewrites each frame. The top-level tree itself is at the
/// front of the node buffer, in the form traced, in a region of `tlas_nodes` nodes kept for it.
struct TwoLevelBuffers {
    /// [`GpuInstance`]s in the top-level tree's leaf order (by id for the binary form).
    instances: wgpu::Buffer,
    /// Each light id's area density ([`crate::render::lights::Lights::pdf_area`]).
    light_pdfs: wgpu::Buffer,
    /// Each mesh's root node in the node buffer (`INVALID_INDEX` for a mesh without triangles).
    mesh_roots: Vec<u32>,
    /// Nodes kept for the top-level tree at the front of the node buffer.
    tlas_nodes: usize,
    /// Bytes of the instances, the top-level tree's region and the light densities.
    bytes: usize,
}

/// Nodes on the longest root-to-leaf path of `bvh` (0 for an empty tree).
fn depth(bvh: &Bvh) -> usize {
    if bvh.nodes.is_empty() {
        return 0;
    }
    let mut deepest = 0;
    let mut stack = vec![(0u32, 1usize)];
    while let Some((i, d)) = stack.pop() {
        deepest = deepest.max(d);
        let n = &bvh.nodes[i as usize];
        if !n.is_leaf() {
            stack.push((n.first, d + 1));
            stack.push((n.first + 1, d + 1));
        }
    }
    deepest
}

fn gpu_material(m: &RenderMaterial) -> GpuMaterial {
    let mut g = GpuMaterial { kind: MAT_BLACK, ..Default::default() };
    match m.bsdf {
        None => {}
        Some(Bsdf::Diffuse { albedo }) => {
            g.kind = MAT_DIFFUSE;
            g.albedo = albedo;
        }
        Some(Bsdf::Conductor { alpha, fresnel }) => {
            g.kind = MAT_CONDUCTOR;
            g.alpha = alpha;
            match fresnel {
                ConductorFresnel::Complex { eta, k } => {
                    g.albedo = eta;
                    g.k = k;
                    g.flags |= MAT_COMPLEX_FRESNEL;
                }
                ConductorFresnel::Schlick { f0 } => g.albedo = f0,
            }
        }
        Some(Bsdf::Dielectric { alpha, ior }) => {
            g.kind = MAT_DIELECTRIC;
            g.alpha = alpha;
            g.ior = ior;
        }
        Some(Bsdf::Coated { base_color, metallic, alpha, ior }) => {
            g.kind = MAT_COATED;
            g.albedo = base_color;
            g.k = Vec3::new(metallic, 0.0, 0.0);
            g.alpha = alpha;
            g.ior = ior;
        }
    }
    if let Some(e) = m.emission {
        g.flags |= MAT_EMITS;
        g.emission = e;
    }
    if m.two_sided {
        g.flags |= MAT_TWO_SIDED;
    }
    g.base_color_tex = gpu_texture_ref(m.base_color);
    g.alpha_tex = gpu_texture_ref(m.alpha.map(|(r, _)| r));
    g.alpha_cutoff = m.alpha.map_or(0.0, |(_, c)| c);
    g.normal_tex = gpu_texture_ref(m.normal.map(|(r, _)| r));
    g.normal_scale = m.normal.map_or(1.0, |(_, s)| s);
    g.emission_tex = gpu_texture_ref(m.emission_tex);
    g.roughness_tex = gpu_texture_channel(m.roughness);
    g.metallic_tex = gpu_texture_channel(m.metallic);
    g
}

/// An environment map as `shaders/trace.wgsl` reads it, one array of f32: the texels' RGB
/// (row-major, row 0 at the top), then the distribution's per-cell density (`width` x
/// `sampling_rows(height)` cells), its marginal CDF (`sampling_rows(height) + 1` values) and
/// its conditional CDFs (`width + 1` values a row); the shader finds each part from the map's
/// size alone.
fn env_map_data(map: &EnvironmentMap) -> Vec<f32> {
    let d = &map.distribution;
    let (w, rows) = (map.width as usize, crate::texture::environment::sampling_rows(map.height) as usize);
    assert!(
        d.pdf.len() == w * rows && d.marginal.len() == rows + 1 && d.conditional.len() == rows * (w + 1),
        "the shader finds the tables from the map's size: {w} x {rows} cells"
    );
    let mut data = Vec::with_capacity(map.texels.len() * 3 + d.pdf.len() + d.marginal.len() + d.conditional.len());
    data.extend(map.texels.iter().flatten());
    data.extend(&d.pdf);
    data.extend(&d.marginal);
    data.extend(&d.conditional);
    data
}

/// `data`, or one zeroed element when it is empty (a binding must hold at least one).
fn at_least_one<T: bytemuck::Pod + Default>(mut data: Vec<T>) -> Vec<T> {
    if data.is_empty() {
        data.push(T::default());
    }
    data
}

impl GpuScene {
    /// Uploads a scene, flat or in two levels (see the module docs).
    /// Fails when a buffer is over the adapter's storage-binding limit, or the tree is deeper
    /// than the traversal stack allows.
    pub fn upload(ctx: &GpuContext, scene: &RenderScene, form: GpuForm) -> Result<GpuScene, GpuError> {
        Self::upload_with(ctx, scene, form, None)
    }

    /// [`GpuScene::upload`] with the wide tree the GPU collapse made of the scene's tree
    /// ([`super::wide::collapse_on_device`]), when given: then in the wide form.
    pub fn upload_with(
        ctx: &GpuContext,
        scene: &RenderScene,
        form: GpuForm,
        wide: Option<super::wide::DeviceWide>,
    ) -> Result<GpuScene, GpuError> {
        let geometry = match &scene.geometry {
            Geometry::Flat(flat) => flat_geometry(ctx, scene, flat, form, wide)?,
            Geometry::Instanced(g) => {
                if wide.is_some() {
                    return Err(GpuError::Other("a wide tree made on the GPU is of a flat scene".into()));
                }
                instanced_geometry(ctx, scene, g, form)?
            }
        };
        let materials: Vec<GpuMaterial> = scene.materials.iter().map(gpu_material).collect();
        let textures = if scene.textures.is_empty() { Vec::new() } else { gpu_texture_data(&scene.textures) };
        let lights = gpu_lights(scene);
        let light_count = lights.len() as u32;
        let camera = scene.camera.parts();
        let mut params = TraceParams {
            cam_origin: camera.origin,
            width: scene.width,
            cam_forward: camera.forward,
            height: scene.height,
            cam_right: camera.right,
            tan_x: camera.tan_x,
            cam_up: camera.up,
            tan_y: camera.tan_y,
            environment: scene.environment.as_ref().map_or(Vec3::ZERO, |e| e.radiance),
            lens_radius: camera.lens_radius,
            focus_distance: camera.focus_distance,
            clamp: scene.sample_clamp.unwrap_or(0.0),
            light_count,
            ..Default::default()
        };
        let mut env_map = Vec::new();
        if let Some((map, _, select)) = scene.environment_light() {
            let rows = map.map_from_world;
            (params.env_x, params.env_y, params.env_z) = (rows.row(0), rows.row(1), rows.row(2));
            (params.env_width, params.env_height, params.env_select) = (map.width, map.height, select);
            env_map = env_map_data(map);
        }
        let g = geometry;
        Ok(GpuScene {
            nodes: g.nodes,
            triangles: ctx.storage_buffer("triangles", &at_least_one(g.triangles))?,
            prim_ids: ctx.storage_buffer("triangle ids", &at_least_one(g.prim_ids))?,
            unused: unused_buffers(ctx)?,
            materials: ctx.storage_buffer("materials", &at_least_one(materials))?,
            lights: ctx.storage_buffer("lights", &at_least_one(lights))?,
            normals: ctx.storage_buffer("normals", &at_least_one(g.normals))?,
            env_map: ctx.storage_buffer("environment map", &at_least_one(env_map))?,
            textures: ctx.storage_buffer("textures", &at_least_one(textures))?,
            uvs: ctx.storage_buffer("texture coordinates", &at_least_one(g.uvs))?,
            params,
            features: if specialization_disabled() { Features::ALL } else { Features::of(scene) },
            width: scene.width,
            height: scene.height,
            depth: g.depth,
            form: g.form,
            tree_bytes: g.tree_bytes,
            tree_sah: g.sah,
            position_of: Vec::new(),
            two_level: g.two_level,
        })
    }

    /// Brings a two-level scene's instances up to date with `scene` (the same scene, its
    /// objects moved by [`RenderScene::set_time`]): the instances, the top-level tree and the
    /// lights are uploaded again; the meshes' trees and triangles stay.
    pub fn update_instances(&mut self, ctx: &GpuContext, scene: &RenderScene) -> Result<(), GpuError> {
        let (Geometry::Instanced(g), Some(two_level)) = (&scene.geometry, self.two_level.as_mut()) else {
            return Err(GpuError::Other("update_instances: not a two-level scene".into()));
        };
        let (fresh, tlas) = two_level_buffers(
            ctx,
            scene,
            g,
            std::mem::take(&mut two_level.mesh_roots),
            two_level.tlas_nodes,
            self.form,
        )?;
        ctx.queue.write_buffer(&self.nodes, 0, bytemuck::cast_slice(&tlas));
        let lights = gpu_lights(scene);
        self.params.light_count = lights.len() as u32;
        self.lights = ctx.storage_buffer("lights", &at_least_one(lights))?;
        self.two_level = Some(fresh);
        Ok(())
    }

    /// Bytes of a two-level scene's instances, top-level tree and light densities (0 for a
    /// flat scene): what the scene costs beyond its meshes.
    pub fn instance_bytes(&self) -> usize {
        self.two_level.as_ref().map_or(0, |t| t.bytes)
    }

    /// Bare triangles (by primitive id) under `bvh`, in `form`, for ray queries ([`trace_rays`]):
    /// no materials, lights or camera.
    pub fn for_rays(ctx: &GpuContext, bvh: &Bvh, triangles: &[Triangle], form: GpuForm) -> Result<GpuScene, GpuError> {
        Self::rays_scene(ctx, Tree::new(bvh, triangles, form)?, triangles, form)
    }

    /// [`GpuScene::for_rays`] with a wide tree the host already made (for a caller that times
    /// or inspects it).
    pub fn for_rays_compressed(
        ctx: &GpuContext,
        wide: super::wide::CompressedBvh,
        triangles: &[Triangle],
    ) -> Result<GpuScene, GpuError> {
        Self::rays_scene(ctx, Tree::from_compressed(wide)?, triangles, GpuForm::Wide8)
    }

    /// [`GpuScene::for_rays`] with the wide tree the GPU collapse made.
    pub fn for_rays_with(
        ctx: &GpuContext,
        wide: super::wide::DeviceWide,
        triangles: &[Triangle],
    ) -> Result<GpuScene, GpuError> {
        Self::rays_scene(ctx, Tree::from_device(wide)?, triangles, GpuForm::Wide8)
    }

    fn rays_scene(
        ctx: &GpuContext,
        mut tree: Tree,
        triangles: &[Triangle],
        form: GpuForm,
    ) -> Result<GpuScene, GpuError> {
        let gpu_triangles: Vec<GpuTriangle> = tree
            .prim_ids
            .iter()
            .map(|&prim| {
                let t = &triangles[prim as usize];
                GpuTriangle { v0: t.v0, v1: t.v1, v2: t.v2, ..Default::default() }
            })
            .collect();
        let one = |what| ctx.storage_buffer(what, &[0u32; 4]);
        let mut position_of = vec![INVALID_INDEX; triangles.len()];
        for (pos, &prim) in tree.prim_ids.iter().enumerate() {
            position_of[prim as usize] = pos as u32;
        }
        let tree_bytes = tree.bytes();
        Ok(GpuScene {
            nodes: tree.buffer(ctx)?,
            triangles: ctx.storage_buffer("triangles", &at_least_one(gpu_triangles))?,
            prim_ids: ctx.storage_buffer("triangle ids", &at_least_one(std::mem::take(&mut tree.prim_ids)))?,
            unused: unused_buffers(ctx)?,
            materials: ctx.storage_buffer("materials", &[GpuMaterial::default()])?,
            lights: ctx.storage_buffer("lights", &[GpuLight::default()])?,
            normals: one("normals")?,
            env_map: one("environment map")?,
            textures: one("textures")?,
            uvs: one("texture coordinates")?,
            params: TraceParams::default(),
            features: Features::NONE,
            width: 0,
            height: 0,
            depth: tree.depth,
            form,
            tree_bytes,
            tree_sah: tree.sah,
            position_of,
            two_level: None,
        })
    }
}

/// The buffers bound to a kernel's unused bindings: one read-only, one read-write.
fn unused_buffers(ctx: &GpuContext) -> Result<(wgpu::Buffer, wgpu::Buffer), GpuError> {
    // Large enough for one element of any array bound (a GpuInstance is the largest).
    Ok((ctx.storage_buffer("unused", &[0u32; 64])?, ctx.storage_buffer("unused", &[0u32; 64])?))
}

/// A scene's geometry as the GPU reads it, before the rest of the upload.
struct GeometryData {
    nodes: wgpu::Buffer,
    triangles: Vec<GpuTriangle>,
    prim_ids: Vec<u32>,
    normals: Vec<f32>,
    uvs: Vec<f32>,
    depth: usize,
    form: GpuForm,
    tree_bytes: usize,
    sah: f64,
    two_level: Option<TwoLevelBuffers>,
}

/// A flat scene's tree (or the wide tree the GPU made of it) and its triangles in the tree's
/// order, with their materials, light densities, normals and texture coordinates.
fn flat_geometry(
    ctx: &GpuContext,
    scene: &RenderScene,
    flat: &crate::render::geometry::Flat,
    form: GpuForm,
    wide: Option<super::wide::DeviceWide>,
) -> Result<GeometryData, GpuError> {
    let (mut tree, form) = match wide {
        Some(w) => (Tree::from_device(w)?, GpuForm::Wide8),
        None => (Tree::new(&flat.mesh.bvh, &flat.triangles, form)?, form),
    };
    // The nodes go first: a device tree's buffer is taken, its bytes counted before.
    let tree_bytes = tree.bytes();
    let nodes = tree.buffer(ctx)?;
    let order = &tree.prim_ids;
    let triangles: Vec<GpuTriangle> = order
        .par_iter()
        .map(|&prim| {
            let t = &flat.triangles[prim as usize];
            GpuTriangle {
                v0: t.v0,
                material: flat.material_of[prim as usize],
                v1: t.v1,
                light_pdf: scene.lights.pdf_area(prim),
                v2: t.v2,
                cutout: u32::from(scene.materials[flat.material_of[prim as usize] as usize].alpha.is_some()),
            }
        })
        .collect();
    let normals: Vec<f32> = if flat.normals.is_empty() {
        Vec::new()
    } else {
        order.iter().flat_map(|&prim| flat.normals[prim as usize].map(|n| n.to_array())).flatten().collect()
    };
    let uvs: Vec<f32> = if scene.textures.is_empty() {
        Vec::new()
    } else if flat.uvs.is_empty() {
        // No mesh has coordinates: every lookup is at (0, 0), as on the CPU.
        vec![0.0; 6 * order.len()]
    } else {
        order.iter().flat_map(|&prim| flat.uvs[prim as usize].map(|t| t.to_array())).flatten().collect()
    };
    Ok(GeometryData {
        nodes,
        triangles,
        prim_ids: std::mem::take(&mut tree.prim_ids),
        normals,
        uvs,
        depth: tree.depth,
        form,
        tree_bytes,
        sah: tree.sah,
        two_level: None,
    })
}

/// A two-level scene: every mesh's tree in `form`, built once, in one node buffer (each tree's
/// child and triangle indices moved by where it starts), the meshes' object-space triangles in
/// one array in their trees' orders (with their materials, normals and texture coordinates),
/// and the instances with their top-level tree ([`two_level_buffers`]). A mesh placed many
/// times is stored once, so the memory follows the instances, not the world's triangles.
fn instanced_geometry(
    ctx: &GpuContext,
    scene: &RenderScene,
    g: &crate::render::geometry::Instanced,
    form: GpuForm,
) -> Result<GeometryData, GpuError> {
    let meshes = g.two_level.meshes();
    let node_words = form.node_words();
    let has_alpha = |m: u32| scene.materials.get(m as usize).is_some_and(|m| m.alpha.is_some());
    // A mesh whose triangles some object overrides with a masked material: its triangles are
    // tested for cut-outs (with the override, where the instance has one).
    let mut overridden_masked = vec![false; meshes.len()];
    for (inst, over) in g.two_level.instances().iter().zip(g.instance_materials()) {
        if over.is_some_and(has_alpha) {
            overridden_masked[inst.mesh as usize] = true;
        }
    }
    let with_normals = g.mesh_normals().iter().any(|n| !n.is_empty());
    let with_uvs = !scene.textures.is_empty();
    // The top-level tree's region first (its root is node 0, as a flat scene's root is), then
    // the meshes.
    let tlas_nodes = tlas_capacity(g.two_level.instances().len(), form);
    let (mut words, mut prim_ids, mut triangles) = (vec![0u32; tlas_nodes * node_words], Vec::new(), Vec::new());
    let (mut normals, mut uvs, mut mesh_roots) = (Vec::new(), Vec::new(), Vec::with_capacity(meshes.len()));
    let (mut depth, mut sah, mut largest) = (0, 0.0, 0);
    for (m, mesh) in meshes.iter().enumerate() {
        let tris = &g.mesh_triangles()[m];
        if tris.is_empty() {
            mesh_roots.push(INVALID_INDEX);
            continue;
        }
        let tree = Tree::new(&mesh.bvh, tris, form)?;
        let node_base = u32::try_from(words.len() / node_words).map_err(|_| too_many("nodes"))?;
        let tri_base = u32::try_from(prim_ids.len()).map_err(|_| too_many("triangles"))?;
        mesh_roots.push(node_base);
        for node in tree.words.chunks_exact(node_words) {
            let mut node = node.to_vec();
            match form {
                // BvhNode: `first` (word 3) is a child for an inner node, a triangle position
                // for a leaf (`prim_count`, word 7, above 0).
                GpuForm::Binary => node[3] += if node[7] > 0 { tri_base } else { node_base },
                // The child base and the triangle base (words 4 and 5).
                GpuForm::Wide8 => {
                    node[4] += node_base;
                    node[5] += tri_base;
                }
            }
            words.extend(node);
        }
        (depth, largest) = (depth.max(tree.depth), largest.max(tris.len()));
        if tris.len() == largest {
            sah = tree.sah;
        }
        let (materials, mesh_normals, mesh_uvs) = (&g.mesh_materials()[m], &g.mesh_normals()[m], &g.mesh_uvs()[m]);
        for &prim in &tree.prim_ids {
            let (t, material) = (&tris[prim as usize], materials[prim as usize]);
            let cutout = u32::from(overridden_masked[m] || has_alpha(material));
            triangles.push(GpuTriangle { v0: t.v0, material, v1: t.v1, light_pdf: 0.0, v2: t.v2, cutout });
            if with_normals {
                let n = mesh_normals.get(prim as usize).copied().unwrap_or([Vec3::ZERO; 3]);
                normals.extend(n.iter().flat_map(|v| v.to_array()));
            }
            if with_uvs {
                let t = mesh_uvs.get(prim as usize).copied().unwrap_or([Vec2::ZERO; 3]);
                uvs.extend(t.iter().flat_map(|v| v.to_array()));
            }
        }
        prim_ids.extend(&tree.prim_ids);
    }
    let (two_level, tlas) = two_level_buffers(ctx, scene, g, mesh_roots, tlas_nodes, form)?;
    words[..tlas.len()].copy_from_slice(&tlas);
    let tree_bytes = size_of_val(&words[tlas_nodes * node_words..]) + size_of_val(prim_ids.as_slice());
    let nodes = ctx.storage_buffer("BVH nodes", &words)?;
    Ok(GeometryData {
        nodes,
        triangles,
        prim_ids,
        normals,
        uvs,
        depth,
        form,
        tree_bytes,
        sah,
        two_level: Some(two_level),
    })
}

fn too_many(what: &str) -> GpuError {
    GpuError::Other(format!("over 2^32 {what} in the meshes of a two-level scene"))
}

/// Nodes kept for the top-level tree of `instances` instances in `form`: a binary tree with one
/// instance a leaf has `2n - 1`; a wide one at most `n` (every node but a lone root has two
/// lanes or more).
fn tlas_capacity(instances: usize, form: GpuForm) -> usize {
    match form {
        GpuForm::Binary => (2 * instances).saturating_sub(1).max(1),
        GpuForm::Wide8 => instances.max(1),
    }
}

/// The instances of `g` as the GPU reads them (their meshes' roots `mesh_roots`, in the top-level
/// tree's leaf order) and each light id's area density, uploaded; and the top-level tree's words
/// in `form`, for the node buffer's first `tlas_nodes` nodes.
fn two_level_buffers(
    ctx: &GpuContext,
    scene: &RenderScene,
    g: &crate::render::geometry::Instanced,
    mesh_roots: Vec<u32>,
    tlas_nodes: usize,
    form: GpuForm,
) -> Result<(TwoLevelBuffers, Vec<u32>), GpuError> {
    let (tlas, order) = top_level_words(g, form)?;
    let node_words = form.node_words();
    if tlas.len() > tlas_nodes * node_words {
        return Err(GpuError::Other(format!(
            "the top-level BVH has {} nodes, more than the {tlas_nodes} kept for it",
            tlas.len() / node_words
        )));
    }
    let bases = g.light_bases();
    let mesh_sizes: Vec<usize> = g.mesh_triangles().iter().map(Vec::len).collect();
    let all = g.two_level.instances();
    let light_ids = all
        .iter()
        .zip(bases)
        .filter(|(_, b)| **b != INVALID_INDEX)
        .map(|(inst, &b)| b as usize + mesh_sizes[inst.mesh as usize])
        .max()
        .unwrap_or(0);
    let instances: Vec<GpuInstance> = order
        .iter()
        .map(|&id| {
            let (i, inst) = (id as usize, &all[id as usize]);
            let (o, w) = (&inst.object_from_world, &inst.world_from_object);
            GpuInstance {
                to_object_x: o.matrix3.x_axis.into(),
                root: mesh_roots[inst.mesh as usize],
                to_object_y: o.matrix3.y_axis.into(),
                material: g.instance_materials()[i].unwrap_or(INVALID_INDEX),
                to_object_z: o.matrix3.z_axis.into(),
                light_base: bases.get(i).copied().unwrap_or(INVALID_INDEX),
                to_object_t: o.translation.into(),
                mirrors: u32::from(inst.mirrors),
                to_world_x: w.matrix3.x_axis.into(),
                id,
                to_world_y: w.matrix3.y_axis.into(),
                to_world_z: w.matrix3.z_axis.into(),
                to_world_t: w.translation.into(),
                ..Default::default()
            }
        })
        .collect();
    let light_pdfs: Vec<f32> = (0..light_ids as u32).map(|id| scene.lights.pdf_area(id)).collect();
    let bytes = size_of_val(instances.as_slice()) + tlas_nodes * node_words * 4 + size_of_val(light_pdfs.as_slice());
    let buffers = TwoLevelBuffers {
        instances: ctx.storage_buffer("instances", &at_least_one(instances))?,
        light_pdfs: ctx.storage_buffer("light densities", &at_least_one(light_pdfs))?,
        mesh_roots,
        tlas_nodes,
        bytes,
    };
    Ok((buffers, tlas))
}

/// The top-level tree of `g` in `form` as words, and the instance id at each of its leaf
/// positions. Binary: the host's dynamic tree laid out afresh depth-first (its free slots
/// dropped), a leaf's `first` the instance's position, positions in id order. Wide: that tree
/// collapsed by the wide SAH ([`super::wide::CompressedBvh`]), leaf lanes of up to three
/// instances, positions in the wide tree's order. An empty top level is one node every ray
/// misses.
fn top_level_words(g: &crate::render::geometry::Instanced, form: GpuForm) -> Result<(Vec<u32>, Vec<u32>), GpuError> {
    let top = g.two_level.top_level();
    let n = g.two_level.instances().len() as u32;
    if top.is_empty() {
        let words = match form {
            GpuForm::Binary => bytemuck::cast_slice(&[BvhNode::leaf(Aabb::EMPTY, 0, 1)]).to_vec(),
            // No lane in use: nothing is entered.
            GpuForm::Wide8 => vec![0; super::wide::WIDE_NODE_WORDS],
        };
        return Ok((words, (0..n).collect()));
    }
    let bvh = top.bvh();
    let (words, order, depth) = match form {
        GpuForm::Binary => {
            let mut nodes = vec![bvh.nodes[0]];
            let mut stack = vec![(0usize, 0usize, 1usize)];
            let mut deepest = 1;
            while let Some((src, dst, d)) = stack.pop() {
                deepest = deepest.max(d);
                let node = bvh.nodes[src];
                if node.is_leaf() {
                    // One instance a leaf (DynamicBvh), its id through prim_ids.
                    let id = bvh.prim_ids[node.first as usize];
                    nodes[dst] = BvhNode::leaf(node.aabb(), id, 1);
                } else {
                    let first = nodes.len();
                    nodes.push(bvh.nodes[node.first as usize]);
                    nodes.push(bvh.nodes[node.first as usize + 1]);
                    nodes[dst].first = first as u32;
                    stack.push((node.first as usize, first, d + 1));
                    stack.push((node.first as usize + 1, first + 1, d + 1));
                }
            }
            (bytemuck::cast_slice(&nodes).to_vec(), (0..n).collect(), deepest)
        }
        GpuForm::Wide8 => {
            let wide = super::wide::CompressedBvh::new(bvh, g.two_level.instance_boxes());
            let depth = wide.depth;
            (wide.nodes.iter().flatten().copied().collect(), wide.prim_ids, depth)
        }
    };
    check_depth(depth, form).map_err(|e| GpuError::Other(format!("the top level: {e}")))?;
    Ok((words, order))
}

/// The scene's lights as the GPU reads them.
fn gpu_lights(scene: &RenderScene) -> Vec<GpuLight> {
    scene
        .lights
        .gpu_arrays()
        .into_iter()
        .map(|(t, cdf, l, texture)| {
            let uvs = texture.map_or([Vec2::ZERO; 3], |(_, uvs)| uvs);
            GpuLight {
                v0: t.v0,
                cdf,
                v1: t.v1,
                pdf_area: l.pdf_area,
                v2: t.v2,
                two_sided: u32::from(l.two_sided),
                normal: l.normal,
                emission_tex: gpu_texture_ref(texture.map(|(r, _)| r)),
                radiance: l.radiance,
                uvs: [uvs[0].x, uvs[0].y, uvs[1].x, uvs[1].y, uvs[2].x, uvs[2].y],
                ..Default::default()
            }
        })
        .collect()
}

/// A tree in the form the GPU traces, before upload.
struct Tree {
    /// Binary nodes, or compressed wide nodes, as words on the host, or already on the device
    /// (the GPU collapse's) with their bytes.
    words: Vec<u32>,
    on_device: Option<(wgpu::Buffer, usize)>,
    /// The primitive id at each triangle position.
    prim_ids: Vec<u32>,
    depth: usize,
    sah: f64,
}

impl Tree {
    /// `bvh` (leaf-collapsed or not) over `triangles` (by primitive id) in `form`; a tree deeper
    /// than the form's traversal stack allows is refused.
    fn new(bvh: &Bvh, triangles: &[Triangle], form: GpuForm) -> Result<Tree, GpuError> {
        let (words, prim_ids, depth, sah) = match form {
            GpuForm::Binary => {
                let nodes: Vec<BvhNode> = if bvh.nodes.is_empty() {
                    // One leaf with an empty box: every ray misses it.
                    vec![BvhNode::leaf(Aabb::EMPTY, 0, 1)]
                } else {
                    bvh.nodes.to_vec()
                };
                let words = bytemuck::cast_slice(&nodes).to_vec();
                (words, bvh.prim_ids.clone(), depth(bvh), crate::bvh::sah_cost(bvh))
            }
            GpuForm::Wide8 => {
                let prim_aabbs: Vec<Aabb> = triangles.par_iter().map(Triangle::aabb).collect();
                return Tree::from_compressed(super::wide::CompressedBvh::new(bvh, &prim_aabbs));
            }
        };
        check_depth(depth, form)?;
        Ok(Tree { words, on_device: None, prim_ids, depth, sah })
    }

    /// A wide tree the host made.
    fn from_compressed(wide: super::wide::CompressedBvh) -> Result<Tree, GpuError> {
        check_depth(wide.depth, GpuForm::Wide8)?;
        let words = wide.nodes.iter().flatten().copied().collect();
        Ok(Tree { words, on_device: None, prim_ids: wide.prim_ids, depth: wide.depth, sah: wide.cost })
    }

    /// The wide tree the GPU collapse left on the device.
    fn from_device(wide: super::wide::DeviceWide) -> Result<Tree, GpuError> {
        check_depth(wide.depth, GpuForm::Wide8)?;
        let bytes = wide.node_count * super::wide::WIDE_NODE_WORDS * 4;
        Ok(Tree {
            words: Vec::new(),
            on_device: Some((wide.nodes, bytes)),
            prim_ids: wide.prim_ids,
            depth: wide.depth,
            sah: f64::NAN,
        })
    }

    /// The nodes' buffer: uploaded, or the device's own (taken: call [`Tree::bytes`] first).
    fn buffer(&mut self, ctx: &GpuContext) -> Result<wgpu::Buffer, GpuError> {
        match self.on_device.take() {
            Some((buffer, _)) => Ok(buffer),
            None => ctx.storage_buffer("BVH nodes", &self.words),
        }
    }

    fn bytes(&self) -> usize {
        let nodes = self.on_device.as_ref().map_or(size_of_val(self.words.as_slice()), |(_, b)| *b);
        nodes + size_of_val(self.prim_ids.as_slice())
    }
}

/// Refuses a tree deeper than `form`'s traversal stack allows.
fn check_depth(depth: usize, form: GpuForm) -> Result<(), GpuError> {
    let stack = match form {
        GpuForm::Binary => TRACE_STACK_SIZE,
        GpuForm::Wide8 => WIDE_STACK_SIZE,
    };
    if depth > stack as usize + 1 {
        return Err(GpuError::Other(format!(
            "the {} BVH is {depth} nodes deep, deeper than the GPU traversal stack allows ({stack} entries: \
             depth {}); use another builder or --device cpu",
            form.name(),
            stack + 1
        )));
    }
    Ok(())
}

impl GpuScene {
    /// Sets the firefly clamp ([`RenderScene::sample_clamp`]; `None`: off).
    pub fn set_clamp(&mut self, clamp: Option<f32>) {
        self.params.clamp = clamp.unwrap_or(0.0);
    }
}

/// A flat [`RenderScene`] of `scene` as it stands at `time`: every object's triangles in world
/// space under one BVH built with `builder`, then the default leaf collapse; materials, lights
/// and camera as [`RenderScene::build`] makes them. How the GPU rendered animated scenes before
/// it had two levels, kept for `bvh-bench --animated --gpu` to compare against.
pub fn flatten(scene: &Scene, time: f32, builder: &Builder) -> (RenderScene, BuildReport) {
    let start = Instant::now();
    let (triangles, material_of) = scene.world_triangles_at(time);
    let prims: Vec<Aabb> = triangles.par_iter().map(Triangle::aabb).collect();
    let built = builder.build(&triangles, &prims, &PrbvhConfig { collapse: None, ..Default::default() });
    let label = format!("{builder}, flattened for the GPU");
    RenderScene::assemble(scene, (triangles, material_of, time), &built.bvh, start, label, crate::bvh::Tracing::gpu())
}

/// The pipeline of `scene`'s variant and form, entry point `entry` (`trace` or `trace_rays`),
/// compiled on first use and cached in `ctx`.
fn pipeline(ctx: &GpuContext, scene: &GpuScene, entry: &str) -> wgpu::ComputePipeline {
    let features = Features { instances: scene.two_level.is_some(), ..scene.features };
    let form = scene.form;
    ctx.pipeline_with_layout(
        &format!("{}[{}]", features.key(), form.name()),
        || shader_source(features, form),
        entry,
        || layout(ctx),
    )
}

/// Bindings of the path tracer and the ray queries, one layout for both kernels: `(binding,
/// read-only)`.
const BINDINGS: [(u32, bool); 15] = [
    (0, true),   // params
    (1, true),   // nodes
    (2, true),   // triangles
    (3, true),   // materials
    (4, true),   // lights
    (5, false),  // film
    (6, true),   // normals
    (7, true),   // environment map
    (8, true),   // textures
    (9, true),   // texture coordinates
    (10, true),  // triangle ids
    (11, true),  // query rays
    (12, false), // query hits
    (13, true),  // instances
    (14, true),  // light densities
];

/// The layout of [`BINDINGS`]: explicit, so that a kernel that reads fewer of them (the ray
/// queries read no film) binds the same group.
fn layout(ctx: &GpuContext) -> wgpu::PipelineLayout {
    let entries: Vec<wgpu::BindGroupLayoutEntry> = BINDINGS
        .iter()
        .map(|&(binding, read_only)| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        })
        .collect();
    let group = ctx
        .device
        .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some("trace"), entries: &entries });
    ctx.device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("trace"),
        bind_group_layouts: &[Some(&group)],
        immediate_size: 0,
    })
}

/// The bind group of a render of `scene` with these parameters and film (as `(buffer, offset,
/// size)` in bytes: a band of rows of it), or of a ray query with its rays and hits in place
/// of the film.
fn bind_group(
    ctx: &GpuContext,
    pipeline: &wgpu::ComputePipeline,
    scene: &GpuScene,
    params: &wgpu::Buffer,
    film: Option<(&wgpu::Buffer, u64, u64)>,
    query: Option<(&wgpu::Buffer, &wgpu::Buffer)>,
) -> wgpu::BindGroup {
    fn whole(binding: u32, b: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
        wgpu::BindGroupEntry { binding, resource: b.as_entire_binding() }
    }
    let (unused_read, unused_write) = (&scene.unused.0, &scene.unused.1);
    let film = match film {
        Some((buffer, offset, size)) => wgpu::BindGroupEntry {
            binding: 5,
            resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer,
                offset,
                size: std::num::NonZeroU64::new(size),
            }),
        },
        None => whole(5, unused_write),
    };
    let (rays, hits) = query.unwrap_or((unused_read, unused_write));
    let entries = [
        whole(0, params),
        whole(1, &scene.nodes),
        whole(2, &scene.triangles),
        whole(3, &scene.materials),
        whole(4, &scene.lights),
        film,
        whole(6, &scene.normals),
        whole(7, &scene.env_map),
        whole(8, &scene.textures),
        whole(9, &scene.uvs),
        whole(10, &scene.prim_ids),
        whole(11, rays),
        whole(12, hits),
        whole(13, scene.two_level.as_ref().map_or(unused_read, |t| &t.instances)),
        whole(14, scene.two_level.as_ref().map_or(unused_read, |t| &t.light_pdfs)),
    ];
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    })
}

/// Compiles `scene`'s variant, if this context has not yet, and runs it once on no pixels:
/// drivers may compile at the first dispatch (lavapipe does, for about a second), so a render
/// timed after this call times rendering alone.
pub fn compile(ctx: &GpuContext, scene: &GpuScene) -> Result<(), GpuError> {
    let pipeline = pipeline(ctx, scene, "trace");
    let params = TraceParams { width: 0, height: 0, ..scene.params };
    let params = ctx.storage_buffer("trace parameters", std::slice::from_ref(&params))?;
    let film = ctx.storage_buffer_zeroed("film", size_of::<GpuPixel>() as u64)?;
    let bind_group = bind_group(ctx, &pipeline, scene, &params, Some((&film, 0, size_of::<GpuPixel>() as u64)), None);
    let mut encoder = ctx.device.create_command_encoder(&Default::default());
    {
        let mut pass = encoder.begin_compute_pass(&Default::default());
        pass.set_pipeline(&pipeline);
        pass.set_bind_group(0, &bind_group, &[]);
        pass.dispatch_workgroups(1, 1, 1);
    }
    ctx.queue.submit([encoder.finish()]);
    ctx.wait()
}

/// A ray for [`trace_rays`]: hits with `0 < t <= t_max` count, and primitive `skip`
/// (`INVALID_INDEX`: none) is left out, as the CPU's [`crate::bvh::Skip`] leaves it.
#[derive(Clone, Copy, Debug)]
pub struct QueryRay {
    pub ray: crate::geometry::Ray,
    pub t_max: f32,
    pub skip: u32,
}

/// A closest hit found by [`trace_rays`]: the primitive id (`INVALID_INDEX`: none), `t`, and the
/// barycentric `u`, `v`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QueryHit {
    pub prim: u32,
    pub t: f32,
    pub u: f32,
    pub v: f32,
}

/// Traces `rays` through `scene` ([`GpuScene::for_rays`] or a flat render's) in one dispatch, for
/// closest hits, or for any hit when `any` (then only `prim` says something: 0 for a hit,
/// `INVALID_INDEX` for none). Returns the hits and the device's seconds for the dispatch alone
/// (upload and read-back excluded, kernel compiled beforehand).
pub fn trace_rays(
    ctx: &GpuContext,
    scene: &GpuScene,
    rays: &[QueryRay],
    any: bool,
) -> Result<(Vec<QueryHit>, f64), GpuError> {
    if scene.two_level.is_some() {
        return Err(GpuError::Other("ray queries take a flat scene (a hit names a primitive, not an instance)".into()));
    }
    let count = u32::try_from(rays.len()).map_err(|_| GpuError::Other("over 2^32 rays in one query".into()))?;
    if rays.iter().any(|q| q.skip != INVALID_INDEX && scene.position_of.get(q.skip as usize).is_none()) {
        return Err(GpuError::Other("a query ray skips a primitive the scene does not have".into()));
    }
    let pipeline = pipeline(ctx, scene, "trace_rays");
    let data: Vec<[f32; 4]> = rays
        .iter()
        .flat_map(|q| {
            let (o, d) = (q.ray.origin, q.ray.dir);
            let skip = if q.skip == INVALID_INDEX { INVALID_INDEX } else { scene.position_of[q.skip as usize] };
            [[o.x, o.y, o.z, q.t_max], [d.x, d.y, d.z, f32::from_bits(skip)]]
        })
        .collect();
    let rays_buffer = ctx.storage_buffer("query rays", &at_least_one(data))?;
    let hits_buffer = ctx.storage_buffer_zeroed("query hits", u64::from(count.max(1)) * 16)?;
    let params = TraceParams { width: count, height: u32::from(any), ..Default::default() };
    let params = ctx.storage_buffer("query parameters", std::slice::from_ref(&params))?;
    let bind_group = bind_group(ctx, &pipeline, scene, &params, None, Some((&rays_buffer, &hits_buffer)));
    let run = |groups: (u32, u32)| -> Result<f64, GpuError> {
        let mut encoder = ctx.device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            pass.dispatch_workgroups(groups.0, groups.1, 1);
        }
        let start = Instant::now();
        ctx.queue.submit([encoder.finish()]);
        ctx.wait()?;
        Ok(start.elapsed().as_secs_f64())
    };
    // Drivers may compile at the first dispatch: one empty dispatch first.
    run((0, 0))?;
    let seconds = run(ctx.dispatch_size(count))?;
    let words: Vec<[u32; 4]> = ctx.read_buffer("query hits", &hits_buffer, rays.len())?;
    let hits = words
        .iter()
        .map(|w| {
            if any {
                QueryHit { prim: if w[0] != 0 { 0 } else { INVALID_INDEX }, t: 0.0, u: 0.0, v: 0.0 }
            } else {
                QueryHit { prim: w[1], t: f32::from_bits(w[0]), u: f32::from_bits(w[2]), v: f32::from_bits(w[3]) }
            }
        })
        .collect();
    Ok((hits, seconds))
}

/// What [`render`] returns.
pub struct GpuRender {
    /// Every sample taken, with per-pixel standard errors, as the CPU's film: of the rectangle
    /// rendered, its pixel (0, 0) the rectangle's top left.
    pub film: Film,
    /// Rays traced (camera, bounce and shadow rays), those of a carried-on [`PartialFilm`]
    /// included.
    pub rays: u64,
    /// Samples per pixel taken, those of a carried-on [`PartialFilm`] included.
    pub samples: u32,
    /// The sample index the render reached: it holds samples `samples.start..end`.
    pub end: u32,
    /// Samples per pixel that came from the [`PartialFilm`] carried on, and the device's seconds
    /// for them (0 and 0.0 for a render from scratch).
    pub carried: (u32, f64),
}

/// Samples already taken on the device: the film of a whole-image render stopped after its
/// first `samples` samples per pixel, for [`render_from`] to carry on. `auto` keeps the passes
/// it timed ([`measure_speed`]), which are the render's own first samples, so that they are not
/// thrown away.
pub struct PartialFilm {
    buffer: wgpu::Buffer,
    samples: u32,
    /// What the samples depend on, checked by [`render_from`].
    key: FilmKey,
    seconds: f64,
}

impl PartialFilm {
    /// Samples per pixel taken.
    pub fn samples(&self) -> u32 {
        self.samples
    }

    /// The device's seconds for them.
    pub fn seconds(&self) -> f64 {
        self.seconds
    }
}

/// Renders `spp` samples per pixel (samples `0..spp` of each pixel's streams under `seed`) of
/// the whole image with paths of at most `max_depth` segments, in passes of [`PASS_SPP`].
pub fn render(ctx: &GpuContext, scene: &GpuScene, seed: u64, max_depth: u32, spp: u32) -> Result<GpuRender, GpuError> {
    let settings = RenderSettings { spp, seed, max_depth, ..Default::default() };
    render_from(
        ctx,
        scene,
        Pass::new(&settings, Region { rect: Rect::full(scene.width, scene.height), samples: 0..spp }),
    )
}

/// Renders `pass`: samples `pass.region.samples` of each pixel of its rectangle, in passes of
/// [`PASS_SPP`], under the pass's seed and path depth. After each pass has finished on the
/// device, the pass's progress hears of it, and the render stops there where the pass's time
/// budget is spent (the carried samples' seconds included) or its pause says so. It carries on
/// from `pass.carried` where that holds samples of this very render: the whole image, the same
/// seed, path depth and clamp, samples `0..k` with `region.samples.start == 0` and
/// `k <= region.samples.end`. The film is then the one an uninterrupted render gives (the film's
/// sums are exact). The tree may differ: every tree finds the same closest hits, but for exact
/// ties (a path through an edge shared by two triangles). A carried film of another render is
/// dropped and the render starts from scratch.
pub fn render_from(ctx: &GpuContext, scene: &GpuScene, mut pass: Pass<'_, PartialFilm>) -> Result<GpuRender, GpuError> {
    let (rect, samples) = (pass.region.rect, pass.region.samples.clone());
    let key = film_key(scene, pass.settings.seed, pass.settings.max_depth, rect);
    pass.carried = pass.carried.filter(|s| s.key == key && samples.start == 0 && s.samples <= samples.end);
    let carried = pass.carried.as_ref().map_or((0, 0.0), |s| (s.samples, s.seconds));
    let film = passes(ctx, scene, pass)?;
    let pixels = rect.pixel_count() as usize;
    let sums: Vec<GpuPixel> = ctx.read_buffer("film", &film.buffer, pixels)?;
    let width = rect.width() as usize;
    let mut out = Film::new(rect.width(), rect.height());
    out.rows_mut().for_each(|(y, row)| {
        for (x, px) in row.iter_mut().enumerate() {
            *px = pixel_accum(&sums[y as usize * width + x]);
        }
    });
    let rays = sums.iter().map(|p| u64::from(p.rays)).sum();
    Ok(GpuRender { film: out, rays, samples: film.samples - samples.start, end: film.samples, carried })
}

/// What a film's samples depend on besides the scene: [`PartialFilm::key`].
type FilmKey = (u64, u32, u32, Rect);

fn film_key(scene: &GpuScene, seed: u64, max_depth: u32, rect: Rect) -> FilmKey {
    (seed, max_depth, scene.params.clamp.to_bits(), rect)
}

/// The passes of [`render_from`] (its carried film already checked), the film left on the
/// device; its `samples` is the sample index reached.
fn passes(ctx: &GpuContext, scene: &GpuScene, pass: Pass<'_, PartialFilm>) -> Result<PartialFilm, GpuError> {
    let Pass { settings, region: Region { rect, samples }, carried: start, progress, pause, abandon } = pass;
    let (seed, max_depth) = (settings.seed, settings.max_depth);
    // The time budget counts from here, setting up included, as the render's seconds do.
    let budget_clock = std::time::Instant::now();
    assert!(rect.x1 <= scene.width && rect.y1 <= scene.height, "{rect} outside the image");
    let pixels = rect.pixel_count() as usize;
    let groups = (rect.width().div_ceil(TRACE_WORKGROUP), rect.height().div_ceil(TRACE_WORKGROUP));
    let max_groups = ctx.limits.max_compute_workgroups_per_dimension;
    if groups.0 > max_groups || groups.1 > max_groups {
        return Err(GpuError::Other(format!(
            "a {}x{} rectangle needs {groups:?} workgroups, over the adapter's {max_groups} per dimension",
            rect.width(),
            rect.height()
        )));
    }
    let key = film_key(scene, seed, max_depth, rect);
    let (mut film_buffer, mut done, mut seconds) = match start {
        Some(s) => (s.buffer, s.samples, s.seconds),
        None => {
            (ctx.storage_buffer_zeroed("film", (pixels.max(1) * size_of::<GpuPixel>()) as u64)?, samples.start, 0.0)
        }
    };
    let mut params = TraceParams {
        seed_lo: seed as u32,
        seed_hi: (seed >> 32) as u32,
        max_depth,
        origin_x: rect.x0,
        origin_y: rect.y0,
        rect_width: rect.width(),
        rect_height: rect.height(),
        ..scene.params
    };
    // A storage buffer, not a uniform one: lavapipe (Mesa 22) inlines uniform values into the
    // shader at every dispatch, which cost time and leaked memory on every pass of this kernel.
    let params_buffer = ctx.storage_buffer("trace parameters", std::slice::from_ref(&params))?;
    let pipeline = pipeline(ctx, scene, "trace");
    let started = std::time::Instant::now();
    let (height, total) = (u64::from(rect.height()), u64::from(samples.len() as u32) * u64::from(rect.height()));
    let carried_seconds = seconds;
    let within_budget =
        || settings.time.is_none_or(|budget| carried_seconds + budget_clock.elapsed().as_secs_f64() < budget);
    // A pass is submitted in bands of rows, each short enough (about BAND_SECONDS) that a signal
    // is heard between them. A pass cut by `abandon` is dropped whole: the film as it was before
    // it is kept in `backup` while a pass runs in more than one band.
    let film_bytes = (pixels.max(1) * size_of::<GpuPixel>()) as u64;
    let row_bytes = u64::from(rect.width()) * size_of::<GpuPixel>() as u64;
    let mut band_rows = rect.height().min(FIRST_BAND_ROWS);
    let mut backup: Option<wgpu::Buffer> = None;
    while done < samples.end && pixels > 0 {
        let count = PASS_SPP.min(samples.end - done);
        let banded = band_rows < rect.height();
        if !banded {
            // A pass of one submission is never cut: its backup's memory can go.
            backup = None;
        }
        if banded {
            let copy = match backup.take() {
                Some(b) => b,
                None => ctx.storage_buffer_zeroed("film backup", film_bytes)?,
            };
            let mut encoder = ctx.device.create_command_encoder(&Default::default());
            encoder.copy_buffer_to_buffer(&film_buffer, 0, &copy, 0, film_bytes);
            ctx.queue.submit([encoder.finish()]);
            backup = Some(copy);
        }
        let mut y = 0;
        let mut abandoned = false;
        while y < rect.height() {
            let rows = band_rows.min(rect.height() - y);
            params.sample_start = done;
            params.sample_count = count;
            params.origin_y = rect.y0 + y;
            params.rect_height = rows;
            ctx.queue.write_buffer(&params_buffer, 0, bytemuck::bytes_of(&params));
            // The film's rows of the band: the kernel indexes the film from the band's first row.
            let band_film = (&film_buffer, u64::from(y) * row_bytes, u64::from(rows) * row_bytes);
            let bind_group = bind_group(ctx, &pipeline, scene, &params_buffer, Some(band_film), None);
            let band_start = std::time::Instant::now();
            let mut encoder = ctx.device.create_command_encoder(&Default::default());
            {
                let mut pass = encoder
                    .begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("trace"), timestamp_writes: None });
                pass.set_pipeline(&pipeline);
                pass.set_bind_group(0, &bind_group, &[]);
                pass.dispatch_workgroups(groups.0, rows.div_ceil(TRACE_WORKGROUP), 1);
            }
            ctx.queue.submit([encoder.finish()]);
            ctx.wait()?;
            y += rows;
            // The next band's height from this one's pace, in whole workgroup rows (which also
            // keeps the film's offsets aligned: 8 rows of 96-byte pixels are a multiple of 256
            // bytes).
            let per_row = band_start.elapsed().as_secs_f64() / f64::from(rows);
            let fit = (BAND_SECONDS / per_row.max(1e-9)).min(f64::from(rect.height())) as u32;
            // The whole height where it fits in one band (whatever its height), so that such
            // passes need no backup.
            band_rows = if fit >= rect.height() {
                rect.height()
            } else {
                (fit / TRACE_WORKGROUP * TRACE_WORKGROUP).max(TRACE_WORKGROUP)
            };
            if y < rect.height() && abandon() {
                abandoned = true;
                break;
            }
        }
        if abandoned {
            // Only a banded pass is cut, so the backup holds the film before it.
            if let Some(before) = backup.take() {
                film_buffer = before;
            }
            break;
        }
        done += count;
        progress(Progress { done: u64::from(done - samples.start) * height, total, rays: 0 });
        if !within_budget() || (done < samples.end && (pause(done - samples.start) || abandon())) {
            break;
        }
    }
    seconds += started.elapsed().as_secs_f64();
    Ok(PartialFilm { buffer: film_buffer, samples: done, key, seconds })
}

/// Samples per pixel [`measure_speed`] renders: two passes.
pub const MEASURE_SPP: u32 = 2 * PASS_SPP;

/// The GPU's time per sample per pixel on `scene`, in seconds, with the kernel's compile time:
/// what `auto` needs to judge a GPU render's length ([`crate::render::AutoDevice::Measured`]).
/// Two passes of [`PASS_SPP`] samples are rendered and the second is timed: the first runs far
/// below the render's speed (docs/benchmarks.md, "On the GPU").
/// The passes are the render's first samples under `seed` and `max_depth`, with the firefly
/// clamp `clamp`, and are returned for the render to carry on ([`render_from`]).
/// `None` if the scene cannot go to the GPU.
pub fn measure_speed(
    ctx: &GpuContext,
    scene: &RenderScene,
    seed: u64,
    max_depth: u32,
    clamp: Option<f32>,
    form: GpuForm,
) -> Option<(f64, std::time::Duration, PartialFilm)> {
    let mut gpu_scene = GpuScene::upload(ctx, scene, form).ok()?;
    gpu_scene.set_clamp(clamp);
    let t = std::time::Instant::now();
    compile(ctx, &gpu_scene).ok()?;
    let compiled = t.elapsed();
    let ends = std::sync::Mutex::new(Vec::with_capacity(2));
    let settings = RenderSettings { seed, max_depth, ..Default::default() };
    let region = Region { rect: Rect::full(gpu_scene.width, gpu_scene.height), samples: 0..MEASURE_SPP };
    // Progress is heard after each pass has finished on the device: its times are the passes' ends.
    let mark = |_| ends.lock().expect("no panic while held").push(std::time::Instant::now());
    let film = passes(ctx, &gpu_scene, Pass::new(&settings, region).with_progress(&mark)).ok()?;
    let ends = ends.into_inner().expect("no panic while held");
    let second = ends.get(1)?.duration_since(ends[0]).as_secs_f64();
    Some((second / f64::from(PASS_SPP), compiled, film))
}

/// `auto`'s build for a GPU render, on the GPU's own terms: its LBVH built on the device and
/// timed there, its render timed on that tree ([`measure_speed`], where that costs at most a
/// sixteenth of the render: at least 16 × [`MEASURE_SPP`] samples over all frames), and the
/// GPU's own PRBVH run where what it is expected to save repays what it is expected to cost
/// ([`gpu_prbvh_repays`]). Shorter renders keep the LBVH unoptimised, since no optimisation is
/// tried blind (docs/benchmarks.md, "On the GPU"). The timed samples are returned with the
/// tree, for the render's first frame to carry on ([`render_from`]); they are the same samples
/// whichever tree traces them, as hits do not depend on the tree. `settings.clamp` is the
/// render's firefly clamp; `form` the tree form it traces. Where the GPU's LBVH would leave long
/// runs of equal Morton codes (a model in a sky box), or the device fails, the decision falls
/// back on the CPU's `auto` with the GPU timed ([`RenderScene::build_auto_for`]).
pub fn build_auto(
    ctx: &GpuContext,
    scene: &crate::scene::Scene,
    settings: &RenderSettings,
    frames: usize,
    form: GpuForm,
) -> (RenderScene, crate::render::BuildReport, Option<PartialFilm>) {
    if let Ok(Some(built)) = auto_on_device(ctx, scene, settings, frames, form) {
        return built;
    }
    use crate::render::AutoDevice;
    use crate::render::auto::{total_budget, total_samples};
    let mut kept = None;
    let mut measure = |rs: &RenderScene| {
        let (seconds, compiled, film) =
            measure_speed(ctx, rs, settings.seed, settings.max_depth, settings.clamp, form)?;
        kept = Some(film);
        Some((seconds, compiled))
    };
    let samples = total_samples(settings, frames);
    let device = if samples >= 16.0 * f64::from(MEASURE_SPP) {
        AutoDevice::Measured { samples, budget: total_budget(settings, frames), measure: &mut measure }
    } else {
        AutoDevice::Unmeasured
    };
    let rays = RenderScene::estimated_rays(scene, settings.spp, settings.max_depth, frames);
    let (rs, report) = RenderScene::build_auto_for(scene, rays, device);
    (rs, report, kept)
}

/// The GPU's PRBVH costs up to this many of its LBVH builds (hairball:1M on the H100: 126.2 ms
/// against 7.1; the dragon 5.3, city:1M 15; docs/benchmarks.md, "Builds on the H100").
pub const GPU_PRBVH_IN_LBVH_BUILDS: f64 = 18.0;

/// The share of a render's time the GPU's PRBVH tree is expected to save over its LBVH: the
/// dragon scene traced 1.25× as fast on the H100 (docs/benchmarks.md, "Rendering on the H100").
pub const GPU_PRBVH_GAIN: f64 = 0.2;

/// Whether the GPU's PRBVH repays itself on a render whose rest takes `rest_seconds` on the
/// LBVH, the LBVH having built in `lbvh_seconds`: its expected saving must exceed its expected
/// cost with half as much again to spare (the CPU's `auto` keeps the same margin).
pub fn gpu_prbvh_repays(rest_seconds: f64, lbvh_seconds: f64) -> bool {
    GPU_PRBVH_GAIN * rest_seconds > 1.5 * GPU_PRBVH_IN_LBVH_BUILDS * lbvh_seconds
}

/// [`build_auto`] on the device; `None` where the CPU's `auto` decides instead.
fn auto_on_device(
    ctx: &GpuContext,
    scene: &crate::scene::Scene,
    settings: &RenderSettings,
    frames: usize,
    form: GpuForm,
) -> Result<Option<(RenderScene, crate::render::BuildReport, Option<PartialFilm>)>, GpuError> {
    use crate::render::auto::total_samples;
    let start = Instant::now();
    let compiled_before = ctx.compile_time();
    let (triangles, material_of) = scene.world_triangles();
    if triangles.len() < 2 {
        return Ok(None);
    }
    let prims: Vec<Aabb> = triangles.par_iter().map(Triangle::aabb).collect();
    let (gpu, times) = super::lbvh::build_on_device(ctx, &prims)?;
    if super::equal_code_runs(ctx, &gpu, &prims)?.is_some() {
        return Ok(None);
    }
    let lbvh_seconds = times.build.as_secs_f64();
    let samples = total_samples(settings, frames);
    let assemble = |tree: &Bvh, label: String, excluded: std::time::Duration| {
        let (triangles, material_of) = (triangles.clone(), material_of.clone());
        RenderScene::assemble(
            scene,
            (triangles, material_of, 0.0),
            tree,
            start + excluded,
            label,
            crate::bvh::Tracing::gpu(),
        )
    };
    let compiled = ctx.compile_time().saturating_sub(compiled_before);
    let lbvh_tree = gpu.read(ctx)?;
    if samples < 16.0 * f64::from(MEASURE_SPP) {
        let label = format!("auto: lbvh on the GPU ({:.1} ms), a render too short to time", lbvh_seconds * 1e3);
        let (rs, report) = assemble(&lbvh_tree, label, compiled);
        return Ok(Some((rs, report, None)));
    }
    let (rs, report) = assemble(&lbvh_tree, String::new(), compiled);
    let Some((per_sample, measure_compiled, film)) =
        measure_speed(ctx, &rs, settings.seed, settings.max_depth, settings.clamp, form)
    else {
        return Ok(None);
    };
    let excluded = compiled + measure_compiled;
    // A time limit bounds the render, whatever its samples.
    let mut rest = (samples - f64::from(MEASURE_SPP)).max(0.0) * per_sample;
    if let Some(budget) = crate::render::auto::total_budget(settings, frames) {
        rest = rest.min(budget);
    }
    if !gpu_prbvh_repays(rest, lbvh_seconds) {
        let label = format!(
            "auto: lbvh on the GPU ({:.1} ms), for a render estimated at {rest:.2} s its PRBVH would not repay",
            lbvh_seconds * 1e3
        );
        let mut report = report;
        (report.builder, report.build_ms) = (label, start.elapsed().saturating_sub(excluded).as_secs_f64() * 1e3);
        return Ok(Some((rs, report, Some(film))));
    }
    drop(rs);
    let scheme = super::prbvh::LockScheme::best_for(ctx);
    let config = PrbvhConfig { collapse: None, ..Default::default() };
    let t = Instant::now();
    let stats = super::prbvh::optimize_on_device(ctx, &gpu, &config, scheme)?;
    let prbvh_seconds = t.elapsed().as_secs_f64();
    let tree = gpu.read(ctx)?;
    let label = format!(
        "auto: lbvh+prbvh on the GPU ({:.1} + {:.1} ms, {} iterations), for a render estimated at {rest:.2} s",
        lbvh_seconds * 1e3,
        prbvh_seconds * 1e3,
        stats.iterations.len()
    );
    let (rs, report) = assemble(&tree, label, excluded);
    Ok(Some((rs, report, Some(film))))
}

/// The film's sums from the device's: the exact sum as it is, and `sum_sq` from the shifted
/// f32 sums (see [`GpuPixel`]), written as `sum² / n` plus the centred sum of squares, so that
/// the film's variance formula gives exactly 0 for a constant pixel.
fn pixel_accum(p: &GpuPixel) -> PixelAccum {
    let mut a = PixelAccum { count: u64::from(p.count), non_finite: u64::from(p.non_finite), ..Default::default() };
    if p.count == 0 {
        return a;
    }
    let n = f64::from(p.count);
    for c in 0..3 {
        let limbs = &p.exact[4 * c..4 * c + 4];
        a.sum[c] = limbs.iter().rev().fold(0u128, |acc, &l| (acc << 32) | u128::from(l)) as i128;
        let (s1, s2) = (f64::from(p.sum[c]), f64::from(p.sum_sq[c]));
        let sum = a.sum_f64(c);
        let centred = (s2 - s1 * s1 / n).max(0.0);
        a.sum_sq[c] = sum * sum / n + centred;
    }
    a
}

/// `sum`'s four limbs, as the device keeps them (tests).
#[cfg(test)]
fn limbs(sum: i128) -> [u32; 4] {
    std::array::from_fn(|i| (sum >> (32 * i)) as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pixel_sums_of_a_constant_pixel_have_zero_variance() {
        let mut p = GpuPixel { shift: Vec3::splat(0.8), count: 64, ..Default::default() };
        let sum = 64 * crate::render::film::to_fixed(0.8).unwrap();
        for c in 0..3 {
            p.exact[4 * c..4 * c + 4].copy_from_slice(&limbs(sum));
        }
        let a = pixel_accum(&p);
        assert_eq!(a.mean(), [0.8; 3]);
        assert_eq!(a.stderr(), [0.0; 3]);
    }

    #[test]
    fn pixel_sums_match_the_film() {
        let samples = [0.5f32, 2.0, 1.25, 7.0];
        let mut film = PixelAccum::default();
        let mut p = GpuPixel { shift: Vec3::splat(samples[0]), count: samples.len() as u32, ..Default::default() };
        for &x in &samples {
            film.add(Vec3::splat(x));
            let d = Vec3::splat(x - samples[0]);
            p.sum += d;
            p.sum_sq += d * d;
        }
        for c in 0..3 {
            p.exact[4 * c..4 * c + 4].copy_from_slice(&limbs(film.sum[c]));
        }
        let a = pixel_accum(&p);
        assert_eq!(a.sum, film.sum);
        assert_eq!(
            pixel_accum(&GpuPixel { exact: [limbs(-5)[0], u32::MAX, u32::MAX, u32::MAX, 0, 0, 0, 0, 0, 0, 0, 0], ..p })
                .sum[0],
            -5
        );
        for c in 0..3 {
            assert!((a.mean()[c] - film.mean()[c]).abs() < 1e-6);
            assert!((a.stderr()[c] - film.stderr()[c]).abs() < 1e-6);
        }
    }
}
