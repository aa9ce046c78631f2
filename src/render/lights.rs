//! Area lights: every emissive triangle, chosen in proportion to its emitted power and then
//! sampled uniformly by area.
//!
//! A textured emitter's power is its radiance times the texture's mean over the triangle,
//! estimated from lookups at the centroids of a regular subdivision of the triangle, finer the
//! more texels its edges span. Any positive estimate keeps the sampling unbiased, since the density
//! used is the one sampled with (selection probability over area) and the radiance is the
//! texture's at the sampled point; a better estimate only lowers the variance. A triangle whose
//! estimate is zero is no light: where it does emit, BSDF sampling alone finds it, with full
//! weight, since its light density is zero.

use std::sync::Arc;

use glam::{Vec2, Vec3};

use super::geometry::interpolate;
use super::sampling::uniform_triangle;
use crate::geometry::Triangle;
use crate::texture::{Texture, TextureRef, luminance};

/// What a triangle emits: its radiance, whether from both faces, and the texture multiplying
/// the radiance with the triangle's texture coordinates (in its vertex order).
#[derive(Clone, Copy, Debug)]
pub struct Emitter {
    pub radiance: Vec3,
    pub two_sided: bool,
    pub texture: Option<EmissionTexture>,
}

/// An emission texture and the texture coordinates of a triangle's vertices.
pub type EmissionTexture = (TextureRef, [Vec2; 3]);

/// Finest subdivision of a triangle for its texture's mean: 16² = 256 lookups.
const MAX_SUBDIVISION: u32 = 16;

/// A point sampled on a light.
#[derive(Clone, Copy, Debug)]
pub struct LightPoint {
    pub point: Vec3,
    /// A bound on `point`'s rounding error per axis ([`Triangle::point_with_error`]).
    pub point_error: Vec3,
    /// The triangle's unit geometric normal (its front side).
    pub normal: Vec3,
    pub radiance: Vec3,
    pub two_sided: bool,
    /// Density of having sampled this point, per unit area (selection probability / area).
    pub pdf_area: f32,
}

#[derive(Clone, Copy, Debug)]
struct LightTriangle {
    triangle: Triangle,
    normal: Vec3,
    area: f32,
    emitter: Emitter,
}

/// The emissive triangles of a scene.
#[derive(Clone, Debug, Default)]
pub struct Lights {
    lights: Vec<LightTriangle>,
    /// Running sums of power, normalised so the last is 1.
    cdf: Vec<f32>,
    /// For each primitive id: its selection probability / area, 0 for non-lights.
    pdf_area_by_prim: Vec<f32>,
    /// The scene's textures, which textured emitters read.
    textures: Vec<Arc<Texture>>,
}

impl Lights {
    /// `emission(prim)` gives what a triangle emits, or `None`; `textures` are the scene's.
    pub fn new(triangles: &[Triangle], textures: &[Arc<Texture>], emission: impl Fn(usize) -> Option<Emitter>) -> Self {
        let mut lights = Vec::new();
        let mut prims = Vec::new();
        let mut power = Vec::new();
        for (i, t) in triangles.iter().enumerate() {
            let Some(emitter) = emission(i) else { continue };
            let area = t.area();
            let mean = emitter.texture.map_or(Vec3::ONE, |(r, uvs)| mean_over(&textures[r.texture as usize], r, uvs));
            // Emitted power of a Lambertian emitter: π · L · area per side.
            let sides = if emitter.two_sided { 2.0 } else { 1.0 };
            let p = std::f32::consts::PI * luminance(emitter.radiance * mean) * area * sides;
            // A triangle so small that its area is subnormal has no usable density (1/area
            // overflows), and one whose area or power overflows none either; such a triangle
            // can be neither sampled nor hit, so it is no light.
            let normal = t.unit_normal();
            if !(p > 0.0 && p.is_finite() && area.is_normal() && (1.0 / area).is_finite() && normal != Vec3::ZERO) {
                continue;
            }
            lights.push(LightTriangle { triangle: *t, normal, area, emitter });
            prims.push(i);
            power.push(p as f64);
        }
        let total: f64 = power.iter().sum();
        let mut acc = 0.0;
        let cdf: Vec<f32> = power
            .iter()
            .map(|p| {
                acc += p;
                (acc / total) as f32
            })
            .collect();
        let mut pdf_area_by_prim = vec![0.0; triangles.len()];
        for (k, &prim) in prims.iter().enumerate() {
            pdf_area_by_prim[prim] = (power[k] / total) as f32 / lights[k].area;
        }
        let textures = if lights.iter().any(|l| l.emitter.texture.is_some()) { textures.to_vec() } else { Vec::new() };
        Self { lights, cdf, pdf_area_by_prim, textures }
    }

    pub fn is_empty(&self) -> bool {
        self.lights.is_empty()
    }

    /// A light chosen by power with `u_select`, and a point on it uniform by area from `u`.
    pub fn sample(&self, u_select: f32, u: Vec2) -> Option<LightPoint> {
        if self.lights.is_empty() {
            return None;
        }
        let k = self.cdf.partition_point(|&c| c <= u_select).min(self.lights.len() - 1);
        let l = &self.lights[k];
        let b = uniform_triangle(u);
        let (point, point_error) = l.triangle.point_with_error(b.y, b.z);
        let p_select = self.cdf[k] - if k == 0 { 0.0 } else { self.cdf[k - 1] };
        let e = &l.emitter;
        let radiance = match e.texture {
            None => e.radiance,
            Some((r, uvs)) => {
                e.radiance
                    * self.textures[r.texture as usize].sample(interpolate(&uvs, b.y, b.z), r.wrap, r.srgb).truncate()
            }
        };
        Some(LightPoint {
            point,
            point_error,
            normal: l.normal,
            radiance,
            two_sided: e.two_sided,
            pdf_area: p_select / l.area,
        })
    }

    /// The lights as the GPU path (`src/gpu/trace.rs`) uploads them: each light's triangle,
    /// its CDF value (the running sum of power up to and including it), the fields of
    /// [`LightPoint`] that do not depend on the point, `pdf_area` as [`Lights::sample`] gives it
    /// (`point` is the first vertex, `point_error` zero, `radiance` untextured), and its
    /// emission texture with its texture coordinates.
    pub fn gpu_arrays(&self) -> Vec<(Triangle, f32, LightPoint, Option<EmissionTexture>)> {
        self.lights
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let p_select = self.cdf[k] - if k == 0 { 0.0 } else { self.cdf[k - 1] };
                let point = LightPoint {
                    point: l.triangle.v0,
                    point_error: Vec3::ZERO,
                    normal: l.normal,
                    radiance: l.emitter.radiance,
                    two_sided: l.emitter.two_sided,
                    pdf_area: p_select / l.area,
                };
                (l.triangle, self.cdf[k], point, l.emitter.texture)
            })
            .collect()
    }

    /// The density per unit area with which [`Lights::sample`] picks points on primitive `prim`.
    pub fn pdf_area(&self, prim: u32) -> f32 {
        self.pdf_area_by_prim.get(prim as usize).copied().unwrap_or(0.0)
    }
}

/// The mean of texture use `r` over a triangle with texture coordinates `uvs`: the lookups at
/// the centroids of its k² equal sub-triangles, k the texels along its longest edge (so that a
/// sliver across many texels is not judged by one lookup), at most [`MAX_SUBDIVISION`].
fn mean_over(texture: &Texture, r: TextureRef, uvs: [Vec2; 3]) -> Vec3 {
    let [a, b, c] = uvs;
    let size = Vec2::new(texture.width as f32, texture.height as f32);
    let longest = [b - a, c - b, a - c].map(|e| (e * size).length()).into_iter().fold(0.0, f32::max);
    let k = (longest.ceil() as u32).clamp(1, MAX_SUBDIVISION);
    let kf = k as f32;
    let mut sum = Vec3::ZERO;
    let mut at = |u: f32, v: f32| sum += texture.sample(interpolate(&uvs, u, v), r.wrap, r.srgb).truncate();
    for i in 0..k {
        for j in 0..k - i {
            at((i as f32 + 1.0 / 3.0) / kf, (j as f32 + 1.0 / 3.0) / kf);
            if i + j + 1 < k {
                at((i as f32 + 2.0 / 3.0) / kf, (j as f32 + 2.0 / 3.0) / kf);
            }
        }
    }
    sum / (kf * kf)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A light far from unit scale is still a light, with its unit normal and its density.
    /// Before, its normal came from normalising the raw cross product, whose squared length
    /// overflows beyond edges of about 10^9 (and underflows below about 3·10^-10): the light was
    /// dropped, and scenes at 10^12 rendered without next-event estimation.
    #[test]
    fn lights_at_extreme_scales_are_kept() {
        for s in [1.0f32, 1e-16, 1e-12, 1e12, 1e16] {
            let tri = Triangle::new(Vec3::ZERO, Vec3::new(s, 0.0, 0.0), Vec3::new(0.0, s, 0.0));
            let other = Triangle::new(Vec3::new(0.0, 0.0, s), Vec3::new(s, 0.0, s), Vec3::new(0.0, 2.0 * s, s));
            let white = Emitter { radiance: Vec3::ONE, two_sided: false, texture: None };
            let lights = Lights::new(&[tri, other], &[], |_| Some(white));
            assert_eq!(lights.lights.len(), 2, "scale {s:e}");
            let n = lights.lights[0].normal;
            assert!((n - Vec3::Z).length() <= 1e-6, "scale {s:e}: normal {n}");
            // Chosen by power (area), then uniform by area: the density is 1 / total area.
            let want = 1.0 / (1.5 * s * s);
            for prim in 0..2 {
                let p = lights.pdf_area(prim);
                assert!((p - want).abs() <= 1e-6 * want, "scale {s:e}: pdf {p}, want {want}");
            }
        }
    }

    /// A textured emitter is chosen by its textured power, and a sampled point emits the
    /// texture's value there. Triangle `a` reads only the black texel (clamped), `b` a ramp:
    /// `a` is never chosen, and each point of `b` emits the ramp at its texture coordinates,
    /// which are (x, 0.5) on `b` (barycentrics map x to u).
    #[test]
    fn textured_emitters_are_chosen_by_textured_power() {
        use crate::texture::{TexelFormat, Wrap};
        let ramp = [0.0f32, 0.0, 0.25, 0.5, 1.0];
        let texels = ramp.iter().flat_map(|&t| [t, t, t, 1.0]).map(f32::to_bits).collect();
        let texture = Texture {
            source: "ramp".into(),
            width: 5,
            height: 1,
            format: TexelFormat::Rgba32F,
            texels,
            has_alpha: false,
        };
        let r = TextureRef { texture: 0, wrap: Wrap::Clamp, srgb: false };
        let a = Triangle::new(Vec3::ZERO, Vec3::X, Vec3::Y);
        let b = Triangle::new(Vec3::Z, Vec3::Z + Vec3::X, Vec3::Z + Vec3::Y);
        let y = |u: f32| Vec2::new(u, 0.5);
        let uvs = [[y(0.0), y(0.1), y(0.0)], [y(0.0), y(1.0), y(0.0)]];
        let emitter =
            |i: usize| Some(Emitter { radiance: Vec3::splat(2.0), two_sided: false, texture: Some((r, uvs[i])) });
        let textures = [Arc::new(texture)];
        let lights = Lights::new(&[a, b], &textures, emitter);
        assert_eq!((lights.lights.len(), lights.pdf_area(0)), (1, 0.0), "the black triangle is no light");
        assert!((lights.pdf_area(1) - 2.0).abs() < 1e-6, "b is chosen always: 1 / its area");
        let mut rng = crate::render::rng::Rng::for_sample(7, 0, 0);
        for _ in 0..100 {
            let p = lights.sample(rng.next_f32(), rng.next_vec2()).unwrap();
            let want = 2.0 * textures[0].sample(y(p.point.x), Wrap::Clamp, false).x;
            assert!((p.radiance.x - want).abs() < 1e-5, "at {}: {} against {want}", p.point, p.radiance.x);
        }
    }
}
