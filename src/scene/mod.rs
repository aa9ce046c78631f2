//! Scenes: the TOML scene format (documented in `docs/scene-format.md`) and its loader.
//!
//! [`Scene::load`] reads a scene file and the OBJ/MTL, PLY and glTF files it names (`gltf`, with the
//! Cargo feature `gltf`), checks every value, and
//! returns plain data: a camera, render settings, materials by index, meshes and the objects
//! placing them, some of them animated ([`Animation`]). Any error names the scene file, the line
//! and the key at fault ([`SceneError`]); nothing panics on bad input.

mod animation;
mod file;
#[cfg(feature = "gltf")]
pub mod gltf;
mod load;

pub use animation::{Animation, AnimationSettings, Keyframe};

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{Mat4, Vec3};

use crate::geometry::{Triangle, TriangleMesh};
use crate::texture::environment::EnvironmentMap;
use crate::texture::{Texture, TextureRef};

/// A pinhole or thin-lens camera.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub position: Vec3,
    pub look_at: Vec3,
    pub up: Vec3,
    /// Vertical field of view, degrees, in (0, 180).
    pub fov_y_degrees: f32,
    pub width: u32,
    pub height: u32,
    /// Lens radius in scene units; 0 is a pinhole.
    pub aperture: f32,
    /// Distance to the plane in focus; defaults to `|look_at - position|`.
    pub focus_distance: f32,
    /// The scene file's line that sets `resolution`, for errors found after loading (the
    /// image's memory); 0 where the camera was not read from a file.
    pub resolution_line: usize,
}

/// What [`Scene::check_flat_fits`] refuses.
#[derive(Debug, thiserror::Error)]
pub enum FlatSceneError {
    #[error("{}: the scene flattened ({triangles} triangles) is more than one BVH holds (2^31 triangles)", file.display())]
    TooManyTriangles { file: PathBuf, triangles: u64 },
    /// The estimate is the error's source, not part of its message: `render` finds its exit
    /// code (3, out of memory) by walking the chain of sources, which an error that wrapped it
    /// in place (`transparent`) ended here. A report of the chain (`{:#}`) says both.
    #[error("{}: not enough memory", file.display())]
    Memory { file: PathBuf, source: crate::memory::OutOfMemory },
}

/// The most radiance an emitter (its emission times its texture's brightest texel) or the sky
/// (a texel of its map times its `scale`) may have: 2^40. The film drops a sample of 2^44 or
/// more as it drops a NaN (`render::film::SAMPLE_LIMIT_LOG2`: 2^32 samples of it still sum in
/// its fixed point), and a sample carries a light's radiance times the weights of its path,
/// which light sampling and MIS can make several times 1: 2^40 leaves them 2^4. A scene
/// brighter than that rendered black, with no error. Nothing real comes near: the sun's disc is
/// about 1.6·10^9 cd/m², below 2^31.
pub const MAX_RADIANCE: f32 = 1_099_511_627_776.0;
const _: () = assert!(MAX_RADIANCE == (1u64 << 40) as f32);

/// How to render: the one settings struct of every render, on either device. A scene file's
/// `[render]` table gives the first four; `render`'s flags override them, and the benchmarks
/// and tests set them directly.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    /// Samples per pixel, at least 1. Default 64.
    pub spp: u32,
    /// Path segments: 1 shows emitters only, 2 adds direct light. At least 1. Default 8.
    pub max_depth: u32,
    /// Seed of the random streams. Default 0.
    pub seed: u64,
    /// Optional time budget per frame in seconds: the render stops after the pass that
    /// crosses it.
    pub time: Option<f64>,
    /// Firefly clamp, off (`None`) unless the user asks (`render --clamp`): a sample whose
    /// largest channel exceeds it is scaled down to it. Biased, so never a default.
    pub clamp: Option<f32>,
}

impl Default for RenderSettings {
    /// The `[render]` table's defaults: 64 spp, 8 segments, seed 0, no time limit, no clamp.
    fn default() -> Self {
        Self { spp: 64, max_depth: 8, seed: 0, time: None, clamp: None }
    }
}

/// How a surface scatters light.
#[derive(Clone, Debug, PartialEq)]
pub enum Scattering {
    /// Absorbs everything (an emitter that does not reflect).
    Black,
    /// Lambertian, `albedo / π`.
    Diffuse { albedo: Vec3 },
    /// GGX microfacet metal; `roughness` is GGX α in [0, 1], 0 a perfect mirror.
    Conductor { roughness: f32, fresnel: ConductorFresnel },
    /// Glass-like: `ior` relative to the outside, GGX `roughness` in [0, 1] (0 smooth).
    Dielectric { ior: f32, roughness: f32 },
    /// glTF 2.0's metallic-roughness model ([`crate::render::bsdf::Bsdf::Coated`]): a metal of
    /// reflectance `base_color` mixed by `metallic` in [0, 1] with a Lambertian `base_color`
    /// under a dielectric coat of index `ior`. `alpha` is the GGX α in [0, 1], the square of
    /// the perceptual roughness that TOML and glTF give.
    Coated { base_color: Vec3, metallic: f32, alpha: f32, ior: f32 },
}

/// A conductor's Fresnel term.
#[derive(Clone, Debug, PartialEq)]
pub enum ConductorFresnel {
    /// Complex index of refraction `eta + i k`, per RGB channel.
    Complex { eta: Vec3, k: Vec3 },
    /// Reflectance at normal incidence.
    BaseColor(Vec3),
}

/// A material: how it scatters, and what it emits.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    pub name: String,
    pub scattering: Scattering,
    /// Emitted radiance (non-negative), or `None`.
    pub emission: Option<Vec3>,
    /// Whether the back face emits too (default: front only).
    pub two_sided: bool,
    pub textures: MaterialTextures,
}

/// A material's image textures ([`Scene::textures`]), looked up at the hit's texture
/// coordinates.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MaterialTextures {
    /// Multiplies the diffuse albedo, a conductor's or a coated material's base colour (`map_Kd`).
    pub base_color: Option<TextureRef>,
    /// A cut-out mask (`map_d`): where its coverage is below `alpha_cutoff` the surface is not
    /// there, for every ray.
    pub alpha: Option<TextureRef>,
    pub alpha_cutoff: f32,
    /// A tangent-space normal map (`norm`, `bump`, glTF's `normalTexture`): red along the
    /// direction of increasing u, green of increasing v, blue along the surface normal; its x and
    /// y scaled by `normal_scale`.
    pub normal: Option<TextureRef>,
    pub normal_scale: f32,
    /// Multiplies the emitted radiance (`map_Ke`, glTF's `emissiveTexture`; sRGB colour). A
    /// material with one is a light sampled by its textured power.
    pub emission: Option<TextureRef>,
    /// Multiply the coated material's perceptual roughness and its metallic: the given channel
    /// of each texture (glTF's `metallicRoughnessTexture`: green and blue; MTL `map_Pr` and
    /// `map_Pm`: red, which is the grey level of a grey image).
    pub roughness: Option<(TextureRef, u8)>,
    pub metallic: Option<(TextureRef, u8)>,
}

/// A mesh with one material per triangle (indices into [`Scene::materials`]). Objects naming the
/// same OBJ or PLY file or the same built-in shape share one, and the objects a glTF file's nodes
/// make share one per glTF mesh; a built-in shape's `material_ids` hold the first such object's
/// material, and every object using it overrides them.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneMesh {
    /// Where it came from: the OBJ or PLY path, the glTF path and mesh (`car.glb#meshes[2]`), or
    /// the built-in shape's name.
    pub source: String,
    pub mesh: TriangleMesh,
    pub material_ids: Vec<u32>,
}

/// An instance of a mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct Object {
    /// Index into [`Scene::meshes`].
    pub mesh: usize,
    /// The static placement; an animation moves the object from there.
    pub world_from_object: Mat4,
    /// Overrides every triangle's material.
    pub material: Option<u32>,
    /// Applied after `world_from_object` ([`Object::world_from_object_at`]).
    pub animation: Option<Animation>,
}

/// Light arriving from infinitely far away: a constant radiance, or an environment map.
#[derive(Clone, Debug, PartialEq)]
pub struct Environment {
    /// The constant radiance from every direction, or with a map the factor its texels are
    /// multiplied by (`[environment] scale`). Finite, non-negative.
    pub radiance: Vec3,
    /// The equirectangular map, turned by `[environment] rotate`; shared, since every frame of
    /// an animation renders with it.
    pub map: Option<Arc<EnvironmentMap>>,
}

/// A loaded, checked scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    pub path: PathBuf,
    pub camera: Camera,
    pub render: RenderSettings,
    /// Light from infinitely far away, or `None` for black.
    pub environment: Option<Environment>,
    pub materials: Vec<Material>,
    /// The image textures materials use, each file loaded once.
    pub textures: Vec<Arc<Texture>>,
    pub meshes: Vec<SceneMesh>,
    pub objects: Vec<Object>,
    /// The `[animation]` table: the frame clock. Present whenever an object is animated.
    pub animation: Option<AnimationSettings>,
    /// The files read while loading it besides the scene file (meshes, MTL files, glTF files
    /// and buffers), as named: what a render must not overwrite ([`Scene::input_files`]).
    /// Textures and the environment map are named by their own fields.
    pub read: Vec<PathBuf>,
}

/// What went wrong loading a scene. Each names the file, and where it can the line and key.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The I/O error is part of the message, not a `source`, so that a report of the whole
    /// error chain (`{:#}`) says it once.
    #[error("{file}: cannot read: {error}")]
    Read { file: PathBuf, error: std::io::Error },
    #[error("{file}:{line}: {key}: {message}")]
    Invalid { file: PathBuf, line: usize, key: String, message: String },
    /// What the value at the key asks for (a mesh, instances, a file's contents) would not fit
    /// in the memory available: a render that may fit elsewhere, not bad input. `message` says
    /// what and the estimate; `error` is the estimate alone (not a `source`, as the message
    /// already says it).
    #[error("{file}:{line}: {key}: {message}")]
    Memory { file: PathBuf, line: usize, key: String, message: String, error: crate::memory::OutOfMemory },
}

impl Scene {
    /// Reads and checks `path` and every mesh it names.
    pub fn load(path: impl Into<PathBuf>) -> Result<Scene, SceneError> {
        load::load(path.into())
    }

    /// Parses scene text as if read from `path` (meshes are found relative to it).
    pub fn parse(text: &str, path: impl Into<PathBuf>) -> Result<Scene, SceneError> {
        load::parse(text, path.into())
    }

    /// How many triangles [`Scene::world_triangles`] gives: every object's mesh, counted once
    /// per object that places it.
    pub fn world_triangle_count(&self) -> u64 {
        self.objects.iter().map(|o| self.meshes[o.mesh].mesh.indices.len() as u64).sum()
    }

    /// Bytes the scene's texels take: its textures and its environment map's texels and
    /// sampling tables (a GPU render uploads the same again).
    pub fn texture_bytes(&self) -> usize {
        let map = self.environment.as_ref().and_then(|e| e.map.as_ref());
        self.textures.iter().map(|t| t.bytes()).sum::<usize>() + map.map_or(0, |m| m.bytes())
    }

    /// An error where the scene flattened to world-space triangles ([`Scene::world_triangles`])
    /// would not fit: more triangles than one BVH indexes (2^31), or more memory than is
    /// available at `bytes_per_triangle` (the flat scene, its BVH and what is built beside it).
    /// `file` names the scene in the message. Checked before flattening, which otherwise aborts
    /// when an allocation fails (a city of 10^8 triangles, or 10^4 instances of a 1.3M-triangle
    /// sphere, which the CPU renders as instances but the GPU and `bvh-bench` flatten).
    pub fn check_flat_fits(&self, file: &std::path::Path, bytes_per_triangle: f64) -> Result<(), FlatSceneError> {
        let n = self.world_triangle_count();
        if n >= 1 << 31 {
            return Err(FlatSceneError::TooManyTriangles { file: file.to_path_buf(), triangles: n });
        }
        let what = format!("the scene flattened ({n} triangles)");
        crate::memory::check_fits(&what, n as f64 * bytes_per_triangle)
            .map_err(|source| FlatSceneError::Memory { file: file.to_path_buf(), source })
    }

    /// An error where the scene rendered as instances would not fit (the CPU's two levels, for an
    /// animated or heavily instanced scene, which [`Scene::check_flat_fits`] does not judge):
    /// every mesh's BVH at `bytes_per_triangle`, and every object's instance at
    /// [`crate::memory::RENDER_BYTES_PER_INSTANCE`]. `file` names the scene in the message.
    pub fn check_instanced_fits(
        &self,
        file: &std::path::Path,
        bytes_per_triangle: f64,
    ) -> Result<(), crate::memory::OutOfMemory> {
        let triangles: u64 = self.meshes.iter().map(|m| m.mesh.indices.len() as u64).sum();
        let instances = self.objects.len() as u64;
        let what = format!("{}: the scene as {instances} instances of {triangles} triangles", file.display());
        let bytes = triangles as f64 * bytes_per_triangle + instances as f64 * crate::memory::RENDER_BYTES_PER_INSTANCE;
        crate::memory::check_fits(&what, bytes)
    }

    /// Every object's triangles in world space at time 0, with their material ids: the same as
    /// `world_triangles_at(0.0)`.
    pub fn world_triangles(&self) -> (Vec<Triangle>, Vec<u32>) {
        self.world_triangles_at(0.0)
    }

    /// Every object's triangles in world space at `time` seconds, with their material ids.
    pub fn world_triangles_at(&self, time: f32) -> (Vec<Triangle>, Vec<u32>) {
        let mut tris = Vec::new();
        let mut mats = Vec::new();
        for o in &self.objects {
            let m = &self.meshes[o.mesh];
            let world_from_object = o.world_from_object_at(time);
            let [b, c] = placed_order(&world_from_object);
            for (i, t) in m.mesh.indices.iter().enumerate() {
                let p = |k: usize| world_from_object.transform_point3(m.mesh.positions[t[k] as usize]);
                tris.push(Triangle::new(p(0), p(b), p(c)));
                mats.push(o.material.unwrap_or(m.material_ids[i]));
            }
        }
        (tris, mats)
    }

    /// The files the scene was read from, as `(what, path)`: the scene file, its meshes
    /// (OBJ, PLY, glTF), textures and environment map, and every other file its loading read
    /// (MTL files, glTF buffers); what a render must not overwrite.
    /// Parts of a file (`car.glb#meshes[2]`) are given as the file; built-in shapes have none.
    pub fn input_files(&self) -> Vec<(&'static str, PathBuf)> {
        let file = |source: &str| -> Option<PathBuf> {
            let path = Path::new(source.split_once('#').map_or(source, |(f, _)| f));
            path.is_file().then(|| path.to_path_buf())
        };
        let mut files = vec![("the scene", self.path.clone())];
        files.extend(self.meshes.iter().filter_map(|m| Some(("a mesh", file(&m.source)?))));
        files.extend(self.textures.iter().filter_map(|t| Some(("a texture", file(&t.source.to_string_lossy())?))));
        let map = self.environment.as_ref().and_then(|e| e.map.as_ref());
        files.extend(map.map(|m| ("the environment map", m.source.clone())));
        files.extend(self.read.iter().map(|p| ("a file the scene reads", p.clone())));
        files.sort_by(|a, b| a.1.cmp(&b.1));
        files.dedup_by(|a, b| a.1 == b.1);
        files
    }

    /// SHA-256 of what the scene renders, as lowercase hex: the camera (but the file line it
    /// came from), the environment, the materials, every mesh's vertices (with their normals
    /// and texture coordinates), triangles and materials, the objects with their animations, and the frame clock; not the file's path or
    /// layout, nor its `[render]` table (a render's seed, depth and samples are recorded beside
    /// it). Two tasks that load the same scene from different folders agree; any change to what
    /// is drawn changes it. Numbers are hashed by their exact bits (vectors and matrices through
    /// their `Debug` forms, which print every float exactly).
    pub fn content_hash(&self) -> String {
        use sha2::{Digest, Sha256};
        let mut h = Sha256::new();
        let mut text = |label: &str, s: String| {
            h.update(label.as_bytes());
            h.update((s.len() as u64).to_le_bytes());
            h.update(s.as_bytes());
        };
        text("camera", format!("{:?}", Camera { resolution_line: 0, ..self.camera.clone() }));
        // A map by its size, rotation and texels, not its path; the distribution follows from them.
        let environment = self
            .environment
            .as_ref()
            .map(|e| (e.radiance, e.map.as_ref().map(|m| (m.width, m.height, m.world_from_map))));
        text("environment", format!("{environment:?}"));
        text("materials", format!("{:?}", self.materials));
        text("objects", format!("{:?}", self.objects));
        text("animation", format!("{:?}", self.animation));
        for t in &self.textures {
            h.update(b"texture");
            h.update(format!("{}x{} {:?} {}", t.width, t.height, t.format, t.has_alpha).as_bytes());
            let bytes = bytemuck::cast_slice::<_, u8>(&t.texels);
            h.update((bytes.len() as u64).to_le_bytes());
            h.update(bytes);
        }
        if let Some(m) = self.environment.as_ref().and_then(|e| e.map.as_ref()) {
            let bytes = bytemuck::cast_slice::<_, u8>(&m.texels);
            h.update(b"environment map");
            h.update((bytes.len() as u64).to_le_bytes());
            h.update(bytes);
        }
        for m in &self.meshes {
            h.update(b"mesh");
            for bytes in [
                bytemuck::cast_slice::<_, u8>(&m.mesh.positions),
                bytemuck::cast_slice(&m.mesh.indices),
                bytemuck::cast_slice(&m.material_ids),
                bytemuck::cast_slice(&m.mesh.normals),
                bytemuck::cast_slice(&m.mesh.uvs),
            ] {
                h.update((bytes.len() as u64).to_le_bytes());
                h.update(bytes);
            }
        }
        h.finalize().iter().map(|b| format!("{b:02x}")).collect()
    }

    /// The shading normals of [`Scene::world_triangles_at`]'s triangles, in the same order and
    /// with the same vertex order (a mirror swaps two vertices): each vertex's normal mapped by
    /// the inverse transpose of its object's placement and normalised; zero where the mesh has
    /// none. Empty where no mesh has normals.
    pub fn world_normals_at(&self, time: f32) -> Vec<[Vec3; 3]> {
        if self.meshes.iter().all(|m| m.mesh.normals.is_empty()) {
            return Vec::new();
        }
        let mut out = Vec::new();
        for o in &self.objects {
            let m = &self.meshes[o.mesh].mesh;
            if m.normals.is_empty() {
                out.extend(std::iter::repeat_n([Vec3::ZERO; 3], m.indices.len()));
                continue;
            }
            let world_from_object = o.world_from_object_at(time);
            let normal_matrix = glam::Mat3::from_mat4(world_from_object).inverse().transpose();
            let [b, c] = placed_order(&world_from_object);
            for t in &m.indices {
                let n = |k: usize| (normal_matrix * m.normals[t[k] as usize]).normalize_or_zero();
                out.push([n(0), n(b), n(c)]);
            }
        }
        out
    }

    /// The texture coordinates of [`Scene::world_triangles_at`]'s triangles, in the same order
    /// and vertex order; zero where a mesh has none. Empty where no material has a texture or
    /// no mesh has coordinates: nothing would read them.
    pub fn world_uvs_at(&self, time: f32) -> Vec<[glam::Vec2; 3]> {
        if self.textures.is_empty() || self.meshes.iter().all(|m| m.mesh.uvs.is_empty()) {
            return Vec::new();
        }
        let mut out = Vec::new();
        for o in &self.objects {
            let m = &self.meshes[o.mesh].mesh;
            if m.uvs.is_empty() {
                out.extend(std::iter::repeat_n([glam::Vec2::ZERO; 3], m.indices.len()));
                continue;
            }
            let [b, c] = placed_order(&o.world_from_object_at(time));
            out.extend(m.indices.iter().map(|t| [m.uvs[t[0] as usize], m.uvs[t[b] as usize], m.uvs[t[c] as usize]]));
        }
        out
    }

    /// Whether any material emits.
    pub fn has_emitters(&self) -> bool {
        self.materials.iter().any(|m| m.emission.is_some())
    }
}

/// Which of a triangle's vertices come second and third once placed by `world_from_object`: a
/// mirror keeps each triangle's front where the file put it, so the winding flips (as
/// [`Triangle::placed`] does).
fn placed_order(world_from_object: &Mat4) -> [usize; 2] {
    if world_from_object.determinant() < 0.0 { [2, 1] } else { [1, 2] }
}
