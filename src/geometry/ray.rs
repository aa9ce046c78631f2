//! Rays, and spawning new rays from surfaces without a scene-scale epsilon.
//!
//! [`offset_ray_origin`] follows Wächter & Binder, "A Fast and Robust Method for Avoiding
//! Self-Intersection" (Ray Tracing Gems, chapter 6): the hit point is moved off the surface along
//! the geometric normal by a fixed number of units in the last place of each coordinate, so the
//! offset grows with the coordinate's magnitude exactly as its rounding error does. Near the
//! origin, where a few ULPs are tiny, a small absolute offset is used instead.

use glam::Vec3;

use super::aabb::RayInv;

/// A ray `origin + t * dir` for `t > 0`. `dir` need not be normalised; distances are in units of
/// `|dir|`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: Vec3,
    pub dir: Vec3,
}

impl Ray {
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        Self { origin, dir }
    }

    #[inline]
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }

    #[inline]
    pub fn inv(&self) -> RayInv {
        RayInv::new(self.origin, self.dir)
    }
}

/// Below this magnitude a coordinate is offset by an absolute amount (chapter 6, "origin()").
const OFFSET_ORIGIN: f32 = 1.0 / 32.0;
/// Absolute offset scale used near the origin.
const OFFSET_FLOAT_SCALE: f32 = 1.0 / 65536.0;
/// Offset in ULPs for a unit normal component.
const OFFSET_INT_SCALE: f32 = 256.0;

/// Moves `p`, a point computed on a surface, off that surface to the side `n` points to.
///
/// `n` is the geometric normal, unit length, flipped by the caller to face the side the new ray
/// leaves into (outward for reflection, inward for transmission).
#[inline]
pub fn offset_ray_origin(p: Vec3, n: Vec3) -> Vec3 {
    let axis = |p: f32, n: f32| -> f32 {
        if p.abs() < OFFSET_ORIGIN {
            return p + OFFSET_FLOAT_SCALE * n;
        }
        // Adding to the bit pattern moves the magnitude; flip the step for negative values so
        // that a positive `n` always moves `p` towards +inf.
        let ulps = (OFFSET_INT_SCALE * n) as i32;
        let step = if p < 0.0 { -ulps } else { ulps };
        f32::from_bits((p.to_bits() as i32).wrapping_add(step) as u32)
    };
    Vec3::new(axis(p.x, n.x), axis(p.y, n.y), axis(p.z, n.z))
}

/// Spawns a ray from surface point `p` with geometric normal `ng` in direction `dir`, offsetting
/// the origin to whichever side of the surface `dir` points to.
#[inline]
pub fn spawn_ray(p: Vec3, ng: Vec3, dir: Vec3) -> Ray {
    let n = if ng.dot(dir) < 0.0 { -ng } else { ng };
    Ray::new(offset_ray_origin(p, n), dir)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offset_moves_to_the_normal_side_at_every_magnitude() {
        for &s in &[1e-6f32, 1e-3, 0.5, 1.0, 1e4, 1e5, 1e7] {
            for &sign in &[1.0f32, -1.0] {
                let p = Vec3::new(s * sign, -s, s * 0.3);
                let n = Vec3::new(0.6, -0.8, 0.0) * sign;
                let q = offset_ray_origin(p, n);
                let d = q - p;
                assert!(d.dot(n) > 0.0, "scale {s} sign {sign}: moved {d} against {n}");
                // 256 ULPs (about 3e-5 relative) away from the origin, 2^-16 absolute near it.
                let bound = (p.abs() * 1e-4).max(Vec3::splat(OFFSET_FLOAT_SCALE));
                assert!(d.abs().cmple(bound).all(), "scale {s}: offset {d} too large");
            }
        }
    }
}
