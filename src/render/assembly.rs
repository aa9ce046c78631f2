//! Scene assembly: a loaded [`Scene`] turned into the [`RenderScene`] the integrator reads, its
//! geometry under a BVH made by a named builder (flat), one BVH per mesh under a top-level tree
//! (instanced), or a tree made elsewhere (on the GPU, or by `auto`: [`super::auto`]).

use std::sync::Arc;
use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;

use super::camera::CameraModel;
use super::geometry::{Cutouts, Flat, Geometry, Instanced, flat_lights, wants_instancing};
use super::lights::Lights;
use super::material::RenderMaterial;
use crate::bvh::build::Builder;
use crate::bvh::build::prbvh::PrbvhConfig;
use crate::bvh::dynamic::instances::TopLevelUpdate;
use crate::bvh::{CollapseConfig, MeshBvh, Tracing, collapse_leaves, sah_cost};
use crate::geometry::Triangle;
use crate::scene::{Environment, Scene};
use crate::texture::Texture;
use crate::texture::environment::EnvironmentMap;

/// Everything a render reads: geometry and its BVH, materials, lights, camera.
pub struct RenderScene {
    pub geometry: Geometry,
    pub materials: Vec<RenderMaterial>,
    pub lights: Lights,
    /// Light from far away; `None` where it is black (a black map, or a scale of 0).
    pub environment: Option<Environment>,
    pub camera: CameraModel,
    /// The image textures materials use ([`Scene::textures`]).
    pub textures: Vec<Arc<Texture>>,
    pub width: u32,
    pub height: u32,
    /// Firefly clamp, off (`None`) unless the user asks (`render --clamp`): a sample whose
    /// largest channel exceeds it is scaled down to it. Biased (energy is lost), so never a
    /// default, and no accuracy test runs with it.
    pub sample_clamp: Option<f32>,
}

/// What building the acceleration structure cost.
#[derive(Clone, Debug)]
pub struct BuildReport {
    /// The whole build, the wide collapse included.
    pub build_ms: f64,
    pub sah: f64,
    pub triangles: usize,
    /// The builder used (for `auto`, what it decided).
    pub builder: String,
    /// How the CPU traces the scene (the binary form for a GPU render, which traces its own).
    pub tracing: Tracing,
    /// Of `build_ms`, the time spent collapsing binary trees into wide ones for tracing.
    pub collapse_ms: f64,
    /// The SAH of the traced form (the wide tree's where it is wide); for two levels, of the
    /// largest mesh's tree.
    pub traced_sah: f64,
}

/// The time of a scene's first frame (0 for a static scene).
pub fn first_frame_time(scene: &Scene) -> f32 {
    scene.animation.as_ref().map_or(0.0, |a| scene.frame_time(a.frames.start))
}

/// An environment map as a light: the map, its scale, and the probability that next-event
/// estimation picks it ([`RenderScene::environment_light`]).
pub type EnvLight<'a> = (&'a EnvironmentMap, Vec3, f32);

impl RenderScene {
    /// The environment map to sample for next-event estimation, if any, with the probability
    /// of choosing it over the area lights: 1 without area lights, else one half. (A map's
    /// power against the lights' depends on how much of the scene it reaches, which is unknown
    /// before rendering; one half never starves either.) A constant environment is found by
    /// BSDF sampling alone, as well as light sampling would.
    pub fn environment_light(&self) -> Option<EnvLight<'_>> {
        let env = self.environment.as_ref()?;
        let map = env.map.as_deref()?;
        Some((map, env.radiance, if self.lights.is_empty() { 1.0 } else { 0.5 }))
    }

    /// Builds the scene's geometry as it is at its first frame (static scenes: as it is).
    ///
    /// A static scene is flattened to world-space triangles under one BVH built with `builder`,
    /// then the default leaf collapse. An animated or heavily instanced scene
    /// ([`wants_instancing`]) gets one such BVH per distinct mesh, in object space, under a
    /// top-level tree of its objects. The trees are traced as `tracing` says ([`Tracing::gpu`]
    /// for a GPU render, which traces its own copy of the binary tree).
    pub fn build(scene: &Scene, builder: &Builder, tracing: Tracing) -> (Self, BuildReport) {
        if wants_instancing(scene) {
            return Self::build_instanced(scene, builder, tracing);
        }
        let t = Instant::now();
        let (triangles, material_of) = scene.world_triangles();
        let prims: Vec<_> = triangles.par_iter().map(Triangle::aabb).collect();
        let built = builder.build(&triangles, &prims, &PrbvhConfig { collapse: None, ..Default::default() });
        Self::assemble(scene, (triangles, material_of, 0.0), &built.bvh, t, builder.to_string(), tracing)
    }

    /// The two-level build (see [`RenderScene::build`]).
    pub(super) fn build_instanced(scene: &Scene, builder: &Builder, tracing: Tracing) -> (Self, BuildReport) {
        let t = Instant::now();
        let meshes: Vec<MeshBvh> =
            scene.meshes.iter().map(|m| builder.build_mesh(&m.mesh.triangles(), tracing)).collect();
        let objects = scene.objects.len();
        Self::assemble_instanced(
            scene,
            meshes,
            t,
            format!("two levels: {builder} per mesh, binned-sah over {objects} objects"),
            tracing,
        )
    }

    /// The rest of a two-level build from each scene mesh's tree (in scene order, built here or
    /// on the GPU: `arbor::gpu::build_instanced_for`) and traced as `tracing` says: the top level
    /// over the objects placed at the first frame, materials, lights, camera. The report's time
    /// runs from `start`.
    pub fn assemble_instanced(
        scene: &Scene,
        meshes: Vec<MeshBvh>,
        start: Instant,
        builder: String,
        tracing: Tracing,
    ) -> (Self, BuildReport) {
        let t = start;
        let materials: Vec<RenderMaterial> = scene.materials.iter().map(RenderMaterial::from_scene).collect();
        let mut instanced = Instanced::new(scene, &materials, meshes, first_frame_time(scene));
        let lights = instanced.lights(&materials, &scene.textures);
        let geometry = Geometry::Instanced(instanced);
        let Geometry::Instanced(g) = &geometry else { unreachable!() };
        let meshes = g.two_level.meshes();
        let largest = meshes.iter().max_by_key(|m| m.triangles.len());
        let report = BuildReport {
            tracing: largest.map_or(tracing, MeshBvh::tracing),
            collapse_ms: meshes.iter().map(MeshBvh::collapse_seconds).sum::<f64>() * 1e3,
            traced_sah: largest.map_or(0.0, |m| m.traced_sah(&Default::default())),
            build_ms: t.elapsed().as_secs_f64() * 1e3,
            sah: g.two_level.top_level().sah_estimate(&Default::default()),
            triangles: geometry.world_triangle_count(),
            builder,
        };
        (Self::with_geometry(scene, geometry, materials, lights), report)
    }

    /// The rest of a flat build from a tree with one primitive per leaf over `triangles` (built
    /// here, or on the GPU: `arbor::gpu::build_render_scene`), the scene's world triangles and
    /// materials at `time`: leaf collapse, the form the CPU traces (`tracing`; a GPU render
    /// needs only the binary tree), shading normals, materials, lights, camera. The report's
    /// time runs from `start`.
    pub fn assemble(
        scene: &Scene,
        (triangles, material_of, time): (Vec<Triangle>, Vec<u32>, f32),
        leaf1: &crate::bvh::Bvh,
        start: Instant,
        builder: String,
        tracing: Tracing,
    ) -> (Self, BuildReport) {
        let bvh = collapse_leaves(leaf1, &CollapseConfig::default());
        let sah = sah_cost(&bvh);
        let mesh = MeshBvh::new(bvh, &triangles, tracing);
        let (tracing, collapse_ms, traced_sah) =
            (mesh.tracing(), mesh.collapse_seconds() * 1e3, mesh.traced_sah(&Default::default()));
        let materials: Vec<RenderMaterial> = scene.materials.iter().map(RenderMaterial::from_scene).collect();
        let (normals, uvs) = (scene.world_normals_at(time), scene.world_uvs_at(time));
        let lights = flat_lights(&triangles, &material_of, &uvs, &materials, &scene.textures);
        let report = BuildReport {
            build_ms: start.elapsed().as_secs_f64() * 1e3,
            sah,
            triangles: triangles.len(),
            builder,
            tracing,
            collapse_ms,
            traced_sah,
        };
        let cutouts = Cutouts::of(&materials, &scene.textures);
        let geometry = Geometry::Flat(Flat { mesh, triangles, material_of, normals, uvs, cutouts });
        (Self::with_geometry(scene, geometry, materials, lights), report)
    }

    fn with_geometry(scene: &Scene, geometry: Geometry, materials: Vec<RenderMaterial>, lights: Lights) -> Self {
        Self {
            geometry,
            materials,
            lights,
            environment: scene
                .environment
                .clone()
                .filter(|e| e.radiance.max_element() > 0.0 && !e.map.as_ref().is_some_and(|m| m.is_black())),
            camera: CameraModel::new(&scene.camera),
            textures: scene.textures.clone(),
            width: scene.camera.width,
            height: scene.camera.height,
            sample_clamp: None,
        }
    }

    /// Moves an animated scene's objects to where they are at `time`, updating the top-level
    /// tree by `how`, and the lights. Returns what the update cost. A flat (static) scene does
    /// not change.
    pub fn set_time(
        &mut self,
        scene: &Scene,
        time: f32,
        how: &TopLevelUpdate,
    ) -> Option<crate::bvh::dynamic::UpdateStats> {
        let Geometry::Instanced(g) = &mut self.geometry else { return None };
        let stats = g.set_time(scene, time, how);
        if g.moves_lights(scene) {
            self.lights = g.lights(&self.materials, &self.textures);
        }
        Some(stats)
    }
}
