//! Unidirectional path tracing with next-event estimation (one shadow ray per bounce) and
//! multiple importance sampling of light and BSDF samples with the power heuristic (Veach 1997,
//! chapter 9), Russian roulette from the fifth segment on.
//!
//! Conventions, those of the Mitsuba reference (`../shared/reference/cornell-box`): `max_depth`
//! counts path segments (1 = emitters seen directly, 2 = direct light); reflectors (diffuse,
//! conductor) are one-sided, black seen from the back of their triangle; emitters emit from the
//! front unless two-sided, and also reflect with their BSDF. An emitter reached by a BSDF sample
//! is weighted against the light sampling that could have found it, so it is neither lost nor
//! counted twice. What a scene lacks costs nothing: no emitters, no shadow rays; no
//! environment, no environment lookups.
//!
//! **Environment maps.** A map is a light at infinity: next-event estimation picks it with the
//! probability [`RenderScene::environment_light`] gives (else an area light), draws a direction
//! from its luminance distribution, and weights it by MIS against the BSDF; a bounce that
//! escapes is weighted against that light sampling (`RenderScene::escaped`). Each strategy's
//! density counts the other's selection probability. A constant environment is left to BSDF
//! sampling.
//!
//! **Shading normals.** Where a mesh gives vertex normals, the BSDF is evaluated in the frame of
//! the interpolated normal `ns` (turned to the side of the geometric normal `ng`, whose winding
//! decides the front). Two rules keep that from breaking what the geometry says:
//! - *No leaks*: a direction counts only where `ns` and `ng` agree on what it does: a
//!   reflection (by `ns`) must stay on the side of the geometric surface it came from, and a
//!   transmission must cross it. Light sampled through the surface, or a bounce sampled into it,
//!   contributes nothing, so light never passes through a closed mesh.
//! - *No black fringes*: where the view direction is above the geometric surface but below
//!   `ns`'s horizon (silhouettes of coarse meshes), every reflection in `ns`'s frame would be
//!   black; the hit is shaded with `ng` instead.
//!
//! Paths start at the camera and carry radiance, so the cosine at each bounce is the shading
//! one, `|wi · ns|`, with no correction: Veach's adjoint correction for shading normals
//! (Veach 1997, §5.3) applies to importance carried from the lights, which this integrator
//! never does.

use glam::Vec3;

use super::RenderScene;
use super::assembly::EnvLight;
use super::bsdf::Bsdf;
use super::geometry::Surface;
use super::rng::Rng;
use super::sampling::{Frame, power_heuristic, robust_length, solid_angle_pdf};
use crate::geometry::{Ray, gamma, spawn_ray};

/// Where a shadow ray's occlusion test ends, as a fraction of the way to the light's plane (see
/// `direct_light`).
pub const SHADOW_T_MAX: f32 = 1.0 - 1e-4;

/// Russian roulette starts at this many path segments (Mitsuba's `rr_depth`).
pub const RR_DEPTH: u32 = 5;

/// A scattering vertex of a path, as next-event estimation reads it.
#[derive(Clone, Copy)]
struct Vertex<'a> {
    bsdf: &'a Bsdf,
    /// The shading frame the BSDF is evaluated in.
    frame: &'a Frame,
    /// The point and its error bound.
    p: Vec3,
    p_error: Vec3,
    /// The surface it lies on, which shadow rays skip.
    surface: Surface,
    /// The geometric normal (unit).
    ng: Vec3,
    /// `Some(wo · ng)` where the shading normal is not the geometric one: directions must
    /// then agree on both (module docs).
    check: Option<f32>,
    /// The direction to the previous vertex, in the shading frame.
    wo: Vec3,
    /// The path's throughput up to here.
    beta: Vec3,
}

impl RenderScene {
    /// Radiance along `ray` (unit direction) for a path of at most `max_depth` segments;
    /// also returns the number of rays traced.
    pub fn radiance(&self, mut ray: Ray, rng: &mut Rng, max_depth: u32) -> (Vec3, u32) {
        let (mut l, mut beta) = (Vec3::ZERO, Vec3::ONE);
        let (mut prev_pdf, mut prev_delta) = (0.0f32, true);
        let mut rays = 0;
        // The surface the ray leaves, which it skips (see `Surface`).
        let mut from = None;
        let env_light = self.environment_light();
        // The probability that next-event estimation picks an area light, not the map.
        let area_select = 1.0 - env_light.map_or(0.0, |(_, _, p)| p);
        let lit = !self.lights.is_empty() || env_light.is_some();
        for depth in 1..=max_depth {
            rays += 1;
            let Some(hit) = self.geometry.intersect_from(&ray, from) else {
                l += beta * self.escaped(env_light, ray.dir, prev_pdf, prev_delta);
                break;
            };
            let tri = &hit.triangle;
            let ng = tri.unit_normal();
            if ng == Vec3::ZERO {
                break;
            }
            let (p, p_error) = tri.point_with_error(hit.u, hit.v);
            let wo_world = -ray.dir;
            let front = ng.dot(wo_world) > 0.0;
            let material = &self.materials[hit.material as usize];
            let emitted =
                if front || material.two_sided { material.emitted(&self.textures, || hit.uv()) } else { None };
            if let Some(le) = emitted {
                if prev_delta {
                    l += beta * le;
                } else {
                    let p_light = area_select
                        * solid_angle_pdf(self.lights.pdf_area(hit.light), p - ray.origin, ng.dot(wo_world).abs());
                    l += beta * le * power_heuristic(prev_pdf, p_light);
                }
            }
            if depth == max_depth {
                break;
            }
            let Some(bsdf) = material.bsdf_at(&self.textures, || hit.uv()) else { break };
            let dielectric = matches!(bsdf, Bsdf::Dielectric { .. });
            if !dielectric && !front {
                break; // one-sided reflector seen from the back
            }
            // The shading normal where the view sees the same side of it as of the surface
            // (module docs).
            let wo_ng = ng.dot(wo_world);
            let shading = material
                .shading_normal(&self.textures, &hit, ng)
                .filter(|ns| (ns.dot(wo_world) > 0.0) == (wo_ng > 0.0));
            let frame = Frame::from_normal(shading.unwrap_or(ng));
            // Without a shading normal the frame is the geometry's, and every direction agrees.
            let check = shading.map(|_| wo_ng);
            let wo = frame.to_local(wo_world);
            if lit && bsdf.has_non_delta() {
                let at = Vertex { bsdf: &bsdf, frame: &frame, p, p_error, surface: hit.surface, ng, check, wo, beta };
                rays += self.direct_light(env_light, &at, rng, &mut l);
            }
            let Some(s) = bsdf.sample(wo, rng.next_vec2(), rng.next_f32()) else { break };
            if !(s.weight.is_finite() && s.weight.max_element() > 0.0) {
                break;
            }
            let wi_world = frame.to_world(s.wi).normalize();
            if check.is_some_and(|wo_ng| !agrees(ng.dot(wi_world), wo_ng, s.wi.z, wo.z)) {
                break;
            }
            beta *= s.weight;
            prev_pdf = s.pdf;
            prev_delta = s.is_delta;
            ray = spawn_ray(p, p_error, ng, wi_world);
            from = Some(hit.surface);
            if depth >= RR_DEPTH {
                let q = beta.max_element().min(0.95);
                if rng.next_f32() >= q {
                    break;
                }
                beta /= q;
            }
        }
        (l, rays)
    }

    /// Next-event estimation: one light sample, MIS-weighted against the BSDF. Adds to `l` and
    /// returns the rays traced (0 or 1). `env_light` is [`RenderScene::environment_light`].
    fn direct_light(&self, env_light: Option<EnvLight>, at: &Vertex, rng: &mut Rng, l: &mut Vec3) -> u32 {
        let Vertex { bsdf, frame, p, p_error, surface, ng, check, wo, beta } = *at;
        let mut u_select = rng.next_f32();
        let u = rng.next_vec2();
        let mut area_select = 1.0;
        if let Some((map, scale, p_env)) = env_light {
            if u_select < p_env {
                let Some((wi_world, pdf)) = map.sample(u) else { return 0 };
                let le = scale * map.eval(wi_world);
                let wi = frame.to_local(wi_world);
                if check.is_some_and(|wo_ng| !agrees(ng.dot(wi_world), wo_ng, wi.z, wo.z)) {
                    return 0;
                }
                let f = bsdf.eval(wo, wi);
                if f.max_element() <= 0.0 || le.max_element() <= 0.0 {
                    return 0;
                }
                // The light is at infinity: the direction is exact, so the ray may start off
                // the surface along the normal, as a bounce does, and has no end.
                let shadow = spawn_ray(p, p_error, ng, wi_world);
                if self.geometry.occluded_from(&shadow, f32::INFINITY, Some(surface)) {
                    return 1;
                }
                let p_light = p_env * pdf;
                let w = power_heuristic(p_light, bsdf.pdf(wo, wi));
                *l += beta * f * wi.z.abs() * le * (w / p_light);
                return 1;
            }
            // The rest of the unit interval picks an area light.
            u_select = ((u_select - p_env) / (1.0 - p_env)).min(1.0 - f32::EPSILON / 2.0);
            area_select = 1.0 - p_env;
        }
        let Some(lp) = self.lights.sample(u_select, u) else { return 0 };
        let to = lp.point - p;
        let dist = robust_length(to);
        if !(dist > 0.0 && dist.is_finite()) {
            return 0;
        }
        let wi_world = to / dist;
        let cos_light = lp.normal.dot(-wi_world);
        if !(cos_light > 0.0 || (lp.two_sided && cos_light < 0.0)) {
            return 0;
        }
        let wi = frame.to_local(wi_world);
        if check.is_some_and(|wo_ng| !agrees(ng.dot(wi_world), wo_ng, wi.z, wo.z)) {
            return 0;
        }
        let f = bsdf.eval(wo, wi);
        // (A textured light's point may emit nothing: no shadow ray for it.)
        if f.max_element() <= 0.0 || lp.radiance.max_element() <= 0.0 {
            return 0;
        }
        // Neither end is moved sideways, off the line from `p` to the sampled point: that would
        // tilt the ray and shift penumbrae by the offsets (about 1% of a Cornell box placed 10⁵
        // from the origin, where one ULP is 0.4% of it). Instead the ray starts along that line
        // just far enough to clear the receiver's surface, by its error bound plus one rounding
        // of the start itself, and stops short of the light's plane by the light point's error
        // bound, both measured along the ray. It stops a further 10⁻⁴ of its length short: once
        // rounded, the two triangles of a quad light are not exactly coplanar, and a ray reaching
        // one near their shared edge can clip the other (the Cornell box's light scaled by 0.1 or
        // 10⁻⁴ lost up to 1% of its direct light that way). Both found by the numerical stress
        // tests (docs/testing.md, "Numerical stress").
        let cos_receiver = ng.dot(wi_world).abs();
        let clear = ng.abs().dot(p_error + p.abs() * gamma(1)) / cos_receiver;
        let from = p + wi_world * clear;
        let shadow = Ray::new(from, lp.point - from);
        let length = robust_length(shadow.dir);
        let short_of_plane = lp.normal.abs().dot(lp.point_error) / (cos_light.abs() * length);
        let t_max = (1.0 - short_of_plane) * SHADOW_T_MAX;
        if !(clear.is_finite() && clear < dist && t_max > 0.0)
            || self.geometry.occluded_from(&shadow, t_max, Some(surface))
        {
            return 1;
        }
        let p_light = area_select * solid_angle_pdf(lp.pdf_area, to, cos_light.abs());
        let w = power_heuristic(p_light, bsdf.pdf(wo, wi));
        *l += beta * f * wi.z.abs() * lp.radiance * (w / p_light);
        1
    }

    /// The radiance arriving along `dir` (unit) from the environment, for a path whose last
    /// bounce was sampled with density `prev_pdf` (`prev_delta`: from a delta lobe): a map's
    /// radiance is weighted against the light sampling (`env_light`) that could have found it.
    fn escaped(&self, env_light: Option<EnvLight>, dir: Vec3, prev_pdf: f32, prev_delta: bool) -> Vec3 {
        let Some(env) = &self.environment else { return Vec3::ZERO };
        let Some((map, scale, p_env)) = env_light else { return env.radiance };
        let le = scale * map.eval(dir);
        if prev_delta { le } else { le * power_heuristic(prev_pdf, p_env * map.pdf(dir)) }
    }
}

/// Whether the shading frame and the geometry agree on what a scattering does: `wi` and `wo`
/// on the same side of the shading normal (`wi_n`, `wo_n`: their local z) exactly when they
/// are on the same side of the geometric surface (`wi_ng`, `wo_ng`), and `wi` not along it.
#[inline]
fn agrees(wi_ng: f32, wo_ng: f32, wi_n: f32, wo_n: f32) -> bool {
    ((wi_ng > 0.0) == (wo_ng > 0.0)) == ((wi_n > 0.0) == (wo_n > 0.0)) && wi_ng != 0.0
}
