//! Turning a parsed scene file into a checked [`Scene`]: value checks, materials (from the TOML
//! and from MTL files), meshes and transforms. Every error names file, line and key.

use std::collections::HashMap;
use std::ops::Range;
use std::path::{Path, PathBuf};

use glam::{EulerRot, Mat4, Quat, Vec3};

use super::file::{MaterialFile, ObjectFile, S, ScaleFile, SceneFile};
use super::{Camera, ConductorFresnel, Material, Object, RenderSettings, Scattering, Scene, SceneError, SceneMesh};
use crate::geometry::TriangleMesh;

/// Most subdivisions of a built-in sphere: 20 · 4^8 ≈ 1.3 M triangles.
const MAX_SUBDIVISIONS: u32 = 8;
/// Largest image side.
const MAX_RESOLUTION: u32 = 65_536;

pub(super) fn load(path: PathBuf) -> Result<Scene, SceneError> {
    let text = std::fs::read_to_string(&path).map_err(|source| SceneError::Read { file: path.clone(), source })?;
    parse(&text, path)
}

/// Where errors point: the file and its text, to turn byte offsets into lines.
struct Ctx<'a> {
    file: &'a Path,
    text: &'a str,
}

impl Ctx<'_> {
    fn line(&self, span: Range<usize>) -> usize {
        let end = span.start.min(self.text.len());
        self.text[..end].bytes().filter(|&b| b == b'\n').count() + 1
    }

    fn err(&self, span: Range<usize>, key: impl Into<String>, message: impl Into<String>) -> SceneError {
        SceneError::Invalid {
            file: self.file.to_owned(),
            line: self.line(span),
            key: key.into(),
            message: message.into(),
        }
    }

    fn vec3(&self, v: &S<[f32; 3]>, key: &str) -> Result<Vec3, SceneError> {
        let a = *v.get_ref();
        if a.iter().any(|x| !x.is_finite()) {
            return Err(self.err(v.span(), key, format!("{a:?} is not finite")));
        }
        Ok(Vec3::from(a))
    }

    /// A colour or radiance: finite and non-negative.
    fn color(&self, v: &S<[f32; 3]>, key: &str) -> Result<Vec3, SceneError> {
        let c = self.vec3(v, key)?;
        if c.min_element() < 0.0 {
            return Err(self.err(v.span(), key, format!("{:?} has a negative component", v.get_ref())));
        }
        Ok(c)
    }

    /// A finite number in `range` (inclusive bounds given as text for the message).
    fn number(&self, v: &S<f32>, key: &str, ok: impl Fn(f32) -> bool, what: &str) -> Result<f32, SceneError> {
        let x = *v.get_ref();
        if !x.is_finite() || !ok(x) {
            return Err(self.err(v.span(), key, format!("{x} is not {what}")));
        }
        Ok(x)
    }
}

pub(super) fn parse(text: &str, file: PathBuf) -> Result<Scene, SceneError> {
    let ctx = Ctx { file: &file, text };
    let de = toml::de::Deserializer::parse(text)
        .map_err(|e| ctx.err(e.span().unwrap_or(0..0), "syntax", e.message().trim().to_string()))?;
    let parsed: SceneFile = serde_path_to_error::deserialize(de).map_err(|e| {
        // `Spanned` shows up in the path as a private field; the user wrote none of it.
        let key = e
            .path()
            .to_string()
            .replace(".$__serde_spanned_private_value", "")
            .replace("$__serde_spanned_private_value", "");
        let inner = e.into_inner();
        ctx.err(inner.span().unwrap_or(0..0), if key == "." { "scene".into() } else { key }, inner.message().trim())
    })?;
    let camera = camera(&ctx, &parsed)?;
    let render = render(&ctx, &parsed)?;
    let environment = match &parsed.environment {
        Some(env) => Some(ctx.color(&env.get_ref().radiance, "environment.radiance")?),
        None => None,
    };
    let mut materials = Vec::new();
    let mut by_name = HashMap::new();
    for (name, m) in &parsed.materials {
        by_name.insert(name.clone(), materials.len() as u32);
        materials.push(material(&ctx, name, m)?);
    }
    let base = file.parent().unwrap_or(Path::new("."));
    let mut meshes = Vec::new();
    let mut objects = Vec::new();
    for (i, o) in parsed.objects.iter().enumerate() {
        objects.push(object(&ctx, i, o, base, &by_name, &mut materials, &mut meshes)?);
    }
    Ok(Scene { path: file.clone(), camera, render, environment, materials, meshes, objects })
}

fn camera(ctx: &Ctx, f: &SceneFile) -> Result<Camera, SceneError> {
    let c = f.camera.get_ref();
    let position = ctx.vec3(&c.position, "camera.position")?;
    let look_at = ctx.vec3(&c.look_at, "camera.look_at")?;
    let up = match &c.up {
        Some(up) => ctx.vec3(up, "camera.up")?,
        None => Vec3::Y,
    };
    let view = look_at - position;
    if view.length_squared() == 0.0 {
        return Err(ctx.err(c.look_at.span(), "camera.look_at", "equals camera.position"));
    }
    if view.cross(up).length_squared() <= 1e-12 * view.length_squared() * up.length_squared() {
        let span = c.up.as_ref().map_or(c.look_at.span(), |u| u.span());
        return Err(ctx.err(span, "camera.up", "is zero or parallel to the view direction"));
    }
    let fov = ctx.number(&c.fov, "camera.fov", |x| x > 0.0 && x < 180.0, "in (0, 180) degrees")?;
    let [width, height] = *c.resolution.get_ref();
    if !(1..=MAX_RESOLUTION).contains(&width) || !(1..=MAX_RESOLUTION).contains(&height) {
        return Err(ctx.err(
            c.resolution.span(),
            "camera.resolution",
            format!("each side must be 1 to {MAX_RESOLUTION}"),
        ));
    }
    let aperture = match &c.aperture {
        Some(a) => ctx.number(a, "camera.aperture", |x| x >= 0.0, "a radius >= 0")?,
        None => 0.0,
    };
    let focus_distance = match &c.focus_distance {
        Some(d) => ctx.number(d, "camera.focus_distance", |x| x > 0.0, "a distance > 0")?,
        None => view.length(),
    };
    Ok(Camera { position, look_at, up, fov_y_degrees: fov, width, height, aperture, focus_distance })
}

fn render(ctx: &Ctx, f: &SceneFile) -> Result<RenderSettings, SceneError> {
    let mut s = RenderSettings { spp: 64, max_depth: 8, seed: 0, time_seconds: None };
    let Some(r) = &f.render else { return Ok(s) };
    let r = r.get_ref();
    if let Some(spp) = &r.spp {
        s.spp = *spp.get_ref();
        if s.spp == 0 {
            return Err(ctx.err(spp.span(), "render.spp", "must be at least 1"));
        }
    }
    if let Some(d) = &r.max_depth {
        s.max_depth = *d.get_ref();
        if s.max_depth == 0 {
            return Err(ctx.err(d.span(), "render.max_depth", "must be at least 1 (1 shows emitters only)"));
        }
    }
    if let Some(seed) = &r.seed {
        s.seed = *seed.get_ref();
    }
    if let Some(t) = &r.time {
        let x = *t.get_ref();
        if !(x.is_finite() && x > 0.0) {
            return Err(ctx.err(t.span(), "render.time", format!("{x} is not a time > 0 seconds")));
        }
        s.time_seconds = Some(x);
    }
    Ok(s)
}

/// The keys each material type accepts, besides `type`.
fn allowed_keys(kind: &str) -> Option<&'static [&'static str]> {
    Some(match kind {
        "diffuse" => &["albedo"],
        "emissive" => &["radiance", "two_sided", "albedo"],
        "conductor" => &["roughness", "eta", "k", "base_color"],
        "dielectric" => &["ior", "roughness"],
        _ => return None,
    })
}

fn material(ctx: &Ctx, name: &str, m: &S<MaterialFile>) -> Result<Material, SceneError> {
    let f = m.get_ref();
    let key = |k: &str| format!("materials.{name}.{k}");
    let kind = f.kind.get_ref().as_str();
    let allowed = allowed_keys(kind).ok_or_else(|| {
        ctx.err(
            f.kind.span(),
            key("type"),
            format!("unknown type `{kind}`; known: diffuse, emissive, conductor, dielectric"),
        )
    })?;
    let present: [(&str, Option<Range<usize>>); 8] = [
        ("albedo", f.albedo.as_ref().map(|v| v.span())),
        ("radiance", f.radiance.as_ref().map(|v| v.span())),
        ("two_sided", f.two_sided.as_ref().map(|v| v.span())),
        ("roughness", f.roughness.as_ref().map(|v| v.span())),
        ("eta", f.eta.as_ref().map(|v| v.span())),
        ("k", f.k.as_ref().map(|v| v.span())),
        ("base_color", f.base_color.as_ref().map(|v| v.span())),
        ("ior", f.ior.as_ref().map(|v| v.span())),
    ];
    for (k, span) in present {
        if let Some(span) = span.filter(|_| !allowed.contains(&k)) {
            return Err(ctx.err(
                span,
                key(k),
                format!("not a key of a {kind} material (it takes {})", allowed.join(", ")),
            ));
        }
    }
    fn required<'a>(
        ctx: &Ctx,
        v: &'a Option<S<[f32; 3]>>,
        m: &S<MaterialFile>,
        key: String,
    ) -> Result<&'a S<[f32; 3]>, SceneError> {
        let (kind, k) = (m.get_ref().kind.get_ref(), key.rsplit('.').next().unwrap_or_default().to_owned());
        v.as_ref().ok_or_else(|| ctx.err(m.span(), key, format!("a {kind} material needs `{k}`")))
    }
    let roughness = match &f.roughness {
        Some(r) => ctx.number(r, &key("roughness"), |x| (0.0..=1.0).contains(&x), "in [0, 1]")?,
        None => 0.0,
    };
    let mut out = Material { name: name.to_owned(), scattering: Scattering::Black, emission: None, two_sided: false };
    match kind {
        "diffuse" => {
            out.scattering =
                Scattering::Diffuse { albedo: ctx.color(required(ctx, &f.albedo, m, key("albedo"))?, &key("albedo"))? }
        }
        "emissive" => {
            out.emission = Some(ctx.color(required(ctx, &f.radiance, m, key("radiance"))?, &key("radiance"))?);
            out.two_sided = f.two_sided.as_ref().is_some_and(|b| *b.get_ref());
            if let Some(a) = &f.albedo {
                out.scattering = Scattering::Diffuse { albedo: ctx.color(a, &key("albedo"))? };
            }
        }
        "conductor" => {
            let fresnel = match (&f.eta, &f.k, &f.base_color) {
                (Some(eta), Some(k), None) => {
                    ConductorFresnel::Complex { eta: ctx.color(eta, &key("eta"))?, k: ctx.color(k, &key("k"))? }
                }
                (None, None, Some(c)) => ConductorFresnel::BaseColor(ctx.color(c, &key("base_color"))?),
                _ => {
                    return Err(ctx.err(
                        m.span(),
                        key("eta"),
                        "a conductor needs either `eta` and `k`, or `base_color`",
                    ));
                }
            };
            out.scattering = Scattering::Conductor { roughness, fresnel };
        }
        _ => {
            let ior = match &f.ior {
                Some(i) => ctx.number(i, &key("ior"), |x| x > 0.0, "an index of refraction > 0")?,
                None => 1.5,
            };
            out.scattering = Scattering::Dielectric { ior, roughness };
        }
    }
    Ok(out)
}

fn object(
    ctx: &Ctx,
    index: usize,
    o: &S<ObjectFile>,
    base: &Path,
    by_name: &HashMap<String, u32>,
    materials: &mut Vec<Material>,
    meshes: &mut Vec<SceneMesh>,
) -> Result<Object, SceneError> {
    let f = o.get_ref();
    let key = |k: &str| format!("objects[{index}].{k}");
    let material = match &f.material {
        Some(name) => Some(*by_name.get(name.get_ref()).ok_or_else(|| {
            let mut known: Vec<_> = by_name.keys().map(String::as_str).collect();
            known.sort();
            ctx.err(
                name.span(),
                key("material"),
                format!("no material `{}` (defined: {})", name.get_ref(), known.join(", ")),
            )
        })?),
        None => None,
    };
    let scene_mesh = match (&f.mesh, &f.shape) {
        (Some(path), None) => {
            if let Some(s) = &f.subdivisions {
                return Err(ctx.err(s.span(), key("subdivisions"), "only a built-in sphere takes subdivisions"));
            }
            obj_mesh(ctx, &key("mesh"), path, base, material.is_some(), materials)?
        }
        (None, Some(shape)) => {
            let m = material.ok_or_else(|| ctx.err(o.span(), key("material"), "a built-in shape needs a material"))?;
            builtin_shape(ctx, &key("shape"), shape, f.subdivisions.as_ref(), m)?
        }
        (Some(p), Some(_)) => return Err(ctx.err(p.span(), key("mesh"), "give either `mesh` or `shape`, not both")),
        (None, None) => return Err(ctx.err(o.span(), key("mesh"), "an object needs `mesh` (an OBJ file) or `shape`")),
    };
    meshes.push(scene_mesh);
    let world_from_object = transform(ctx, index, f)?;
    Ok(Object { mesh: meshes.len() - 1, world_from_object, material })
}

fn builtin_shape(
    ctx: &Ctx,
    key: &str,
    shape: &S<String>,
    subdivisions: Option<&S<u32>>,
    material: u32,
) -> Result<SceneMesh, SceneError> {
    let name = shape.get_ref().as_str();
    if let Some(s) = subdivisions.filter(|_| name != "sphere") {
        return Err(ctx.err(
            s.span(),
            key.replace("shape", "subdivisions"),
            "only a built-in sphere takes subdivisions",
        ));
    }
    let mesh = match name {
        "quad" => TriangleMesh::quad(),
        "box" => TriangleMesh::cube(),
        "sphere" => {
            let level = subdivisions.map_or(Ok(3), |s| {
                let l = *s.get_ref();
                if l > MAX_SUBDIVISIONS {
                    Err(ctx.err(
                        s.span(),
                        key.replace("shape", "subdivisions"),
                        format!("{l} is more than {MAX_SUBDIVISIONS}"),
                    ))
                } else {
                    Ok(l)
                }
            })?;
            TriangleMesh::icosphere(level)
        }
        other => return Err(ctx.err(shape.span(), key, format!("unknown shape `{other}`; known: quad, box, sphere"))),
    };
    let material_ids = vec![material; mesh.triangle_count()];
    Ok(SceneMesh { source: name.to_owned(), mesh, material_ids })
}

/// An OBJ mesh relative to the scene file, its MTL materials appended to `materials`.
fn obj_mesh(
    ctx: &Ctx,
    key: &str,
    rel: &S<String>,
    base: &Path,
    overridden: bool,
    materials: &mut Vec<Material>,
) -> Result<SceneMesh, SceneError> {
    let path = base.join(rel.get_ref());
    let opts = tobj::LoadOptions { triangulate: true, single_index: true, ..Default::default() };
    let (models, mtl) = tobj::load_obj(&path, &opts)
        .map_err(|e| ctx.err(rel.span(), key, format!("cannot load {}: {e}", path.display())))?;
    let mtl_base = materials.len() as u32;
    let mtl_materials = match mtl {
        Ok(m) => m,
        Err(_) if overridden => Vec::new(),
        Err(e) => {
            return Err(ctx.err(rel.span(), key, format!("{}: cannot load its MTL materials: {e}", path.display())));
        }
    };
    let stem = path.file_stem().map_or(String::new(), |s| s.to_string_lossy().into_owned());
    for m in &mtl_materials {
        materials.push(from_mtl(&format!("{stem}/{}", m.name), m));
    }
    let mut mesh = TriangleMesh::default();
    let mut material_ids = Vec::new();
    for model in &models {
        let id = match model.mesh.material_id {
            Some(i) if i < mtl_materials.len() => mtl_base + i as u32,
            _ if overridden => u32::MAX,
            _ => {
                let msg = format!(
                    "{}: object `{}` has no MTL material; give the object a `material`",
                    path.display(),
                    model.name
                );
                return Err(ctx.err(rel.span(), key, msg));
            }
        };
        let part = TriangleMesh {
            positions: model.mesh.positions.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])).collect(),
            indices: model.mesh.indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
        };
        if let Some(bad) = part.positions.iter().position(|p| !p.is_finite()) {
            let msg = format!("{}: object `{}`, vertex {bad}: non-finite position", path.display(), model.name);
            return Err(ctx.err(rel.span(), key, msg));
        }
        material_ids.extend(std::iter::repeat_n(id, part.indices.len()));
        mesh.append(&part);
    }
    Ok(SceneMesh { source: path.display().to_string(), mesh, material_ids })
}

/// MTL to Arbor, documented in `docs/scene-format.md`: `Ke` makes an emitter (which also
/// reflects `Kd`); `d < 1` or `illum` 4, 6, 7, 9 a dielectric of index `Ni`; `Ks` without `Kd` a
/// conductor with base colour `Ks` and GGX α = sqrt(2 / (Ns + 2)); otherwise diffuse `Kd`.
fn from_mtl(name: &str, m: &tobj::Material) -> Material {
    let v = |a: Option<[f32; 3]>| a.map(Vec3::from).filter(|c| c.is_finite()).map(|c| c.max(Vec3::ZERO));
    let (kd, ks, ke) = (v(m.diffuse).unwrap_or(Vec3::ZERO), v(m.specular).unwrap_or(Vec3::ZERO), v(m.emissive));
    let roughness = m.shininess.filter(|s| s.is_finite() && *s >= 0.0).map_or(1.0, |ns| (2.0 / (ns + 2.0)).sqrt());
    let glass = m.dissolve.is_some_and(|d| d < 1.0) || matches!(m.illumination_model, Some(4 | 6 | 7 | 9));
    let emission = ke.filter(|e| e.max_element() > 0.0);
    let scattering = if emission.is_some() {
        if kd.max_element() > 0.0 { Scattering::Diffuse { albedo: kd } } else { Scattering::Black }
    } else if glass {
        let ior = m.optical_density.filter(|n| n.is_finite() && *n > 0.0).unwrap_or(1.5);
        Scattering::Dielectric { ior, roughness: if m.shininess.is_some() { roughness } else { 0.0 } }
    } else if kd.max_element() == 0.0 && ks.max_element() > 0.0 {
        Scattering::Conductor { roughness, fresnel: ConductorFresnel::BaseColor(ks) }
    } else {
        Scattering::Diffuse { albedo: kd }
    };
    Material { name: name.to_owned(), scattering, emission, two_sided: false }
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
        if mat.row(3) != glam::Vec4::W || mat.determinant().abs() < 1e-12 {
            return Err(ctx.err(m.span(), key("matrix"), "must be affine (last row 0 0 0 1) and invertible"));
        }
        return Ok(mat);
    }
    let translate = f.translate.as_ref().map(|t| ctx.vec3(t, &key("translate"))).transpose()?.unwrap_or(Vec3::ZERO);
    let rotate = f.rotate.as_ref().map(|r| ctx.vec3(r, &key("rotate"))).transpose()?.unwrap_or(Vec3::ZERO);
    let scale = match &f.scale {
        None => Vec3::ONE,
        Some(s) => {
            let v = match s.get_ref() {
                ScaleFile::Uniform(x) => Vec3::splat(*x),
                ScaleFile::PerAxis(a) => Vec3::from(*a),
            };
            if !v.is_finite() || v.min_element() <= 0.0 {
                return Err(ctx.err(s.span(), key("scale"), format!("{v} must be finite and > 0")));
            }
            v
        }
    };
    let r = rotate * (std::f32::consts::PI / 180.0);
    // Rotations about x, then y, then z (extrinsic), in degrees.
    let rotation = Quat::from_euler(EulerRot::ZYX, r.z, r.y, r.x);
    Ok(Mat4::from_scale_rotation_translation(scale, rotation, translate))
}
