//! glTF 2.0 files (`.gltf`, `.glb`), as the Khronos glTF 2.0 Specification (version 2.0.1, 2021)
//! defines them: the JSON document parsed and its references checked by the `gltf` crate's
//! schema (`gltf-json`); the GLB container, the buffers, the accessors and the node hierarchy
//! read here, with every size checked against the file before anything is allocated.
//!
//! What is read:
//! - The container: a `.gltf` file is JSON (UTF-8, a leading byte-order mark skipped); a file
//!   that starts with the magic `glTF` is GLB (section 4.4, "Binary glTF Layout"): a 12-byte
//!   header (version 2), a JSON chunk first, an optional BIN chunk, unknown chunks skipped. A
//!   `.glb` file without the magic is an error. `extensionsRequired` naming an extension this
//!   reader does not know is an error naming it (Draco, meshopt, mesh quantization, ...).
//! - Buffers (3.6.1): the GLB's BIN chunk (a buffer without `uri`), base64 `data:` URIs, and
//!   files relative to the glTF file (percent-encoded URIs decoded, RFC 3986). Each must hold
//!   at least its `byteLength`; only those bytes are used.
//! - Accessors (3.6.2): `FLOAT` positions and normals; texture coordinates as `FLOAT` or
//!   normalized `UNSIGNED_BYTE`/`UNSIGNED_SHORT` (c / 255, c / 65535); indices as
//!   `UNSIGNED_BYTE`, `UNSIGNED_SHORT` or `UNSIGNED_INT`. Interleaved views (`byteStride`) are
//!   read; an accessor with no buffer view is zeros. Sparse accessors (3.6.2.3) are applied:
//!   their indices must strictly increase and stay below the accessor's count. Every
//!   accessor's last byte is checked against its view, and every view against its buffer,
//!   before its elements are read.
//! - Meshes (3.7.2): primitives of mode `TRIANGLES`, `TRIANGLE_STRIP` and `TRIANGLE_FAN`, the
//!   last two turned into triangles by the table of 3.7.2.1 (strip triangle i is
//!   {v_i, v_(i+1+i%2), v_(i+2-i%2)}, fan triangle i is {v_(i+1), v_(i+2), v_0}), a strip's or
//!   fan's triangles with a repeated vertex dropped (strips repeat vertices to join). `POINTS`
//!   and the `LINE*` modes have no surface: such primitives are skipped, and a file whose
//!   scene has no triangle at all is an error where a mesh is asked for. `POSITION` (required,
//!   finite), `NORMAL` (normalised; zero or non-finite becomes zero: none) and `TEXCOORD_0`
//!   (finite) are kept; other attributes, morph targets and skins are ignored (a skinned mesh
//!   is drawn in its bind pose, at its node). Indices must be below the vertex count, and a
//!   `TRIANGLES` primitive's count a multiple of 3.
//! - Texture coordinates: glTF's origin is the image's top-left corner, v down (3.8); Arbor's,
//!   as OBJ's, is the bottom-left, v up, so v is stored as 1 - v.
//! - The scene (3.5): the document's `scene`, else its first scene, else (no scenes) every node
//!   that is no node's child. Each node's local transform is its `matrix` (column-major,
//!   affine) or its translation × rotation (a unit quaternion x, y, z, w, normalised) × scale
//!   (3.5.3), composed from the root down. Nodes form disjoint trees (3.5.2): a node reached
//!   twice (a cycle, or two parents) is an error naming it. The traversal is depth first,
//!   children in their listed order; that order is the order of [`GltfFile::instances`] and
//!   [`GltfFile::cameras`]. A node with a mesh whose world matrix is singular (by the rule of
//!   the scene's own `matrix`: columns within rounding of dependent) is an error naming it; a
//!   mirroring one is fine.
//! - Materials (3.9): the metallic-roughness factors, emission (× `KHR_materials_emissive_strength`),
//!   `doubleSided`, `alphaMode`/`alphaCutoff` and every texture reference (texture, image,
//!   sampler, texture coordinate set, normal scale, occlusion strength) are kept as plain data
//!   ([`GltfMaterial`]); factors must be finite and within the spec's ranges. Textures are not
//!   read here: the scene loader maps each material's factors to Arbor's coated
//!   metallic-roughness material ([`GltfMaterial::to_arbor`]) and attaches its textures (all but
//!   occlusion). The default material (3.9.6) is [`GltfMaterial::default`].
//! - Cameras (3.10): every camera node, with its world matrix; [`GltfFile::projection`] reads a
//!   camera's projection.
//!
//! Where this reader departs from the specification, on the lenient side: accessor and view
//! offsets need not be aligned (values are read byte by byte); `POSITION` needs no `min`/`max`;
//! attribute names it does not know are ignored rather than refused; bytes after the GLB's
//! declared length are ignored.
//!
//! Why only the crate's JSON schema and checks: its `import` feature would read buffers and
//! decode images with `image` (every codec), sizes unchecked; its GLB splitter subtracts the
//! header's length from 12 unchecked (an overflow panic under overflow checks); its check of a
//! primitive's `POSITION` indexes the accessor list before knowing the index exists (checked
//! here first); and its wrapper types unwrap a camera's projection object by the camera's
//! `type`. So the raw document (`gltf::json::Root`) is read here, after its validation.
//!
//! Errors ([`GltfError`]) name the file, then the place: a byte offset in the GLB container, a
//! line and column in the JSON, or the JSON path of the object at fault
//! (`meshes[2].primitives[0].attributes.POSITION`) with the accessor, view or buffer index.

use std::path::{Path, PathBuf};

use glam::{Mat4, Quat, Vec2, Vec3, Vec4};
use gltf::json;
use json::accessor::{ComponentType, Type};
use json::mesh::{Mode, Semantic};
use json::validation::{Checked, Validate};

use super::{Material, Scattering};
use crate::geometry::TriangleMesh;

/// The material id of a triangle whose primitive names no material: the spec's default
/// material ([`GltfMaterial::default`]).
pub const DEFAULT_MATERIAL: u32 = u32::MAX;

/// Most elements of an accessor without a buffer view (all zeros, perhaps made sparse): its
/// size is not bounded by any file, so by this (6.7 · 10^7, 800 MB of positions), and by the
/// memory available.
const MAX_UNBACKED_ELEMENTS: u64 = 1 << 26;

/// Bytes the parsed document takes per byte of its JSON and per JSON object, beyond the file's
/// own bytes ([`GltfFile::open`] checks them before parsing). Measured as the peak resident set
/// of `GltfFile::open` less the file: 445 MB for each of two documents of 10^6 nodes (18 and
/// 45 MB of JSON), 284 MB for 200,000 meshes with their accessors, 237 MB for 300,000
/// materials, 38 MB for one base64 buffer of 21 MB (its text kept and its bytes decoded). The
/// objects dominate where they are small: a file size times one factor would have to be 25 for
/// the 18 MB of nodes, and would refuse files of large buffers that fit.
const PARSED_BYTES_PER_JSON_BYTE: f64 = 2.5;
const PARSED_BYTES_PER_JSON_OBJECT: f64 = 500.0;

/// Why a glTF file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum GltfError {
    /// The I/O error is part of the message, not a `source`, so that a report of the whole
    /// error chain (`{:#}`) says it once.
    #[error("{path}: cannot read: {error}")]
    Read { path: PathBuf, error: std::io::Error },
    /// `place`: a byte offset of the GLB container, a line of the JSON, or a JSON path.
    #[error("{path}: {place}: {message}")]
    Invalid { path: PathBuf, place: String, message: String },
    /// What the file asks for would not fit in memory (the document once parsed, a buffer, an
    /// accessor without a buffer view): a render that may fit elsewhere, not a bad file.
    #[error("{path}: {error}")]
    Memory { path: PathBuf, error: crate::memory::OutOfMemory },
}

/// A glTF file read and checked: its document and buffers, the mesh nodes and camera nodes of
/// its scene with their world matrices, and its materials. Meshes are decoded on demand
/// ([`GltfFile::mesh`]).
#[derive(Debug)]
pub struct GltfFile {
    pub path: PathBuf,
    root: json::Root,
    /// The whole file: a GLB's BIN chunk is a range of it.
    bytes: Vec<u8>,
    buffers: Vec<BufferData>,
    /// One per `materials` entry of the file.
    pub materials: Vec<GltfMaterial>,
    /// Every node with a mesh, in traversal order.
    pub instances: Vec<GltfInstance>,
    /// Every node with a camera, in traversal order.
    pub cameras: Vec<GltfCameraNode>,
}

#[derive(Debug)]
enum BufferData {
    /// Bytes of [`GltfFile::bytes`] (the BIN chunk), already cut to `byteLength`.
    InFile(std::ops::Range<usize>),
    Owned(Vec<u8>),
}

/// A node that places a mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct GltfInstance {
    pub node: usize,
    pub name: Option<String>,
    /// Index into the file's `meshes`.
    pub mesh: usize,
    /// The node's world matrix: every local transform from the scene's root down to it.
    /// Invertible; it may mirror.
    pub world_from_object: Mat4,
}

/// A node that carries a camera.
#[derive(Clone, Debug, PartialEq)]
pub struct GltfCameraNode {
    pub node: usize,
    pub node_name: Option<String>,
    /// Index into the file's `cameras`.
    pub camera: usize,
    pub camera_name: Option<String>,
    /// The node's world matrix; the camera looks down its -Z with +Y up (3.10.1).
    pub world_from_camera: Mat4,
}

/// A camera's projection (3.10.2), as written.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GltfProjection {
    /// `yfov` in radians, in (0, π); `aspect_ratio` as given (Arbor takes the image's).
    Perspective {
        yfov: f32,
        aspect_ratio: Option<f32>,
        znear: f32,
        zfar: Option<f32>,
    },
    Orthographic {
        xmag: f32,
        ymag: f32,
        znear: f32,
        zfar: f32,
    },
}

/// The triangles of one glTF mesh (all its triangle primitives, appended), and each triangle's
/// material: an index into [`GltfFile::materials`], or [`DEFAULT_MATERIAL`].
#[derive(Clone, Debug, PartialEq)]
pub struct GltfMesh {
    pub mesh: TriangleMesh,
    pub material_ids: Vec<u32>,
}

/// `alphaMode` (3.9.4).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AlphaMode {
    Opaque,
    /// Cut out where alpha is below `alpha_cutoff`.
    Mask,
    Blend,
}

/// A sampler's wrap mode (3.8.4.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WrapMode {
    ClampToEdge,
    MirroredRepeat,
    Repeat,
}

/// A sampler's magnification filter (3.8.4.2); `None` in [`GltfSampler`] leaves it to the
/// renderer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MagFilter {
    Nearest,
    Linear,
}

/// A sampler's minification filter (3.8.4.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MinFilter {
    Nearest,
    Linear,
    NearestMipmapNearest,
    LinearMipmapNearest,
    NearestMipmapLinear,
    LinearMipmapLinear,
}

/// A texture's sampler; a texture without one samples with repeat wrapping and filters of the
/// renderer's choice (3.8.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GltfSampler {
    pub wrap_s: WrapMode,
    pub wrap_t: WrapMode,
    pub mag_filter: Option<MagFilter>,
    pub min_filter: Option<MinFilter>,
}

impl Default for GltfSampler {
    fn default() -> Self {
        Self { wrap_s: WrapMode::Repeat, wrap_t: WrapMode::Repeat, mag_filter: None, min_filter: None }
    }
}

/// Where an image's bytes are (3.8.3). Nothing is read or decoded yet.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum GltfImageSource {
    /// A file: the `uri` as written, and the path it names (relative to the glTF file,
    /// percent-decoding undone).
    File { uri: String, path: PathBuf, mime_type: Option<String> },
    /// A `data:` URI: the bytes are in `images[image].uri` of the document.
    DataUri { mime_type: Option<String> },
    /// Bytes of a buffer view: `buffer` from `offset`, `length` bytes.
    BufferView { view: usize, buffer: usize, offset: u64, length: u64, mime_type: Option<String> },
}

/// A texture reference of a material (`textureInfo`, 3.9.2): the texture, its image and
/// sampler, and which `TEXCOORD_n` set it reads.
#[derive(Clone, Debug, PartialEq)]
pub struct GltfTexture {
    /// Index into the file's `textures`.
    pub texture: usize,
    /// Index into the file's `images`.
    pub image: usize,
    pub source: GltfImageSource,
    pub sampler: GltfSampler,
    pub tex_coord: u32,
}

/// A glTF material as the file describes it (3.9). Defaults are the spec's (3.9.6, [`Default`]).
#[derive(Clone, Debug, PartialEq)]
pub struct GltfMaterial {
    pub name: Option<String>,
    /// Linear RGBA, each in [0, 1].
    pub base_color_factor: Vec4,
    pub base_color_texture: Option<GltfTexture>,
    /// In [0, 1].
    pub metallic_factor: f32,
    /// In [0, 1]; perceptual roughness (GGX α is its square).
    pub roughness_factor: f32,
    /// Blue: metalness, green: roughness, each times its factor.
    pub metallic_roughness_texture: Option<GltfTexture>,
    /// Tangent-space normals, with the `scale` of their x and y.
    pub normal_texture: Option<(GltfTexture, f32)>,
    /// Red: ambient occlusion, with its `strength` in [0, 1].
    pub occlusion_texture: Option<(GltfTexture, f32)>,
    /// Linear RGB, each in [0, 1].
    pub emissive_factor: Vec3,
    pub emissive_texture: Option<GltfTexture>,
    /// `KHR_materials_emissive_strength`, >= 0; 1 without the extension.
    pub emissive_strength: f32,
    pub alpha_mode: AlphaMode,
    /// Used with [`AlphaMode::Mask`]; >= 0, default 0.5.
    pub alpha_cutoff: f32,
    pub double_sided: bool,
}

impl Default for GltfMaterial {
    /// The default material of 3.9.6: white, fully metallic, fully rough, no emission, opaque,
    /// one-sided.
    fn default() -> Self {
        Self {
            name: None,
            base_color_factor: Vec4::ONE,
            base_color_texture: None,
            metallic_factor: 1.0,
            roughness_factor: 1.0,
            metallic_roughness_texture: None,
            normal_texture: None,
            occlusion_texture: None,
            emissive_factor: Vec3::ZERO,
            emissive_texture: None,
            emissive_strength: 1.0,
            alpha_mode: AlphaMode::Opaque,
            alpha_cutoff: 0.5,
            double_sided: false,
        }
    }
}

impl GltfMaterial {
    /// The emitted radiance: `emissiveFactor × emissive_strength`.
    pub fn emission(&self) -> Vec3 {
        self.emissive_factor * self.emissive_strength
    }

    /// The Arbor material for this one, by its factors: the coated metallic-roughness material
    /// ([`Scattering::Coated`], the specification's Appendix B model with the departures
    /// `src/render/bsdf.rs` states) of base colour `baseColorFactor` (RGB; its alpha is
    /// ignored), `metallicFactor`, GGX α = `roughnessFactor`² and a coat of index 1.5 (the
    /// specification's F0 = 0.04). A non-zero emission makes it emit, from both sides where the
    /// material is `doubleSided`. The textures are attached by the scene loader.
    pub fn to_arbor(&self, name: String) -> Material {
        let scattering = Scattering::Coated {
            base_color: self.base_color_factor.truncate(),
            metallic: self.metallic_factor,
            alpha: self.roughness_factor * self.roughness_factor,
            ior: 1.5,
        };
        let emission = Some(self.emission()).filter(|e| e.max_element() > 0.0);
        let two_sided = emission.is_some() && self.double_sided;
        Material { name, scattering, emission, two_sided, textures: Default::default() }
    }
}

impl GltfFile {
    /// Reads the glTF (JSON) or GLB file at `path`, its buffers and its scene's hierarchy.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, GltfError> {
        let path = path.as_ref();
        let bytes = crate::memory::read_file(path).map_err(|error| GltfError::Read { path: path.to_owned(), error })?;
        let fail = |place: String, message: String| GltfError::Invalid { path: path.to_owned(), place, message };
        let glb_extension = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("glb"));
        let (json_range, bin) = if bytes.starts_with(b"glTF") {
            let (json, bin) = split_glb(&bytes).map_err(|(at, message)| fail(format!("byte {at}"), message))?;
            (json, bin)
        } else if glb_extension {
            let start: Vec<String> = bytes.iter().take(4).map(|b| format!("{b:02x}")).collect();
            let message = format!("not a GLB file: it starts with bytes {}, not the magic `glTF`", start.join(" "));
            return Err(fail("byte 0".into(), message));
        } else {
            (0..bytes.len(), None)
        };
        let json_bytes = &bytes[json_range];
        let json_bytes = json_bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(json_bytes);
        let objects = json_objects(json_bytes);
        let what = format!("its JSON ({:.1} MB, {objects} objects), parsed,", json_bytes.len() as f64 / 1e6);
        let parsed =
            json_bytes.len() as f64 * PARSED_BYTES_PER_JSON_BYTE + objects as f64 * PARSED_BYTES_PER_JSON_OBJECT;
        crate::memory::check_fits(&what, parsed).map_err(|error| GltfError::Memory { path: path.to_owned(), error })?;
        let mut root: json::Root = json::deserialize::from_slice(json_bytes).map_err(|e| {
            let what = if bin.is_some() || bytes.starts_with(b"glTF") { "JSON chunk line" } else { "line" };
            let message = e.to_string();
            // serde_json ends its message with the place, which the place already says.
            let message = message.rsplit_once(" at line ").map_or(message.as_str(), |(m, _)| m).to_owned();
            fail(format!("{what} {}, column {}", e.line(), e.column()), message)
        })?;
        check_document(&mut root).map_err(|(place, message)| fail(place, message))?;
        let mut file = GltfFile {
            path: path.to_owned(),
            root,
            bytes: Vec::new(),
            buffers: Vec::new(),
            materials: Vec::new(),
            instances: Vec::new(),
            cameras: Vec::new(),
        };
        file.buffers = file.load_buffers(bin)?;
        file.bytes = bytes;
        file.materials = (0..file.root.materials.len()).map(|i| file.material(i)).collect::<Result<_, _>>()?;
        file.traverse()?;
        Ok(file)
    }

    fn fail(&self, place: impl Into<String>, message: impl Into<String>) -> GltfError {
        GltfError::Invalid { path: self.path.clone(), place: place.into(), message: message.into() }
    }

    /// How many meshes the file has (`meshes`), used by the scene or not.
    pub fn mesh_count(&self) -> usize {
        self.root.meshes.len()
    }

    /// The name of mesh `index`, if it has one.
    pub fn mesh_name(&self, index: usize) -> Option<&str> {
        self.root.meshes.get(index)?.name.as_deref()
    }

    /// The projection of camera `index` (an index into the file's `cameras`).
    pub fn projection(&self, index: usize) -> Result<GltfProjection, GltfError> {
        let c = &self.root.cameras[index];
        let place = format!("cameras[{index}]");
        let finite = |x: f32, key: &str| {
            if x.is_finite() { Ok(x) } else { Err(self.fail(format!("{place}.{key}"), format!("{x} is not finite"))) }
        };
        match c.type_ {
            Checked::Valid(json::camera::Type::Perspective) => {
                let p = c.perspective.as_ref().ok_or_else(|| {
                    self.fail(&place, "its type is `perspective`, but it has no `perspective` object")
                })?;
                let yfov = finite(p.yfov, "perspective.yfov")?;
                if !(yfov > 0.0 && yfov < std::f32::consts::PI) {
                    return Err(self.fail(
                        format!("{place}.perspective.yfov"),
                        format!("{yfov} is not an angle in (0, π) radians"),
                    ));
                }
                let aspect_ratio = p.aspect_ratio.map(|a| finite(a, "perspective.aspectRatio")).transpose()?;
                let zfar = p.zfar.map(|z| finite(z, "perspective.zfar")).transpose()?;
                Ok(GltfProjection::Perspective {
                    yfov,
                    aspect_ratio,
                    znear: finite(p.znear, "perspective.znear")?,
                    zfar,
                })
            }
            Checked::Valid(json::camera::Type::Orthographic) => {
                let o = c.orthographic.as_ref().ok_or_else(|| {
                    self.fail(&place, "its type is `orthographic`, but it has no `orthographic` object")
                })?;
                Ok(GltfProjection::Orthographic { xmag: o.xmag, ymag: o.ymag, znear: o.znear, zfar: o.zfar })
            }
            // Refused by the document check.
            Checked::Invalid => Err(self.fail(format!("{place}.type"), "is neither perspective nor orthographic")),
        }
    }

    /// Every mesh node's triangles in the file's world space, each mesh decoded once: a
    /// mirroring node's triangles have their winding turned, so that fronts stay where the
    /// file put them (as [`super::Scene::world_triangles`] does). For tools that want one mesh.
    pub fn world_mesh(&self) -> Result<TriangleMesh, GltfError> {
        let mut decoded: Vec<Option<TriangleMesh>> = vec![None; self.mesh_count()];
        let mut out = TriangleMesh::default();
        for inst in &self.instances {
            if decoded[inst.mesh].is_none() {
                decoded[inst.mesh] = Some(self.mesh(inst.mesh)?.mesh);
            }
            let Some(mesh) = &decoded[inst.mesh] else { continue };
            let mut placed = mesh.transformed(inst.world_from_object);
            if inst.world_from_object.determinant() < 0.0 {
                placed.indices.iter_mut().for_each(|t| t.swap(1, 2));
            }
            let total = out.positions.len() as u64 + placed.positions.len() as u64;
            if total > u64::from(u32::MAX) {
                return Err(self.fail(format!("nodes[{}]", inst.node), "the scene has more than 2^32 vertices"));
            }
            out.append(&placed);
        }
        Ok(out)
    }

    // -----------------------------------------------------------------------------------------
    // Buffers

    /// Every buffer's bytes, cut to its `byteLength`; `bin` is the GLB's BIN chunk in `bytes`.
    fn load_buffers(&self, bin: Option<std::ops::Range<usize>>) -> Result<Vec<BufferData>, GltfError> {
        let mut out = Vec::with_capacity(self.root.buffers.len());
        for (i, b) in self.root.buffers.iter().enumerate() {
            let declared = b.byte_length.0;
            let place = format!("buffers[{i}]");
            let short = |what: String, held: usize| {
                self.fail(&place, format!("byteLength is {declared}, but {what} holds only {held} bytes"))
            };
            let data = match &b.uri {
                None => {
                    let range = bin.clone().ok_or_else(|| {
                        self.fail(&place, "has no `uri`, so it is a GLB file's BIN chunk, but the file has none")
                    })?;
                    if (range.len() as u64) < declared {
                        return Err(short("the BIN chunk".into(), range.len()));
                    }
                    BufferData::InFile(range.start..range.start + declared as usize)
                }
                Some(uri) => {
                    let mut data = if let Some(data) = uri.strip_prefix("data:") {
                        decode_data_uri(data).map_err(|m| self.fail(format!("{place}.uri"), m))?
                    } else {
                        let at = format!("{place}.uri");
                        let file = self.uri_path(uri).map_err(|m| self.fail(&at, m))?;
                        let cannot =
                            |e: std::io::Error| self.fail(&at, format!("{}: cannot read: {e}", file.display()));
                        // Its length before anything is read: a file shorter than `byteLength`
                        // is refused, and a longer one is read only that far.
                        let held = crate::memory::regular_file_len(&file).map_err(cannot)?;
                        if held < declared {
                            return Err(short(format!("`{uri}`"), held as usize));
                        }
                        crate::memory::check_fits(&format!("{place} ({declared} bytes)"), declared as f64)
                            .map_err(|error| GltfError::Memory { path: self.path.clone(), error })?;
                        crate::memory::read_prefix(&file, declared).map_err(cannot)?
                    };
                    if (data.len() as u64) < declared {
                        let what =
                            if uri.starts_with("data:") { "its data URI".to_owned() } else { format!("`{uri}`") };
                        return Err(short(what, data.len()));
                    }
                    data.truncate(declared as usize);
                    BufferData::Owned(data)
                }
            };
            out.push(data);
        }
        Ok(out)
    }

    /// The encoded bytes of an image held in the file (a buffer view or a `data:` URI), with
    /// the JSON path that names it; `None` for an image in a file of its own.
    pub fn embedded_image(&self, t: &GltfTexture) -> Option<Result<(Vec<u8>, String), GltfError>> {
        let place = format!("images[{}]", t.image);
        let fail = |message: String| GltfError::Invalid { path: self.path.clone(), place: place.clone(), message };
        match &t.source {
            GltfImageSource::File { .. } => None,
            GltfImageSource::BufferView { buffer, offset, length, .. } => {
                let data = self.buffer(*buffer);
                let range = usize::try_from(*offset).ok().zip(usize::try_from(offset + length).ok());
                Some(match range.and_then(|(a, b)| data.get(a..b)) {
                    Some(bytes) => Ok((bytes.to_vec(), place.clone())),
                    None => Err(fail("its buffer view reads past the end of its buffer".into())),
                })
            }
            GltfImageSource::DataUri { .. } => {
                let uri = self.root.images.get(t.image).and_then(|i| i.uri.as_deref()).unwrap_or_default();
                Some(
                    decode_data_uri(uri.strip_prefix("data:").unwrap_or(uri)).map(|b| (b, place.clone())).map_err(fail),
                )
            }
        }
    }

    fn buffer(&self, index: usize) -> &[u8] {
        match &self.buffers[index] {
            BufferData::InFile(r) => &self.bytes[r.clone()],
            BufferData::Owned(v) => v,
        }
    }

    /// The file a relative URI names (section 2.8: RFC 3986 URIs, relative to the glTF file).
    fn uri_path(&self, uri: &str) -> Result<PathBuf, String> {
        if let Some((scheme, _)) = uri
            .split_once(':')
            .filter(|(s, _)| s.len() > 1 && s.chars().all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c)))
        {
            return Err(format!("`{scheme}:` URIs are not read: only data URIs and paths relative to the glTF file"));
        }
        let decoded = percent_decode(uri).ok_or_else(|| format!("`{uri}` is not a valid percent-encoded URI"))?;
        Ok(self.path.parent().unwrap_or(Path::new(".")).join(decoded))
    }

    // -----------------------------------------------------------------------------------------
    // Accessors

    /// The bytes of buffer view `view` from `offset`, which must hold `count` elements of `size`
    /// bytes, `stride` apart; `what` names the reader for errors.
    fn view_bytes(
        &self,
        view: usize,
        offset: u64,
        count: u64,
        size: u64,
        stride: u64,
        what: &dyn Fn() -> String,
    ) -> Result<&[u8], GltfError> {
        let v = &self.root.buffer_views[view];
        let buffer = self.buffer(v.buffer.value());
        let (start, length) = (v.byte_offset.map_or(0, |o| o.0), v.byte_length.0);
        let end = start.checked_add(length).filter(|&e| e <= buffer.len() as u64).ok_or_else(|| {
            self.fail(
                format!("bufferViews[{view}]"),
                format!(
                    "bytes {start} to {} lie past the end of buffer {} ({} bytes)",
                    u128::from(start) + u128::from(length),
                    v.buffer.value(),
                    buffer.len()
                ),
            )
        })?;
        let view_bytes = &buffer[start as usize..end as usize];
        // In u128: count and stride come from the file and their product may overflow u64.
        let needed = if count == 0 { 0 } else { u128::from(count - 1) * u128::from(stride) + u128::from(size) };
        if u128::from(offset) + needed > length as u128 {
            return Err(self.fail(
                what(),
                format!(
                    "reads past the end of bufferViews[{view}] (buffer {}): {count} elements of {size} bytes, {stride} apart, from byte {offset} need {} bytes, and the view has {length}",
                    v.buffer.value(),
                    u128::from(offset) + needed
                ),
            ));
        }
        Ok(&view_bytes[offset as usize..])
    }

    /// Accessor `index` read as `N` components of f32 per element, its components of one of
    /// `allowed` types (integers normalized); `place` names the reference to it.
    fn read_floats<const N: usize>(
        &self,
        index: usize,
        place: &str,
        allowed: &[ComponentType],
    ) -> Result<Vec<[f32; N]>, GltfError> {
        let a = &self.root.accessors[index];
        let at = || format!("{place}: accessor {index}");
        let (component, dims) = self.accessor_type(index, place)?;
        if dims != N {
            return Err(self.fail(at(), format!("has {dims} components per element; {place} needs {N}")));
        }
        if !allowed.contains(&component) {
            let names: Vec<&str> = allowed.iter().map(|&c| component_name(c)).collect();
            return Err(self.fail(
                at(),
                format!("has component type {}; {place} takes {}", component_name(component), names.join(", ")),
            ));
        }
        if component != ComponentType::F32 && !a.normalized {
            return Err(self.fail(at(), format!("{} components must be `normalized`", component_name(component))));
        }
        let size = component_size(component);
        let elem = size * N as u64;
        let read = |b: &[u8]| -> f32 {
            match component {
                ComponentType::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
                ComponentType::U8 => f32::from(b[0]) / 255.0,
                ComponentType::U16 => f32::from(u16::from_le_bytes([b[0], b[1]])) / 65535.0,
                ComponentType::I8 => (f32::from(b[0] as i8) / 127.0).max(-1.0),
                ComponentType::I16 => (f32::from(i16::from_le_bytes([b[0], b[1]])) / 32767.0).max(-1.0),
                ComponentType::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
            }
        };
        let element = |bytes: &[u8]| -> [f32; N] { std::array::from_fn(|c| read(&bytes[c * size as usize..])) };
        self.read_accessor(index, place, elem, [0.0; N], element)
    }

    /// Accessor `index` read as vertex indices: scalar unsigned integers.
    fn read_indices(&self, index: usize, place: &str) -> Result<Vec<u32>, GltfError> {
        let at = || format!("{place}: accessor {index}");
        let (component, dims) = self.accessor_type(index, place)?;
        if dims != 1 || !matches!(component, ComponentType::U8 | ComponentType::U16 | ComponentType::U32) {
            return Err(self.fail(
                at(),
                format!(
                    "is {} of {}; indices are scalars of UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT",
                    type_name(dims),
                    component_name(component)
                ),
            ));
        }
        let size = component_size(component);
        let element = |b: &[u8]| match component {
            ComponentType::U8 => u32::from(b[0]),
            ComponentType::U16 => u32::from(u16::from_le_bytes([b[0], b[1]])),
            _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        };
        self.read_accessor(index, place, size, 0, element)
    }

    /// The elements of accessor `index`, `elem` bytes each, decoded by `element`: from its
    /// buffer view (zeros without one), then its sparse substitutions.
    fn read_accessor<T: Clone>(
        &self,
        index: usize,
        place: &str,
        elem: u64,
        zero: T,
        element: impl Fn(&[u8]) -> T,
    ) -> Result<Vec<T>, GltfError> {
        let a = &self.root.accessors[index];
        let at = || format!("{place}: accessor {index}");
        let count = a.count.0;
        let mut out: Vec<T> = match a.buffer_view {
            Some(view) => {
                let stride = self.stride(view.value(), elem, &at)?;
                let bytes =
                    self.view_bytes(view.value(), a.byte_offset.map_or(0, |o| o.0), count, elem, stride, &at)?;
                // Bounded by the view's length: count <= length / stride + 1.
                let mut out = Vec::with_capacity(count as usize);
                if count > 0 {
                    out.extend(bytes.chunks(stride as usize).take(count as usize).map(&element));
                }
                out
            }
            None => vec![zero; self.unbacked(index, place, count, elem)?],
        };
        if let Some(sparse) = &a.sparse {
            let sparse_at = || format!("{place}: accessor {index} sparse");
            let targets = self.sparse_indices(index, sparse, count, &sparse_at)?;
            let values = self.view_bytes(
                sparse.values.buffer_view.value(),
                sparse.values.byte_offset.0,
                targets.len() as u64,
                elem,
                elem,
                &|| format!("{} values", sparse_at()),
            )?;
            for (&t, bytes) in targets.iter().zip(values.chunks(elem as usize)) {
                out[t as usize] = element(bytes);
            }
        }
        Ok(out)
    }

    /// The component type and component count of accessor `index`.
    fn accessor_type(&self, index: usize, place: &str) -> Result<(ComponentType, usize), GltfError> {
        let a = &self.root.accessors[index];
        let (Checked::Valid(c), Checked::Valid(t)) = (&a.component_type, &a.type_) else {
            // Refused by the document check.
            return Err(self.fail(format!("{place}: accessor {index}"), "has an invalid type or component type"));
        };
        let dims = match t {
            Type::Scalar => 1,
            Type::Vec2 => 2,
            Type::Vec3 => 3,
            Type::Vec4 => 4,
            Type::Mat2 => 4,
            Type::Mat3 => 9,
            Type::Mat4 => 16,
        };
        Ok((c.0, dims))
    }

    /// The distance between elements of `elem` bytes in buffer view `view`: its `byteStride`,
    /// which must hold an element, or `elem` (tightly packed).
    fn stride(&self, view: usize, elem: u64, at: &dyn Fn() -> String) -> Result<u64, GltfError> {
        match self.root.buffer_views[view].byte_stride {
            Some(s) if (s.0 as u64) < elem => Err(self.fail(
                at(),
                format!("elements of {elem} bytes do not fit bufferViews[{view}]'s byteStride of {}", s.0),
            )),
            Some(s) => Ok(s.0 as u64),
            None => Ok(elem),
        }
    }

    /// The element count of an accessor without a buffer view, checked before it is
    /// allocated: no file bounds it.
    fn unbacked(&self, index: usize, place: &str, count: u64, elem: u64) -> Result<usize, GltfError> {
        let at = || format!("{place}: accessor {index}");
        if count > MAX_UNBACKED_ELEMENTS {
            return Err(self.fail(
                at(),
                format!("has no bufferView and {count} elements, more than {MAX_UNBACKED_ELEMENTS} (all zeros)"),
            ));
        }
        let what = format!("{} ({count} elements without a bufferView)", at());
        crate::memory::check_fits(&what, count as f64 * (elem as f64).max(4.0))
            .map_err(|error| GltfError::Memory { path: self.path.clone(), error })?;
        Ok(count as usize)
    }

    /// The element indices a sparse accessor replaces: strictly increasing, below `count`.
    fn sparse_indices(
        &self,
        index: usize,
        sparse: &json::accessor::sparse::Sparse,
        count: u64,
        at: &dyn Fn() -> String,
    ) -> Result<Vec<u32>, GltfError> {
        let n = sparse.count.0;
        if n > count {
            return Err(self.fail(at(), format!("replaces {n} elements of an accessor of {count}")));
        }
        let Checked::Valid(ty) = &sparse.indices.component_type else {
            return Err(self.fail(format!("{} indices", at()), "has an invalid component type"));
        };
        let ty = ty.0;
        if !matches!(ty, ComponentType::U8 | ComponentType::U16 | ComponentType::U32) {
            return Err(self.fail(
                format!("{} indices", at()),
                format!("are {}; sparse indices are UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT", component_name(ty)),
            ));
        }
        let size = component_size(ty);
        let bytes =
            self.view_bytes(sparse.indices.buffer_view.value(), sparse.indices.byte_offset.0, n, size, size, &|| {
                format!("{} indices", at())
            })?;
        let mut out = Vec::with_capacity(n as usize);
        for (k, b) in bytes.chunks(size as usize).take(n as usize).enumerate() {
            let i = match ty {
                ComponentType::U8 => u32::from(b[0]),
                ComponentType::U16 => u32::from(u16::from_le_bytes([b[0], b[1]])),
                _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            };
            if u64::from(i) >= count {
                return Err(self.fail(
                    format!("{} indices", at()),
                    format!("index {k} is {i}, past the accessor's {count} elements (accessor {index})"),
                ));
            }
            if let Some(&prev) = out.last().filter(|&&p| p >= i) {
                return Err(self.fail(
                    format!("{} indices", at()),
                    format!("index {k} is {i}, after {prev}: sparse indices must strictly increase"),
                ));
            }
            out.push(i);
        }
        Ok(out)
    }

    // -----------------------------------------------------------------------------------------
    // Meshes

    /// Mesh `index` (of the file's `meshes`): its triangle primitives' triangles, appended.
    pub fn mesh(&self, index: usize) -> Result<GltfMesh, GltfError> {
        let mut out = GltfMesh { mesh: TriangleMesh::default(), material_ids: Vec::new() };
        for (p, prim) in self.root.meshes[index].primitives.iter().enumerate() {
            let place = format!("meshes[{index}].primitives[{p}]");
            let Some(part) = self.primitive(prim, &place)? else { continue };
            let total = out.mesh.positions.len() as u64 + part.positions.len() as u64;
            if total > u64::from(u32::MAX) {
                return Err(self.fail(place, "the mesh has more than 2^32 vertices"));
            }
            let material = prim.material.map_or(DEFAULT_MATERIAL, |m| m.value() as u32);
            out.material_ids.extend(std::iter::repeat_n(material, part.indices.len()));
            if out.mesh.positions.is_empty() {
                out.mesh = part;
            } else {
                out.mesh.append(&part);
            }
        }
        Ok(out)
    }

    /// One primitive's triangles; `None` for points and lines.
    fn primitive(&self, prim: &json::mesh::Primitive, place: &str) -> Result<Option<TriangleMesh>, GltfError> {
        let mode = match prim.mode {
            Checked::Valid(m @ (Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan)) => m,
            Checked::Valid(_) => return Ok(None),
            Checked::Invalid => return Err(self.fail(format!("{place}.mode"), "is not a primitive mode (0 to 6)")),
        };
        let attribute = |s: Semantic| prim.attributes.get(&Checked::Valid(s)).map(|i| i.value());
        let Some(position) = attribute(Semantic::Positions) else {
            return Err(self.fail(format!("{place}.attributes"), "has no POSITION"));
        };
        let pos_place = format!("{place}.attributes.POSITION");
        let positions = self.read_floats::<3>(position, &pos_place, &[ComponentType::F32])?;
        if let Some(k) = positions.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
            return Err(self.fail(
                format!("{pos_place}: accessor {position}"),
                format!("element {k} is {:?}, not finite", positions[k]),
            ));
        }
        let n = positions.len();
        let same_count = |got: usize, what: &str, accessor: usize| {
            if got == n {
                Ok(())
            } else {
                Err(self.fail(
                    format!("{place}.attributes.{what}: accessor {accessor}"),
                    format!("has {got} elements, but POSITION has {n}"),
                ))
            }
        };
        let normals = match attribute(Semantic::Normals) {
            Some(a) => {
                let v = self.read_floats::<3>(a, &format!("{place}.attributes.NORMAL"), &[ComponentType::F32])?;
                same_count(v.len(), "NORMAL", a)?;
                v.into_iter().map(|v| Vec3::from(v).normalize_or_zero()).collect()
            }
            None => Vec::new(),
        };
        let uvs = match attribute(Semantic::TexCoords(0)) {
            Some(a) => {
                let uv_place = format!("{place}.attributes.TEXCOORD_0");
                let allowed = [ComponentType::F32, ComponentType::U8, ComponentType::U16];
                let v = self.read_floats::<2>(a, &uv_place, &allowed)?;
                same_count(v.len(), "TEXCOORD_0", a)?;
                if let Some(k) = v.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
                    let message = format!("element {k} is {:?}, not finite", v[k]);
                    return Err(self.fail(format!("{uv_place}: accessor {a}"), message));
                }
                // glTF's v runs down from the image's top; Arbor's (OBJ's) up from its bottom.
                v.into_iter().map(|[u, v]| Vec2::new(u, 1.0 - v)).collect()
            }
            None => Vec::new(),
        };
        let indices = match prim.indices {
            Some(a) => {
                let index_place = format!("{place}.indices");
                let v = self.read_indices(a.value(), &index_place)?;
                if let Some(k) = v.iter().position(|&i| i as usize >= n) {
                    return Err(self.fail(
                        format!("{index_place}: accessor {}", a.value()),
                        format!("element {k} is {}, but POSITION has {n} vertices", v[k]),
                    ));
                }
                v
            }
            None => {
                if n > u32::MAX as usize {
                    return Err(self.fail(pos_place, format!("{n} vertices are more than 2^32")));
                }
                (0..n as u32).collect()
            }
        };
        let triangles = match mode {
            Mode::Triangles => {
                if indices.len() % 3 != 0 {
                    let what = if prim.indices.is_some() { "indices" } else { "vertices (no indices)" };
                    return Err(
                        self.fail(place, format!("is TRIANGLES with {} {what}, not a multiple of 3", indices.len()))
                    );
                }
                indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect()
            }
            Mode::TriangleStrip => (0..indices.len().saturating_sub(2))
                .map(|i| [indices[i], indices[i + 1 + i % 2], indices[i + 2 - i % 2]])
                .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
                .collect(),
            _ => (0..indices.len().saturating_sub(2))
                .map(|i| [indices[i + 1], indices[i + 2], indices[0]])
                .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
                .collect(),
        };
        let positions = positions.into_iter().map(Vec3::from).collect();
        Ok(Some(TriangleMesh { positions, indices: triangles, normals, uvs }))
    }

    // -----------------------------------------------------------------------------------------
    // The node hierarchy

    /// Fills `instances` and `cameras` from the scene's trees.
    fn traverse(&mut self) -> Result<(), GltfError> {
        let root = &self.root;
        let (roots, from): (Vec<usize>, String) =
            match root.scene.map(|s| s.value()).or((!root.scenes.is_empty()).then_some(0)) {
                Some(s) => (root.scenes[s].nodes.iter().map(|n| n.value()).collect(), format!("scenes[{s}].nodes")),
                None => {
                    let mut child = vec![false; root.nodes.len()];
                    for n in &root.nodes {
                        for c in n.children.iter().flatten() {
                            child[c.value()] = true;
                        }
                    }
                    ((0..root.nodes.len()).filter(|&i| !child[i]).collect(), "the root nodes".into())
                }
            };
        let mut reached = vec![false; root.nodes.len()];
        // Depth first, by hand: a chain of nodes as deep as the file is long must not overflow
        // the call stack.
        let mut stack: Vec<(usize, Option<Mat4>)> = roots.iter().rev().map(|&n| (n, None)).collect();
        let (mut instances, mut cameras) = (Vec::new(), Vec::new());
        while let Some((n, parent)) = stack.pop() {
            let node = &root.nodes[n];
            let label = node_label(n, node.name.as_deref());
            if std::mem::replace(&mut reached[n], true) {
                return Err(self.fail(
                    label,
                    format!("is reached a second time from {from}: a cycle, or a node with two parents (nodes form disjoint trees, glTF 3.5.2)"),
                ));
            }
            let local = self.local_transform(n)?;
            let world = match parent {
                Some(p) => p * local,
                None => local,
            };
            if !world.is_finite() {
                return Err(self.fail(label, "its world transform overflows"));
            }
            if let Some(mesh) = node.mesh {
                if !super::load::invertible(&world) {
                    return Err(self.fail(
                        label,
                        "its world matrix is singular (its columns are within rounding of dependent), which would flatten its mesh",
                    ));
                }
                instances.push(GltfInstance {
                    node: n,
                    name: node.name.clone(),
                    mesh: mesh.value(),
                    world_from_object: world,
                });
            }
            if let Some(camera) = node.camera {
                cameras.push(GltfCameraNode {
                    node: n,
                    node_name: node.name.clone(),
                    camera: camera.value(),
                    camera_name: root.cameras[camera.value()].name.clone(),
                    world_from_camera: world,
                });
            }
            stack.extend(node.children.iter().flatten().rev().map(|c| (c.value(), Some(world))));
        }
        self.instances = instances;
        self.cameras = cameras;
        Ok(())
    }

    /// Node `n`'s transform relative to its parent (3.5.3).
    fn local_transform(&self, n: usize) -> Result<Mat4, GltfError> {
        let node = &self.root.nodes[n];
        let at = |key: &str| format!("nodes[{n}].{key}");
        if let Some(m) = &node.matrix {
            if m.iter().any(|x| !x.is_finite()) {
                return Err(self.fail(at("matrix"), "has a non-finite entry"));
            }
            let mat = Mat4::from_cols_array(m);
            if mat.row(3) != Vec4::W {
                return Err(self.fail(at("matrix"), "is not affine: its last row must be 0 0 0 1"));
            }
            return Ok(mat);
        }
        let t = node.translation.unwrap_or([0.0; 3]);
        let r = node.rotation.map_or([0.0, 0.0, 0.0, 1.0], |q| q.0);
        let s = node.scale.unwrap_or([1.0; 3]);
        for (key, v) in [("translation", &t[..]), ("rotation", &r[..]), ("scale", &s[..])] {
            if v.iter().any(|x| !x.is_finite()) {
                return Err(self.fail(at(key), format!("{v:?} is not finite")));
            }
        }
        let q = Quat::from_array(r);
        // Exporters write unit quaternions to a few digits; a zero one is no rotation at all.
        if q.length_squared() <= 1e-12 || !q.is_finite() {
            return Err(self.fail(at("rotation"), format!("{r:?} is not a rotation (zero length)")));
        }
        Ok(Mat4::from_scale_rotation_translation(Vec3::from(s), q.normalize(), Vec3::from(t)))
    }

    // -----------------------------------------------------------------------------------------
    // Materials

    fn material(&self, index: usize) -> Result<GltfMaterial, GltfError> {
        let m = &self.root.materials[index];
        let at = |key: &str| format!("materials[{index}].{key}");
        let unit = |x: f32, key: &str| {
            if (0.0..=1.0).contains(&x) { Ok(x) } else { Err(self.fail(at(key), format!("{x} is not in [0, 1]"))) }
        };
        let pbr = &m.pbr_metallic_roughness;
        let base = pbr.base_color_factor.0;
        for x in base {
            unit(x, "pbrMetallicRoughness.baseColorFactor").map_err(|_| {
                self.fail(at("pbrMetallicRoughness.baseColorFactor"), format!("{base:?} is not in [0, 1]"))
            })?;
        }
        let emissive = m.emissive_factor.0;
        for x in emissive {
            unit(x, "emissiveFactor")
                .map_err(|_| self.fail(at("emissiveFactor"), format!("{emissive:?} is not in [0, 1]")))?;
        }
        let emissive_strength = match m.extensions.as_ref().and_then(|e| e.emissive_strength.as_ref()) {
            Some(s) => {
                let x = s.emissive_strength.0;
                if !(x.is_finite() && x >= 0.0) {
                    let key = "extensions.KHR_materials_emissive_strength.emissiveStrength";
                    return Err(self.fail(at(key), format!("{x} is not a finite number >= 0")));
                }
                x
            }
            None => 1.0,
        };
        let alpha_mode = match m.alpha_mode {
            Checked::Valid(json::material::AlphaMode::Opaque) => AlphaMode::Opaque,
            Checked::Valid(json::material::AlphaMode::Mask) => AlphaMode::Mask,
            Checked::Valid(json::material::AlphaMode::Blend) => AlphaMode::Blend,
            Checked::Invalid => return Err(self.fail(at("alphaMode"), "is not OPAQUE, MASK or BLEND")),
        };
        let alpha_cutoff = m.alpha_cutoff.map_or(0.5, |c| c.0);
        if !(alpha_cutoff.is_finite() && alpha_cutoff >= 0.0) {
            return Err(self.fail(at("alphaCutoff"), format!("{alpha_cutoff} is not a finite number >= 0")));
        }
        let normal_texture = match &m.normal_texture {
            Some(t) => {
                if !t.scale.is_finite() {
                    return Err(self.fail(at("normalTexture.scale"), format!("{} is not finite", t.scale)));
                }
                Some((self.texture(t.index.value(), t.tex_coord, &at("normalTexture"))?, t.scale))
            }
            None => None,
        };
        let occlusion_texture = match &m.occlusion_texture {
            Some(t) => Some((
                self.texture(t.index.value(), t.tex_coord, &at("occlusionTexture"))?,
                unit(t.strength.0, "occlusionTexture.strength")?,
            )),
            None => None,
        };
        let info = |i: &Option<json::texture::Info>, key: &str| {
            i.as_ref().map(|i| self.texture(i.index.value(), i.tex_coord, &at(key))).transpose()
        };
        Ok(GltfMaterial {
            name: m.name.clone(),
            base_color_factor: Vec4::from(base),
            base_color_texture: info(&pbr.base_color_texture, "pbrMetallicRoughness.baseColorTexture")?,
            metallic_factor: unit(pbr.metallic_factor.0, "pbrMetallicRoughness.metallicFactor")?,
            roughness_factor: unit(pbr.roughness_factor.0, "pbrMetallicRoughness.roughnessFactor")?,
            metallic_roughness_texture: info(
                &pbr.metallic_roughness_texture,
                "pbrMetallicRoughness.metallicRoughnessTexture",
            )?,
            normal_texture,
            occlusion_texture,
            emissive_factor: Vec3::from(emissive),
            emissive_texture: info(&m.emissive_texture, "emissiveTexture")?,
            emissive_strength,
            alpha_mode,
            alpha_cutoff,
            double_sided: m.double_sided,
        })
    }

    /// Texture `index` as a material references it (`place`), with `tex_coord`.
    fn texture(&self, index: usize, tex_coord: u32, place: &str) -> Result<GltfTexture, GltfError> {
        let t = &self.root.textures[index];
        let image_index = t.source.value();
        let image = &self.root.images[image_index];
        let mime_type = image.mime_type.as_ref().map(|m| m.0.clone());
        let source = match (&image.uri, image.buffer_view) {
            (Some(uri), _) if uri.starts_with("data:") => GltfImageSource::DataUri { mime_type },
            (Some(uri), _) => {
                let path = self.uri_path(uri).map_err(|m| self.fail(format!("images[{image_index}].uri"), m))?;
                GltfImageSource::File { uri: uri.clone(), path, mime_type }
            }
            (None, Some(view)) => {
                let v = &self.root.buffer_views[view.value()];
                GltfImageSource::BufferView {
                    view: view.value(),
                    buffer: v.buffer.value(),
                    offset: v.byte_offset.map_or(0, |o| o.0),
                    length: v.byte_length.0,
                    mime_type,
                }
            }
            (None, None) => {
                return Err(self.fail(
                    format!("images[{image_index}]"),
                    format!("has neither `uri` nor `bufferView` (referenced by {place})"),
                ));
            }
        };
        let sampler = match t.sampler {
            Some(s) => {
                let s = &self.root.samplers[s.value()];
                let wrap = |w: &Checked<json::texture::WrappingMode>| match w {
                    Checked::Valid(json::texture::WrappingMode::ClampToEdge) => WrapMode::ClampToEdge,
                    Checked::Valid(json::texture::WrappingMode::MirroredRepeat) => WrapMode::MirroredRepeat,
                    _ => WrapMode::Repeat,
                };
                GltfSampler {
                    wrap_s: wrap(&s.wrap_s),
                    wrap_t: wrap(&s.wrap_t),
                    mag_filter: s.mag_filter.as_ref().and_then(|f| match f {
                        Checked::Valid(json::texture::MagFilter::Nearest) => Some(MagFilter::Nearest),
                        Checked::Valid(json::texture::MagFilter::Linear) => Some(MagFilter::Linear),
                        Checked::Invalid => None,
                    }),
                    min_filter: s.min_filter.as_ref().and_then(|f| {
                        use json::texture::MinFilter as M;
                        Some(match f {
                            Checked::Valid(M::Nearest) => MinFilter::Nearest,
                            Checked::Valid(M::Linear) => MinFilter::Linear,
                            Checked::Valid(M::NearestMipmapNearest) => MinFilter::NearestMipmapNearest,
                            Checked::Valid(M::LinearMipmapNearest) => MinFilter::LinearMipmapNearest,
                            Checked::Valid(M::NearestMipmapLinear) => MinFilter::NearestMipmapLinear,
                            Checked::Valid(M::LinearMipmapLinear) => MinFilter::LinearMipmapLinear,
                            Checked::Invalid => return None,
                        })
                    }),
                }
            }
            None => GltfSampler::default(),
        };
        Ok(GltfTexture { texture: index, image: image_index, source, sampler, tex_coord })
    }
}

/// `nodes[3] ("Wheel")`, or `nodes[3]` for a node without a name.
fn node_label(n: usize, name: Option<&str>) -> String {
    match name {
        Some(name) => format!("nodes[{n}] ({name:?})"),
        None => format!("nodes[{n}]"),
    }
}

/// The JSON and BIN chunks of a GLB file (section 4.4) as ranges of `bytes`, or the byte
/// offset at fault and why.
#[allow(clippy::type_complexity)]
fn split_glb(bytes: &[u8]) -> Result<(std::ops::Range<usize>, Option<std::ops::Range<usize>>), (usize, String)> {
    const JSON: u32 = 0x4E4F_534A;
    const BIN: u32 = 0x004E_4942;
    let u32_at = |at: usize| bytes.get(at..at + 4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
    let (Some(version), Some(length)) = (u32_at(4), u32_at(8)) else {
        return Err((0, format!("a GLB file starts with a 12-byte header, and this one has {} bytes", bytes.len())));
    };
    if version != 2 {
        return Err((4, format!("GLB version {version}; only version 2 (glTF 2.0) is read")));
    }
    let length = length as usize;
    if length > bytes.len() {
        return Err((
            8,
            format!("the header gives the file's length as {length} bytes, but it has {} (truncated?)", bytes.len()),
        ));
    }
    let (mut at, mut json, mut bin) = (12, None, None);
    while at < length {
        let (Some(chunk_length), Some(kind)) = (u32_at(at).filter(|_| at + 8 <= length), u32_at(at + 4)) else {
            return Err((at, format!("a chunk header (8 bytes) is cut off by the end of the file at byte {length}")));
        };
        let start = at + 8;
        let end = start + chunk_length as usize;
        if end > length {
            return Err((
                at,
                format!(
                    "a chunk of {chunk_length} bytes from byte {start} runs past the end of the file at byte {length}"
                ),
            ));
        }
        match kind {
            JSON if json.is_none() && at == 12 => json = Some(start..end),
            JSON => return Err((at, "a second JSON chunk (a GLB file has one, first)".into())),
            _ if json.is_none() => {
                return Err((at + 4, format!("the first chunk is of type {kind:#010x}, not JSON (0x4e4f534a)")));
            }
            BIN if bin.is_none() => bin = Some(start..end),
            BIN => return Err((at, "a second BIN chunk (a GLB file has at most one)".into())),
            // Unknown chunk types are to be skipped (4.4.3.1).
            _ => {}
        }
        at = end;
    }
    let json = json.ok_or((12, "no JSON chunk".to_owned()))?;
    Ok((json, bin))
}

/// The bytes of a `data:` URI's payload (after `data:`): base64 only, as glTF requires.
fn decode_data_uri(data: &str) -> Result<Vec<u8>, String> {
    use base64::Engine as _;
    let (header, payload) = data.split_once(',').ok_or("a data URI needs a `,` before its data")?;
    if !header.ends_with(";base64") {
        return Err(format!("data URI `data:{header},...` is not base64, which glTF buffers are"));
    }
    let engine = base64::engine::GeneralPurpose::new(
        &base64::alphabet::STANDARD,
        base64::engine::GeneralPurposeConfig::new()
            .with_decode_padding_mode(base64::engine::DecodePaddingMode::Indifferent),
    );
    engine.decode(payload.trim_end()).map_err(|e| format!("bad base64 in the data URI: {e}"))
}

/// How many objects the JSON text `json` opens: its `{` outside strings.
fn json_objects(json: &[u8]) -> u64 {
    let (mut count, mut in_string, mut escaped) = (0, false, false);
    for &b in json {
        if in_string {
            match b {
                _ if escaped => escaped = false,
                b'\\' => escaped = true,
                b'"' => in_string = false,
                _ => {}
            }
        } else if b == b'"' {
            in_string = true;
        } else if b == b'{' {
            count += 1;
        }
    }
    count
}

/// `%XX` escapes undone (RFC 3986, 2.1); `None` where one is malformed or the result is not
/// UTF-8.
fn percent_decode(uri: &str) -> Option<String> {
    let b = uri.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = std::str::from_utf8(b.get(i + 1..i + 3)?).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// Checks the document before any of it is used: every index refers to an object that exists,
/// every enumerated value is known, every required extension is one this reader knows
/// (`gltf-json`'s validation), as a place and a message. Unknown attribute names (which glTF
/// allows for application data, `_NAME`) are dropped first; a missing `min`/`max` of POSITION,
/// which nothing here reads, is not an error, nor is an accessor without a buffer view.
fn check_document(root: &mut json::Root) -> Result<(), (String, String)> {
    for (m, mesh) in root.meshes.iter_mut().enumerate() {
        for (p, prim) in mesh.primitives.iter_mut().enumerate() {
            prim.attributes.retain(|k, _| matches!(k, Checked::Valid(_)));
            // gltf-json's own check of POSITION indexes the accessors without a bounds check.
            if let Some(i) = prim.attributes.get(&Checked::Valid(Semantic::Positions)).map(|i| i.value()) {
                if i >= root.accessors.len() {
                    return Err((
                        format!("meshes[{m}].primitives[{p}].attributes.POSITION"),
                        format!("accessor {i} does not exist (the file has {})", root.accessors.len()),
                    ));
                }
            }
        }
    }
    let root: &json::Root = root;
    let mut errors = Vec::new();
    root.validate(root, json::Path::new, &mut |path, error| errors.push((path().to_string(), error)));
    errors.retain(|(path, error)| {
        use json::validation::Error::{Invalid, Missing};
        let min_max = path.contains("[\"POSITION\"]") && (path.ends_with(".min") || path.ends_with(".max"));
        // An accessor without a buffer view is zeros (3.6.2.1); gltf-json wants one unless sparse.
        let no_view = path
            .strip_prefix("accessors[")
            .and_then(|p| p.strip_suffix("].bufferView"))
            .is_some_and(|i| i.bytes().all(|b| b.is_ascii_digit()));
        !((min_max && matches!(error, Missing | Invalid)) || (no_view && matches!(error, Missing)))
    });
    let Some((path, error)) = errors.first() else { return Ok(()) };
    // gltf-json writes object keys as `["POSITION"]`; the rest of these errors, as `.POSITION`.
    let place = path.replace("[\"", ".").replace("\"]", "");
    let mut message = match error {
        json::validation::Error::IndexOutOfBounds => "refers to an object that does not exist".to_owned(),
        json::validation::Error::Invalid => "is not a valid value".to_owned(),
        json::validation::Error::Missing => "is missing".to_owned(),
        json::validation::Error::Oversize => "is too large".to_owned(),
        json::validation::Error::Unsupported => "is a required extension that Arbor does not read".to_owned(),
    };
    if errors.len() > 1 {
        message += &format!(" (and {} more problems)", errors.len() - 1);
    }
    Err((place, message))
}

fn component_size(c: ComponentType) -> u64 {
    match c {
        ComponentType::I8 | ComponentType::U8 => 1,
        ComponentType::I16 | ComponentType::U16 => 2,
        ComponentType::U32 | ComponentType::F32 => 4,
    }
}

fn component_name(c: ComponentType) -> &'static str {
    match c {
        ComponentType::I8 => "BYTE",
        ComponentType::U8 => "UNSIGNED_BYTE",
        ComponentType::I16 => "SHORT",
        ComponentType::U16 => "UNSIGNED_SHORT",
        ComponentType::U32 => "UNSIGNED_INT",
        ComponentType::F32 => "FLOAT",
    }
}

fn type_name(dims: usize) -> &'static str {
    match dims {
        1 => "SCALAR",
        2 => "VEC2",
        3 => "VEC3",
        4 => "VEC4 (or MAT2)",
        9 => "MAT3",
        _ => "MAT4",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percent_escapes_are_undone() {
        assert_eq!(percent_decode("a%20b.bin").as_deref(), Some("a b.bin"));
        assert_eq!(percent_decode("plain.bin").as_deref(), Some("plain.bin"));
        assert_eq!(percent_decode("bad%2"), None);
        assert_eq!(percent_decode("bad%zz"), None);
    }

    #[test]
    fn json_objects_are_counted_outside_strings() {
        assert_eq!(json_objects(br#"{"a":{"b":"{{\"{"},"c":[{},{}]}"#), 4);
        assert_eq!(json_objects(b"[]"), 0);
    }

    #[test]
    fn data_uris_decode_base64_only() {
        assert_eq!(decode_data_uri("application/octet-stream;base64,AAEC").unwrap(), vec![0, 1, 2]);
        assert_eq!(decode_data_uri("application/gltf-buffer;base64,AAE").unwrap(), vec![0, 1]);
        assert!(decode_data_uri("text/plain,abc").unwrap_err().contains("not base64"));
        assert!(decode_data_uri("application/octet-stream;base64,@@@@").unwrap_err().contains("bad base64"));
    }

    #[test]
    fn glb_chunks_are_found_and_checked() {
        let mut glb = b"glTF".to_vec();
        glb.extend(2u32.to_le_bytes());
        glb.extend(36u32.to_le_bytes());
        glb.extend(4u32.to_le_bytes());
        glb.extend(b"JSON{}  ");
        glb.extend(4u32.to_le_bytes());
        glb.extend(b"BIN\0\x01\x02\x03\x04");
        assert_eq!(glb.len(), 36);
        assert_eq!(split_glb(&glb).unwrap(), (20..24, Some(32..36)));
        assert_eq!(split_glb(&glb[..30]).unwrap_err().0, 8, "truncated");
        let mut long = glb.clone();
        long[24..28].copy_from_slice(&5u32.to_le_bytes());
        assert_eq!(split_glb(&long).unwrap_err().0, 24, "a chunk past the end");
        let mut unknown = glb.clone();
        unknown[28..32].copy_from_slice(b"XTRA");
        assert_eq!(split_glb(&unknown).unwrap(), (20..24, None), "unknown chunks are skipped");
        let mut v1 = glb.clone();
        v1[4] = 1;
        assert_eq!(split_glb(&v1).unwrap_err().0, 4);
        assert_eq!(split_glb(b"glTF\x02\0\0").unwrap_err().0, 0);
    }

    #[test]
    fn the_default_material_is_the_specs() {
        let m = GltfMaterial::default();
        assert_eq!((m.base_color_factor, m.metallic_factor, m.roughness_factor), (Vec4::ONE, 1.0, 1.0));
        let arbor = m.to_arbor("d".into());
        assert_eq!(arbor.scattering, Scattering::Coated { base_color: Vec3::ONE, metallic: 1.0, alpha: 1.0, ior: 1.5 });
        assert_eq!((arbor.emission, arbor.two_sided), (None, false));
    }
}
