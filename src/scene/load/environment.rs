//! The `[environment]` table: light from infinitely far away.

use std::path::Path;
use std::sync::Arc;

use glam::Vec3;

use super::Ctx;
use super::objects::trs;
use crate::scene::file::{EnvironmentFile, S, ScaleFile};
use crate::scene::{Environment, SceneError};
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
