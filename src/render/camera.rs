//! The camera: primary rays through pixel positions, pinhole or thin lens.
//!
//! Conventions, the same as the Mitsuba reference in `../shared/reference/cornell-box`: row 0
//! is the top of the image, column 0 its left; `fov` is the vertical opening angle; a film
//! position `(px, py)` in pixels maps to the direction
//! `forward + (2 px / W - 1) tan_x right + (1 - 2 py / H) tan_y up`.

use glam::{Vec2, Vec3};

use super::sampling::concentric_disk;
use crate::geometry::Ray;
use crate::scene::Camera;

/// A camera ready to make rays.
#[derive(Clone, Copy, Debug)]
pub struct CameraModel {
    origin: Vec3,
    forward: Vec3,
    right: Vec3,
    up: Vec3,
    tan_x: f32,
    tan_y: f32,
    width: f32,
    height: f32,
    lens_radius: f32,
    focus_distance: f32,
}

/// What [`CameraModel::parts`] gives: the unit frame, the tangents of the half opening
/// angles, and the thin lens (radius 0: a pinhole).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraParts {
    pub origin: Vec3,
    pub forward: Vec3,
    pub right: Vec3,
    pub up: Vec3,
    pub tan_x: f32,
    pub tan_y: f32,
    pub lens_radius: f32,
    pub focus_distance: f32,
}

impl CameraModel {
    pub fn new(c: &Camera) -> Self {
        let forward = (c.look_at - c.position).normalize();
        let right = forward.cross(c.up).normalize();
        let up = right.cross(forward);
        let tan_y = (c.fov_y_degrees.to_radians() * 0.5).tan();
        Self {
            origin: c.position,
            forward,
            right,
            up,
            tan_x: tan_y * c.width as f32 / c.height as f32,
            tan_y,
            width: c.width as f32,
            height: c.height as f32,
            lens_radius: c.aperture,
            focus_distance: c.focus_distance,
        }
    }

    /// The model's numbers, for the GPU path (`src/gpu/trace.rs`), which makes the same rays.
    pub fn parts(&self) -> CameraParts {
        CameraParts {
            origin: self.origin,
            forward: self.forward,
            right: self.right,
            up: self.up,
            tan_x: self.tan_x,
            tan_y: self.tan_y,
            lens_radius: self.lens_radius,
            focus_distance: self.focus_distance,
        }
    }

    /// The ray through film position `film` (pixels, from the top-left corner), with `lens` in
    /// [0, 1)² choosing the point on the lens. The direction is unit length.
    pub fn ray(&self, film: Vec2, lens: Vec2) -> Ray {
        let sx = (2.0 * film.x / self.width - 1.0) * self.tan_x;
        let sy = (1.0 - 2.0 * film.y / self.height) * self.tan_y;
        let dir = (self.forward + self.right * sx + self.up * sy).normalize();
        if self.lens_radius == 0.0 {
            return Ray::new(self.origin, dir);
        }
        // Thin lens: every ray through the same film point meets at the plane in focus.
        let focus = self.origin + dir * (self.focus_distance / dir.dot(self.forward));
        let d = concentric_disk(lens) * self.lens_radius;
        let origin = self.origin + self.right * d.x + self.up * d.y;
        Ray::new(origin, (focus - origin).normalize())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Camera {
        Camera {
            position: Vec3::new(0.0, 0.0, 3.9),
            look_at: Vec3::ZERO,
            up: Vec3::Y,
            fov_y_degrees: 39.3077,
            width: 256,
            height: 256,
            aperture: 0.0,
            focus_distance: 3.9,
            resolution_line: 0,
        }
    }

    #[test]
    fn centre_corners_and_orientation() {
        let m = CameraModel::new(&camera());
        let centre = m.ray(Vec2::splat(128.0), Vec2::ZERO);
        assert!((centre.dir - Vec3::NEG_Z).length() < 1e-6);
        // Top-left pixel looks up and to the left (-x: the red wall of the Cornell box).
        let tl = m.ray(Vec2::ZERO, Vec2::ZERO).dir;
        assert!(tl.x < 0.0 && tl.y > 0.0);
        // The reference's tan(fov / 2): 0.357143367667.
        assert!((tl.x / tl.z - 0.357_143_37).abs() < 1e-6, "{}", tl.x / tl.z);
    }

    #[test]
    fn thin_lens_rays_meet_in_the_focus_plane() {
        let mut c = camera();
        c.aperture = 0.2;
        let m = CameraModel::new(&c);
        let film = Vec2::new(40.0, 200.0);
        let a = m.ray(film, Vec2::new(0.1, 0.9));
        let b = m.ray(film, Vec2::new(0.8, 0.3));
        assert_ne!(a.origin, b.origin);
        // Both reach depth 3.9 along -z at the same point.
        let at = |r: &Ray| r.at((r.origin.z - (3.9 - 3.9)) / -r.dir.z);
        assert!((at(&a) - at(&b)).length() < 1e-4);
    }
}
