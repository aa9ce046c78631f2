//! The `[environment]` table: light from infinitely far away.

use std::path::Path;
use std::sync::Arc;

use glam::Vec3;

use super::objects::trs;
use super::{ABOVE_MAX_RADIANCE, Ctx};
use crate::scene::file::{EnvironmentFile, S, ScaleFile};
use crate::scene::{Environment, MAX_RADIANCE, SceneError};
use crate::texture::environment::{EnvironmentMap, Sampling};

/// The `[environment]` table: a constant `radiance`, or a `map` with its `scale` and `rotate`.
pub(super) fn environment(ctx: &Ctx, e: &S<EnvironmentFile>, file: &Path) -> Result<Environment, SceneError> {
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
        let value = ctx.color(radiance, "environment.radiance")?;
        if value.max_element() > MAX_RADIANCE {
            let message = format!("{:?} is {ABOVE_MAX_RADIANCE}", value.to_array());
            return Err(ctx.err(radiance.span(), "environment.radiance", message));
        }
        return Ok(Environment { radiance: value, map: None });
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
        .map_err(|e| ctx.file_err(map.span(), "environment.map", &e))?;
    // The brightest radiance the map gives: its texel times the scale.
    let scaled = |t: &[f32; 3]| (Vec3::from(*t) * radiance).max_element();
    let brightest =
        (0..loaded.texels.len()).max_by(|&a, &b| scaled(&loaded.texels[a]).total_cmp(&scaled(&loaded.texels[b])));
    if let Some(i) = brightest.filter(|&i| scaled(&loaded.texels[i]) > MAX_RADIANCE) {
        let texel = loaded.texels[i];
        let (x, y) = (i % loaded.width as usize, i / loaded.width as usize);
        let at = format!("{}: texel ({x}, {y}) is {texel:?}", path.display());
        // The map's fault where the texel alone is over, else the scale's.
        let (message, span, key) = match &f.scale {
            Some(s) if Vec3::from(texel).max_element() <= MAX_RADIANCE => (
                format!("{at}, and times the scale {:?} its radiance is {ABOVE_MAX_RADIANCE}", radiance.to_array()),
                s.span(),
                "environment.scale",
            ),
            _ => (format!("{at}, {ABOVE_MAX_RADIANCE}"), map.span(), "environment.map"),
        };
        return Err(ctx.err(span, key, message));
    }
    Ok(Environment { radiance, map: Some(Arc::new(loaded)) })
}
