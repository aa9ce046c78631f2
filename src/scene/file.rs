//! The scene file as written: serde structs mirroring the TOML, every leaf `Spanned` so that
//! checks after parsing can still name the line. Unknown keys are rejected here.

use std::collections::BTreeMap;

use serde::Deserialize;
use toml::Spanned;

pub(super) type S<T> = Spanned<T>;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SceneFile {
    pub camera: S<CameraFile>,
    pub render: Option<S<RenderFile>>,
    pub environment: Option<S<EnvironmentFile>>,
    #[serde(default)]
    pub materials: BTreeMap<String, S<MaterialFile>>,
    #[serde(default)]
    pub objects: Vec<S<ObjectFile>>,
    pub animation: Option<S<AnimationFile>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct CameraFile {
    pub position: S<[f32; 3]>,
    pub look_at: S<[f32; 3]>,
    pub up: Option<S<[f32; 3]>>,
    pub fov: S<f32>,
    pub resolution: S<[u32; 2]>,
    pub aperture: Option<S<f32>>,
    pub focus_distance: Option<S<f32>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RenderFile {
    pub spp: Option<S<u32>>,
    pub max_depth: Option<S<u32>>,
    pub seed: Option<S<u64>>,
    pub time: Option<S<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct EnvironmentFile {
    pub radiance: S<[f32; 3]>,
}

/// Every key any material type takes; which ones a type allows is checked when building.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct MaterialFile {
    #[serde(rename = "type")]
    pub kind: S<String>,
    pub albedo: Option<S<[f32; 3]>>,
    pub radiance: Option<S<[f32; 3]>>,
    pub two_sided: Option<S<bool>>,
    pub roughness: Option<S<f32>>,
    pub eta: Option<S<[f32; 3]>>,
    pub k: Option<S<[f32; 3]>>,
    pub base_color: Option<S<[f32; 3]>>,
    pub ior: Option<S<f32>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ObjectFile {
    pub mesh: Option<S<String>>,
    pub shape: Option<S<String>>,
    pub subdivisions: Option<S<u32>>,
    pub triangles: Option<S<u64>>,
    pub seed: Option<S<u64>>,
    pub material: Option<S<String>>,
    pub translate: Option<S<[f32; 3]>>,
    pub rotate: Option<S<[f32; 3]>>,
    pub scale: Option<S<ScaleFile>>,
    pub matrix: Option<S<[[f32; 4]; 4]>>,
    pub keyframes: Option<S<Vec<S<KeyframeFile>>>>,
    pub scatter: Option<S<ScatterFile>>,
}

#[derive(Deserialize)]
#[serde(untagged)]
pub(super) enum ScaleFile {
    Uniform(f32),
    PerAxis([f32; 3]),
}

/// Required keys are `Option` here so that a missing one is reported at its table's line.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct AnimationFile {
    pub fps: Option<S<f32>>,
    pub frames: Option<S<[u32; 2]>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct KeyframeFile {
    pub time: Option<S<f32>>,
    pub translate: Option<S<[f32; 3]>>,
    pub rotate: Option<S<[f32; 3]>>,
    pub scale: Option<S<ScaleFile>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ScatterFile {
    pub count: Option<S<u64>>,
    pub seed: Option<S<u64>>,
    pub min: Option<S<[f32; 3]>>,
    pub max: Option<S<[f32; 3]>>,
    pub moving: Option<S<f32>>,
    pub radius: Option<S<f32>>,
    pub period: Option<S<f32>>,
}
