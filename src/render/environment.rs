//! Environment maps: an equirectangular (latitude-longitude) image of the radiance arriving from
//! every direction, importance sampled for next-event estimation.
//!
//! **Mapping.** That of Mitsuba 3's `envmap` emitter (version 3.9 and later), so that a map
//! renders the same in both: in the map's frame (the world's, turned by the scene's `rotate`),
//! `+y` is straight up and is the image's top row; a direction `d` has
//! `u = atan2(d.x, -d.z) / 2π` (wrapped to [0, 1)) across the image and `v = acos(d.y) / π` down
//! it. The image's left edge looks along `-z`, its centre along `+z`, a quarter across along
//! `+x`. Texel column `j` sits at `u = (j + 0.5) / W` and row `i` at `v = i / (H - 1)`: the top
//! row straight up, the bottom row straight down (a single row is seen at every `v`). Radiance
//! between texels is interpolated bilinearly, wrapping from the last column to the first.
//! Mitsuba's versions before 3.9 put column `j` at `u = j / W`, half a texel over; rows are the
//! same in all of them, except that Mitsuba takes no map under three rows (`docs/scene-format.md`
//! says what it does instead). Until issue 34, Arbor put row `i` at `(i + 0.5) / H`: the same at
//! the horizon, and up to half a texel off towards the poles.
//!
//! **Sampling** (Pharr, Jakob and Humphreys, *Physically Based Rendering*, 4th ed., §12.5.2 and
//! A.5.3): a piecewise-constant density over the `(u, v)` square, sampled by inverting a marginal
//! CDF over rows of cells and the chosen row's conditional CDF; a `(u, v)` density `p` is
//! `p / (2π² sin θ)` per steradian. Departure: a cell is not a texel but the patch between four
//! texel centres, over which the radiance is one bilinear interpolant: `W` columns of cells from
//! `u = (c + 0.5) / W` to `(c + 1.5) / W` (the last wrapping round), and `H - 1` rows from
//! `v = r / (H - 1)` to `(r + 1) / (H - 1)` (one row for a map of one). A cell's constant is the
//! mean luminance of its four corners, which is the interpolant's mean over it, times the mean
//! of `sin θ` over its rows (`texture::environment` builds the tables). The density is then
//! positive wherever the radiance is, which keeps light sampling alone (without MIS) unbiased.
//! A one-texel sun lights exactly the four patches around its centre, so its light is drawn from
//! them and from nowhere else. (Until issue 34 the cells were the texels, each weighted by a
//! 3 x 3 filter of its neighbourhood, which spread a one-texel sun over nine texels; the cells
//! could stay the texels only while texel centres sat mid-cell, which rows at `i / (H - 1)` do
//! not.)
//!
//! Sums are taken in f64 and stored as f32, the form both devices sample from
//! (`shaders/trace.wgsl` reads the same arrays).

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use crate::texture::environment::{Distribution, EnvironmentMap, sampling_rows};

impl EnvironmentMap {
    /// The radiance arriving from world direction `dir` (unit), before the scene's `scale`.
    pub fn eval(&self, dir: Vec3) -> Vec3 {
        let uv = direction_to_uv(self.map_from_world * dir);
        let (w, h) = (self.width as f32, self.height as f32);
        // Columns at half-integers of u W, rows at integers of v (H - 1) (module docs).
        let x = uv.x * w - 0.5;
        let y = (uv.y * (h - 1.0)).clamp(0.0, h - 1.0);
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
    /// weight. The cells are those of the module docs.
    pub fn sample(&self, width: u32, height: u32, u: Vec2) -> Option<(Vec2, f32)> {
        let (w, rows) = (width as usize, sampling_rows(height) as usize);
        if self.marginal[rows] != 1.0 {
            return None;
        }
        // The first row whose CDF passes u.y, so never one of no weight.
        let r = self.marginal.partition_point(|&c| c <= u.y).clamp(1, rows) - 1;
        let cdf = &self.conditional[r * (w + 1)..(r + 1) * (w + 1)];
        let c = cdf.partition_point(|&x| x <= u.x).clamp(1, w) - 1;
        let within = |lo: f32, hi: f32, x: f32| if hi > lo { ((x - lo) / (hi - lo)).clamp(0.0, 1.0) } else { 0.5 };
        let dv = within(self.marginal[r], self.marginal[r + 1], u.y);
        let du = within(cdf[c], cdf[c + 1], u.x);
        // Kept inside the cell: rounding must not carry a sample into a neighbour of no weight.
        // Across, in texels from the first column's centre, then shifted back by half a texel.
        let x = (c as f32 + du).min(next_down((c + 1) as f32));
        let mut su = (x + 0.5) / width as f32;
        if su >= 1.0 {
            su -= 1.0;
        }
        let sv = ((r as f32 + dv) / rows as f32).min(next_down((r + 1) as f32 / rows as f32));
        let p = self.pdf[r * w + c];
        (p > 0.0).then_some((Vec2::new(su, sv), p))
    }

    /// The density at `uv`.
    pub fn pdf_at(&self, width: u32, height: u32, uv: Vec2) -> f32 {
        let rows = sampling_rows(height);
        let mut x = uv.x * width as f32 - 0.5;
        if x < 0.0 {
            x += width as f32;
        }
        let c = (x as usize).min(width as usize - 1);
        let r = ((uv.y * rows as f32) as usize).min(rows as usize - 1);
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

    /// A map of texels from a hash: about a third black, the rest lit unevenly, so that black
    /// texels lie beside lit ones.
    fn speckled(x: u32, y: u32) -> [f32; 3] {
        let k = ((x + 7).wrapping_mul(0x9e37_79b9) ^ (y + 3).wrapping_mul(0x85eb_ca6b)).wrapping_mul(0xc2b2_ae35) >> 8;
        if k % 3 == 0 { [0.0; 3] } else { [0.1 + (k % 100) as f32 * 0.1, 0.5, 0.2 + (k % 7) as f32] }
    }

    /// Maps of every shape the distribution treats apart: one row, one column, one texel, two
    /// rows (one row of cells), and larger ones.
    fn shapes() -> Vec<(&'static str, EnvironmentMap)> {
        let mut maps = Vec::new();
        for sampling in [Sampling::Luminance, Sampling::Uniform] {
            maps.push(("sun 16x8", map(16, 8, sun, sampling)));
            for (w, h) in [(1, 1), (7, 1), (1, 5), (3, 2), (16, 9), (5, 4)] {
                maps.push(("speckled", map(w, h, speckled, sampling)));
            }
        }
        assert!(maps.iter().all(|(_, m)| !m.is_black()));
        maps
    }

    /// What `sample` returns as the density is what `pdf` says for the direction, and the density
    /// integrates to 1 over the sphere (estimated with uniform directions).
    #[test]
    fn sampled_densities_match_and_integrate_to_one() {
        for (name, m) in shapes() {
            let what = format!("{name} {}x{} {:?}", m.width, m.height, m.distribution.pdf.len());
            let mut rng = crate::render::rng::Rng::for_sample(1, 2, 0);
            for _ in 0..2000 {
                let (dir, p) = m.sample(rng.next_vec2()).unwrap();
                let q = m.pdf(dir);
                assert!((p - q).abs() <= 2e-3 * p, "{what}: sampled {p}, pdf {q} at {dir}");
            }
            let n = 400_000;
            let mut sum = 0.0f64;
            for _ in 0..n {
                let d = crate::render::sampling::uniform_sphere(rng.next_vec2());
                sum += f64::from(m.pdf(d)) * 4.0 * std::f64::consts::PI;
            }
            let integral = sum / f64::from(n);
            assert!((integral - 1.0).abs() < 0.03, "{what}: the density integrates to {integral}");
        }
    }

    /// Samples fall in each cell (the patch between four texel centres, module docs) as often as
    /// its density says: within 5 standard deviations of the binomial count, or 1 where the
    /// density is 0.
    #[test]
    fn samples_fall_in_cells_as_their_density_says() {
        for (name, m) in shapes() {
            let (w, rows) = (m.width as usize, sampling_rows(m.height) as usize);
            let what = format!("{name} {}x{}", m.width, m.height);
            let mut counts = vec![0u32; w * rows];
            let mut rng = crate::render::rng::Rng::for_sample(7, 8, 0);
            let n = 100_000;
            for _ in 0..n {
                let (dir, _) = m.sample(rng.next_vec2()).unwrap();
                let uv = direction_to_uv(m.map_from_world * dir);
                let x = (uv.x * m.width as f32 - 0.5).rem_euclid(m.width as f32);
                let (c, r) = ((x as usize).min(w - 1), ((uv.y * rows as f32) as usize).min(rows - 1));
                counts[r * w + c] += 1;
            }
            for (i, &count) in counts.iter().enumerate() {
                let p = f64::from(m.distribution.pdf[i]) / (w * rows) as f64;
                let expected = p * f64::from(n);
                let sd = (expected * (1.0 - p)).sqrt();
                let off = (f64::from(count) - expected).abs();
                assert!(off <= 5.0 * sd + 1.0, "{what}: cell {i} drew {count} of {n}, expected {expected:.1}");
            }
        }
    }

    /// Drawing directions from the map alone (no MIS) integrates its luminance over the sphere
    /// as uniform directions do: the density is positive wherever the radiance is, also in a
    /// black texel's patches next to a lit one. Within 5 combined standard errors.
    #[test]
    fn light_sampling_alone_integrates_the_map() {
        for (name, m) in shapes() {
            let what = format!("{name} {}x{}", m.width, m.height);
            let mut rng = crate::render::rng::Rng::for_sample(9, 10, 0);
            let n = 200_000;
            let (mut a, mut a2, mut b, mut b2) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
            for _ in 0..n {
                let (dir, p) = m.sample(rng.next_vec2()).unwrap();
                let x = f64::from(crate::texture::luminance(m.eval(dir)) / p);
                (a, a2) = (a + x, a2 + x * x);
                let d = crate::render::sampling::uniform_sphere(rng.next_vec2());
                let l = crate::texture::luminance(m.eval(d));
                let y = f64::from(l) * 4.0 * std::f64::consts::PI;
                (b, b2) = (b + y, b2 + y * y);
                if l > 0.0 {
                    assert!(m.pdf(d) > 0.0, "{what}: radiance {l} along {d}, density 0");
                }
            }
            let nf = f64::from(n);
            let (ma, mb) = (a / nf, b / nf);
            let se = ((a2 / nf - ma * ma) / nf + (b2 / nf - mb * mb) / nf).sqrt();
            assert!((ma - mb).abs() <= 5.0 * se, "{what}: light sampling {ma}, uniform {mb} ± {se}");
        }
    }

    /// The sun's four patches (between its texel's centre and its neighbours', where bilinear
    /// filtering spreads it) hold most of the luminance-sampled density.
    #[test]
    fn luminance_sampling_finds_the_sun() {
        let m = map(16, 8, sun, Sampling::Luminance);
        let mut rng = crate::render::rng::Rng::for_sample(3, 4, 0);
        let n = 10_000;
        let near = (0..n)
            .filter(|_| {
                let (dir, _) = m.sample(rng.next_vec2()).unwrap();
                let uv = direction_to_uv(m.map_from_world * dir);
                // Texel units: the sun at column 5, row 3.
                let (x, y) = (uv.x * 16.0 - 0.5, uv.y * 7.0);
                (x - 5.0).abs() < 1.0 && (y - 3.0).abs() < 1.0
            })
            .count();
        assert!(near > n * 9 / 10, "{near} of {n} samples near the sun");
    }

    /// Texel column `j` at `u = (j + 0.5) / W`, row `i` at `v = i / (H - 1)`, as in Mitsuba 3;
    /// halfway between two texels, their mean; a single row at every `v`.
    #[test]
    fn texels_sit_where_mitsuba_puts_them() {
        for (w, h) in [(6u32, 5u32), (4, 2), (3, 1)] {
            // Unturned: a turn's rounding would move directions near the poles.
            let pixels = (0..h).flat_map(|y| (0..w).map(move |x| speckled(x, y))).collect();
            let image = Image { width: w, height: h, pixels };
            let m = EnvironmentMap::new("test".into(), image, Mat3::IDENTITY, Sampling::Luminance).unwrap();
            let at = |u: f32, v: f32| m.eval(uv_to_direction(Vec2::new(u, v)).0);
            let texel = |x: u32, y: u32| Vec3::from(speckled(x % w, y));
            let rows = (h - 1).max(1) as f32;
            for y in 0..h {
                for x in 0..w {
                    let (u, v) = ((x as f32 + 0.5) / w as f32, (y as f32 / rows).min(1.0));
                    // A hair off the poles, where u is lost; acos rounds it back to 0 or 1.
                    let v = v.clamp(1e-6, 1.0 - 1e-6);
                    let tol = 2e-3 * texel(x, y).max_element().max(1.0);
                    let want = if h == 1 { texel(x, 0) } else { texel(x, y) };
                    assert!(
                        (at(u, v) - want).abs().max_element() < tol,
                        "{w}x{h} texel ({x}, {y}): {} against {want}",
                        at(u, v)
                    );
                    let mid = at((x as f32 + 1.0) / w as f32, v);
                    let want = 0.5 * (texel(x, y) + texel(x + 1, y));
                    assert!(
                        (mid - want).abs().max_element() < tol,
                        "{w}x{h} between ({x}, {y}) and the next: {mid} against {want}"
                    );
                    if y + 1 < h {
                        let mid = at(u, (y as f32 + 0.5) / rows);
                        let want = 0.5 * (texel(x, y) + texel(x, y + 1));
                        assert!(
                            (mid - want).abs().max_element() < tol,
                            "{w}x{h} between ({x}, {y}) and below: {mid} against {want}"
                        );
                    }
                }
            }
            if h == 1 {
                assert!(
                    (at(0.5 / w as f32, 0.9) - texel(0, 0)).abs().max_element() < 1e-3,
                    "one row is seen at every v"
                );
            }
        }
    }

    #[test]
    fn a_constant_map_evaluates_to_its_constant_everywhere() {
        for (w, h) in [(7, 3), (1, 1), (4, 1), (1, 3)] {
            let m = map(w, h, |_, _| [0.5, 1.0, 2.0], Sampling::Luminance);
            let mut rng = crate::render::rng::Rng::for_sample(5, 6, 0);
            for _ in 0..1000 {
                let d = crate::render::sampling::uniform_sphere(rng.next_vec2());
                let l = m.eval(d);
                assert!((l - Vec3::new(0.5, 1.0, 2.0)).abs().max_element() < 1e-6, "{w}x{h} {d}: {l}");
            }
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
