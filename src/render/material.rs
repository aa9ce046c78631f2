//! Materials as the integrator uses them: a scene's material turned into a BSDF and an emission.

use std::sync::Arc;

use glam::{Vec2, Vec3};

use super::bsdf::{Bsdf, ConductorFresnel as BsdfFresnel};
use super::geometry::SurfaceHit;
use crate::scene::{ConductorFresnel, Scattering};
use crate::texture::{Texture, TextureRef};

/// A material as the integrator uses it.
#[derive(Clone, Copy, Debug)]
pub struct RenderMaterial {
    /// `None`: absorbs everything.
    pub bsdf: Option<Bsdf>,
    pub emission: Option<Vec3>,
    pub two_sided: bool,
    /// Multiplies the diffuse albedo, the conductor's Schlick F0 or the coated material's base
    /// colour at the hit.
    pub base_color: Option<TextureRef>,
    /// The cut-out mask and its cutoff (the CPU's traversal reads them through
    /// [`super::geometry::Cutouts`], made from these).
    pub alpha: Option<(TextureRef, f32)>,
    /// A tangent-space normal map and the scale of its x and y.
    pub normal: Option<(TextureRef, f32)>,
    /// Multiplies `emission` at the hit.
    pub emission_tex: Option<TextureRef>,
    /// Multiply the coated material's perceptual roughness (α by its square) and metallic:
    /// the given channel of each texture.
    pub roughness: Option<(TextureRef, u8)>,
    pub metallic: Option<(TextureRef, u8)>,
}

impl RenderMaterial {
    pub fn from_scene(m: &crate::scene::Material) -> Self {
        let bsdf = match &m.scattering {
            Scattering::Black => None,
            Scattering::Diffuse { albedo } => Some(Bsdf::Diffuse { albedo: *albedo }),
            Scattering::Conductor { roughness, fresnel } => Some(Bsdf::Conductor {
                alpha: *roughness,
                fresnel: match fresnel {
                    ConductorFresnel::Complex { eta, k } => BsdfFresnel::Complex { eta: *eta, k: *k },
                    ConductorFresnel::BaseColor(c) => BsdfFresnel::Schlick { f0: *c },
                },
            }),
            Scattering::Dielectric { ior, roughness } => Some(Bsdf::Dielectric { alpha: *roughness, ior: *ior }),
            Scattering::Coated { base_color, metallic, alpha, ior } => {
                Some(Bsdf::Coated { base_color: *base_color, metallic: *metallic, alpha: *alpha, ior: *ior })
            }
        };
        Self {
            bsdf,
            emission: m.emission,
            two_sided: m.two_sided,
            base_color: m.textures.base_color,
            alpha: m.textures.alpha.map(|r| (r, m.textures.alpha_cutoff)),
            normal: m.textures.normal.map(|r| (r, m.textures.normal_scale)),
            emission_tex: m.textures.emission,
            roughness: m.textures.roughness,
            metallic: m.textures.metallic,
        }
    }

    /// Whether any texture is read at a hit on this material (the GPU's textured variant).
    pub fn is_textured(&self) -> bool {
        self.base_color.is_some()
            || self.alpha.is_some()
            || self.normal.is_some()
            || self.emission_tex.is_some()
            || self.roughness.is_some()
            || self.metallic.is_some()
    }

    /// The radiance emitted at a hit with texture coordinates `uv()` (computed only for a
    /// textured emission), or `None` for a material that does not emit.
    #[inline]
    pub fn emitted(&self, textures: &[Arc<Texture>], uv: impl FnOnce() -> Vec2) -> Option<Vec3> {
        let e = self.emission?;
        Some(match self.emission_tex {
            None => e,
            Some(r) => e * textures[r.texture as usize].sample(uv(), r.wrap, r.srgb).truncate(),
        })
    }

    /// The shading normal at `hit`: the vertex normals' (or `ng` where there are none), turned
    /// by the normal map where the material has one, and on `ng`'s side. Its tangent frame is the
    /// triangle's: the directions of increasing u and v in its plane, made orthonormal about the
    /// normal (Gram-Schmidt), the bitangent keeping the texture's handedness. `None` where there
    /// is no shading normal, or the map's is degenerate (a triangle whose texture coordinates
    /// span no area keeps its unmapped normal).
    pub fn shading_normal(&self, textures: &[Arc<Texture>], hit: &SurfaceHit, ng: Vec3) -> Option<Vec3> {
        let vertex = hit.shading_normal(ng);
        let Some((r, scale)) = self.normal else { return vertex };
        let n = vertex.unwrap_or(ng);
        let t = &hit.triangle;
        let (dp1, dp2) = (t.v1 - t.v0, t.v2 - t.v0);
        let (duv1, duv2) = (hit.uvs[1] - hit.uvs[0], hit.uvs[2] - hit.uvs[0]);
        let det = duv1.x * duv2.y - duv1.y * duv2.x;
        if det == 0.0 || !det.is_finite() {
            return vertex;
        }
        let (tangent, bitangent) = ((dp1 * duv2.y - dp2 * duv1.y) / det, (dp2 * duv1.x - dp1 * duv2.x) / det);
        let tangent = (tangent - n * n.dot(tangent)).normalize_or_zero();
        if tangent == Vec3::ZERO {
            return vertex;
        }
        let b = n.cross(tangent);
        let b = if b.dot(bitangent) < 0.0 { -b } else { b };
        let m = textures[r.texture as usize].sample(hit.uv(), r.wrap, false).truncate() * 2.0 - Vec3::ONE;
        let mapped = (tangent * (m.x * scale) + b * (m.y * scale) + n * m.z).normalize_or_zero();
        if mapped == Vec3::ZERO {
            return vertex;
        }
        Some(if mapped.dot(ng) < 0.0 { -mapped } else { mapped })
    }

    /// The BSDF at a hit with texture coordinates `uv()` (computed only for a textured
    /// material): the base colour, roughness and metallic textures applied.
    #[inline]
    pub fn bsdf_at(&self, textures: &[Arc<Texture>], uv: impl FnOnce() -> Vec2) -> Option<Bsdf> {
        let bsdf = self.bsdf?;
        if self.base_color.is_none() && self.roughness.is_none() && self.metallic.is_none() {
            return Some(bsdf);
        }
        let uv = uv();
        let channel = |(r, c): (TextureRef, u8)| textures[r.texture as usize].sample(uv, r.wrap, false)[c as usize];
        let bsdf = match bsdf {
            Bsdf::Coated { base_color, metallic, alpha, ior } => Bsdf::Coated {
                base_color,
                metallic: metallic * self.metallic.map_or(1.0, channel),
                alpha: alpha * self.roughness.map_or(1.0, |r| channel(r).powi(2)),
                ior,
            },
            other => other,
        };
        let Some(r) = self.base_color else { return Some(bsdf) };
        let c = textures[r.texture as usize].sample(uv, r.wrap, r.srgb).truncate();
        Some(match bsdf {
            Bsdf::Diffuse { albedo } => Bsdf::Diffuse { albedo: albedo * c },
            Bsdf::Conductor { alpha, fresnel: BsdfFresnel::Schlick { f0 } } => {
                Bsdf::Conductor { alpha, fresnel: BsdfFresnel::Schlick { f0: f0 * c } }
            }
            Bsdf::Coated { base_color, metallic, alpha, ior } => {
                Bsdf::Coated { base_color: base_color * c, metallic, alpha, ior }
            }
            other => other,
        })
    }
}
