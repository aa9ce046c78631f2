//! The `[camera]` table: a camera of its own (`position`, `look_at`, `up`, `fov`), or one from a
//! glTF file (`from`, `name`), with the resolution and the thin lens either way.

use std::path::Path;

use glam::Vec3;

use super::{Ctx, GltfFiles, file_camera};
use crate::scene::file::{S, SceneFile};
use crate::scene::{Camera, SceneError};

/// Largest image side.
const MAX_RESOLUTION: u32 = 65_536;

pub(super) fn camera(ctx: &Ctx, f: &SceneFile, base: &Path, gltf: &mut GltfFiles) -> Result<Camera, SceneError> {
    let c = f.camera.get_ref();
    let (position, look_at, up, fov, from_file) = match &c.from {
        Some(from) => {
            from_alone(ctx, f, from)?;
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

/// With `from`, the placement and the field of view come from the file: the table gives none
/// of them, and names a file.
fn from_alone(ctx: &Ctx, f: &SceneFile, from: &S<String>) -> Result<(), SceneError> {
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
    Ok(())
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
