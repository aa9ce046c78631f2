//! Triangles and the watertight ray/triangle test of Woop, Benthin and Wald, "Watertight
//! Ray/Triangle Intersection" (JCGT 2013).
//!
//! The ray is sheared and scaled so that it runs along +z from the origin; the triangle is then
//! tested in 2D with edge functions. Edges shared by two triangles evaluate the same edge function
//! on the same floats in both, so a ray through an edge or vertex hits at least one of them.
//! Departures from the paper:
//! - Edge functions that come out exactly zero are recomputed in f64 (the paper's section 5
//!   fallback), for all three at once, and so are edge functions that overflow (relative
//!   coordinates beyond about 10^19), underflow to subnormals (below about 10^-19), or whose
//!   weighted sum `T` overflows or underflows (near 10^16 and 10^-16): the rest of the test then runs in f64 too
//!   ([`Triangle::intersect_f64`]), so that scenes at any f32 scale are hit.
//! - The hit distance is computed (`T / det`) before the range test and the range test is done on
//!   it, instead of comparing `T` against `t_max * det`. That costs a division for the few rays
//!   that pass the edge tests, and makes a triangle's reported `t` the only thing deciding
//!   whether it is accepted, so BVH traversal and brute force agree to the bit.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use super::{Aabb, Ray};

/// A triangle by its three vertex positions.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Triangle {
    pub v0: Vec3,
    pub v1: Vec3,
    pub v2: Vec3,
}

const _: () = assert!(size_of::<Triangle>() == 36);

/// Where a ray meets a triangle: distance and barycentrics of `v1` (`u`) and `v2` (`v`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleHit {
    pub t: f32,
    pub u: f32,
    pub v: f32,
}

/// Whether `m` mirrors (its linear part has a negative determinant).
#[inline]
pub fn mirrors(m: &glam::Affine3A) -> bool {
    m.matrix3.determinant() < 0.0
}

impl Triangle {
    pub fn new(v0: Vec3, v1: Vec3, v2: Vec3) -> Self {
        Self { v0, v1, v2 }
    }

    /// The triangle with its vertices moved by `m`.
    pub fn transformed(&self, m: &glam::Affine3A) -> Self {
        Self::new(m.transform_point3(self.v0), m.transform_point3(self.v1), m.transform_point3(self.v2))
    }

    /// The triangle placed by `m`, its front kept: where `m` mirrors (`mirrored`: its
    /// determinant is negative, as glTF files and exports from modelling tools give), placing
    /// would turn its winding, and so which side is its front, inside out, so `v1` and `v2` are
    /// swapped. A point at barycentrics `(u, v)` of `self` is then at `(v, u)` of the result.
    pub fn placed(&self, m: &glam::Affine3A, mirrored: bool) -> Self {
        let t = self.transformed(m);
        if mirrored { Self::new(t.v0, t.v2, t.v1) } else { t }
    }

    pub fn aabb(&self) -> Aabb {
        Aabb::from_point(self.v0).grow(self.v1).grow(self.v2)
    }

    /// Unnormalised geometric normal `(v1 - v0) × (v2 - v0)`.
    pub fn normal(&self) -> Vec3 {
        (self.v1 - self.v0).cross(self.v2 - self.v0)
    }

    /// The unit geometric normal, or zero for a degenerate triangle. Where the squared length
    /// of the edges' cross product leaves f32's normal range (edges beyond about 10^9 or below
    /// about 3·10^-10), the edges are first scaled by a power of two, which leaves the direction
    /// exact. (Plain normalisation gave zero there, and the renderer ended such paths black.)
    pub fn unit_normal(&self) -> Vec3 {
        let n = self.normal();
        if n.length_squared().is_normal() {
            return n.normalize();
        }
        self.scaled_normal().map_or(Vec3::ZERO, |(n, _)| n.normalize_or_zero())
    }

    /// The area, computed as [`Triangle::unit_normal`] computes the normal where the squared
    /// length would overflow or underflow: infinite or zero only where the area itself is.
    pub fn area(&self) -> f32 {
        let n = self.normal();
        if n.length_squared().is_normal() {
            return 0.5 * n.length();
        }
        self.scaled_normal().map_or(0.0, |(n, scale)| 0.5 * n.length() / scale / scale)
    }

    /// The edges' cross product with both edges multiplied by a power of two that brings the
    /// longer coordinate difference to [1, 2), and that power; `None` for a point triangle or
    /// non-finite edges.
    fn scaled_normal(&self) -> Option<(Vec3, f32)> {
        let (e1, e2) = (self.v1 - self.v0, self.v2 - self.v0);
        let largest = e1.abs().max(e2.abs()).max_element();
        if !(largest.is_finite() && largest > 0.0) {
            return None;
        }
        let scale = super::aabb::pow2_normalizer(largest);
        Some(((e1 * scale).cross(e2 * scale), scale))
    }

    /// The point with barycentrics `(1 - u - v, u, v)`. Interpolating the vertices is far more
    /// accurate than `origin + t * dir` for spawning rays (Wächter & Binder, section 6.2).
    pub fn point(&self, u: f32, v: f32) -> Vec3 {
        self.v0 * (1.0 - u - v) + self.v1 * u + self.v2 * v
    }

    /// The point at barycentrics `(u, v)` as `v₀ + u (v₁ − v₀) + v (v₂ − v₀)`, and a bound on
    /// its rounding error per axis, for [`crate::geometry::offset_ray_origin`].
    ///
    /// In this form only the last addition rounds at the point's magnitude: the edges and their
    /// multiples round at the triangle's size. Each operation rounds with relative error at most
    /// ε/2, so the error is at most `γ₂ |p| + γ₄ (|u e₁| + |v e₂|)` (`γₙ = nε / (1 − nε)`, the
    /// notation of pbrt-v4, 4th ed., section 6.8). A point 10⁵ from the origin on a small
    /// triangle gets about 2 ULPs, where the interpolation `b₀ v₀ + b₁ v₁ + b₂ v₂` (pbrt's form)
    /// needs a bound of 7; the offset, and with it the shift of penumbrae, is that much smaller.
    pub fn point_with_error(&self, u: f32, v: f32) -> (Vec3, Vec3) {
        let (e1, e2) = (self.v1 - self.v0, self.v2 - self.v0);
        let (ue1, ve2) = (e1 * u, e2 * v);
        let p = self.v0 + (ue1 + ve2);
        let err = p.abs() * gamma(2) + (ue1.abs() + ve2.abs()) * gamma(4);
        (p, err)
    }

    /// Watertight intersection with `ray` for `0 < t <= t_max`. Both faces are hit.
    #[inline]
    pub fn intersect(&self, ray: &WatertightRay, t_max: f32) -> Option<TriangleHit> {
        let (kx, ky, kz) = (ray.kx, ray.ky, ray.kz);
        let a = self.v0 - ray.origin;
        let b = self.v1 - ray.origin;
        let c = self.v2 - ray.origin;
        let ax = a[kx] - ray.sx * a[kz];
        let ay = a[ky] - ray.sy * a[kz];
        let bx = b[kx] - ray.sx * b[kz];
        let by = b[ky] - ray.sy * b[kz];
        let cx = c[kx] - ray.sx * c[kz];
        let cy = c[ky] - ray.sy * c[kz];

        let u = cx * by - cy * bx;
        let v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;
        let sheared = [ax, ay, bx, by, cx, cy];
        // Zero (a ray through an edge or vertex), subnormal, infinite or NaN: the f64 test.
        if !(u.is_normal() && v.is_normal() && w.is_normal()) {
            return self.intersect_f64(ray, t_max, sheared);
        }
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + v + w;
        let az = ray.sz * a[kz];
        let bz = ray.sz * b[kz];
        let cz = ray.sz * c[kz];
        let t_scaled = u * az + v * bz + w * cz;
        let rcp = 1.0 / det;
        // Zero or subnormal T is `t` lost to underflow (relative coordinates near 10^-16), not a
        // hit at the origin: the f64 test decides.
        if !(t_scaled.is_normal() && rcp.is_normal()) {
            return self.intersect_f64(ray, t_max, sheared);
        }
        let t = t_scaled * rcp;
        // `t` is finite here (normal numerator and reciprocal). Not `t > 0` yet: a `t` within
        // its error bound of zero is decided below.
        if t > t_max {
            return None;
        }
        // Computed only where the ray's line passes through the triangle in front of the
        // origin's neighbourhood, which is rare among tests.
        let d = |v: [f32; 3]| v.map(f64::from);
        let coords = [d([ax, bx, cx]), d([ay, by, cy]), d([az, bz, cz]), d([a[kz], b[kz], c[kz]])];
        let bound = t_error_bound(ray, coords, d([u, v, w]), f64::from(rcp.abs()), gamma_f32);
        if f64::from(t) > bound {
            return Some(TriangleHit { t, u: v * rcp, v: w * rcp });
        }
        if f64::from(t) < -bound {
            return None;
        }
        // f32 cannot tell this `t` from zero: the f64 test decides.
        self.intersect_exact(ray, t_max)
    }

    /// The hit distance of a ray the f32 test found inside the triangle but could not place in
    /// front of or behind the origin (`|t|` within its error bound), recomputed in f64 from the
    /// vertices, with an f64 error bound. A triangle far larger than its distance from the
    /// origin needs it: the f32 bound grows with the vertices' distance, so a ground quad of
    /// 10^6 units seen from 2 units above lost every hit within about 1 unit of the camera.
    /// Taken by the few tests whose f32 `t` is that close to zero: mostly a ray against the
    /// surface it leaves, which the f64 test rejects as well (the ray starts off the surface by
    /// its hit point's error bound).
    #[cold]
    #[inline(never)]
    fn intersect_exact(&self, ray: &WatertightRay, t_max: f32) -> Option<TriangleHit> {
        let o = ray.origin.as_dvec3();
        let (a, b, c) = (self.v0.as_dvec3() - o, self.v1.as_dvec3() - o, self.v2.as_dvec3() - o);
        let (sx, sy) = (f64::from(ray.sx), f64::from(ray.sy));
        let (kx, ky, kz) = (ray.kx, ray.ky, ray.kz);
        let shear = |p: glam::DVec3| (p[kx] - sx * p[kz], p[ky] - sy * p[kz]);
        let ((ax, ay), (bx, by), (cx, cy)) = (shear(a), shear(b), shear(c));
        // The f32 test already decided that the ray passes inside: its edge decisions stand, so
        // a shared edge stays watertight; here only the distance and barycentrics are computed.
        let (u, v, w) = (cx * by - cy * bx, ax * cy - ay * cx, bx * ay - by * ax);
        let det = u + v + w;
        if det == 0.0 {
            return None;
        }
        let sz = f64::from(ray.sz);
        let (az, bz, cz) = (sz * a[kz], sz * b[kz], sz * c[kz]);
        let t = (u * az + v * bz + w * cz) / det;
        let t32 = t as f32;
        if !(t32 > 0.0 && t32 <= t_max) {
            return None;
        }
        let coords = [[ax, bx, cx], [ay, by, cy], [az, bz, cz], [a[kz], b[kz], c[kz]]];
        if t <= t_error_bound(ray, coords, [u, v, w], 1.0 / det.abs(), gamma_f64) {
            return None;
        }
        let (bu, bv) = ((v / det).max(0.0), (w / det).max(0.0));
        Some(TriangleHit { t: t32, u: bu as f32, v: bv as f32 })
    }

    /// The rest of [`Triangle::intersect`] in f64, from the sheared coordinates
    /// `[ax, ay, bx, by, cx, cy]` (computed in f32, the same floats for a shared edge in both
    /// triangles): products of two f32 values are exact in f64 and never overflow nor underflow,
    /// so edges are decided exactly and any scene an f32 can hold is hit. Rarely taken (rays
    /// exactly through an edge, and scenes of extreme scale), so kept out of line.
    #[cold]
    #[inline(never)]
    fn intersect_f64(&self, ray: &WatertightRay, t_max: f32, sheared: [f32; 6]) -> Option<TriangleHit> {
        let [ax, ay, bx, by, cx, cy] = sheared.map(f64::from);
        let u = cx * by - cy * bx;
        let v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + v + w;
        if det == 0.0 {
            return None;
        }
        let kz = ray.kz;
        let (sz, o) = (f64::from(ray.sz), f64::from(ray.origin[kz]));
        let (a, b, c) = (f64::from(self.v0[kz]) - o, f64::from(self.v1[kz]) - o, f64::from(self.v2[kz]) - o);
        let (az, bz, cz) = (sz * a, sz * b, sz * c);
        let t = (u * az + v * bz + w * cz) / det;
        // The range test on the f32 distance reported, as in the f32 path: the reported `t`
        // alone decides acceptance, so a query bounded by a hit's own `t` finds it again.
        let t32 = t as f32;
        // Sheared coordinates that overflowed f32 give infinite edge functions here, and then a
        // NaN `t`: no hit, as before (the f64 test below would not recheck the edges).
        if !t.is_finite() || t32 > t_max {
            return None;
        }
        // The f32 path's bound: the shear rounded in f32, the rest is nearly exact here, so
        // this is conservative.
        let coords = [[ax, bx, cx], [ay, by, cy], [az, bz, cz], [a, b, c]];
        let bound = t_error_bound(ray, coords, [u, v, w], 1.0 / det.abs(), gamma_f32);
        if t > bound && t32 > 0.0 {
            return Some(TriangleHit { t: t32, u: (v / det) as f32, v: (w / det) as f32 });
        }
        if t < -bound {
            return None;
        }
        // The shear was rounded in f32: without that rounding the distance may be clear of zero.
        self.intersect_exact(ray, t_max)
    }
}

/// The bound on the error of a hit's `t` (pbrt-v4, 4th ed., section 6.8.7), from the three
/// vertices' sheared coordinates `[x, y, z, raw_z]` (z in `t` units, raw z before the shear's
/// scaling: a length), the edge functions `e` and `|1 / det|`. With it `t` is conservatively
/// positive: without it a ray leaving a surface, offset by only the hit point's error bound,
/// can still hit that surface at a tiny positive `t` that is rounding noise (glass lost energy
/// that way).
///
/// One departure: pbrt bounds the shear's error by the scaled z (`t` units), which is length
/// only for unit directions; ours are not (shadow rays span `p` to the light), so the shear's
/// term is `|s_x| max |raw z|` in length units, as the shear computes it.
///
/// One definition for the f32 test and its f64 fallback, evaluated in f64, where nothing
/// overflows or underflows (in f32, `max |e| * max |z|` grows as the cube of the scene's size).
/// The GPU's copy (`woop_2d` in shaders/trace.wgsl) is f32 and groups the terms so that no
/// product does: `max |e| / |det|` lies in [1/3, 1].
///
/// `g` is the `γ_n` of the arithmetic the coordinates were computed in: [`gamma_f32`], or
/// [`gamma_f64`] for [`Triangle::intersect_exact`].
fn t_error_bound(
    ray: &WatertightRay,
    sheared: [[f64; 3]; 4],
    e: [f64; 3],
    inv_det: f64,
    g: impl Fn(u32) -> f64,
) -> f64 {
    let max_abs = |v: [f64; 3]| v[0].abs().max(v[1].abs()).max(v[2].abs());
    let [max_x, max_y, max_z, shear_z] = sheared.map(max_abs);
    let max_e = max_abs(e);
    let delta_z = g(3) * max_z;
    let delta_x = g(5) * (max_x + f64::from(ray.sx).abs() * shear_z);
    let delta_y = g(5) * (max_y + f64::from(ray.sy).abs() * shear_z);
    let delta_e = 2.0 * (g(2) * max_x * max_y + delta_y * max_x + delta_x * max_y);
    3.0 * (g(3) * max_e * max_z + delta_e * max_z + delta_z * max_e) * inv_det
}

/// A ray prepared for the watertight test: the axis permutation and shear of section 3.
#[derive(Clone, Copy, Debug)]
pub struct WatertightRay {
    pub origin: Vec3,
    kx: usize,
    ky: usize,
    kz: usize,
    sx: f32,
    sy: f32,
    sz: f32,
}

impl WatertightRay {
    #[inline]
    pub fn new(ray: &Ray) -> Self {
        let d = ray.dir;
        let ad = d.abs();
        let kz = if ad.x > ad.y {
            if ad.x > ad.z { 0 } else { 2 }
        } else if ad.y > ad.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        // Swapping keeps the triangle's winding, so the sign of det tells the facing.
        if d[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        Self { origin: ray.origin, kx, ky, kz, sx: d[kx] / d[kz], sy: d[ky] / d[kz], sz: 1.0 / d[kz] }
    }

    /// The axis permutation `[kx, ky, kz]` and the shear `[sx, sy, sz]`, for kernels that run
    /// the same test on several triangles at once.
    pub fn permutation(&self) -> ([usize; 3], [f32; 3]) {
        ([self.kx, self.ky, self.kz], [self.sx, self.sy, self.sz])
    }
}

/// `γₙ = nε / (1 − nε)`, ε = 2⁻²⁴: a bound on the relative error of `n` rounded operations.
#[inline]
pub fn gamma(n: u32) -> f32 {
    let ne = n as f32 * (f32::EPSILON * 0.5);
    ne / (1.0 - ne)
}

/// [`gamma`] as an f64, for [`t_error_bound`].
fn gamma_f32(n: u32) -> f64 {
    f64::from(gamma(n))
}

/// `γ_n` of f64 arithmetic.
fn gamma_f64(n: u32) -> f64 {
    let ne = f64::from(n) * (f64::EPSILON * 0.5);
    ne / (1.0 - ne)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri() -> Triangle {
        Triangle::new(Vec3::new(0.0, 0.0, 2.0), Vec3::new(1.0, 0.0, 2.0), Vec3::new(0.0, 1.0, 2.0))
    }

    #[test]
    fn hits_inside_with_barycentrics() {
        let r = Ray::new(Vec3::new(0.25, 0.5, 0.0), Vec3::Z);
        let h = tri().intersect(&WatertightRay::new(&r), f32::INFINITY).unwrap();
        assert_eq!(h.t, 2.0);
        assert_eq!((h.u, h.v), (0.25, 0.5));
        assert_eq!(tri().point(h.u, h.v), r.at(h.t));
    }

    #[test]
    fn both_faces_and_range() {
        let r = Ray::new(Vec3::new(0.25, 0.25, 4.0), -Vec3::Z);
        let wr = WatertightRay::new(&r);
        assert_eq!(tri().intersect(&wr, f32::INFINITY).unwrap().t, 2.0);
        assert!(tri().intersect(&wr, 1.5).is_none());
        let behind = Ray::new(Vec3::new(0.25, 0.25, 4.0), Vec3::Z);
        assert!(tri().intersect(&WatertightRay::new(&behind), f32::INFINITY).is_none());
    }

    #[test]
    fn a_shared_edge_lets_no_ray_through() {
        // A quad split along its diagonal; rays from one point aimed at points along the shared
        // edge must hit at least one of the two triangles.
        let (a, b, c, d) =
            (Vec3::new(0.0, 0.0, 2.0), Vec3::new(1.3, 0.1, 2.2), Vec3::new(0.2, 1.1, 1.9), Vec3::new(1.1, 1.3, 2.5));
        let (t0, t1) = (Triangle::new(a, b, c), Triangle::new(b, d, c));
        let o = Vec3::new(0.37, 0.41, -1.0);
        for k in 0..=1000 {
            let target = b.lerp(c, k as f32 / 1000.0);
            let wr = WatertightRay::new(&Ray::new(o, target - o));
            let hits =
                t0.intersect(&wr, f32::INFINITY).is_some() as u32 + t1.intersect(&wr, f32::INFINITY).is_some() as u32;
            assert!(hits >= 1, "ray {k} leaked through the shared edge");
        }
    }

    /// The same hit, relatively, at scales where f32 edge functions overflow (10^25: products
    /// of 10^50) or underflow (10^-25), and a shared edge still lets no ray through there.
    #[test]
    fn extreme_scales_hit_like_unit_scale() {
        for s in [1e25f32, 1e-25, 1e16, 1e-16, 3e37, 1e-37] {
            let t = Triangle::new(tri().v0 * s, tri().v1 * s, tri().v2 * s);
            let r = Ray::new(Vec3::new(0.25, 0.5, 0.0) * s, Vec3::Z);
            let h = t.intersect(&WatertightRay::new(&r), f32::INFINITY).unwrap_or_else(|| panic!("missed at {s:e}"));
            assert!(
                (h.t / s - 2.0).abs() < 1e-6 && (h.u - 0.25).abs() < 1e-6 && (h.v - 0.5).abs() < 1e-6,
                "{s:e}: {h:?}"
            );
            let outside = Ray::new(Vec3::new(0.75, 0.5, 0.0) * s, Vec3::Z);
            assert!(t.intersect(&WatertightRay::new(&outside), f32::INFINITY).is_none(), "{s:e}");
            let (a, b, c, d) = (
                Vec3::new(0.0, 0.0, 2.0) * s,
                Vec3::new(1.3, 0.1, 2.2) * s,
                Vec3::new(0.2, 1.1, 1.9) * s,
                Vec3::new(1.1, 1.3, 2.5) * s,
            );
            let (t0, t1) = (Triangle::new(a, b, c), Triangle::new(b, d, c));
            let o = Vec3::new(0.37, 0.41, -1.0) * s;
            for k in 0..=200 {
                let wr = WatertightRay::new(&Ray::new(o, b.lerp(c, k as f32 / 200.0) - o));
                let hits = t0.intersect(&wr, f32::INFINITY).is_some() || t1.intersect(&wr, f32::INFINITY).is_some();
                assert!(hits, "{s:e}: ray {k} leaked through the shared edge");
            }
        }
    }

    /// A ground quad of 2 × 10^6 units seen from 1.7 units above: the f32 bound on `t` is over
    /// 1 there, and every hit within about a unit of the camera was rejected (a wedge of ground
    /// missing from the image). The hits are found at their distance, the shared diagonal lets
    /// no ray through, and a ray leaving the ground does not hit it again.
    #[test]
    fn a_huge_ground_is_hit_next_to_the_camera() {
        let s = 1e6f32;
        let (a, b, c, d) = (Vec3::new(-s, 0.0, -s), Vec3::new(s, 0.0, -s), Vec3::new(s, 0.0, s), Vec3::new(-s, 0.0, s));
        let (t0, t1) = (Triangle::new(a, b, c), Triangle::new(a, c, d));
        let o = Vec3::new(0.3, 1.7, 0.2);
        for k in 0..=400 {
            let f = k as f32 / 400.0 * 3.0 - 1.5;
            // Points on the diagonal (the shared edge) and beside it, all within 2.3 units.
            for target in [Vec3::new(f, 0.0, f), Vec3::new(f, 0.0, 0.5 - f)] {
                let r = Ray::new(o, target - o);
                let wr = WatertightRay::new(&r);
                let hit = t0.intersect(&wr, f32::INFINITY).or_else(|| t1.intersect(&wr, f32::INFINITY));
                let h = hit.unwrap_or_else(|| panic!("the ray to {target} missed the ground"));
                assert!((h.t - 1.0).abs() < 1e-4, "{target}: t = {}", h.t);
                let tri = if t0.intersect(&wr, f32::INFINITY).is_some() { t0 } else { t1 };
                let (p, err) = tri.point_with_error(h.u, h.v);
                // The point comes from vertices 10^6 away (a 0.06 ulp), and its bound says so.
                assert!(((p - target).abs() - err).max_element() <= 1e-4, "{target}: hit at {p} ± {err}");
                let up = crate::geometry::spawn_ray(p, err, Vec3::Y, Vec3::new(0.3, 1.0, -0.2));
                let up = WatertightRay::new(&up);
                assert!(t0.intersect(&up, f32::INFINITY).is_none() && t1.intersect(&up, f32::INFINITY).is_none());
            }
        }
    }

    #[test]
    fn unit_normals_and_areas_at_every_scale() {
        for s in [1.0f32, 1e10, 1e-10, 1e19, 1e-19, 1e25, 1e-25, 3e37, 1e-37, 1e-40] {
            let t = Triangle::new(tri().v0 * s, tri().v1 * s, tri().v2 * s);
            assert_eq!(t.unit_normal(), Vec3::Z, "{s:e}");
            let area = 0.5 * s as f64 * s as f64;
            if (1e-30..1e30).contains(&area) {
                assert!((t.area() as f64 / area - 1.0).abs() < 1e-6, "{s:e}: area {} against {area:e}", t.area());
            }
        }
        let p = Vec3::ONE;
        assert_eq!(Triangle::new(p, p, p).unit_normal(), Vec3::ZERO);
    }

    #[test]
    fn degenerate_triangles_never_hit() {
        let p = Vec3::new(0.0, 0.0, 1.0);
        let line = Triangle::new(p, p + Vec3::X, p + 2.0 * Vec3::X);
        let r = Ray::new(Vec3::new(0.5, 0.0, 0.0), Vec3::Z);
        assert!(line.intersect(&WatertightRay::new(&r), f32::INFINITY).is_none());
        let point = Triangle::new(p, p, p);
        let r = Ray::new(Vec3::ZERO, p);
        assert!(point.intersect(&WatertightRay::new(&r), f32::INFINITY).is_none());
    }
}
