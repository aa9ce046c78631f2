//! Materials as the integrator uses them: a scene's material turned into a BSDF and an emission.

use std::sync::Arc;

use glam::{Vec2, Vec3};

use super::bsdf::{Bsdf, ConductorFresnel as BsdfFresnel};
use super::texture::{Texture, TextureRef};
use crate::scene::{ConductorFresnel, Scattering};

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
    /// The cut-out mask and its cutoff (the CPU reads them through
    /// [`super::geometry::Cutouts`], the GPU from here).
    pub alpha: Option<(TextureRef, f32)>,
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
        }
    }

    /// The BSDF at a hit with texture coordinates `uv()` (computed only for a textured
    /// material): the base colour texture applied.
    #[inline]
    pub fn bsdf_at(&self, textures: &[Arc<Texture>], uv: impl FnOnce() -> Vec2) -> Option<Bsdf> {
        let bsdf = self.bsdf?;
        let Some(r) = self.base_color else { return Some(bsdf) };
        let c = textures[r.texture as usize].sample(uv(), r.wrap, r.srgb).truncate();
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
