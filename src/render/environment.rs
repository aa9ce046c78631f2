//! Environment maps: an equirectangular (latitude-longitude) image of the radiance arriving from
//! every direction, importance sampled for next-event estimation.
//!
//! **Mapping.** The convention of Mitsuba 3's `envmap` emitter, so that a map renders the same
//! in both: in the map's frame (the world's, turned by the scene's `rotate`), `+y` is straight up
//! and is the image's top row; a direction `d` has
//! `u = atan2(d.x, -d.z) / 2π` (wrapped to [0, 1)) across the image and `v = acos(d.y) / π` down
//! it. The image's left edge looks along `-z`, its centre along `+z`, a quarter across along
//! `+x`. Radiance between texel centres is interpolated bilinearly, wrapping across the left and
//! right edges and held at the top and bottom rows.
//!
//! **Sampling** (Pharr, Jakob and Humphreys, *Physically Based Rendering*, 4th ed., §12.5.2 and
//! A.5.3): a piecewise-constant density over the image, one constant per texel, proportional to
//! the texel's luminance times `sin θ` at its centre (the solid angle a texel spans), sampled by
//! inverting a marginal CDF over rows and the chosen row's conditional CDF. A `(u, v)` density
//! `p` is `p / (2π² sin θ)` per steradian. Departure: the luminance taken for a texel is the
//! mean over the texel of the bilinearly filtered radiance (the texel and its eight neighbours
//! weighted 1/8, 6/8, 1/8 along each axis), not the texel's own value. Filtering spreads a
//! texel's radiance half a texel into its neighbours, so a texel's own value can be zero where
//! the radiance is not; the filtered mean is positive wherever the radiance is, which keeps light
//! sampling alone (without MIS) unbiased, and it follows the radiance closely enough that a small
//! sun is sampled with little waste (the largest of the nine, tried first, spread a one-texel sun
//! over nine texels' worth of samples and left the sunlit surfaces grainy).
//!
//! Sums are taken in f64 and stored as f32, the form both devices sample from
//! (`shaders/trace.wgsl` reads the same arrays).

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use crate::texture::environment::{Distribution, EnvironmentMap};

impl EnvironmentMap {
    /// The radiance arriving from world direction `dir` (unit), before the scene's `scale`.
    pub fn eval(&self, dir: Vec3) -> Vec3 {
        let uv = direction_to_uv(self.map_from_world * dir);
        let (w, h) = (self.width as f32, self.height as f32);
        // Texel centres sit at half-integers.
        let x = uv.x * w - 0.5;
        let y = (uv.y * h - 0.5).clamp(0.0, h - 1.0);
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let wrap = |i: f32| (i as i64).rem_euclid(i64::from(self.width)) as usize;
        let (c0, c1) = (wrap(x0), wrap(x0 + 1.0));
        let r0 = y0 as usize;
        let r1 = (r0 + 1).min(self.height as usize - 1);
        let at = |c: usize, r: usize| Vec3::from(self.texels[r * self.width as usize + c]);
        let top = at(c0, r0) * (1.0 - fx) + at(c1, r0) * fx;
        let bottom = at(c0, r1) * (1.0 - fx) + at(c1, r1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// A world direction drawn from the distribution with `u`, and its density per steradian;
    /// `None` for a black map or at a pole, where the density is unbounded.
    pub fn sample(&self, u: Vec2) -> Option<(Vec3, f32)> {
        let (uv, p) = self.distribution.sample(self.width, self.height, u)?;
        let (dir, sin_theta) = uv_to_direction(uv);
        if sin_theta <= 0.0 {
            return None;
        }
        Some((self.world_from_map * dir, p / (2.0 * PI * PI * sin_theta)))
    }

    /// The density per steradian with which [`EnvironmentMap::sample`] draws world direction
    /// `dir` (unit).
    pub fn pdf(&self, dir: Vec3) -> f32 {
        let local = self.map_from_world * dir;
        let sin_theta = (local.x * local.x + local.z * local.z).sqrt();
        if sin_theta <= 0.0 {
            return 0.0;
        }
        let uv = direction_to_uv(local);
        self.distribution.pdf_at(self.width, self.height, uv) / (2.0 * PI * PI * sin_theta)
    }
}

impl Distribution {
    /// A point of the unit square drawn with `u`, and its density; `None` where nothing has
    /// weight.
    pub fn sample(&self, width: u32, height: u32, u: Vec2) -> Option<(Vec2, f32)> {
        let (w, h) = (width as usize, height as usize);
        if self.marginal[h] != 1.0 {
            return None;
        }
        // The first row whose CDF passes u.y, so never one of no weight.
        let r = self.marginal.partition_point(|&c| c <= u.y).clamp(1, h) - 1;
        let cdf = &self.conditional[r * (w + 1)..(r + 1) * (w + 1)];
        let c = cdf.partition_point(|&x| x <= u.x).clamp(1, w) - 1;
        let within = |lo: f32, hi: f32, x: f32| if hi > lo { ((x - lo) / (hi - lo)).clamp(0.0, 1.0) } else { 0.5 };
        let dv = within(self.marginal[r], self.marginal[r + 1], u.y);
        let du = within(cdf[c], cdf[c + 1], u.x);
        // Kept inside the texel: rounding must not carry a sample into a neighbour of no weight.
        let uv = Vec2::new(
            ((c as f32 + du) / width as f32).min(next_down((c + 1) as f32 / width as f32)),
            ((r as f32 + dv) / height as f32).min(next_down((r + 1) as f32 / height as f32)),
        );
        let p = self.pdf[r * w + c];
        (p > 0.0).then_some((uv, p))
    }

    /// The density at `uv`.
    pub fn pdf_at(&self, width: u32, height: u32, uv: Vec2) -> f32 {
        let c = ((uv.x * width as f32) as usize).min(width as usize - 1);
        let r = ((uv.y * height as f32) as usize).min(height as usize - 1);
        self.pdf[r * width as usize + c]
    }
}

/// The largest f32 below `x` (positive, normal `x`).
fn next_down(x: f32) -> f32 {
    f32::from_bits(x.to_bits() - 1)
}

/// `(u, v)` of a direction in the map's frame (module docs), `u` in [0, 1), `v` in [0, 1].
pub fn direction_to_uv(d: Vec3) -> Vec2 {
    let mut u = d.x.atan2(-d.z) * (0.5 / PI);
    if u < 0.0 {
        u += 1.0;
    }
    // atan2 of a tiny negative angle rounds u + 1 up to 1.
    if u >= 1.0 {
        u = 0.0;
    }
    Vec2::new(u, d.y.clamp(-1.0, 1.0).acos() * (1.0 / PI))
}

/// The direction in the map's frame at `(u, v)`, and its `sin θ`.
pub fn uv_to_direction(uv: Vec2) -> (Vec3, f32) {
    let (sin_phi, cos_phi) = (2.0 * PI * uv.x).sin_cos();
    let (sin_theta, cos_theta) = (PI * uv.y).sin_cos();
    (Vec3::new(sin_phi * sin_theta, cos_theta, -cos_phi * sin_theta), sin_theta)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image_io::Image;
    use crate::texture::environment::Sampling;
    use glam::Mat3;

    fn map(width: u32, height: u32, f: impl Fn(u32, u32) -> [f32; 3], sampling: Sampling) -> EnvironmentMap {
        let pixels = (0..height).flat_map(|y| (0..width).map(move |x| (x, y))).map(|(x, y)| f(x, y)).collect();
        let rotation = Mat3::from_rotation_y(0.7) * Mat3::from_rotation_x(0.2);
        EnvironmentMap::new("test".into(), Image { width, height, pixels }, rotation, sampling).unwrap()
    }

    /// A small bright "sun" on a dim sky.
    fn sun(x: u32, y: u32) -> [f32; 3] {
        if (x, y) == (5, 3) { [5000.0, 4000.0, 3000.0] } else { [0.2, 0.3, 0.5] }
    }

    #[test]
    fn uv_and_direction_are_inverse_and_follow_the_convention() {
        let (d, _) = uv_to_direction(Vec2::new(0.0, 0.5));
        assert!((d - Vec3::NEG_Z).length() < 1e-6, "u = 0 looks along -z: {d}");
        let (d, _) = uv_to_direction(Vec2::new(0.25, 0.5));
        assert!((d - Vec3::X).length() < 1e-6, "u = 1/4 looks along +x: {d}");
        let (d, _) = uv_to_direction(Vec2::new(0.5, 0.0));
        assert!((d - Vec3::Y).length() < 1e-6, "v = 0 is straight up: {d}");
        for i in 0..200 {
            let uv = Vec2::new((i as f32 * 0.618_034).fract(), 0.01 + 0.98 * (i as f32 * 0.414_213).fract());
            let back = direction_to_uv(uv_to_direction(uv).0);
            let du = (back.x - uv.x).abs().min(1.0 - (back.x - uv.x).abs());
            assert!(du < 1e-5 && (back.y - uv.y).abs() < 1e-5, "{uv} -> {back}");
        }
    }

    /// What `sample` returns as the density is what `pdf` says for the direction, and the density
    /// integrates to 1 over the sphere (estimated with uniform directions).
    #[test]
    fn sampled_densities_match_and_integrate_to_one() {
        for sampling in [Sampling::Luminance, Sampling::Uniform] {
            let m = map(16, 8, sun, sampling);
            let mut rng = crate::render::rng::Rng::for_sample(1, 2, 0);
            for _ in 0..2000 {
                let (dir, p) = m.sample(rng.next_vec2()).unwrap();
                let q = m.pdf(dir);
                assert!((p - q).abs() <= 2e-3 * p, "{sampling:?}: sampled {p}, pdf {q} at {dir}");
            }
            let n = 400_000;
            let mut sum = 0.0f64;
            for _ in 0..n {
                let d = crate::render::sampling::uniform_sphere(rng.next_vec2());
                sum += f64::from(m.pdf(d)) * 4.0 * std::f64::consts::PI;
            }
            let integral = sum / f64::from(n);
            assert!((integral - 1.0).abs() < 0.03, "{sampling:?}: the density integrates to {integral}");
        }
    }

    /// The sun's texel and its neighbours, where bilinear filtering spreads it, hold most of the
    /// luminance-sampled density; uniform sampling puts them at their solid angle.
    #[test]
    fn luminance_sampling_finds_the_sun() {
        let m = map(16, 8, sun, Sampling::Luminance);
        let mut rng = crate::render::rng::Rng::for_sample(3, 4, 0);
        let n = 10_000;
        let near = (0..n)
            .filter(|_| {
                let (dir, _) = m.sample(rng.next_vec2()).unwrap();
                let uv = direction_to_uv(m.map_from_world * dir);
                let (c, r) = ((uv.x * 16.0) as i32, (uv.y * 8.0) as i32);
                (c - 5).abs() <= 1 && (r - 3).abs() <= 1
            })
            .count();
        assert!(near > n * 9 / 10, "{near} of {n} samples near the sun");
    }

    #[test]
    fn a_constant_map_evaluates_to_its_constant_everywhere() {
        let m = map(7, 3, |_, _| [0.5, 1.0, 2.0], Sampling::Luminance);
        let mut rng = crate::render::rng::Rng::for_sample(5, 6, 0);
        for _ in 0..1000 {
            let d = crate::render::sampling::uniform_sphere(rng.next_vec2());
            let l = m.eval(d);
            assert!((l - Vec3::new(0.5, 1.0, 2.0)).abs().max_element() < 1e-6, "{d}: {l}");
        }
    }

    #[test]
    fn black_and_bad_maps() {
        assert!(map(4, 2, |_, _| [0.0; 3], Sampling::Luminance).is_black());
        assert!(map(4, 2, |_, _| [0.0; 3], Sampling::Luminance).sample(Vec2::splat(0.5)).is_none());
        let image = Image { width: 2, height: 1, pixels: vec![[1.0; 3], [f32::NAN, 0.0, 0.0]] };
        let e = EnvironmentMap::new("x".into(), image, Mat3::IDENTITY, Sampling::Luminance).unwrap_err();
        assert!(e.contains("pixel (1, 0)"), "{e}");
    }
}
