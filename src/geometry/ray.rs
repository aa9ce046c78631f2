//! Rays, and spawning new rays from surfaces without a scene-scale epsilon.
//!
//! [`offset_ray_origin`] moves a hit point off its surface along the geometric normal by a bound
//! on the point's rounding error, computed from the triangle's vertices and the barycentrics
//! (pbrt-v4, 4th ed., sections 6.8.4–6.8.6). The offset scales with the geometry, so a scene
//! renders alike at 10⁻⁴ and at 10⁴, and far from the origin.
//!
//! History: this was the Wächter–Binder offset (Ray Tracing Gems, chapter 6), a fixed 256 ULPs
//! of each coordinate, or 2⁻¹⁶ absolute near the origin. The stress suite showed both constants
//! are scene scales in disguise: 256 ULPs at 10⁵ is 2 units (a Cornell box moved there lit
//! nothing), and 2⁻¹⁶ is 8% of a Cornell box scaled by 10⁻⁴.

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

/// Moves `p`, a point computed on a surface with rounding error at most `p_error` per axis
/// (e.g. from [`crate::geometry::Triangle::point_with_error`]), off that surface to the side `n`
/// points to.
///
/// `n` is the geometric normal, unit length, flipped by the caller to face the side the new ray
/// leaves into (outward for reflection, inward for transmission). The offset along `n` is the
/// error box's extent along `n`, `|n| · p_error`, and the sum is then rounded one more ULP
/// away from `p` on each axis, so that its own rounding cannot pull it back (pbrt-v4,
/// `OffsetRayOrigin`).
#[inline]
pub fn offset_ray_origin(p: Vec3, p_error: Vec3, n: Vec3) -> Vec3 {
    let d = n.abs().dot(p_error);
    let offset = n * d;
    let po = p + offset;
    let away = |v: f32, o: f32| {
        if o > 0.0 {
            next_up(v)
        } else if o < 0.0 {
            -next_up(-v)
        } else {
            v
        }
    };
    Vec3::new(away(po.x, offset.x), away(po.y, offset.y), away(po.z, offset.z))
}

/// The next float towards +∞ (`f32::next_up`, which needs Rust 1.86; our minimum is 1.85).
#[inline]
fn next_up(v: f32) -> f32 {
    if v.is_nan() || v == f32::INFINITY {
        return v;
    }
    if v == 0.0 {
        return f32::from_bits(1);
    }
    let bits = v.to_bits();
    f32::from_bits(if v > 0.0 { bits + 1 } else { bits - 1 })
}

/// Spawns a ray from surface point `p` (rounding error `p_error`) with geometric normal `ng` in
/// direction `dir`, offsetting the origin to whichever side of the surface `dir` points to.
#[inline]
pub fn spawn_ray(p: Vec3, p_error: Vec3, ng: Vec3, dir: Vec3) -> Ray {
    let n = if ng.dot(dir) < 0.0 { -ng } else { ng };
    Ray::new(offset_ray_origin(p, p_error, n), dir)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offset_moves_to_the_normal_side_at_every_magnitude() {
        for &s in &[1e-6f32, 1e-3, 0.5, 1.0, 1e4, 1e5, 1e7] {
            for &sign in &[1.0f32, -1.0] {
                let tri = crate::geometry::Triangle::new(
                    Vec3::new(s * sign, -s, 0.0),
                    Vec3::new(2.0 * s * sign, s, s),
                    Vec3::new(-s * sign, s, -s),
                );
                let (p, err) = tri.point_with_error(0.3, 0.3);
                let n = tri.normal().normalize() * sign;
                let q = offset_ray_origin(p, err, n);
                let d = q - p;
                assert!(d.dot(n) > 0.0, "scale {s} sign {sign}: moved {d} against {n}");
                // A few ULPs of the vertices: about 1e-6 relative to the triangle's scale.
                assert!(d.abs().max_element() <= 4e-6 * s, "scale {s}: offset {d} too large");
            }
        }
    }
}
