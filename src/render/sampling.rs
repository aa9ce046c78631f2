//! Sampling routines: hemispheres, the unit disk, triangles, the MIS power heuristic and an
//! orthonormal shading frame.
//!
//! - Cosine-weighted hemisphere: Malley's method (project a uniform disk sample up onto the
//!   hemisphere) with the concentric disk map of Shirley and Chiu, "A Low Distortion Map Between
//!   Disk and Square" (JGT 1997), which keeps stratified samples stratified.
//! - Triangle: Heitz, "A Low-Distortion Map Between Triangle and Square" (2019 technical report),
//!   section 3. The map is piecewise linear and area preserving, so it is exactly uniform, needs
//!   no square root, and keeps strata compact (the classic `1 - sqrt(u)` map of Osada et al. 2002
//!   stretches them into slivers). Departure: the third barycentric is clamped at 0 so that a
//!   rounding in `1 - b0 - b1` can never put a sample outside the triangle.
//! - Power heuristic: Veach, "Robust Monte Carlo Methods for Light Transport Simulation" (thesis,
//!   1997), section 9.2.4, with β = 2 and one sample per strategy. Departure: it is evaluated as a
//!   ratio so that squaring large pdfs (near-delta lobes, tiny lights) cannot overflow to inf/inf.
//! - Frame: Duff et al., "Building an Orthonormal Basis, Revisited" (JCGT 2017), through glam's
//!   `any_orthonormal_pair`, which implements that paper's branchless listing.
//!
//! Every direction here is a unit vector in a local frame whose normal is +z.

use std::f32::consts::{FRAC_1_PI, FRAC_PI_2, FRAC_PI_4, PI};

use glam::{Vec2, Vec3, vec2, vec3};

/// A direction uniformly distributed over the hemisphere `z >= 0`, from `u` in `[0, 1)²`.
pub fn uniform_hemisphere(u: Vec2) -> Vec3 {
    let z = u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    vec3(r * phi.cos(), r * phi.sin(), z)
}

/// Solid-angle density of [`uniform_hemisphere`] at `w`: `1 / 2π` for `w.z >= 0`, else 0.
pub fn uniform_hemisphere_pdf(w: Vec3) -> f32 {
    if w.z >= 0.0 { 0.5 * FRAC_1_PI } else { 0.0 }
}

/// A direction uniformly distributed over the whole unit sphere, from `u` in `[0, 1)²`.
pub fn uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    vec3(r * phi.cos(), r * phi.sin(), z)
}

/// Solid-angle density of [`uniform_sphere`]: `1 / 4π` everywhere.
pub fn uniform_sphere_pdf() -> f32 {
    0.25 * FRAC_1_PI
}

/// A point uniformly distributed over the unit disk, from `u` in `[0, 1)²`, by the concentric map
/// (Shirley and Chiu 1997): squares around the centre go to rings, so strata stay compact.
pub fn concentric_disk(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o == Vec2::ZERO {
        return Vec2::ZERO;
    }
    let (r, theta) =
        if o.x.abs() > o.y.abs() { (o.x, FRAC_PI_4 * (o.y / o.x)) } else { (o.y, FRAC_PI_2 - FRAC_PI_4 * (o.x / o.y)) };
    vec2(r * theta.cos(), r * theta.sin())
}

/// A direction over the hemisphere `z >= 0` with density `cos θ / π` (Malley's method), from `u`
/// in `[0, 1)²`. On the boundary of the square (`u.x = 0`) it can return `z = 0`, where the
/// density is 0: callers that divide by the pdf must reject that sample.
pub fn cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = concentric_disk(u);
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    vec3(d.x, d.y, z)
}

/// Solid-angle density of [`cosine_hemisphere`] at `w`: `max(w.z, 0) / π`.
pub fn cosine_hemisphere_pdf(w: Vec3) -> f32 {
    w.z.max(0.0) * FRAC_1_PI
}

/// Barycentrics `(b0, b1, b2)` of a point uniformly distributed by area over a triangle
/// `(v0, v1, v2)`, from `u` in `[0, 1)²` (Heitz 2019). The point is `b0 v0 + b1 v1 + b2 v2`; in
/// the `(u, v)` convention of [`crate::geometry::Triangle::point`] it is `(b1, b2)`. Every
/// component is in `[0, 1]` and they sum to 1 up to one rounding. The density over the triangle
/// is `1 / area`.
pub fn uniform_triangle(u: Vec2) -> Vec3 {
    // Heitz's map folds the unit square onto the triangle along its diagonal: each half of the
    // square is an affine image of the triangle with Jacobian 1/2, so area is preserved exactly.
    let (b0, b1) = if u.x < u.y {
        let b0 = 0.5 * u.x;
        (b0, u.y - b0)
    } else {
        let b1 = 0.5 * u.y;
        (u.x - b1, b1)
    };
    vec3(b0, b1, (1.0 - b0 - b1).max(0.0))
}

/// The power heuristic weight (β = 2, one sample from each strategy) for a sample drawn from a
/// strategy with density `pdf_f` when another strategy could have drawn it with density `pdf_g`:
/// `pdf_f² / (pdf_f² + pdf_g²)`. `power_heuristic(a, b) + power_heuristic(b, a) == 1` for all
/// non-negative inputs except two zeros (both weights are then 0: neither strategy produces the
/// sample). An infinite `pdf_f` (a delta lobe) gets weight 1 against any finite `pdf_g`.
pub fn power_heuristic(pdf_f: f32, pdf_g: f32) -> f32 {
    debug_assert!(pdf_f >= 0.0 && pdf_g >= 0.0, "pdfs must be non-negative, got {pdf_f}, {pdf_g}");
    if pdf_f == 0.0 {
        return 0.0;
    }
    if pdf_f.is_infinite() && pdf_g.is_infinite() {
        return 0.5;
    }
    // The ratio form: `r` may overflow to inf, which gives the correct limit 0, whereas the
    // textbook form would give inf / inf = NaN for pdfs above ~1.8e19.
    let r = pdf_g / pdf_f;
    1.0 / (1.0 + r * r)
}

/// `|v|`, also where `|v|²` overflows or underflows f32 (lengths beyond about 10^19 or below
/// about 10^-19): then from `v` divided by its largest component. Elsewhere the same bits as
/// `v.length()`. Shared in form with the GPU's `robust_length` (shaders/bsdf.wgsl).
pub fn robust_length(v: Vec3) -> f32 {
    let dist2 = v.length_squared();
    if dist2.is_normal() {
        return dist2.sqrt();
    }
    let m = v.abs().max_element();
    if m > 0.0 && m.is_finite() { m * (v / m).length() } else { m }
}

/// The solid-angle density `pdf_area · |to|² / cos` of a light point `to` away, seen from there at
/// cosine `cos`. Zero for a light that is never sampled (`pdf_area` 0: a light dropped for its
/// overflowing area), where the product was 0 · ∞ = NaN past distances of 10^19; and ordered so
/// that such distances give a finite density (their square overflows f32). Elsewhere the same
/// bits as the plain product. The GPU's `solid_angle_pdf` is the same.
pub fn solid_angle_pdf(pdf_area: f32, to: Vec3, cos: f32) -> f32 {
    if pdf_area == 0.0 {
        return 0.0;
    }
    let dist2 = to.length_squared();
    if dist2.is_normal() {
        return pdf_area * dist2 / cos;
    }
    let dist = robust_length(to);
    pdf_area * dist * (dist / cos)
}

/// A right-handed orthonormal frame `(s, t, n)`: `s × t = n`. Local coordinates have the normal
/// along +z, which is the frame every BSDF in [`super::bsdf`] works in.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    pub s: Vec3,
    pub t: Vec3,
    pub n: Vec3,
}

impl Frame {
    /// The frame with `n` as its +z axis; `n` must be unit length. Continuous in `n` everywhere
    /// except across `n.z = 0` (Duff et al. 2017 move the unavoidable discontinuity there).
    pub fn from_normal(n: Vec3) -> Self {
        debug_assert!(n.is_normalized(), "Frame::from_normal needs a unit normal, got {n} (length {})", n.length());
        let (s, t) = n.any_orthonormal_pair();
        Self { s, t, n }
    }

    /// World (or whatever space `s`, `t`, `n` are in) to local, where `n` is +z.
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        vec3(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }

    /// Local to world: the inverse of [`Frame::to_local`] (the frame is orthonormal).
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.s * v.x + self.t * v.y + self.n * v.z
    }
}

#[cfg(test)]
pub(crate) mod test_rng {
    //! Seeded random numbers and a Monte Carlo helper for the sampling and BSDF tests: one
    //! stream of the renderer's own generator per seed.

    use glam::Vec2;

    use crate::render::rng::Rng;

    pub struct Pcg32(Rng);

    impl Pcg32 {
        pub fn new(seed: u64) -> Self {
            Self(Rng::for_sample(seed, 0, 0))
        }

        /// Uniform in `[0, 1)`.
        pub fn f32(&mut self) -> f32 {
            self.0.next_f32()
        }

        pub fn vec2(&mut self) -> Vec2 {
            self.0.next_vec2()
        }
    }

    /// Mean and standard error of the mean of `n` draws of `f`.
    pub fn mean_and_se(n: usize, mut f: impl FnMut() -> f64) -> (f64, f64) {
        let (mut sum, mut sum2) = (0.0, 0.0);
        for _ in 0..n {
            let x = f();
            sum += x;
            sum2 += x * x;
        }
        let mean = sum / n as f64;
        let var = (sum2 / n as f64 - mean * mean).max(0.0);
        (mean, (var / n as f64).sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::test_rng::{Pcg32, mean_and_se};
    use super::*;

    /// ∫ pdf dω over the sphere, estimated with uniform sphere samples: E[pdf(ω) · 4π] = 1.
    /// Accepted within 5 standard errors (a fixed seed makes the test deterministic; 5σ is where a
    /// correct pdf would fail with probability below 1e-6).
    fn assert_integrates_to_one(name: &str, pdf: impl Fn(Vec3) -> f32) {
        let mut rng = Pcg32::new(7);
        let (mean, se) =
            mean_and_se(1_000_000, || f64::from(pdf(uniform_sphere(rng.vec2()))) / f64::from(uniform_sphere_pdf()));
        assert!((mean - 1.0).abs() < 5.0 * se, "{name}: ∫ pdf = {mean} ± {se}");
    }

    #[test]
    fn hemisphere_pdfs_integrate_to_one() {
        assert_integrates_to_one("uniform hemisphere", uniform_hemisphere_pdf);
        assert_integrates_to_one("cosine hemisphere", cosine_hemisphere_pdf);
    }

    /// The samples follow their pdf: E[cos θ] is 1/2 for uniform and 2/3 for cosine-weighted, and
    /// E[cos θ²] is 1/3 and 1/2. Checked within 5 standard errors, as above.
    #[test]
    fn hemisphere_samples_have_the_right_moments() {
        type Case = (&'static str, fn(Vec2) -> Vec3, f64, f64);
        let cases: [Case; 2] =
            [("uniform", uniform_hemisphere, 0.5, 1.0 / 3.0), ("cosine", cosine_hemisphere, 2.0 / 3.0, 0.5)];
        for (name, sample, m1, m2) in cases {
            let mut rng = Pcg32::new(11);
            let mut first = |k: i32| {
                mean_and_se(500_000, || {
                    let w = sample(rng.vec2());
                    assert!((w.length() - 1.0).abs() < 1e-5 && w.z >= 0.0, "{name}: bad sample {w}");
                    f64::from(w.z).powi(k)
                })
            };
            let (mean1, se1) = first(1);
            let (mean2, se2) = first(2);
            assert!((mean1 - m1).abs() < 5.0 * se1, "{name}: E[cos] = {mean1} ± {se1}, want {m1}");
            assert!((mean2 - m2).abs() < 5.0 * se2, "{name}: E[cos²] = {mean2} ± {se2}, want {m2}");
        }
    }

    #[test]
    fn disk_samples_lie_in_the_disk_and_cover_it_uniformly() {
        let mut rng = Pcg32::new(3);
        let n = 400_000;
        let mut inner = 0usize;
        for _ in 0..n {
            let d = concentric_disk(rng.vec2());
            assert!(d.length() <= 1.0 + 1e-6, "outside the disk: {d}");
            inner += usize::from(d.length() < 0.5);
        }
        // P(r < 1/2) = 1/4; binomial standard error sqrt(p(1-p)/n) ≈ 6.8e-4; 5σ ≈ 3.4e-3.
        let p = inner as f64 / n as f64;
        assert!((p - 0.25).abs() < 3.4e-3, "P(r < 1/2) = {p}");
    }

    /// Samples lie on the triangle, and each of the four midpoint sub-triangles (area 1/4 each)
    /// gets a quarter of them within 5 binomial standard errors.
    #[test]
    fn triangle_samples_are_on_the_triangle_and_uniform() {
        let mut rng = Pcg32::new(5);
        let n = 400_000;
        let mut counts = [0usize; 4];
        for _ in 0..n {
            let b = uniform_triangle(rng.vec2());
            assert!(b.min_element() >= 0.0 && b.max_element() <= 1.0, "barycentrics out of range: {b}");
            assert!((b.element_sum() - 1.0).abs() < 1e-6, "barycentrics do not sum to 1: {b}");
            let corner = (0..3).find(|&i| b[i] > 0.5);
            counts[corner.unwrap_or(3)] += 1;
        }
        let se = (0.25f64 * 0.75 / n as f64).sqrt();
        for (i, &c) in counts.iter().enumerate() {
            let p = c as f64 / n as f64;
            assert!((p - 0.25).abs() < 5.0 * se, "sub-triangle {i}: fraction {p}, want 0.25 ± {se}");
        }
        assert_eq!(uniform_triangle(Vec2::ZERO), vec3(0.0, 0.0, 1.0));
    }

    #[test]
    fn power_heuristic_weights_sum_to_one_and_handle_extremes() {
        for (a, b) in [(1.0f32, 1.0f32), (0.3, 2.0), (1e30, 1e-30), (1e20, 3e20), (0.0, 5.0)] {
            let sum = power_heuristic(a, b) + power_heuristic(b, a);
            assert!((sum - 1.0).abs() < 1e-6, "weights for ({a}, {b}) sum to {sum}");
        }
        assert_eq!(power_heuristic(1.0, 1.0), 0.5);
        assert_eq!(power_heuristic(f32::INFINITY, 3.0), 1.0);
        assert_eq!(power_heuristic(3.0, f32::INFINITY), 0.0);
        assert_eq!(power_heuristic(0.0, 0.0), 0.0);
    }

    #[test]
    fn frame_is_orthonormal_right_handed_and_round_trips() {
        let mut rng = Pcg32::new(9);
        let mut normals: Vec<Vec3> = (0..10_000).map(|_| uniform_sphere(rng.vec2())).collect();
        normals.extend([Vec3::Z, Vec3::NEG_Z, Vec3::X, vec3(0.0, 1e-7, -1.0).normalize()]);
        for n in normals {
            let f = Frame::from_normal(n);
            assert!((f.s.length() - 1.0).abs() < 1e-5 && (f.t.length() - 1.0).abs() < 1e-5, "{f:?}");
            assert!(f.s.dot(f.t).abs() < 1e-5 && f.s.dot(n).abs() < 1e-5 && f.t.dot(n).abs() < 1e-5, "{f:?}");
            assert!(f.s.cross(f.t).distance(n) < 1e-5, "left-handed: {f:?}");
            assert!(f.to_world(Vec3::Z).distance(n) < 1e-6);
            let v = uniform_sphere(rng.vec2());
            assert!(f.to_world(f.to_local(v)).distance(v) < 1e-5, "round trip of {v} in {f:?}");
            assert!((f.to_local(v).z - v.dot(n)).abs() < 1e-6);
        }
    }
}
