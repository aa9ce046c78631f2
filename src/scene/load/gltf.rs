//! The loader's glue to the glTF reader ([`crate::scene::gltf`]): the files a scene names, read
//! once each; the objects and materials a file makes, with its textures; and a camera from a
//! file's camera node.

use std::collections::HashMap;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::rc::Rc;

use glam::Vec3;

use super::materials::too_bright;
use super::objects::{Built, Parts, invertible};
use super::{Ctx, FileError, FileFailure, io_out_of_memory};
use crate::memory::OutOfMemory;
use crate::scene::file::{S, SceneFile};
use crate::scene::gltf::{
    AlphaMode, DEFAULT_MATERIAL, GltfCameraNode, GltfError, GltfFile, GltfImageSource, GltfMaterial, GltfProjection,
    GltfTexture, WrapMode,
};
use crate::scene::{MaterialTextures, SceneError, SceneMesh};
use crate::texture::{TextureCache, TextureRef, Wrap};

impl FileError for GltfError {
    fn out_of_memory(&self) -> Option<&OutOfMemory> {
        match self {
            GltfError::Memory { error, .. } => Some(error),
            GltfError::Read { error, .. } => io_out_of_memory(error),
            GltfError::Invalid { .. } => None,
        }
    }
}

/// The glTF files a scene names, by canonical path: each read once, by the camera and the
/// objects naming it.
#[derive(Default)]
pub(super) struct GltfFiles {
    /// The files opened so far and still needed.
    open: HashMap<PathBuf, Rc<GltfFile>>,
    /// Per file, the objects it makes: each mesh node's scene mesh and world matrix.
    parts: HashMap<PathBuf, Parts>,
}

impl GltfFiles {
    fn open(&mut self, path: &Path) -> Result<Rc<GltfFile>, GltfError> {
        let id = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_owned());
        if let Some(f) = self.open.get(&id) {
            return Ok(f.clone());
        }
        let file = Rc::new(GltfFile::open(path)?);
        self.open.insert(id, file.clone());
        Ok(file)
    }
}

/// The textures of glTF material `index` that Arbor applies: the base colour texture (sRGB),
/// with `alphaMode` MASK its alpha as a cut-out at `alphaCutoff` (the factor's alpha folded into
/// the cutoff), the normal texture with its scale, the metallic-roughness texture (green:
/// roughness, blue: metallic, each multiplying its factor) and the emissive texture (sRGB,
/// multiplying the emissive factor). The occlusion texture is not: a path tracer computes the
/// occlusion it approximates. Only `TEXCOORD_0` is kept, so a texture reading another set is
/// left out; the wrap is the sampler's `wrapS`.
fn gltf_textures(
    file: &GltfFile,
    index: usize,
    m: &GltfMaterial,
    cache: &mut TextureCache,
) -> Result<MaterialTextures, FileFailure> {
    let mut out = MaterialTextures { normal_scale: 1.0, ..Default::default() };
    let mut load = |t: &GltfTexture, what: &str, srgb: bool| -> Result<Option<TextureRef>, FileFailure> {
        if t.tex_coord != 0 {
            return Ok(None);
        }
        let place = format!("materials[{index}].{what}");
        let texture = match file.embedded_image(t) {
            None => {
                let GltfImageSource::File { path, .. } = &t.source else { unreachable!("only files are not embedded") };
                cache.get(path).map_err(|e| FileFailure::at(&place, &e))?
            }
            Some(bytes) => {
                let key = PathBuf::from(format!("{}#images[{}]", file.path.display(), t.image));
                let read = |e: GltfError| FileFailure { message: e.to_string(), memory: e.out_of_memory().cloned() };
                cache
                    .get_embedded(key, || bytes.map(|(b, _)| b).map_err(read))
                    .map_err(|e| FileFailure { message: format!("{place}: {}", e.message), ..e })?
            }
        };
        let wrap = match t.sampler.wrap_s {
            WrapMode::Repeat => Wrap::Repeat,
            WrapMode::ClampToEdge => Wrap::Clamp,
            WrapMode::MirroredRepeat => Wrap::Mirror,
        };
        Ok(Some(TextureRef { texture, wrap, srgb }))
    };
    if let Some(t) = &m.base_color_texture {
        out.base_color = load(t, "pbrMetallicRoughness.baseColorTexture", true)?;
    }
    if let Some((t, scale)) = &m.normal_texture {
        out.normal = load(t, "normalTexture", false)?;
        out.normal_scale = *scale;
    }
    if let Some(t) = &m.metallic_roughness_texture {
        let r = load(t, "pbrMetallicRoughness.metallicRoughnessTexture", false)?;
        (out.roughness, out.metallic) = (r.map(|r| (r, 1)), r.map(|r| (r, 2)));
    }
    if let Some(t) = &m.emissive_texture {
        out.emission = load(t, "emissiveTexture", true)?;
    }
    // A texture without an alpha channel has alpha 1 (3.9.2), so only the factor would cut.
    if let Some(r) =
        out.base_color.filter(|r| m.alpha_mode == AlphaMode::Mask && cache.textures[r.texture as usize].has_alpha)
    {
        out.alpha = Some(TextureRef { srgb: false, ..r });
        out.alpha_cutoff = m.alpha_cutoff / m.base_color_factor.w.max(1e-6);
    }
    Ok(out)
}

/// The objects the glTF file `rel` makes, as (scene mesh, the node's world matrix), the file
/// read the first time: its materials appended (with the default material where a primitive has
/// none), and one scene mesh per glTF mesh that a node places, shared by every node placing it.
pub(super) fn gltf_parts(
    ctx: &Ctx,
    key: &str,
    rel: &S<String>,
    base: &Path,
    out: &mut Built,
) -> Result<Parts, SceneError> {
    let path = base.join(rel.get_ref());
    let id = std::fs::canonicalize(&path).unwrap_or_else(|_| path.clone());
    if let Some(parts) = out.gltf.parts.get(&id) {
        return Ok(parts.clone());
    }
    let err = |e: GltfError| ctx.file_err(rel.span(), key, &e);
    let file = out.gltf.open(&path).map_err(err)?;
    let stem = path.file_stem().map_or(String::new(), |s| s.to_string_lossy().into_owned());
    let first = out.materials.len() as u32;
    for (i, m) in file.materials.iter().enumerate() {
        let id = add_material(out, &stem, m.name.clone().unwrap_or_else(|| i.to_string()), m);
        let textures = gltf_textures(&file, i, m, &mut out.textures).map_err(|e| {
            ctx.file_err(rel.span(), key, &FileFailure { message: format!("{}: {e}", path.display()), ..e })
        })?;
        out.materials[id as usize].textures = textures;
        let material = &out.materials[id as usize];
        // The factor times the strength, and times the emissive texture's brightest texel.
        let texture = material.textures.emission.map(|t| &*out.textures.textures[t.texture as usize]);
        if let Some((why, _)) = material.emission.and_then(|e| too_bright(e, texture)) {
            let message = format!("{}: materials[{i}]: emission: {why}", path.display());
            return Err(ctx.err(rel.span(), key, message));
        }
    }
    let mut default = None;
    let mut scene_mesh: HashMap<usize, Option<usize>> = HashMap::new();
    let mut parts = Vec::with_capacity(file.instances.len());
    for inst in &file.instances {
        let index = match scene_mesh.get(&inst.mesh) {
            Some(&i) => i,
            None => {
                let m = file.mesh(inst.mesh).map_err(err)?;
                let made = if m.mesh.indices.is_empty() {
                    None
                } else {
                    let mut material_ids = m.material_ids;
                    for id in &mut material_ids {
                        *id = if *id == DEFAULT_MATERIAL {
                            match default {
                                Some(d) => d,
                                None => *default.insert(add_material(
                                    out,
                                    &stem,
                                    "default".into(),
                                    &GltfMaterial::default(),
                                )),
                            }
                        } else {
                            first + *id
                        };
                    }
                    let source = format!("{}#meshes[{}]", path.display(), inst.mesh);
                    out.meshes.push(SceneMesh { source, mesh: m.mesh, material_ids });
                    Some(out.meshes.len() - 1)
                };
                scene_mesh.insert(inst.mesh, made);
                made
            }
        };
        parts.extend(index.map(|i| (i, Some(inst.world_from_object))));
    }
    if parts.is_empty() {
        let msg = format!(
            "{}: its scene has no triangles (no node places a mesh with triangle primitives; points and lines are not drawn)",
            path.display()
        );
        return Err(ctx.err(rel.span(), key, msg));
    }
    // Its buffers are not needed again: objects naming the file again take these parts.
    out.gltf.open.remove(&id);
    out.gltf.parts.insert(id, parts.clone());
    Ok(parts)
}

/// Appends glTF material `m` of the file named `stem`, as `<stem>/<name>`; its index.
fn add_material(out: &mut Built, stem: &str, name: String, m: &GltfMaterial) -> u32 {
    let id = out.materials.len() as u32;
    out.materials.push(m.to_arbor(format!("{stem}/{name}")));
    id
}

/// The camera node of the glTF file `from` names (`name`, or the first in traversal order), as
/// position, look-at point, up and vertical field of view in degrees. The `[camera]` table has
/// been checked to give no placement of its own, and `from` to be a name.
pub(super) fn file_camera(
    ctx: &Ctx,
    f: &SceneFile,
    from: &S<String>,
    base: &Path,
    gltf: &mut GltfFiles,
) -> Result<(Vec3, Vec3, Vec3, f32), SceneError> {
    let path = base.join(from.get_ref());
    let file = gltf.open(&path).map_err(|e| ctx.file_err(from.span(), "camera.from", &e))?;
    let (node, span, key) = camera_node(ctx, f, from, &path, &file)?;
    let what = format!("{}: {}", path.display(), node_label(node));
    let yfov = match file.projection(node.camera).map_err(|e| ctx.err(span.clone(), key, e.to_string()))? {
        GltfProjection::Perspective { yfov, .. } => yfov,
        GltfProjection::Orthographic { .. } => {
            return Err(ctx.err(
                span,
                key,
                format!("{what}: cameras[{}] is orthographic; Arbor renders perspective cameras only", node.camera),
            ));
        }
    };
    let w = node.world_from_camera;
    if !invertible(&w) {
        return Err(ctx.err(span, key, format!("{what}: its world matrix is singular")));
    }
    // glTF cameras look down their node's -Z, with +Y up (3.10.1).
    let position = w.transform_point3(Vec3::ZERO);
    let forward = w.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
    let up = w.transform_vector3(Vec3::Y).normalize_or_zero();
    // The look-at point at least as far as the camera is from the origin: the view direction
    // is rebuilt from their difference, which then keeps f32's relative precision.
    let look_at = position + forward * position.length().max(1.0);
    let ok = position.is_finite()
        && look_at.is_finite()
        && forward != Vec3::ZERO
        && (look_at - position).length_squared() >= f32::MIN_POSITIVE
        && forward.cross(up).length_squared() > 1e-12;
    if !ok {
        return Err(ctx.err(
            span,
            key,
            format!("{what}: its world matrix gives no usable view (too large or too small a scale)"),
        ));
    }
    let fov = yfov.to_degrees();
    if !(fov > 0.0 && fov < 180.0) {
        return Err(ctx.err(span, key, format!("{what}: yfov {yfov} is not in (0, 180) degrees")));
    }
    Ok((position, look_at, up, fov))
}

/// The camera node `camera.name` names (a node's name or its camera's), or else the first, with
/// the span and key that an error about it points at.
fn camera_node<'a>(
    ctx: &Ctx,
    f: &SceneFile,
    from: &S<String>,
    path: &Path,
    file: &'a GltfFile,
) -> Result<(&'a GltfCameraNode, Range<usize>, &'static str), SceneError> {
    let shown = path.display();
    let Some(name) = &f.camera.get_ref().name else {
        let node = file.cameras.first().ok_or_else(|| {
            ctx.err(from.span(), "camera.from", format!("{shown}: its scene has no node with a camera"))
        })?;
        return Ok((node, from.span(), "camera.from"));
    };
    let n = name.get_ref();
    let found = file.cameras.iter().find(|k| k.node_name.as_ref() == Some(n) || k.camera_name.as_ref() == Some(n));
    let node = found.ok_or_else(|| {
        let known: Vec<String> = file.cameras.iter().map(node_label).collect();
        let known = if known.is_empty() { "none".to_owned() } else { known.join(", ") };
        ctx.err(
            name.span(),
            "camera.name",
            format!("{shown}: no camera node or camera is named `{n}` (camera nodes in its scene: {known})"),
        )
    })?;
    Ok((node, name.span(), "camera.name"))
}

/// A camera node as messages name it: its index, with its name or else its camera's.
fn node_label(k: &GltfCameraNode) -> String {
    match (&k.node_name, &k.camera_name) {
        (Some(n), _) => format!("nodes[{}] ({n:?})", k.node),
        (None, Some(c)) => format!("nodes[{}] (camera {c:?})", k.node),
        (None, None) => format!("nodes[{}]", k.node),
    }
}
