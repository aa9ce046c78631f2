//! Area lights: every emissive triangle, chosen in proportion to its emitted power and then
//! sampled uniformly by area.

use glam::{Vec2, Vec3};

use super::sampling::uniform_triangle;
use crate::geometry::Triangle;

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
    radiance: Vec3,
    two_sided: bool,
}

/// The emissive triangles of a scene.
#[derive(Clone, Debug, Default)]
pub struct Lights {
    lights: Vec<LightTriangle>,
    /// Running sums of power, normalised so the last is 1.
    cdf: Vec<f32>,
    /// For each primitive id: its selection probability / area, 0 for non-lights.
    pdf_area_by_prim: Vec<f32>,
}

impl Lights {
    /// `emission(prim)` gives a triangle's radiance and two-sidedness, or `None`.
    pub fn new(triangles: &[Triangle], emission: impl Fn(usize) -> Option<(Vec3, bool)>) -> Self {
        let mut lights = Vec::new();
        let mut prims = Vec::new();
        let mut power = Vec::new();
        for (i, t) in triangles.iter().enumerate() {
            let Some((radiance, two_sided)) = emission(i) else { continue };
            let area = t.area();
            // Emitted power of a Lambertian emitter: π · L · area per side.
            let p = std::f32::consts::PI * luminance(radiance) * area * if two_sided { 2.0 } else { 1.0 };
            // A triangle so small that its area is subnormal has no usable density (1/area
            // overflows), and one whose area or power overflows none either; such a triangle
            // can be neither sampled nor hit, so it is no light.
            let normal = t.unit_normal();
            if !(p > 0.0 && p.is_finite() && area.is_normal() && (1.0 / area).is_finite() && normal != Vec3::ZERO) {
                continue;
            }
            lights.push(LightTriangle { triangle: *t, normal, area, radiance, two_sided });
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
        Self { lights, cdf, pdf_area_by_prim }
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
        Some(LightPoint {
            point,
            point_error,
            normal: l.normal,
            radiance: l.radiance,
            two_sided: l.two_sided,
            pdf_area: p_select / l.area,
        })
    }

    /// The lights as the GPU path (`src/gpu/trace.rs`) uploads them: each light's triangle,
    /// its CDF value (the running sum of power up to and including it), and the fields of
    /// [`LightPoint`] that do not depend on the point, `pdf_area` as [`Lights::sample`] gives it
    /// (`point` is the first vertex, `point_error` zero).
    pub fn gpu_arrays(&self) -> Vec<(Triangle, f32, LightPoint)> {
        self.lights
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let p_select = self.cdf[k] - if k == 0 { 0.0 } else { self.cdf[k - 1] };
                let point = LightPoint {
                    point: l.triangle.v0,
                    point_error: Vec3::ZERO,
                    normal: l.normal,
                    radiance: l.radiance,
                    two_sided: l.two_sided,
                    pdf_area: p_select / l.area,
                };
                (l.triangle, self.cdf[k], point)
            })
            .collect()
    }

    /// The density per unit area with which [`Lights::sample`] picks points on primitive `prim`.
    pub fn pdf_area(&self, prim: u32) -> f32 {
        self.pdf_area_by_prim.get(prim as usize).copied().unwrap_or(0.0)
    }
}

/// Rec. 709 luminance.
pub fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
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
            let lights = Lights::new(&[tri, other], |_| Some((Vec3::ONE, false)));
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
}
