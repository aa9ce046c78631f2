//! Materials as the integrator uses them: a scene's material turned into a BSDF and an emission.

use glam::Vec3;

use super::bsdf::{Bsdf, ConductorFresnel as BsdfFresnel};
use crate::scene::{ConductorFresnel, Scattering};

/// A material as the integrator uses it.
#[derive(Clone, Copy, Debug)]
pub struct RenderMaterial {
    /// `None`: absorbs everything.
    pub bsdf: Option<Bsdf>,
    pub emission: Option<Vec3>,
    pub two_sided: bool,
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
        };
        Self { bsdf, emission: m.emission, two_sided: m.two_sided }
    }
}
