//! The `[[objects]]` array: each object's mesh (an OBJ or PLY file, a built-in shape, or a glTF
//! file's mesh nodes), its material, its placement (`matrix`, or `translate`, `rotate` and
//! `scale`), and its keyframes; scattered instances are in [`super::scatter`].

use std::collections::HashMap;
use std::collections::hash_map::Entry;
use std::path::{Path, PathBuf};

use glam::{EulerRot, Mat4, Quat, Vec3};

use super::materials::{from_mtl, mtl_textures, mtl_too_bright};
use super::scatter::{MAX_SCATTER, scatter};
use super::{Ctx, FileFailure, GltfFiles, gltf_parts};
use crate::geometry::obj::{ObjFile, read_obj};
use crate::geometry::{TriangleMesh, procedural};
use crate::scene::file::{KeyframeFile, ObjectFile, S, ScaleFile};
use crate::scene::{Animation, Keyframe, Material, Object, SceneError, SceneMesh};
use crate::texture::TextureCache;

/// Most subdivisions of a built-in sphere: 20 · 4^8 ≈ 1.3 M triangles.
const MAX_SUBDIVISIONS: u32 = 8;
/// Most triangles of a procedural shape (`city`, `hairball`), and of all of them in a scene.
/// Whether they fit is checked against the memory available: when they are made
/// ([`PROCEDURAL_MESH_BYTES_PER_TRIANGLE`]), and before the scene is flattened for a BVH
/// ([`crate::scene::Scene::check_flat_fits`]: about 300 bytes per triangle, so 10^8 need about 32 GB).
const MAX_PROCEDURAL_TRIANGLES: u64 = 100_000_000;
/// Bytes per triangle of a procedural mesh or a sphere as made: positions and indices (about 20
/// for a city), with room to spare (a sphere of subdivision 8 peaks at 37 while it is made).
const PROCEDURAL_MESH_BYTES_PER_TRIANGLE: f64 = 64.0;
/// Most objects in a scene, scattered instances included: a scene file of a few lines must not
/// ask for unbounded memory (many scatters of `MAX_SCATTER` each).
pub(super) const MAX_OBJECTS: u64 = MAX_SCATTER;

/// What every object is built against.
pub(super) struct ObjectEnv<'a> {
    /// The scene file's folder, where mesh paths start.
    pub(super) base: &'a Path,
    pub(super) by_name: HashMap<String, u32>,
    /// Whether the scene has an `[animation]` table, which anything that moves needs.
    pub(super) clock: bool,
}

/// What building objects accumulates.
pub(super) struct Built {
    /// The scene's materials, then each OBJ file's MTL materials, appended once per file.
    pub(super) materials: Vec<Material>,
    pub(super) textures: TextureCache,
    pub(super) meshes: Vec<SceneMesh>,
    /// The mesh already made for an OBJ or PLY file or a built-in shape.
    known: HashMap<MeshKey, KnownMesh>,
    pub(super) objects: Vec<Object>,
    /// Triangles of the procedural shapes made so far.
    procedural_triangles: u64,
    /// The glTF files read so far, and the objects each makes.
    #[cfg_attr(not(feature = "gltf"), expect(dead_code, reason = "without glTF support no file is read"))]
    pub(super) gltf: GltfFiles,
}

impl Built {
    /// Nothing built yet, beside the scene's own materials and the glTF files the camera read.
    pub(super) fn new(materials: Vec<Material>, textures: TextureCache, gltf: GltfFiles) -> Self {
        let (meshes, known, objects) = (Vec::new(), HashMap::new(), Vec::new());
        Built { materials, textures, meshes, known, objects, procedural_triangles: 0, gltf }
    }
}

/// An object's parts: each a scene mesh, and the world matrix of the glTF node placing it where
/// it comes from a glTF file.
pub(super) type Parts = Vec<(usize, Option<Mat4>)>;

/// Whether `mesh` names a glTF file: extension `.gltf` or `.glb`, in any case.
fn is_gltf(mesh: &str) -> bool {
    Path::new(mesh).extension().is_some_and(|x| x.eq_ignore_ascii_case("gltf") || x.eq_ignore_ascii_case("glb"))
}

/// What makes two objects' meshes the same.
#[derive(PartialEq, Eq, Hash)]
enum MeshKey {
    /// The OBJ or PLY file's canonical path (the joined path when it has none).
    File(PathBuf),
    /// A built-in shape ([`ShapeSpec`]).
    Shape(ShapeSpec),
}

struct KnownMesh {
    index: usize,
    /// Why an object using this mesh needs its own `material` (a triangle without an MTL
    /// material, or any PLY triangle), if it does.
    needs_material: Option<String>,
}

/// Builds object `index` (or, with `scatter`, its instances) into `out`.
pub(super) fn object(
    ctx: &Ctx,
    index: usize,
    o: &S<ObjectFile>,
    env: &ObjectEnv,
    out: &mut Built,
) -> Result<(), SceneError> {
    let f = o.get_ref();
    let key = |k: &str| format!("objects[{index}].{k}");
    let material = object_material(ctx, &key, f, &env.by_name)?;
    let parts = match (&f.mesh, &f.shape) {
        (Some(path), None) => file_parts(ctx, &key, path, f, material, env.base, out)?,
        (None, Some(shape)) => {
            let m = material.ok_or_else(|| ctx.err(o.span(), key("material"), "a built-in shape needs a material"))?;
            shape_parts(ctx, index, shape, f, m, out)?
        }
        (Some(p), Some(_)) => return Err(ctx.err(p.span(), key("mesh"), "give either `mesh` or `shape`, not both")),
        (None, None) => {
            return Err(ctx.err(o.span(), key("mesh"), "an object needs `mesh` (an OBJ, PLY or glTF file) or `shape`"));
        }
    };
    let mut placed = place(ctx, index, o, parts, material)?;
    match (&f.keyframes, &f.scatter) {
        (Some(_), Some(s)) => {
            return Err(ctx.err(s.span(), key("scatter"), "give either `keyframes` or `scatter`, not both"));
        }
        (Some(k), None) => {
            // Applied in world space after each part's placement: the parts move as one.
            let animation = keyframes(ctx, index, k, env.clock)?;
            placed.iter_mut().for_each(|o| o.animation = Some(animation.clone()));
        }
        (None, Some(s)) => return scatter(ctx, index, s, env.clock, &placed, &mut out.objects),
        (None, None) => {}
    }
    let total = out.objects.len() as u64 + placed.len() as u64;
    if total > MAX_OBJECTS {
        let span = f.mesh.as_ref().map_or(o.span(), |m| m.span());
        let msg = format!("its {} mesh nodes make {total} objects in the scene, more than {MAX_OBJECTS}", placed.len());
        return Err(ctx.err(span, key("mesh"), msg));
    }
    out.objects.extend(placed);
    Ok(())
}

/// The object's `material`, by its index in the scene's materials.
fn object_material(
    ctx: &Ctx,
    key: &dyn Fn(&str) -> String,
    f: &ObjectFile,
    by_name: &HashMap<String, u32>,
) -> Result<Option<u32>, SceneError> {
    let Some(name) = &f.material else { return Ok(None) };
    let id = by_name.get(name.get_ref()).ok_or_else(|| {
        let mut known: Vec<_> = by_name.keys().map(String::as_str).collect();
        known.sort();
        ctx.err(
            name.span(),
            key("material"),
            format!("no material `{}` (defined: {})", name.get_ref(), known.join(", ")),
        )
    })?;
    Ok(Some(*id))
}

/// The parts of an object whose `mesh` names a file: a glTF file's mesh nodes, or the one mesh
/// of an OBJ or PLY file, which may need the object's `material`.
fn file_parts(
    ctx: &Ctx,
    key: &dyn Fn(&str) -> String,
    path: &S<String>,
    f: &ObjectFile,
    material: Option<u32>,
    base: &Path,
    out: &mut Built,
) -> Result<Parts, SceneError> {
    if path.get_ref().trim().is_empty() {
        return Err(ctx.err(path.span(), key("mesh"), "is empty: name an OBJ, PLY or glTF file"));
    }
    if let Some(s) = &f.subdivisions {
        return Err(ctx.err(s.span(), key("subdivisions"), "only a built-in sphere takes subdivisions"));
    }
    if let Some(s) = &f.triangles {
        return Err(ctx.err(s.span(), key("triangles"), "only a procedural shape takes `triangles`"));
    }
    if let Some(s) = &f.seed {
        return Err(ctx.err(s.span(), key("seed"), "only a procedural shape takes `seed`"));
    }
    if is_gltf(path.get_ref()) {
        return gltf_parts(ctx, &key("mesh"), path, base, out);
    }
    let known = shared_file_mesh(ctx, &key("mesh"), path, base, out)?;
    if let (None, Some(why)) = (material, &known.needs_material) {
        return Err(ctx.err(path.span(), key("mesh"), why.clone()));
    }
    Ok(vec![(known.index, None)])
}

/// The one part of an object whose `shape` names a built-in shape, every triangle of `material`
/// (made the first time), within the scene's budget of procedural triangles.
fn shape_parts(
    ctx: &Ctx,
    index: usize,
    shape: &S<String>,
    f: &ObjectFile,
    material: u32,
    out: &mut Built,
) -> Result<Parts, SceneError> {
    let key = |k: &str| format!("objects[{index}].{k}");
    let spec = builtin_shape(ctx, index, shape, f)?;
    if !out.known.contains_key(&MeshKey::Shape(spec)) {
        // Each procedural shape is within its limit; their sum must be too. Past it the meshes
        // alone would take tens of gigabytes: a memory refusal (exit code 3), as a smaller
        // scene might fit a larger machine.
        if let Some(n) = &f.triangles {
            out.procedural_triangles += spec.size;
            let total = out.procedural_triangles;
            if total > MAX_PROCEDURAL_TRIANGLES {
                let message = format!(
                    "{} more make {total} triangles of procedural shapes in the scene, more than {MAX_PROCEDURAL_TRIANGLES}",
                    spec.size
                );
                let error = crate::memory::OutOfMemory {
                    what: message.clone(),
                    bytes: total as f64 * PROCEDURAL_MESH_BYTES_PER_TRIANGLE,
                    available: crate::memory::available_bytes().unwrap_or(0),
                };
                let (file, line) = (ctx.file.to_owned(), ctx.line(n.span()));
                return Err(SceneError::Memory { file, line, key: key("triangles"), message, error });
            }
        }
        // The mesh itself, before any BVH (positions and indices, with room); the shapes made
        // before it are in use already, which the memory available counts.
        let made = match (&f.triangles, &f.subdivisions) {
            (Some(n), _) => Some((spec.size, n.span(), "triangles")),
            // 20 · 4^level.
            (None, s) if spec.name == "sphere" => {
                Some((20 << (2 * spec.size), s.as_ref().map_or(shape.span(), |s| s.span()), "subdivisions"))
            }
            _ => None,
        };
        if let Some((triangles, span, k)) = made {
            let what = format!("a `{}` of {triangles} triangles", spec.name);
            crate::memory::check_fits(&what, triangles as f64 * PROCEDURAL_MESH_BYTES_PER_TRIANGLE)
                .map_err(|e| ctx.memory_err(span, key(k), e))?;
        }
    }
    let meshes = &mut out.meshes;
    let known = out.known.entry(MeshKey::Shape(spec)).or_insert_with(|| {
        meshes.push(shape_mesh(spec, material));
        KnownMesh { index: meshes.len() - 1, needs_material: None }
    });
    Ok(vec![(known.index, None)])
}

/// One object per part: a glTF file's mesh nodes, each placed by the object's transform after
/// its own world matrix; one part, placed by the object alone, otherwise.
fn place(
    ctx: &Ctx,
    index: usize,
    o: &S<ObjectFile>,
    parts: Parts,
    material: Option<u32>,
) -> Result<Vec<Object>, SceneError> {
    let f = o.get_ref();
    let world_from_object = transform(ctx, index, f)?;
    let mut placed = Vec::with_capacity(parts.len());
    for (mesh, node) in parts {
        let world_from_object = node.map_or(world_from_object, |n| world_from_object * n);
        if !world_from_object.is_finite() {
            let span = f.mesh.as_ref().map_or(o.span(), |m| m.span());
            let msg = "a node of the file, placed by the object's transform, overflows: scale the object down";
            return Err(ctx.err(span, format!("objects[{index}].mesh"), msg));
        }
        placed.push(Object { mesh, world_from_object, material, animation: None });
    }
    Ok(placed)
}

/// The mesh of the file `rel` names, loaded the first time: a PLY file where its extension is
/// `.ply` (in any case), an OBJ file (with its MTL materials) otherwise.
fn shared_file_mesh<'a>(
    ctx: &Ctx,
    key: &str,
    rel: &S<String>,
    base: &Path,
    out: &'a mut Built,
) -> Result<&'a KnownMesh, SceneError> {
    let path = base.join(rel.get_ref());
    // Canonical, so `a.obj` and `./models/../a.obj` are one mesh; a file that is not there keeps
    // its joined path, and loading it reports the error.
    let id = MeshKey::File(std::fs::canonicalize(&path).unwrap_or_else(|_| path.clone()));
    match out.known.entry(id) {
        Entry::Occupied(e) => Ok(e.into_mut()),
        Entry::Vacant(e) => {
            let ply = path.extension().is_some_and(|x| x.eq_ignore_ascii_case("ply"));
            let (mesh, needs_material) = if ply {
                ply_mesh(ctx, key, rel, &path)?
            } else {
                obj_mesh(ctx, key, rel, &path, &mut out.materials, &mut out.textures)?
            };
            out.meshes.push(mesh);
            Ok(e.insert(KnownMesh { index: out.meshes.len() - 1, needs_material }))
        }
    }
}

/// A built-in shape as an object asks for it: what makes two objects' shapes one mesh.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
struct ShapeSpec {
    name: &'static str,
    /// The sphere's subdivision level, a procedural shape's triangle count; 0 otherwise.
    size: u64,
    /// A procedural shape's seed; 0 otherwise.
    seed: u64,
}

/// The checked built-in shape of object `index` (`shape`, `subdivisions`, `triangles`, `seed`).
fn builtin_shape(ctx: &Ctx, index: usize, shape: &S<String>, f: &ObjectFile) -> Result<ShapeSpec, SceneError> {
    let key = |k: &str| format!("objects[{index}].{k}");
    let name = shape.get_ref().as_str();
    let procedural = matches!(name, "city" | "hairball");
    if let Some(s) = f.subdivisions.as_ref().filter(|_| name != "sphere") {
        return Err(ctx.err(s.span(), key("subdivisions"), "only a built-in sphere takes subdivisions"));
    }
    if !procedural {
        if let Some(s) = &f.triangles {
            return Err(ctx.err(
                s.span(),
                key("triangles"),
                "only a procedural shape (city, hairball) takes `triangles`",
            ));
        }
        if let Some(s) = &f.seed {
            return Err(ctx.err(s.span(), key("seed"), "only a procedural shape (city, hairball) takes `seed`"));
        }
    }
    let spec = |name, size, seed| ShapeSpec { name, size, seed };
    Ok(match name {
        "quad" => spec("quad", 0, 0),
        "box" => spec("box", 0, 0),
        "sphere" => {
            let level = match &f.subdivisions {
                None => 3,
                Some(s) if *s.get_ref() > MAX_SUBDIVISIONS => {
                    let msg = format!("{} is more than {MAX_SUBDIVISIONS}", s.get_ref());
                    return Err(ctx.err(s.span(), key("subdivisions"), msg));
                }
                Some(s) => *s.get_ref(),
            };
            spec("sphere", u64::from(level), 0)
        }
        "city" | "hairball" => {
            let n = f.triangles.as_ref().ok_or_else(|| {
                ctx.err(shape.span(), key("triangles"), format!("shape `{name}` needs `triangles` (how many)"))
            })?;
            if !(1..=MAX_PROCEDURAL_TRIANGLES).contains(n.get_ref()) {
                let msg = format!("{} is not in 1 to {MAX_PROCEDURAL_TRIANGLES}", n.get_ref());
                return Err(ctx.err(n.span(), key("triangles"), msg));
            }
            let name = if name == "city" { "city" } else { "hairball" };
            spec(name, *n.get_ref(), f.seed.as_ref().map_or(0, |s| *s.get_ref()))
        }
        other => {
            let msg = format!("unknown shape `{other}`; known: quad, box, sphere, city, hairball");
            return Err(ctx.err(shape.span(), key("shape"), msg));
        }
    })
}

/// A shape [`builtin_shape`] accepted, every triangle of `material`.
fn shape_mesh(spec: ShapeSpec, material: u32) -> SceneMesh {
    let mesh = match spec.name {
        "quad" => TriangleMesh::quad(),
        "box" => TriangleMesh::cube(),
        "city" => procedural::city(spec.size as usize, spec.seed),
        "hairball" => procedural::hairball(spec.size as usize, spec.seed),
        _ => TriangleMesh::icosphere(spec.size as u32),
    };
    let material_ids = vec![material; mesh.triangle_count()];
    SceneMesh { source: spec.name.to_owned(), mesh, material_ids }
}

/// The OBJ mesh at `path` (`rel` as written), its MTL materials appended to `materials`. A
/// triangle without an MTL material gets id `u32::MAX`, and the second value says why: an object
/// using the mesh then needs its own `material`.
fn obj_mesh(
    ctx: &Ctx,
    key: &str,
    rel: &S<String>,
    path: &Path,
    materials: &mut Vec<Material>,
    textures: &mut TextureCache,
) -> Result<(SceneMesh, Option<String>), SceneError> {
    let obj = read_obj(path, true).map_err(|e| ctx.file_err(rel.span(), key, &e))?;
    let mtl_base = materials.len() as u32;
    let stem = path.file_stem().map_or(String::new(), |s| s.to_string_lossy().into_owned());
    let mut needs_material =
        obj.mtl_error.as_ref().map(|e| format!("{}: cannot load its MTL materials: {e}", path.display()));
    // Each MTL file the OBJ file named, and its bytes: read again for the lines of statements.
    let mut mtl_texts = None;
    let mut texts = || -> Vec<(PathBuf, Vec<u8>)> {
        obj.mtl_files.iter().map(|f| (f.clone(), crate::memory::read_file(f).unwrap_or_default())).collect()
    };
    for m in &obj.materials {
        let mut material = from_mtl(&format!("{stem}/{}", m.name), m);
        if m.diffuse_texture.is_some()
            || m.dissolve_texture.is_some()
            || m.normal_texture.is_some()
            || ["norm", "map_Ke", "map_Pr", "map_Pm"].iter().any(|k| m.unknown_param.contains_key(*k))
        {
            let texts = mtl_texts.get_or_insert_with(&mut texts);
            // A texture that cannot be used breaks its material as a broken MTL file does: an
            // error only where an object uses the file's own materials. One that does not fit
            // in memory is an error at once.
            match mtl_textures(texts, m, textures) {
                Ok(t) => material.textures = t,
                Err(e) if e.memory.is_some() => {
                    let e = FileFailure { message: format!("{}: {e}", path.display()), ..e };
                    return Err(ctx.file_err(rel.span(), key, &e));
                }
                Err(e) => drop(needs_material.get_or_insert_with(|| format!("{}: {e}", path.display()))),
            }
        }
        // An emitter too bright to render breaks its material the same way.
        if material.emission.is_some() {
            let texts = mtl_texts.get_or_insert_with(&mut texts);
            if let Some(why) = mtl_too_bright(texts, m, &material, textures) {
                needs_material.get_or_insert_with(|| format!("{}: {why}", path.display()));
            }
        }
        materials.push(material);
    }
    let mut mesh = TriangleMesh::default();
    let mut material_ids = Vec::new();
    // tobj ends with an object of no faces when the file's last object has none.
    for model in obj.models.iter().filter(|m| !m.mesh.indices.is_empty()) {
        let id = match model.mesh.material_id {
            Some(i) if i < obj.materials.len() => mtl_base + i as u32,
            _ => {
                needs_material.get_or_insert_with(|| missing_material(path, &obj, &model.name));
                u32::MAX
            }
        };
        let part = TriangleMesh::from_tobj(&model.mesh);
        material_ids.extend(std::iter::repeat_n(id, part.indices.len()));
        mesh.append(&part);
    }
    if mesh.indices.is_empty() {
        return Err(ctx.err(rel.span(), key, format!("{}: no faces (`f` lines)", path.display())));
    }
    Ok((SceneMesh { source: path.display().to_string(), mesh, material_ids }, needs_material))
}

/// The PLY mesh at `path` (`rel` as written). A PLY file has no materials: every triangle gets id
/// `u32::MAX`, and the second value says that an object using the mesh needs its own `material`.
fn ply_mesh(ctx: &Ctx, key: &str, rel: &S<String>, path: &Path) -> Result<(SceneMesh, Option<String>), SceneError> {
    let mesh = TriangleMesh::load_ply(path).map_err(|e| ctx.file_err(rel.span(), key, &e))?;
    if mesh.indices.is_empty() {
        let msg = format!("{}: no faces (a `face` element with `vertex_indices`)", path.display());
        return Err(ctx.err(rel.span(), key, msg));
    }
    let material_ids = vec![u32::MAX; mesh.indices.len()];
    let needs_material = format!("{}: a PLY file has no materials; give the object a `material`", path.display());
    Ok((SceneMesh { source: path.display().to_string(), mesh, material_ids }, Some(needs_material)))
}

/// Why object `model` of the OBJ file at `path` has no MTL material: the error when the scene
/// object using it gives none.
fn missing_material(path: &Path, obj: &ObjFile, model: &str) -> String {
    let give = "give the object a `material`";
    let Some((line, name)) = &obj.unknown_material else {
        return format!("{}: object `{model}` has no MTL material; {give}", path.display());
    };
    let files: Vec<String> = obj.mtl_files.iter().map(|p| p.display().to_string()).collect();
    let searched = if files.is_empty() { "no `mtllib` names an MTL file".to_owned() } else { files.join(", ") };
    format!("{}:{line}: `usemtl {name}`: no MTL material `{name}` ({searched}); {give}", path.display())
}

fn transform(ctx: &Ctx, index: usize, f: &ObjectFile) -> Result<Mat4, SceneError> {
    let key = |k: &str| format!("objects[{index}].{k}");
    if let Some(m) = &f.matrix {
        if let Some(t) = f.translate.as_ref().or(f.rotate.as_ref()) {
            return Err(ctx.err(t.span(), key("matrix"), "give either `matrix` or translate/rotate/scale"));
        }
        if let Some(s) = &f.scale {
            return Err(ctx.err(s.span(), key("matrix"), "give either `matrix` or translate/rotate/scale"));
        }
        let rows = *m.get_ref();
        if rows.iter().flatten().any(|x| !x.is_finite()) {
            return Err(ctx.err(m.span(), key("matrix"), "has a non-finite entry"));
        }
        // Written row by row; glam is column-major.
        let mat = Mat4::from_cols_array_2d(&rows).transpose();
        if mat.row(3) != glam::Vec4::W || !invertible(&mat) {
            return Err(ctx.err(m.span(), key("matrix"), "must be affine (last row 0 0 0 1) and invertible"));
        }
        // A mirror (negative determinant) is accepted: placing the mesh flips its winding, so
        // fronts stay where the file put them (`Triangle::placed`).
        return Ok(mat);
    }
    let (scale, rotation, translation) = trs(ctx, &key, &f.scale, &f.rotate, &f.translate)?;
    let mat = Mat4::from_scale_rotation_translation(scale, rotation, translation);
    // A rotated scale near f32::MAX can round past it.
    if let Some(s) = f.scale.as_ref().filter(|_| !mat.is_finite()) {
        return Err(ctx.err(s.span(), key("scale"), "is too large: the placement overflows"));
    }
    Ok(mat)
}

/// Whether the linear part of `m` is invertible, judged without a scale: its determinant
/// against the product of its columns' lengths (Hadamard's bound, which it reaches for
/// orthogonal columns), so that a tiny object or a huge one is judged as its shape, not its
/// size. Below 10^-6 the columns are within rounding of being dependent (f32 keeps 7 digits):
/// the mesh would be flattened.
pub(in crate::scene) fn invertible(m: &Mat4) -> bool {
    let m3 = glam::Mat3::from_mat4(*m);
    let det = f64::from(m3.determinant());
    let bound: f64 = [m3.x_axis, m3.y_axis, m3.z_axis].iter().map(|c| f64::from(c.length())).product();
    det.is_finite() && bound.is_finite() && det.abs() > 1e-6 * bound
}

/// Checked `scale`, `rotate` and `translate` keys (defaults 1, 0, 0), as scale, rotation and
/// translation; `key` names a key of the table holding them.
pub(super) fn trs(
    ctx: &Ctx,
    key: &dyn Fn(&str) -> String,
    scale: &Option<S<ScaleFile>>,
    rotate: &Option<S<[f32; 3]>>,
    translate: &Option<S<[f32; 3]>>,
) -> Result<(Vec3, Quat, Vec3), SceneError> {
    let translation = translate.as_ref().map(|t| ctx.vec3(t, &key("translate"))).transpose()?.unwrap_or(Vec3::ZERO);
    let rotate = rotate.as_ref().map(|r| ctx.vec3(r, &key("rotate"))).transpose()?.unwrap_or(Vec3::ZERO);
    let scale = match scale {
        None => Vec3::ONE,
        Some(s) => {
            let v = match s.get_ref() {
                ScaleFile::Uniform(x) => Vec3::splat(*x),
                ScaleFile::PerAxis(a) => Vec3::from(*a),
            };
            // A negative factor mirrors (placing the mesh flips its winding, so fronts stay
            // where the file put them); zero would flatten it. Keyframes check that no factor
            // changes sign between keys, which would pass through zero.
            if !v.is_finite() || v.cmpeq(Vec3::ZERO).any() {
                return Err(ctx.err(s.span(), key("scale"), format!("{v} must be finite and not 0")));
            }
            v
        }
    };
    let r = rotate * (std::f32::consts::PI / 180.0);
    // Rotations about x, then y, then z (extrinsic), in degrees.
    let rotation = Quat::from_euler(EulerRot::ZYX, r.z, r.y, r.x);
    Ok((scale, rotation, translation))
}

/// An object's `[[objects.keyframes]]`, which need the `[animation]` clock.
fn keyframes(ctx: &Ctx, index: usize, list: &S<Vec<S<KeyframeFile>>>, clock: bool) -> Result<Animation, SceneError> {
    let list_key = format!("objects[{index}].keyframes");
    if !clock {
        return Err(ctx.err(list.span(), list_key, "keyframes need an [animation] table (fps and frames)"));
    }
    if list.get_ref().is_empty() {
        return Err(ctx.err(list.span(), list_key, "is empty; give at least one keyframe"));
    }
    let mut keys: Vec<Keyframe> = Vec::with_capacity(list.get_ref().len());
    for (j, k) in list.get_ref().iter().enumerate() {
        let key = |name: &str| format!("objects[{index}].keyframes[{j}].{name}");
        let f = k.get_ref();
        let time = f.time.as_ref().ok_or_else(|| ctx.err(k.span(), key("time"), "a keyframe needs a `time`"))?;
        let t = ctx.number(time, &key("time"), |_| true, "a finite time in seconds")?;
        if let Some(prev) = keys.last().filter(|p| t <= p.time) {
            return Err(ctx.err(
                time.span(),
                key("time"),
                format!("keyframe times must increase (previous {}, this {t})", prev.time),
            ));
        }
        let (scale, rotation, translation) = trs(ctx, &key, &f.scale, &f.rotate, &f.translate)?;
        if let Some(first) = keys.first()
            && first.scale.cmplt(Vec3::ZERO) != scale.cmplt(Vec3::ZERO)
        {
            return Err(ctx.err(
                f.scale.as_ref().map_or(k.span(), |s| s.span()),
                key("scale"),
                format!(
                    "{scale} mirrors differently from keyframes[0]'s {}: between them a factor would pass through 0",
                    first.scale
                ),
            ));
        }
        keys.push(Keyframe { time: t, translation, rotation, scale });
    }
    Ok(Animation::Keyframes(keys))
}
