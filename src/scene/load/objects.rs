//! Turning a parsed scene file into a checked [`Scene`]: value checks, materials (from the TOML,
//! from MTL files and from glTF files), meshes (one per OBJ or PLY file or built-in shape, one per
//! glTF mesh, shared by the objects naming it), transforms, cameras (from the TOML or a glTF
//! file), keyframes and scattered instances. Every error names file, line and key.
//!
//! Scattered instances draw from a local SplitMix64 (Steele, Lea and Flood 2014, "Fast splittable
//! pseudorandom number generators"), not the renderer's PCG32 streams: a scene's layout must not
//! move when the renderer changes how it samples.

use std::collections::HashMap;
use std::collections::hash_map::Entry;
use std::f32::consts::TAU;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::sync::Arc;

use glam::{EulerRot, Mat4, Quat, Vec3};

use super::super::file::{EnvironmentFile, KeyframeFile, MaterialFile, ObjectFile, S, ScaleFile, ScatterFile, SceneFile};
use super::super::gltf::{
    AlphaMode, DEFAULT_MATERIAL, GltfCameraNode, GltfError, GltfFile, GltfImageSource, GltfMaterial, GltfProjection,
    GltfTexture, WrapMode,
};
use super::super::{
    Animation, AnimationSettings, Camera, ConductorFresnel, Environment, Keyframe, Material, MaterialTextures, Object,
    RenderSettings, Scattering, Scene, SceneError, SceneMesh,
};
use crate::geometry::obj::{ObjFile, read_obj};
use crate::geometry::{TriangleMesh, procedural};
use crate::texture::environment::{EnvironmentMap, Sampling};
use crate::texture::{TextureCache, TextureRef, Wrap};

/// Most subdivisions of a built-in sphere: 20 · 4^8 ≈ 1.3 M triangles.
const MAX_SUBDIVISIONS: u32 = 8;
/// Most triangles of a procedural shape (`city`, `hairball`), and of all of them in a scene.
/// Whether they fit is checked against the memory available: when they are made
/// ([`PROCEDURAL_MESH_BYTES_PER_TRIANGLE`]), and before the scene is flattened for a BVH
/// ([`Scene::check_flat_fits`]: about 300 bytes per triangle, so 10^8 need about 32 GB).
const MAX_PROCEDURAL_TRIANGLES: u64 = 100_000_000;
/// Bytes per triangle of a procedural mesh as made: positions and indices (about 20 for a city),
/// with room to spare.
const PROCEDURAL_MESH_BYTES_PER_TRIANGLE: f64 = 64.0;
/// Largest conductor `eta` or `k` (see the conductor material).
const MAX_CONDUCTOR_INDEX: f32 = 1e6;
/// Largest image side.
const MAX_RESOLUTION: u32 = 65_536;
/// Most instances one `scatter` makes (each object is about 100 bytes).
const MAX_SCATTER: u64 = 10_000_000;
/// Most objects in a scene, scattered instances included: a scene file of a few lines must not
/// ask for unbounded memory (many scatters of `MAX_SCATTER` each).
const MAX_OBJECTS: u64 = MAX_SCATTER;
/// A scatter's orbit period when none is given, seconds.
const DEFAULT_PERIOD: f32 = 4.0;

pub(in crate::scene) fn load(path: PathBuf) -> Result<Scene, SceneError> {
    let bytes = crate::memory::read_at_most(&path, crate::memory::text_file_limit())
        .map_err(|error| SceneError::Read { file: path.clone(), error })?;
    match String::from_utf8(bytes) {
        Ok(text) => parse(&text, path),
        Err(e) => {
            // TOML is UTF-8; say where it stops being that, as a syntax error.
            let (bytes, at) = (e.as_bytes(), e.utf8_error().valid_up_to());
            let line = bytes[..at].iter().filter(|&&b| b == b'\n').count() + 1;
            let message = format!("not UTF-8 (byte {:#04x})", bytes[at]);
            Err(SceneError::Invalid { file: path, line, key: "syntax".into(), message })
        }
    }
}

/// Where errors point: the file and its text, to turn byte offsets into lines.
struct Ctx<'a> {
    file: &'a Path,
    text: &'a str,
}

impl Ctx<'_> {
    fn line(&self, span: Range<usize>) -> usize {
        // Bytes, not `str`: a span need not start at a character boundary.
        let end = span.start.min(self.text.len());
        self.text.as_bytes()[..end].iter().filter(|&&b| b == b'\n').count() + 1
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

pub(in crate::scene) fn parse(text: &str, file: PathBuf) -> Result<Scene, SceneError> {
    let ctx = Ctx { file: &file, text };
    let de = toml::de::Deserializer::parse(text).map_err(|e| {
        let span = e.span().unwrap_or(0..0);
        let mut message = e.message().trim().to_string();
        // toml says only "duplicate key"; its span is the key as written.
        if message == "duplicate key" {
            if let Some(k) = text.get(span.clone()).map(str::trim).filter(|k| !k.is_empty() && !k.contains('\n')) {
                message = format!("duplicate key `{k}`");
            }
        }
        ctx.err(span, "syntax", message)
    })?;
    let parsed: SceneFile = serde_path_to_error::deserialize(de).map_err(|e| {
        // `Spanned` shows up in the path as a private field; the user wrote none of it.
        let key = e
            .path()
            .to_string()
            .replace(".$__serde_spanned_private_value", "")
            .replace("$__serde_spanned_private_value", "");
        let inner = e.into_inner();
        let span = inner.span().unwrap_or(0..0);
        let mut message = inner.message().trim().to_string();
        // toml hands a datetime to serde as a one-entry map, and serde says "map".
        let is_datetime = text.get(span.clone()).is_some_and(|v| v.trim().parse::<toml::value::Datetime>().is_ok());
        if is_datetime && message.starts_with("invalid type: map") {
            message = message.replacen("invalid type: map", "invalid type: datetime", 1);
        }
        ctx.err(span, if key == "." { "scene".into() } else { key }, message)
    })?;
    let base = file.parent().unwrap_or(Path::new("."));
    let mut gltf_files = GltfFiles::default();
    let camera = camera(&ctx, &parsed, base, &mut gltf_files)?;
    let render = render(&ctx, &parsed)?;
    let environment = parsed.environment.as_ref().map(|e| environment(&ctx, e, &file)).transpose()?;
    let base = file.parent().unwrap_or(Path::new("."));
    let mut textures = TextureCache::default();
    let mut materials = Vec::new();
    let mut by_name = HashMap::new();
    for (name, m) in &parsed.materials {
        by_name.insert(name.clone(), materials.len() as u32);
        materials.push(material(&ctx, name, m, base, &mut textures)?);
    }
    let animation = animation(&ctx, &parsed)?;
    let env = ObjectEnv { base, by_name, clock: animation.is_some() };
    let mut out = Built {
        materials,
        textures,
        meshes: Vec::new(),
        known: HashMap::new(),
        objects: Vec::new(),
        procedural_triangles: 0,
        gltf_files,
        gltf_parts: HashMap::new(),
    };
    for (i, o) in parsed.objects.iter().enumerate() {
        object(&ctx, i, o, &env, &mut out)?;
    }
    let Built { materials, textures, meshes, objects, .. } = out;
    let textures = textures.textures;
    Ok(Scene { path: file.clone(), camera, render, environment, materials, textures, meshes, objects, animation })
}

fn animation(ctx: &Ctx, f: &SceneFile) -> Result<Option<AnimationSettings>, SceneError> {
    let Some(a) = &f.animation else { return Ok(None) };
    let t = a.get_ref();
    let fps = t.fps.as_ref().ok_or_else(|| ctx.err(a.span(), "animation.fps", "[animation] needs `fps`"))?;
    let fps = ctx.number(fps, "animation.fps", |x| x > 0.0, "a rate > 0 frames per second")?;
    let frames = t.frames.as_ref().ok_or_else(|| {
        ctx.err(a.span(), "animation.frames", "[animation] needs `frames = [first, one past the last]`")
    })?;
    let [start, end] = *frames.get_ref();
    if end <= start {
        return Err(ctx.err(
            frames.span(),
            "animation.frames",
            format!("[{start}, {end}] is empty: the end (one past the last frame) must be after the start"),
        ));
    }
    Ok(Some(AnimationSettings { fps, frames: start..end }))
}

fn camera(ctx: &Ctx, f: &SceneFile, base: &Path, gltf: &mut GltfFiles) -> Result<Camera, SceneError> {
    let c = f.camera.get_ref();
    let (position, look_at, up, fov, from_file) = match &c.from {
        Some(from) => {
            let (position, look_at, up, fov) = file_camera(ctx, f, from, base, gltf)?;
            (position, look_at, up, fov, true)
        }
        None => {
            let (position, look_at, up, fov) = toml_camera(ctx, f)?;
            (position, look_at, up, fov, false)
        }
    };
    let view = look_at - position;
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
        // A glTF camera has no distance in focus, and the look-at point made for it is not one.
        None if from_file && aperture > 0.0 => {
            let span = c.aperture.as_ref().map_or(f.camera.span(), |a| a.span());
            return Err(ctx.err(
                span,
                "camera.focus_distance",
                "a thin lens (aperture > 0) on a camera from a glTF file needs `focus_distance`: the file has none",
            ));
        }
        None => view.length(),
    };
    let resolution_line = ctx.line(c.resolution.span());
    Ok(Camera { position, look_at, up, fov_y_degrees: fov, width, height, aperture, focus_distance, resolution_line })
}

/// The camera node of the glTF file `from` names (`name`, or the first in traversal order), as
/// position, look-at point, up and vertical field of view in degrees.
fn file_camera(
    ctx: &Ctx,
    f: &SceneFile,
    from: &S<String>,
    base: &Path,
    gltf: &mut GltfFiles,
) -> Result<(Vec3, Vec3, Vec3, f32), SceneError> {
    let c = f.camera.get_ref();
    let given =
        [("position", c.position.as_ref().map(|v| v.span())), ("look_at", c.look_at.as_ref().map(|v| v.span()))];
    let given =
        given.into_iter().chain([("up", c.up.as_ref().map(|v| v.span())), ("fov", c.fov.as_ref().map(|v| v.span()))]);
    for (k, span) in given {
        if let Some(span) = span {
            return Err(ctx.err(
                span,
                format!("camera.{k}"),
                "is not given with `camera.from`: the camera's placement and field of view come from the file",
            ));
        }
    }
    if from.get_ref().trim().is_empty() {
        return Err(ctx.err(from.span(), "camera.from", "is empty: name a glTF file (.gltf or .glb)"));
    }
    let path = base.join(from.get_ref());
    let file = gltf.open(&path).map_err(|e| ctx.err(from.span(), "camera.from", e.to_string()))?;
    let shown = path.display();
    let label = |k: &GltfCameraNode| match (&k.node_name, &k.camera_name) {
        (Some(n), _) => format!("nodes[{}] ({n:?})", k.node),
        (None, Some(c)) => format!("nodes[{}] (camera {c:?})", k.node),
        (None, None) => format!("nodes[{}]", k.node),
    };
    let (node, span, key) = match &c.name {
        Some(name) => {
            let n = name.get_ref();
            let found =
                file.cameras.iter().find(|k| k.node_name.as_ref() == Some(n) || k.camera_name.as_ref() == Some(n));
            let node = found.ok_or_else(|| {
                let known: Vec<String> = file.cameras.iter().map(label).collect();
                let known = if known.is_empty() { "none".to_owned() } else { known.join(", ") };
                ctx.err(
                    name.span(),
                    "camera.name",
                    format!("{shown}: no camera node or camera is named `{n}` (camera nodes in its scene: {known})"),
                )
            })?;
            (node, name.span(), "camera.name")
        }
        None => {
            let node = file.cameras.first().ok_or_else(|| {
                ctx.err(from.span(), "camera.from", format!("{shown}: its scene has no node with a camera"))
            })?;
            (node, from.span(), "camera.from")
        }
    };
    let what = format!("{shown}: {}", label(node));
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

/// The `[camera]` table's own position, look-at point, up and field of view.
fn toml_camera(ctx: &Ctx, f: &SceneFile) -> Result<(Vec3, Vec3, Vec3, f32), SceneError> {
    let c = f.camera.get_ref();
    if let Some(n) = &c.name {
        return Err(ctx.err(n.span(), "camera.name", "names a camera of a glTF file: give `from` too"));
    }
    let missing = |k: &str| ctx.err(f.camera.span(), "camera", format!("missing field `{k}`"));
    let position_s = c.position.as_ref().ok_or_else(|| missing("position"))?;
    let look_at_s = c.look_at.as_ref().ok_or_else(|| missing("look_at"))?;
    let fov_s = c.fov.as_ref().ok_or_else(|| missing("fov"))?;
    let position = ctx.vec3(position_s, "camera.position")?;
    let look_at = ctx.vec3(look_at_s, "camera.look_at")?;
    let up = match &c.up {
        Some(up) => ctx.vec3(up, "camera.up")?,
        None => Vec3::Y,
    };
    let view = look_at - position;
    if view == Vec3::ZERO {
        return Err(ctx.err(look_at_s.span(), "camera.look_at", "equals camera.position"));
    }
    // The camera normalizes the view direction in f32: its squared length must not underflow.
    if view.length_squared() < f32::MIN_POSITIVE {
        let distance = view.as_dvec3().length();
        return Err(ctx.err(
            look_at_s.span(),
            "camera.look_at",
            format!(
                "is {distance:.2e} from camera.position, too close for f32 (at least {:.1e}): scale the scene up",
                f32::MIN_POSITIVE.sqrt()
            ),
        ));
    }
    // The camera normalizes both: their squared lengths must be finite.
    if !view.length_squared().is_finite() {
        return Err(ctx.err(
            look_at_s.span(),
            "camera.look_at",
            "is too far from camera.position (the distance overflows)",
        ));
    }
    if let Some(u) = c.up.as_ref().filter(|_| !up.length_squared().is_finite()) {
        return Err(ctx.err(u.span(), "camera.up", format!("{up} is too long (its length overflows)")));
    }
    if view.cross(up).length_squared() <= 1e-12 * view.length_squared() * up.length_squared() {
        let span = c.up.as_ref().map_or(look_at_s.span(), |u| u.span());
        return Err(ctx.err(span, "camera.up", "is zero or parallel to the view direction"));
    }
    let fov = ctx.number(fov_s, "camera.fov", |x| x > 0.0 && x < 180.0, "in (0, 180) degrees")?;
    Ok((position, look_at, up, fov))
}

fn render(ctx: &Ctx, f: &SceneFile) -> Result<RenderSettings, SceneError> {
    let mut s = RenderSettings::default();
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
        s.time = Some(x);
    }
    Ok(s)
}

/// The keys each material type accepts, besides `type`.
fn allowed_keys(kind: &str) -> Option<&'static [&'static str]> {
    Some(match kind {
        "diffuse" => &["albedo", "texture", "alpha_texture", "normal_texture"],
        "emissive" => {
            &["radiance", "two_sided", "albedo", "texture", "alpha_texture", "normal_texture", "emission_texture"]
        }
        "conductor" => &["roughness", "eta", "k", "base_color", "texture", "alpha_texture", "normal_texture"],
        "dielectric" => &["ior", "roughness", "alpha_texture", "normal_texture"],
        "metallic-roughness" => &[
            "base_color",
            "metallic",
            "roughness",
            "ior",
            "texture",
            "alpha_texture",
            "normal_texture",
            "roughness_texture",
            "metallic_texture",
        ],
        _ => return None,
    })
}

fn material(
    ctx: &Ctx,
    name: &str,
    m: &S<MaterialFile>,
    base: &Path,
    textures: &mut TextureCache,
) -> Result<Material, SceneError> {
    let f = m.get_ref();
    let key = |k: &str| format!("materials.{name}.{k}");
    let kind = f.kind.get_ref().as_str();
    let allowed = allowed_keys(kind).ok_or_else(|| {
        ctx.err(
            f.kind.span(),
            key("type"),
            format!("unknown type `{kind}`; known: diffuse, emissive, conductor, dielectric, metallic-roughness"),
        )
    })?;
    let present: [(&str, Option<Range<usize>>); 15] = [
        ("texture", f.texture.as_ref().map(|v| v.span())),
        ("emission_texture", f.emission_texture.as_ref().map(|v| v.span())),
        ("roughness_texture", f.roughness_texture.as_ref().map(|v| v.span())),
        ("metallic_texture", f.metallic_texture.as_ref().map(|v| v.span())),
        ("normal_texture", f.normal_texture.as_ref().map(|v| v.span())),
        ("metallic", f.metallic.as_ref().map(|v| v.span())),
        ("alpha_texture", f.alpha_texture.as_ref().map(|v| v.span())),
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
                format!("not a key of the `{kind}` material type (it takes {})", allowed.join(", ")),
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
        v.as_ref().ok_or_else(|| ctx.err(m.span(), key, format!("the `{kind}` material type needs `{k}`")))
    }
    // Beside its texture, a number the texture multiplies defaults to 1.
    let roughness = match &f.roughness {
        Some(r) => ctx.number(r, &key("roughness"), |x| (0.0..=1.0).contains(&x), "in [0, 1]")?,
        None if f.roughness_texture.is_some() => 1.0,
        None => 0.0,
    };
    let ior = || match &f.ior {
        Some(i) => ctx.number(i, &key("ior"), |x| x > 0.0, "an index of refraction > 0"),
        None => Ok(1.5),
    };
    let mut out = Material {
        name: name.to_owned(),
        scattering: Scattering::Black,
        emission: None,
        two_sided: false,
        textures: MaterialTextures::default(),
    };
    let mut texture = |t: &Option<S<String>>, k: &str, srgb: bool| -> Result<Option<TextureRef>, SceneError> {
        let Some(t) = t else { return Ok(None) };
        if t.get_ref().trim().is_empty() {
            return Err(ctx.err(t.span(), key(k), "is empty: name an image file"));
        }
        let index = textures.get(&base.join(t.get_ref())).map_err(|e| ctx.err(t.span(), key(k), e.to_string()))?;
        Ok(Some(TextureRef { texture: index, wrap: Wrap::Repeat, srgb }))
    };
    out.textures.base_color = texture(&f.texture, "texture", true)?;
    out.textures.alpha = texture(&f.alpha_texture, "alpha_texture", false)?;
    out.textures.alpha_cutoff = 0.5;
    out.textures.normal = texture(&f.normal_texture, "normal_texture", false)?;
    out.textures.normal_scale = 1.0;
    out.textures.emission = texture(&f.emission_texture, "emission_texture", true)?;
    out.textures.roughness = texture(&f.roughness_texture, "roughness_texture", false)?.map(|r| (r, 0));
    out.textures.metallic = texture(&f.metallic_texture, "metallic_texture", false)?.map(|r| (r, 0));
    // A texture alone gives the colour: `albedo` (or `base_color`) then defaults to white.
    let textured = out.textures.base_color.is_some();
    match kind {
        "diffuse" => {
            let albedo = match (&f.albedo, textured) {
                (None, true) => Vec3::ONE,
                _ => ctx.color(required(ctx, &f.albedo, m, key("albedo"))?, &key("albedo"))?,
            };
            out.scattering = Scattering::Diffuse { albedo }
        }
        "emissive" => {
            out.emission = Some(match (&f.radiance, out.textures.emission.is_some()) {
                (None, true) => Vec3::ONE,
                _ => ctx.color(required(ctx, &f.radiance, m, key("radiance"))?, &key("radiance"))?,
            });
            out.two_sided = f.two_sided.as_ref().is_some_and(|b| *b.get_ref());
            if let Some(a) = &f.albedo {
                out.scattering = Scattering::Diffuse { albedo: ctx.color(a, &key("albedo"))? };
            }
        }
        "conductor" => {
            let fresnel = match (&f.eta, &f.k, &f.base_color) {
                (Some(eta), Some(k), None) => {
                    // Real metals are below 100; past about 4e9 the Fresnel terms overflow f32 and
                    // the metal rendered black. 1e6 is already a perfect mirror.
                    let bounded = |v: &S<[f32; 3]>, name: &str| {
                        let c = ctx.color(v, &key(name))?;
                        if c.max_element() > MAX_CONDUCTOR_INDEX {
                            let msg = format!(
                                "{:?} is over {MAX_CONDUCTOR_INDEX:e} (real metals are below 100)",
                                v.get_ref()
                            );
                            return Err(ctx.err(v.span(), key(name), msg));
                        }
                        Ok(c)
                    };
                    ConductorFresnel::Complex { eta: bounded(eta, "eta")?, k: bounded(k, "k")? }
                }
                (None, None, Some(c)) => ConductorFresnel::BaseColor(ctx.color(c, &key("base_color"))?),
                (None, None, None) if textured => ConductorFresnel::BaseColor(Vec3::ONE),
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
        "metallic-roughness" => {
            let base_color = match (&f.base_color, textured) {
                (None, true) => Vec3::ONE,
                _ => ctx.color(required(ctx, &f.base_color, m, key("base_color"))?, &key("base_color"))?,
            };
            let metallic = match &f.metallic {
                Some(v) => ctx.number(v, &key("metallic"), |x| (0.0..=1.0).contains(&x), "in [0, 1]")?,
                None if f.metallic_texture.is_some() => 1.0,
                None => 0.0,
            };
            // `roughness` is perceptual here, as in glTF: GGX α is its square.
            out.scattering = Scattering::Coated { base_color, metallic, alpha: roughness * roughness, ior: ior()? };
        }
        _ => out.scattering = Scattering::Dielectric { ior: ior()?, roughness },
    }
    Ok(out)
}

/// What every object is built against.
struct ObjectEnv<'a> {
    /// The scene file's folder, where mesh paths start.
    base: &'a Path,
    by_name: HashMap<String, u32>,
    /// Whether the scene has an `[animation]` table, which anything that moves needs.
    clock: bool,
}

/// What building objects accumulates.
struct Built {
    /// The scene's materials, then each OBJ file's MTL materials, appended once per file.
    materials: Vec<Material>,
    textures: TextureCache,
    meshes: Vec<SceneMesh>,
    /// The mesh already made for an OBJ or PLY file or a built-in shape.
    known: HashMap<MeshKey, KnownMesh>,
    objects: Vec<Object>,
    /// Triangles of the procedural shapes made so far.
    procedural_triangles: u64,
    gltf_files: GltfFiles,
    /// Per glTF file (canonical path), the objects it makes: each mesh node's scene mesh and
    /// world matrix.
    gltf_parts: HashMap<PathBuf, Vec<(usize, Option<Mat4>)>>,
}

/// The glTF files opened so far, by canonical path: the camera and the objects naming one file
/// read it once.
#[derive(Default)]
struct GltfFiles(HashMap<PathBuf, Rc<GltfFile>>);

impl GltfFiles {
    fn open(&mut self, path: &Path) -> Result<Rc<GltfFile>, GltfError> {
        let id = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_owned());
        if let Some(f) = self.0.get(&id) {
            return Ok(f.clone());
        }
        let file = Rc::new(GltfFile::open(path)?);
        self.0.insert(id, file.clone());
        Ok(file)
    }
}

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
fn object(ctx: &Ctx, index: usize, o: &S<ObjectFile>, env: &ObjectEnv, out: &mut Built) -> Result<(), SceneError> {
    let f = o.get_ref();
    let key = |k: &str| format!("objects[{index}].{k}");
    let by_name = &env.by_name;
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
    let parts: Vec<(usize, Option<Mat4>)> = match (&f.mesh, &f.shape) {
        (Some(path), None) => {
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
                gltf_parts(ctx, &key("mesh"), path, env.base, out)?
            } else {
                let known = shared_file_mesh(ctx, &key("mesh"), path, env.base, out)?;
                if let (None, Some(why)) = (material, &known.needs_material) {
                    return Err(ctx.err(path.span(), key("mesh"), why.clone()));
                }
                vec![(known.index, None)]
            }
        }
        (None, Some(shape)) => {
            let m = material.ok_or_else(|| ctx.err(o.span(), key("material"), "a built-in shape needs a material"))?;
            let spec = builtin_shape(ctx, index, shape, f)?;
            // Each procedural shape is within its limit; their sum must be too.
            if let Some(n) = f.triangles.as_ref().filter(|_| !out.known.contains_key(&MeshKey::Shape(spec))) {
                out.procedural_triangles += spec.size;
                if out.procedural_triangles > MAX_PROCEDURAL_TRIANGLES {
                    let msg = format!(
                        "{} more make {} triangles of procedural shapes in the scene, more than {MAX_PROCEDURAL_TRIANGLES}",
                        spec.size, out.procedural_triangles
                    );
                    return Err(ctx.err(n.span(), key("triangles"), msg));
                }
                // The meshes themselves, before any BVH (positions and indices, with room).
                let what = format!("{} triangles of procedural shapes", out.procedural_triangles);
                crate::memory::check_fits(&what, out.procedural_triangles as f64 * PROCEDURAL_MESH_BYTES_PER_TRIANGLE)
                    .map_err(|e| ctx.err(n.span(), key("triangles"), e.to_string()))?;
            }
            let meshes = &mut out.meshes;
            let known = out.known.entry(MeshKey::Shape(spec)).or_insert_with(|| {
                meshes.push(shape_mesh(spec, m));
                KnownMesh { index: meshes.len() - 1, needs_material: None }
            });
            vec![(known.index, None)]
        }
        (Some(p), Some(_)) => return Err(ctx.err(p.span(), key("mesh"), "give either `mesh` or `shape`, not both")),
        (None, None) => {
            return Err(ctx.err(o.span(), key("mesh"), "an object needs `mesh` (an OBJ, PLY or glTF file) or `shape`"));
        }
    };
    let world_from_object = transform(ctx, index, f)?;
    // One object per part: a glTF file's mesh nodes, each placed by the object's transform
    // after its own world matrix; one part, placed by the object alone, otherwise.
    let mut placed = Vec::with_capacity(parts.len());
    for (mesh, node) in parts {
        let world_from_object = node.map_or(world_from_object, |n| world_from_object * n);
        if !world_from_object.is_finite() {
            let span = f.mesh.as_ref().map_or(o.span(), |m| m.span());
            let msg = "a node of the file, placed by the object's transform, overflows: scale the object down";
            return Err(ctx.err(span, key("mesh"), msg));
        }
        placed.push(Object { mesh, world_from_object, material, animation: None });
    }
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
) -> Result<MaterialTextures, String> {
    let mut out = MaterialTextures { normal_scale: 1.0, ..Default::default() };
    let mut load = |t: &GltfTexture, what: &str, srgb: bool| -> Result<Option<TextureRef>, String> {
        if t.tex_coord != 0 {
            return Ok(None);
        }
        let place = format!("materials[{index}].{what}");
        let texture = match file.embedded_image(t) {
            None => {
                let GltfImageSource::File { path, .. } = &t.source else { unreachable!("only files are not embedded") };
                cache.get(path).map_err(|e| format!("{place}: {e}"))?
            }
            Some(bytes) => {
                let key = PathBuf::from(format!("{}#images[{}]", file.path.display(), t.image));
                cache
                    .get_embedded(key, || bytes.map(|(b, _)| b).map_err(|e| e.to_string()))
                    .map_err(|e| format!("{place}: {e}"))?
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
fn gltf_parts(
    ctx: &Ctx,
    key: &str,
    rel: &S<String>,
    base: &Path,
    out: &mut Built,
) -> Result<Vec<(usize, Option<Mat4>)>, SceneError> {
    let path = base.join(rel.get_ref());
    let id = std::fs::canonicalize(&path).unwrap_or_else(|_| path.clone());
    if let Some(parts) = out.gltf_parts.get(&id) {
        return Ok(parts.clone());
    }
    let err = |e: GltfError| ctx.err(rel.span(), key, e.to_string());
    let file = out.gltf_files.open(&path).map_err(err)?;
    let stem = path.file_stem().map_or(String::new(), |s| s.to_string_lossy().into_owned());
    let add_material = |out: &mut Built, name: String, m: &GltfMaterial| {
        let id = out.materials.len() as u32;
        out.materials.push(m.to_arbor(format!("{stem}/{name}")));
        id
    };
    let first = out.materials.len() as u32;
    for (i, m) in file.materials.iter().enumerate() {
        let id = add_material(out, m.name.clone().unwrap_or_else(|| i.to_string()), m);
        let textures = gltf_textures(&file, i, m, &mut out.textures)
            .map_err(|e| ctx.err(rel.span(), key, format!("{}: {e}", path.display())))?;
        out.materials[id as usize].textures = textures;
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
                                None => *default.insert(add_material(out, "default".into(), &GltfMaterial::default())),
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
    out.gltf_files.0.remove(&id);
    out.gltf_parts.insert(id, parts.clone());
    Ok(parts)
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
    let obj = read_obj(path, true).map_err(|e| ctx.err(rel.span(), key, e.to_string()))?;
    let mtl_base = materials.len() as u32;
    let stem = path.file_stem().map_or(String::new(), |s| s.to_string_lossy().into_owned());
    let mut needs_material =
        obj.mtl_error.as_ref().map(|e| format!("{}: cannot load its MTL materials: {e}", path.display()));
    let mut mtl_texts = None;
    for m in &obj.materials {
        let mut material = from_mtl(&format!("{stem}/{}", m.name), m);
        if m.diffuse_texture.is_some()
            || m.dissolve_texture.is_some()
            || m.normal_texture.is_some()
            || ["norm", "map_Ke", "map_Pr", "map_Pm"].iter().any(|k| m.unknown_param.contains_key(*k))
        {
            let texts = mtl_texts.get_or_insert_with(|| {
                obj.mtl_files.iter().map(|f| (f.clone(), std::fs::read(f).unwrap_or_default())).collect::<Vec<_>>()
            });
            // A texture that cannot be used breaks its material as a broken MTL file does: an
            // error only where an object uses the file's own materials.
            match mtl_textures(texts, m, textures) {
                Ok(t) => material.textures = t,
                Err(e) => drop(needs_material.get_or_insert_with(|| format!("{}: {e}", path.display()))),
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
    let mesh = TriangleMesh::load_ply(path).map_err(|e| ctx.err(rel.span(), key, e.to_string()))?;
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

/// MTL to Arbor, documented in `docs/scene-format.md`: `Ke` makes an emitter (which also
/// reflects `Kd`); `d < 1` or `illum` 4, 6, 7, 9 a dielectric of index `Ni`; the PBR extension's
/// `Pr` or `Pm`, or `Kd` and `Ks` both non-zero, the coated metallic-roughness material of base
/// colour `Kd`, metallic `Pm` (default 0) and GGX α = `Pr`² or else sqrt(2 / (Ns + 2)); `Ks`
/// without `Kd` a conductor with base colour `Ks` and that α; otherwise diffuse `Kd`.
fn from_mtl(name: &str, m: &tobj::Material) -> Material {
    let v = |a: Option<[f32; 3]>| a.map(Vec3::from).filter(|c| c.is_finite()).map(|c| c.max(Vec3::ZERO));
    // `map_Kd` multiplies `Kd` (the MTL specification), which defaults to white beside a map.
    let kd_default = if m.diffuse_texture.is_some() { Vec3::ONE } else { Vec3::ZERO };
    let (kd, ks) = (v(m.diffuse).unwrap_or(kd_default), v(m.specular).unwrap_or(Vec3::ZERO));
    // So does `Ke` beside `map_Ke`, and `Pr` and `Pm` beside theirs (below).
    let has = |key: &str| m.unknown_param.contains_key(key);
    let ke = v(m.emissive).or_else(|| has("map_Ke").then_some(Vec3::ONE));
    let roughness = m.shininess.filter(|s| s.is_finite() && *s >= 0.0).map_or(1.0, |ns| (2.0 / (ns + 2.0)).sqrt());
    // The PBR extension's statements, which tobj keeps as unknown: a number in [0, 1], else
    // ignored as if absent.
    let pbr = |key: &str| {
        let x = m.unknown_param.get(key)?.split_whitespace().next()?.parse::<f32>().ok()?;
        x.is_finite().then_some(x.clamp(0.0, 1.0))
    };
    let (pr, pm) =
        (pbr("Pr").or_else(|| has("map_Pr").then_some(1.0)), pbr("Pm").or_else(|| has("map_Pm").then_some(1.0)));
    let glass = m.dissolve.is_some_and(|d| d < 1.0) || matches!(m.illumination_model, Some(4 | 6 | 7 | 9));
    let emission = ke.filter(|e| e.max_element() > 0.0);
    let scattering = if emission.is_some() {
        if kd.max_element() > 0.0 { Scattering::Diffuse { albedo: kd } } else { Scattering::Black }
    } else if glass {
        let ior = m.optical_density.filter(|n| n.is_finite() && *n > 0.0).unwrap_or(1.5);
        Scattering::Dielectric { ior, roughness: if m.shininess.is_some() { roughness } else { 0.0 } }
    } else if pr.is_some() || pm.is_some() || (kd.max_element() > 0.0 && ks.max_element() > 0.0) {
        let alpha = pr.map_or(roughness, |r| r * r);
        Scattering::Coated { base_color: kd, metallic: pm.unwrap_or(0.0), alpha, ior: 1.5 }
    } else if kd.max_element() == 0.0 && ks.max_element() > 0.0 {
        Scattering::Conductor { roughness, fresnel: ConductorFresnel::BaseColor(ks) }
    } else {
        Scattering::Diffuse { albedo: kd }
    };
    Material { name: name.to_owned(), scattering, emission, two_sided: false, textures: MaterialTextures::default() }
}

/// The textures of MTL material `m` (`map_Kd`, `map_d`, the normal map, `map_Ke`, `map_Pr`,
/// `map_Pm`), loaded into `cache`, with paths
/// relative to the MTL file that defines it (`texts`: each MTL file the OBJ file named, and its
/// bytes). An error names that file, the statement's line and the texture.
fn mtl_textures(
    texts: &[(PathBuf, Vec<u8>)],
    m: &tobj::Material,
    cache: &mut TextureCache,
) -> Result<MaterialTextures, String> {
    let mut out = MaterialTextures { alpha_cutoff: 0.5, normal_scale: 1.0, ..Default::default() };
    // tobj reads `bump` and `map_Bump` as the normal texture, and leaves `norm` unread.
    let (normal_statement, normal) = match (&m.normal_texture, m.unknown_param.get("norm")) {
        (Some(t), _) => ("bump", Some(t.clone())),
        (None, n) => ("norm", n.cloned()),
    };
    let unknown = |k: &str| m.unknown_param.get(k).cloned();
    let textures = [
        ("map_Kd", &m.diffuse_texture, true),
        ("map_d", &m.dissolve_texture, false),
        (normal_statement, &normal, false),
        ("map_Ke", &unknown("map_Ke"), true),
        ("map_Pr", &unknown("map_Pr"), false),
        ("map_Pm", &unknown("map_Pm"), false),
    ];
    for (statement, value, srgb) in textures {
        let Some(value) = value else { continue };
        // The last MTL file defining the material wins, as in tobj.
        let (mtl, line) = texts
            .iter()
            .rev()
            .find_map(|(f, text)| {
                let spellings: &[&str] =
                    if statement == "bump" { &["bump", "map_Bump", "map_bump"] } else { &[statement] };
                spellings.iter().find_map(|s| mtl_line(text, &m.name, s)).map(|l| (f.as_path(), l))
            })
            .unwrap_or((texts.first().map_or(Path::new("?"), |(f, _)| f.as_path()), 0));
        let at = format!("{}:{line}: `{statement}`", mtl.display());
        let (file, wrap) = texture_statement(value).ok_or_else(|| format!("{at}: names no file"))?;
        let path = mtl.parent().unwrap_or(Path::new(".")).join(file);
        let texture = cache.get(&path).map_err(|e| format!("{at}: {e}"))?;
        let r = Some(TextureRef { texture, wrap, srgb });
        match statement {
            "map_Kd" => out.base_color = r,
            "map_d" => out.alpha = r,
            "map_Ke" => out.emission = r,
            // Only the coated material has them: `from_mtl` makes it where these are given.
            "map_Pr" => out.roughness = r.map(|r| (r, 0)),
            "map_Pm" => out.metallic = r.map(|r| (r, 0)),
            _ => out.normal = r,
        }
    }
    Ok(out)
}

/// The line of statement `key` in material `name`'s block of an MTL file's `text`.
fn mtl_line(text: &[u8], name: &str, key: &str) -> Option<usize> {
    let mut current = None;
    for (i, line) in text.split(|&b| b == b'\n').enumerate() {
        let line = String::from_utf8_lossy(line);
        let line = line.trim();
        let (first, rest) = line.split_once(char::is_whitespace).unwrap_or((line, ""));
        if first == "newmtl" {
            current = Some(rest.trim().to_owned());
        } else if first == key && current.as_deref() == Some(name) {
            return Some(i + 1);
        }
    }
    None
}

/// A texture statement's file name and wrap, after its options (`-clamp on` clamps; `-bm`,
/// `-o`, `-s`, `-t`, `-mm`, `-blendu` and the rest are read past and not used).
fn texture_statement(value: &str) -> Option<(&str, Wrap)> {
    let mut rest = value.trim();
    let mut wrap = Wrap::Repeat;
    while rest.starts_with('-') {
        let (option, after) = rest.split_once(char::is_whitespace).unwrap_or((rest, ""));
        let mut after = after.trim_start();
        let mut take = |n: usize, numeric: bool| -> Option<&str> {
            let mut first = None;
            for k in 0..n {
                let (word, more) = after.split_once(char::is_whitespace).unwrap_or((after, ""));
                // `-o`, `-s` and `-t` take one to three numbers.
                if word.is_empty() || (numeric && k > 0 && word.parse::<f32>().is_err()) {
                    break;
                }
                first.get_or_insert(word);
                after = more.trim_start();
            }
            first
        };
        match option {
            "-clamp" => wrap = if take(1, false) == Some("on") { Wrap::Clamp } else { Wrap::Repeat },
            "-o" | "-s" | "-t" => drop(take(3, true)),
            "-mm" => drop(take(2, true)),
            _ => drop(take(1, false)),
        }
        rest = after;
    }
    (!rest.is_empty()).then_some((rest, wrap))
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

/// The `[environment]` table: a constant `radiance`, or a `map` with its `scale` and `rotate`.
fn environment(ctx: &Ctx, e: &S<EnvironmentFile>, file: &Path) -> Result<Environment, SceneError> {
    let f = e.get_ref();
    let Some(map) = &f.map else {
        if let Some(k) = &f.scale {
            return Err(ctx.err(k.span(), "environment.scale", "only a `map` takes a scale"));
        }
        if let Some(k) = &f.rotate {
            return Err(ctx.err(k.span(), "environment.rotate", "only a `map` takes `rotate`"));
        }
        let radiance = f.radiance.as_ref().ok_or_else(|| {
            ctx.err(e.span(), "environment", "give `radiance` (a constant) or `map` (an .exr or .hdr file)")
        })?;
        return Ok(Environment { radiance: ctx.color(radiance, "environment.radiance")?, map: None });
    };
    if let Some(r) = &f.radiance {
        return Err(ctx.err(r.span(), "environment.radiance", "give either `radiance` or `map` (with `scale`)"));
    }
    let radiance = match &f.scale {
        None => Vec3::ONE,
        Some(s) => {
            let v = match s.get_ref() {
                ScaleFile::Uniform(x) => Vec3::splat(*x),
                ScaleFile::PerAxis(a) => Vec3::from(*a),
            };
            if !v.is_finite() || v.min_element() < 0.0 {
                let msg = format!("{v} must be finite and not negative (a number, or one per channel)");
                return Err(ctx.err(s.span(), "environment.scale", msg));
            }
            v
        }
    };
    let key = |k: &str| format!("environment.{k}");
    let (_, rotation, _) = trs(ctx, &key, &None, &f.rotate, &None)?;
    if map.get_ref().trim().is_empty() {
        return Err(ctx.err(map.span(), "environment.map", "is empty: name an .exr or .hdr file"));
    }
    let path = file.parent().unwrap_or(Path::new(".")).join(map.get_ref());
    let loaded = EnvironmentMap::load(&path, glam::Mat3::from_quat(rotation), Sampling::Luminance)
        .map_err(|e| ctx.err(map.span(), "environment.map", e.to_string()))?;
    Ok(Environment { radiance, map: Some(Arc::new(loaded)) })
}

/// Checked `scale`, `rotate` and `translate` keys (defaults 1, 0, 0), as scale, rotation and
/// translation; `key` names a key of the table holding them.
fn trs(
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

/// An object's `[objects.scatter]`: `count` copies of `placed` (the object's parts: one, or a glTF
/// file's mesh nodes, which move as one) at seeded random points of the box [min, max], each
/// turned by a random angle about y, `round(moving · count)` of them orbiting.
fn scatter(
    ctx: &Ctx,
    index: usize,
    s: &S<ScatterFile>,
    clock: bool,
    placed: &[Object],
    objects: &mut Vec<Object>,
) -> Result<(), SceneError> {
    let f = s.get_ref();
    let key = |k: &str| format!("objects[{index}].scatter.{k}");
    let missing = |k: &str| ctx.err(s.span(), key(k), format!("a scatter needs `{k}`"));
    let count_s = f.count.as_ref().ok_or_else(|| missing("count"))?;
    let count = *count_s.get_ref();
    if !(1..=MAX_SCATTER).contains(&count) {
        return Err(ctx.err(count_s.span(), key("count"), format!("{count} is not 1 to {MAX_SCATTER}")));
    }
    let seed = f.seed.as_ref().map_or(0, |s| *s.get_ref());
    let min_s = f.min.as_ref().ok_or_else(|| missing("min"))?;
    let min = ctx.vec3(min_s, &key("min"))?;
    let max = ctx.vec3(f.max.as_ref().ok_or_else(|| missing("max"))?, &key("max"))?;
    if min.cmpgt(max).any() {
        return Err(ctx.err(min_s.span(), key("min"), format!("{min} is above max {max} on some axis")));
    }
    if !(max - min).is_finite() {
        return Err(ctx.err(
            min_s.span(),
            key("min"),
            format!("the box from {min} to {max} is too large (it overflows)"),
        ));
    }
    let radius = match &f.radius {
        Some(r) => ctx.number(r, &key("radius"), |x| x >= 0.0, "a radius >= 0")?,
        None => 0.0,
    };
    let moving = match &f.moving {
        Some(m) => ctx.number(m, &key("moving"), |x| (0.0..=1.0).contains(&x), "a fraction in [0, 1]")?,
        None if radius > 0.0 => 1.0,
        None => 0.0,
    };
    let period = match &f.period {
        Some(p) => ctx.number(p, &key("period"), |x| x > 0.0, "a period > 0 seconds")?,
        None => DEFAULT_PERIOD,
    };
    if let Some(r) = f.radius.as_ref().filter(|_| radius > 0.0 && !clock) {
        return Err(ctx.err(r.span(), key("radius"), "moving instances need an [animation] table (fps and frames)"));
    }
    // Radius 0: nothing moves, so no instance carries an animation.
    let mut left = if radius > 0.0 { (f64::from(moving) * count as f64).round() as u64 } else { 0 };
    let total = objects.len() as u64 + count * placed.len() as u64;
    if total > MAX_OBJECTS {
        let msg = format!("{count} instances make {total} objects in the scene, more than {MAX_OBJECTS}");
        return Err(ctx.err(count_s.span(), key("count"), msg));
    }
    let mut rng = SplitMix64(seed);
    objects.reserve((count * placed.len() as u64) as usize);
    for i in 0..count {
        let u = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        // Clamped: min + (max - min) · u can round one ulp past max.
        let at = (min + (max - min) * u).clamp(min, max);
        let yaw = TAU * rng.next_f32();
        let phase = TAU * rng.next_f32();
        // Selection sampling (Knuth, TAOCP vol. 2, 3.4.2, Algorithm S): exactly the rounded
        // count moves, and every subset of that size is equally likely.
        let moves = rng.below(count - i) < left;
        left -= u64::from(moves);
        let instance = Mat4::from_translation(at) * Mat4::from_rotation_y(yaw);
        for part in placed {
            let world_from_object = instance * part.world_from_object;
            if !world_from_object.is_finite() {
                let msg = format!("instance {i} at {at}, after the object's own placement, overflows");
                return Err(ctx.err(min_s.span(), key("min"), msg));
            }
            objects.push(Object {
                mesh: part.mesh,
                world_from_object,
                material: part.material,
                animation: moves.then_some(Animation::Orbit { radius, period, phase }),
            });
        }
    }
    Ok(())
}

/// SplitMix64 (Steele, Lea and Flood 2014): one 64-bit state, every output a mix of it.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1): 24 random bits.
    fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u32 << 24) as f32)
    }

    /// Uniform in [0, n) by a 128-bit multiply (Lemire 2019) without the rejection step: the
    /// bias is below n / 2^64, nothing at the counts a scatter allows.
    fn below(&mut self, n: u64) -> u64 {
        ((u128::from(self.next_u64()) * u128::from(n)) >> 64) as u64
    }
}
