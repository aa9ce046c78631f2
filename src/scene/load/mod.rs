//! Turning a parsed scene file into a checked [`Scene`]: value checks, materials (from the TOML,
//! from MTL files and from glTF files), meshes (one per OBJ or PLY file or built-in shape, one per
//! glTF mesh, shared by the objects naming it), transforms, cameras (from the TOML or a glTF
//! file), keyframes and scattered instances. Every error names file, line and key.
//!
//! A file per table: this one reads the file and holds what every table's checks share ([`Ctx`]),
//! with the `[render]` and `[animation]` tables; [`camera`], [`materials`] (with MTL materials
//! and texture statements), [`objects`] (meshes, shapes, OBJ and PLY files, transforms,
//! keyframes), [`scatter`] and [`environment`] the others; `gltf` the glue to the glTF reader
//! (feature `gltf`), which a build without it replaces by `no_gltf`, a refusal that says so.

mod camera;
mod environment;
#[cfg(feature = "gltf")]
mod gltf;
mod materials;
#[cfg(not(feature = "gltf"))]
mod no_gltf;
mod objects;
mod scatter;

use std::collections::HashMap;
use std::ops::Range;
use std::path::{Path, PathBuf};

use glam::Vec3;

use super::file::{S, SceneFile};
use super::{AnimationSettings, RenderSettings, Scene, SceneError};
use crate::geometry::MeshError;
use crate::memory::OutOfMemory;
use crate::texture::{TextureCache, TextureError};
#[cfg(feature = "gltf")]
use gltf::{GltfFiles, file_camera, gltf_parts};
#[cfg(not(feature = "gltf"))]
use no_gltf::{GltfFiles, file_camera, gltf_parts};
use objects::{Built, ObjectEnv};

// The glTF reader judges its nodes' matrices as the loader does objects'.
#[cfg(feature = "gltf")]
pub(super) use objects::invertible;

pub(super) fn load(path: PathBuf) -> Result<Scene, SceneError> {
    // A pipe too: `render <(generate) -o out.exr`.
    let bytes =
        crate::memory::read_file_or_pipe(&path).map_err(|error| SceneError::Read { file: path.clone(), error })?;
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

    /// The error at `span` and `key` for `e`, the failure of a file the key names: a
    /// [`SceneError::Memory`] where what the file asks for would not fit, else
    /// [`SceneError::Invalid`]; either with `e`'s message.
    fn file_err(&self, span: Range<usize>, key: impl Into<String>, e: &dyn FileError) -> SceneError {
        match e.out_of_memory() {
            Some(error) => SceneError::Memory {
                file: self.file.to_owned(),
                line: self.line(span),
                key: key.into(),
                message: e.to_string(),
                error: error.clone(),
            },
            None => self.err(span, key, e.to_string()),
        }
    }

    /// [`SceneError::Memory`] at `span` and `key`, with `error`'s message.
    fn memory_err(&self, span: Range<usize>, key: impl Into<String>, error: OutOfMemory) -> SceneError {
        self.file_err(span, key, &error)
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

/// How an error says that a radiance is above [`super::MAX_RADIANCE`].
const ABOVE_MAX_RADIANCE: &str = "above 2^40, the most radiance Arbor renders (the film drops brighter samples)";

/// The error of a file a scene names (a mesh, a texture, a sky map), which may be a refusal for
/// memory: that is exit code 3 to `render` (retry with more), the rest bad input.
trait FileError: std::fmt::Display {
    fn out_of_memory(&self) -> Option<&OutOfMemory>;
}

impl FileError for OutOfMemory {
    fn out_of_memory(&self) -> Option<&OutOfMemory> {
        Some(self)
    }
}

/// A refusal by [`crate::memory::read_file`] carries its estimate in the I/O error.
fn io_out_of_memory(e: &std::io::Error) -> Option<&OutOfMemory> {
    e.get_ref()?.downcast_ref::<OutOfMemory>()
}

impl FileError for MeshError {
    fn out_of_memory(&self) -> Option<&OutOfMemory> {
        match self {
            MeshError::Memory { error, .. } => Some(error),
            MeshError::Read { error, .. } => io_out_of_memory(error),
            _ => None,
        }
    }
}

impl FileError for TextureError {
    fn out_of_memory(&self) -> Option<&OutOfMemory> {
        match self {
            TextureError::Memory(error) => Some(error),
            _ => None,
        }
    }
}

/// A file's failure as a message that says where (`file:line: statement: ...`), with the
/// estimate where memory refused it: what the MTL and glTF textures of a mesh give.
struct FileFailure {
    message: String,
    memory: Option<OutOfMemory>,
}

impl FileFailure {
    /// `e` at `at` (the file and the place in it).
    fn at(at: &str, e: &dyn FileError) -> Self {
        FileFailure { message: format!("{at}: {e}"), memory: e.out_of_memory().cloned() }
    }
}

impl From<TextureError> for FileFailure {
    fn from(e: TextureError) -> Self {
        FileFailure { message: e.to_string(), memory: e.out_of_memory().cloned() }
    }
}

impl std::fmt::Display for FileFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl FileError for FileFailure {
    fn out_of_memory(&self) -> Option<&OutOfMemory> {
        self.memory.as_ref()
    }
}

pub(super) fn parse(text: &str, file: PathBuf) -> Result<Scene, SceneError> {
    let (scene, read) = crate::memory::recording_reads(|| parse_text(text, file));
    scene.map(|scene| Scene { read, ..scene })
}

/// [`parse`], but for the list of files read.
fn parse_text(text: &str, file: PathBuf) -> Result<Scene, SceneError> {
    let ctx = Ctx { file: &file, text };
    let parsed = deserialize(&ctx)?;
    let base = file.parent().unwrap_or(Path::new("."));
    let mut gltf_files = GltfFiles::default();
    let camera = camera::camera(&ctx, &parsed, base, &mut gltf_files)?;
    let render = render(&ctx, &parsed)?;
    let environment = parsed.environment.as_ref().map(|e| environment::environment(&ctx, e, &file)).transpose()?;
    let mut textures = TextureCache::default();
    let mut materials = Vec::new();
    let mut by_name = HashMap::new();
    for (name, m) in &parsed.materials {
        by_name.insert(name.clone(), materials.len() as u32);
        materials.push(materials::material(&ctx, name, m, base, &mut textures)?);
    }
    let animation = animation(&ctx, &parsed)?;
    let env = ObjectEnv { base, by_name, clock: animation.is_some() };
    let mut out = Built::new(materials, textures, gltf_files);
    for (i, o) in parsed.objects.iter().enumerate() {
        objects::object(&ctx, i, o, &env, &mut out)?;
    }
    let Built { materials, textures, meshes, objects, .. } = out;
    let textures = textures.textures;
    let read = Vec::new();
    Ok(Scene { path: file.clone(), camera, render, environment, materials, textures, meshes, objects, animation, read })
}

/// The scene file's text as its schema, or a syntax or schema error at its line and key.
fn deserialize(ctx: &Ctx) -> Result<SceneFile, SceneError> {
    let text = ctx.text;
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
    serde_path_to_error::deserialize(de).map_err(|e| {
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
    })
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
