//! Materials: the `[materials]` table's, and those of MTL files (their conversion and their
//! texture statements).

use std::ops::Range;
use std::path::{Path, PathBuf};

use glam::Vec3;

use super::{ABOVE_MAX_RADIANCE, Ctx, FileFailure};
use crate::scene::file::{MaterialFile, S};
use crate::scene::{ConductorFresnel, MAX_RADIANCE, Material, MaterialTextures, Scattering, SceneError};
use crate::texture::{Texture, TextureCache, TextureRef, Wrap};

/// Largest conductor `eta` or `k` (see the conductor material).
const MAX_CONDUCTOR_INDEX: f32 = 1e6;

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

/// The material `name` of the `[materials]` table, checked, its textures loaded into `textures`.
pub(super) fn material(
    ctx: &Ctx,
    name: &str,
    m: &S<MaterialFile>,
    base: &Path,
    textures: &mut TextureCache,
) -> Result<Material, SceneError> {
    let f = m.get_ref();
    let key = |k: &str| format!("materials.{name}.{k}");
    let kind = checked_keys(ctx, &key, f)?;
    // Beside its texture, a number the texture multiplies defaults to 1.
    let roughness = match &f.roughness {
        Some(r) => ctx.number(r, &key("roughness"), |x| (0.0..=1.0).contains(&x), "in [0, 1]")?,
        None if f.roughness_texture.is_some() => 1.0,
        None => 0.0,
    };
    let maps = material_textures(ctx, &key, f, base, textures)?;
    let mut out = Material {
        name: name.to_owned(),
        scattering: Scattering::Black,
        emission: None,
        two_sided: false,
        textures: maps,
    };
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
            let emission = match (&f.radiance, out.textures.emission.is_some()) {
                (None, true) => Vec3::ONE,
                _ => ctx.color(required(ctx, &f.radiance, m, key("radiance"))?, &key("radiance"))?,
            };
            let texture = out.textures.emission.map(|t| &*textures.textures[t.texture as usize]);
            if let Some((message, texture_too)) = too_bright(emission, texture) {
                let (k, span) = match (&f.radiance, &f.emission_texture) {
                    (Some(_), Some(t)) if texture_too => ("emission_texture", t.span()),
                    (Some(r), _) => ("radiance", r.span()),
                    (None, t) => ("emission_texture", t.as_ref().map_or(m.span(), |t| t.span())),
                };
                return Err(ctx.err(span, key(k), message));
            }
            out.emission = Some(emission);
            out.two_sided = f.two_sided.as_ref().is_some_and(|b| *b.get_ref());
            if let Some(a) = &f.albedo {
                out.scattering = Scattering::Diffuse { albedo: ctx.color(a, &key("albedo"))? };
            }
        }
        "conductor" => {
            let fresnel = conductor_fresnel(ctx, &key, m, textured)?;
            out.scattering = Scattering::Conductor { roughness, fresnel };
        }
        "metallic-roughness" => out.scattering = coated(ctx, &key, m, textured, roughness)?,
        _ => out.scattering = Scattering::Dielectric { ior: ior(ctx, &key, f)?, roughness },
    }
    Ok(out)
}

/// The material's `type`, once every key it gives is one that type takes.
fn checked_keys<'a>(ctx: &Ctx, key: &dyn Fn(&str) -> String, f: &'a MaterialFile) -> Result<&'a str, SceneError> {
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
    Ok(kind)
}

/// A colour the material's type needs, at `key`.
fn required<'a>(
    ctx: &Ctx,
    v: &'a Option<S<[f32; 3]>>,
    m: &S<MaterialFile>,
    key: String,
) -> Result<&'a S<[f32; 3]>, SceneError> {
    let (kind, k) = (m.get_ref().kind.get_ref(), key.rsplit('.').next().unwrap_or_default().to_owned());
    v.as_ref().ok_or_else(|| ctx.err(m.span(), key, format!("the `{kind}` material type needs `{k}`")))
}

/// The `ior` key, 1.5 when not given.
fn ior(ctx: &Ctx, key: &dyn Fn(&str) -> String, f: &MaterialFile) -> Result<f32, SceneError> {
    match &f.ior {
        Some(i) => ctx.number(i, &key("ior"), |x| x > 0.0, "an index of refraction > 0"),
        None => Ok(1.5),
    }
}

/// The material's image textures, each file loaded once into `cache`, paths relative to `base`.
fn material_textures(
    ctx: &Ctx,
    key: &dyn Fn(&str) -> String,
    f: &MaterialFile,
    base: &Path,
    cache: &mut TextureCache,
) -> Result<MaterialTextures, SceneError> {
    let mut texture = |t: &Option<S<String>>, k: &str, srgb: bool| -> Result<Option<TextureRef>, SceneError> {
        let Some(t) = t else { return Ok(None) };
        if t.get_ref().trim().is_empty() {
            return Err(ctx.err(t.span(), key(k), "is empty: name an image file"));
        }
        let index = cache.get(&base.join(t.get_ref())).map_err(|e| ctx.file_err(t.span(), key(k), &e))?;
        Ok(Some(TextureRef { texture: index, wrap: Wrap::Repeat, srgb }))
    };
    Ok(MaterialTextures {
        base_color: texture(&f.texture, "texture", true)?,
        alpha: texture(&f.alpha_texture, "alpha_texture", false)?,
        alpha_cutoff: 0.5,
        normal: texture(&f.normal_texture, "normal_texture", false)?,
        normal_scale: 1.0,
        emission: texture(&f.emission_texture, "emission_texture", true)?,
        roughness: texture(&f.roughness_texture, "roughness_texture", false)?.map(|r| (r, 0)),
        metallic: texture(&f.metallic_texture, "metallic_texture", false)?.map(|r| (r, 0)),
    })
}

/// A conductor's Fresnel term: `eta` and `k`, or `base_color` (white beside a texture).
fn conductor_fresnel(
    ctx: &Ctx,
    key: &dyn Fn(&str) -> String,
    m: &S<MaterialFile>,
    textured: bool,
) -> Result<ConductorFresnel, SceneError> {
    let f = m.get_ref();
    Ok(match (&f.eta, &f.k, &f.base_color) {
        (Some(eta), Some(k), None) => {
            // Real metals are below 100; past about 4e9 the Fresnel terms overflow f32 and
            // the metal rendered black. 1e6 is already a perfect mirror.
            let bounded = |v: &S<[f32; 3]>, name: &str| {
                let c = ctx.color(v, &key(name))?;
                if c.max_element() > MAX_CONDUCTOR_INDEX {
                    let msg = format!("{:?} is over {MAX_CONDUCTOR_INDEX:e} (real metals are below 100)", v.get_ref());
                    return Err(ctx.err(v.span(), key(name), msg));
                }
                Ok(c)
            };
            ConductorFresnel::Complex { eta: bounded(eta, "eta")?, k: bounded(k, "k")? }
        }
        (None, None, Some(c)) => ConductorFresnel::BaseColor(ctx.color(c, &key("base_color"))?),
        (None, None, None) if textured => ConductorFresnel::BaseColor(Vec3::ONE),
        _ => {
            return Err(ctx.err(m.span(), key("eta"), "a conductor needs either `eta` and `k`, or `base_color`"));
        }
    })
}

/// The `metallic-roughness` type's scattering: `base_color` (white beside a texture),
/// `metallic` (1 beside its texture, else 0), `ior`, and the perceptual `roughness`.
fn coated(
    ctx: &Ctx,
    key: &dyn Fn(&str) -> String,
    m: &S<MaterialFile>,
    textured: bool,
    roughness: f32,
) -> Result<Scattering, SceneError> {
    let f = m.get_ref();
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
    Ok(Scattering::Coated { base_color, metallic, alpha: roughness * roughness, ior: ior(ctx, key, f)? })
}

/// Why `emission`, times the brightest texel of its emission `texture` where it has one, is more
/// radiance than [`MAX_RADIANCE`], or `None`; with whether the texture takes it over (the
/// emission alone is within the limit).
pub(super) fn too_bright(emission: Vec3, texture: Option<&Texture>) -> Option<(String, bool)> {
    if emission.max_element() > MAX_RADIANCE {
        return Some((format!("radiance {:?} is {ABOVE_MAX_RADIANCE}", emission.to_array()), false));
    }
    let texture = texture?;
    let brightest = texture.brightest();
    (emission * brightest).max_element().gt(&MAX_RADIANCE).then(|| {
        let message = format!(
            "radiance {:?} times the brightest texel of {}, {:?}, is {ABOVE_MAX_RADIANCE}",
            emission.to_array(),
            texture.source.display(),
            brightest.to_array()
        );
        (message, true)
    })
}

/// Why MTL material `m`, made into `material` (its textures loaded into `cache`), emits more
/// radiance than [`MAX_RADIANCE`], as the MTL file, the line and the statement at fault (`Ke`, or
/// `map_Ke` where the texture takes it over) and why (`texts`: each MTL file the OBJ file named,
/// and its bytes); `None` where it does not.
pub(super) fn mtl_too_bright(
    texts: &[(PathBuf, Vec<u8>)],
    m: &tobj::Material,
    material: &Material,
    cache: &TextureCache,
) -> Option<String> {
    let texture = material.textures.emission.map(|t| &*cache.textures[t.texture as usize]);
    let (message, texture_too) = too_bright(material.emission?, texture)?;
    let statement = if texture_too || m.emissive.is_none() { "map_Ke" } else { "Ke" };
    let (mtl, line) = statement_line(texts, &m.name, &[statement]);
    Some(format!("{}:{line}: `{statement}`: {message}", mtl.display()))
}

/// MTL to Arbor, documented in `docs/scene-format.md`: `Ke` makes an emitter (which also
/// reflects `Kd`); `d < 1` or `illum` 4, 6, 7, 9 a dielectric of index `Ni`; the PBR extension's
/// `Pr` or `Pm`, or `Kd` and `Ks` both non-zero, the coated metallic-roughness material of base
/// colour `Kd`, metallic `Pm` (default 0) and GGX α = `Pr`² or else sqrt(2 / (Ns + 2)); `Ks`
/// without `Kd` a conductor with base colour `Ks` and that α; otherwise diffuse `Kd`.
pub(super) fn from_mtl(name: &str, m: &tobj::Material) -> Material {
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
pub(super) fn mtl_textures(
    texts: &[(PathBuf, Vec<u8>)],
    m: &tobj::Material,
    cache: &mut TextureCache,
) -> Result<MaterialTextures, FileFailure> {
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
        let spellings: &[&str] = if statement == "bump" { &["bump", "map_Bump", "map_bump"] } else { &[statement] };
        let (mtl, line) = statement_line(texts, &m.name, spellings);
        let at = format!("{}:{line}: `{statement}`", mtl.display());
        let (file, wrap) = texture_statement(value)
            .ok_or_else(|| FileFailure { message: format!("{at}: names no file"), memory: None })?;
        let path = mtl.parent().unwrap_or(Path::new(".")).join(file);
        let texture = cache.get(&path).map_err(|e| FileFailure::at(&at, &e))?;
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

/// The MTL file of `texts` that defines material `name` with a statement spelt one of
/// `spellings`, and its line: the last such file, which wins, as in tobj (the first file and
/// line 0 where none does).
fn statement_line<'a>(texts: &'a [(PathBuf, Vec<u8>)], name: &str, spellings: &[&str]) -> (&'a Path, usize) {
    texts
        .iter()
        .rev()
        .find_map(|(f, text)| spellings.iter().find_map(|s| mtl_line(text, name, s)).map(|l| (f.as_path(), l)))
        .unwrap_or((texts.first().map_or(Path::new("?"), |(f, _)| f.as_path()), 0))
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
