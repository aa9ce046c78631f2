//! What the integrator traces rays against.
//!
//! - [`Geometry::Flat`]: every triangle in world space under one BVH. Static scenes take this
//!   path, so they pay nothing for instancing or animation.
//! - [`Geometry::Instanced`]: one BVH per distinct mesh, in object space, and a top-level
//!   [`TwoLevel`] tree over the objects. Animated scenes take it, and so do static scenes that
//!   place meshes many times, when flattening would store over a million triangles and more than
//!   twice what the distinct meshes hold: a flat tree traces faster, so it is given up only
//!   where memory matters.
//!
//! Both answer with a [`SurfaceHit`] carrying the hit triangle in world space, so shading is the
//! same code either way.

use std::sync::Arc;

use glam::{Affine3A, Vec2, Vec3};
use rayon::prelude::*;

use super::lights::{Emitter, Lights};
use super::material::RenderMaterial;
use crate::bvh::dynamic::UpdateStats;
use crate::bvh::dynamic::instances::{Instance, TopLevelUpdate, TwoLevel};
use crate::bvh::{INVALID_INDEX, MeshBvh, SkipReject};
use crate::geometry::{Ray, Triangle};
use crate::scene::Scene;
use crate::texture::{Texture, TextureRef};

/// A hit, resolved to what shading needs.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceHit {
    pub t: f32,
    /// The hit triangle in world space.
    pub triangle: Triangle,
    pub u: f32,
    pub v: f32,
    pub material: u32,
    /// The triangle's id in [`Lights`] (meaningful when its material emits).
    pub light: u32,
    /// Which triangle was hit, for rays spawned from it to skip.
    pub surface: Surface,
    /// The vertices' shading normals in world space, in `triangle`'s vertex order; zero where
    /// the mesh has none.
    pub normals: [Vec3; 3],
    /// The vertices' texture coordinates, in `triangle`'s vertex order; zero where the mesh has
    /// none or the scene has no textures.
    pub uvs: [Vec2; 3],
}

impl SurfaceHit {
    /// The shading normal at the hit: the vertex normals interpolated, normalised, and turned to
    /// the side of `ng` (the geometric normal, whose winding decides which side is the front);
    /// `None` where a vertex has none or they cancel.
    #[inline]
    pub fn shading_normal(&self, ng: Vec3) -> Option<Vec3> {
        let [a, b, c] = self.normals;
        if a == Vec3::ZERO || b == Vec3::ZERO || c == Vec3::ZERO {
            return None;
        }
        let n = ((1.0 - self.u - self.v) * a + self.u * b + self.v * c).normalize_or_zero();
        if n == Vec3::ZERO {
            return None;
        }
        Some(if n.dot(ng) < 0.0 { -n } else { n })
    }

    /// The texture coordinates at the hit.
    #[inline]
    pub fn uv(&self) -> Vec2 {
        interpolate(&self.uvs, self.u, self.v)
    }
}

/// The texture coordinates at barycentrics `(u, v)` (the weights of the second and third
/// vertex) of a triangle whose vertices have `uvs`.
#[inline]
pub(crate) fn interpolate(uvs: &[Vec2; 3], u: f32, v: f32) -> Vec2 {
    (1.0 - u - v) * uvs[0] + u * uvs[1] + v * uvs[2]
}

/// The cut-out masks of a scene's materials (`map_d`): a hit where a mask's coverage is below
/// its cutoff is no hit, for closest-hit and shadow rays alike. Absent where no material has
/// one, and then tracing is as it was.
#[derive(Debug)]
pub struct Cutouts {
    /// Each material's mask and cutoff, `None` for an opaque material.
    masks: Vec<Option<(TextureRef, f32)>>,
    textures: Vec<Arc<Texture>>,
}

impl Cutouts {
    /// The masks of `materials`, or `None` where none has one.
    pub fn of(materials: &[RenderMaterial], textures: &[Arc<Texture>]) -> Option<Self> {
        let masks: Vec<_> = materials.iter().map(|m| m.alpha).collect();
        masks.iter().any(Option::is_some).then(|| Self { masks, textures: textures.to_vec() })
    }

    /// Whether material `material` is cut out at barycentrics `(u, v)` of a triangle with
    /// texture coordinates `uvs`.
    #[inline]
    pub fn cut(&self, material: u32, uvs: &[Vec2; 3], u: f32, v: f32) -> bool {
        let Some(Some((r, cutoff))) = self.masks.get(material as usize) else { return false };
        self.textures[r.texture as usize].coverage(interpolate(uvs, u, v), r.wrap) < *cutoff
    }
}

/// A triangle of the scene: its instance (0 in a flat scene) and its id there. A ray spawned
/// from a triangle skips it ([`crate::bvh::MeshBvh::closest_hit_skipping`]): it cannot hit it,
/// and that test is the costliest one it would make.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Surface {
    pub instance: u32,
    pub prim: u32,
}

/// Flat world-space triangles.
#[derive(Debug)]
pub struct Flat {
    pub mesh: MeshBvh,
    /// World-space triangles by primitive id.
    pub triangles: Vec<Triangle>,
    pub material_of: Vec<u32>,
    /// Their vertices' shading normals by primitive id ([`Scene::world_normals_at`]), or empty.
    pub normals: Vec<[Vec3; 3]>,
    /// Their vertices' texture coordinates by primitive id ([`Scene::world_uvs_at`]), or empty.
    pub uvs: Vec<[Vec2; 3]>,
    pub cutouts: Option<Cutouts>,
}

/// Meshes in object space under a top-level tree of instances (one per scene object).
#[derive(Debug)]
pub struct Instanced {
    pub two_level: TwoLevel,
    /// Each mesh's triangles (object space) and materials, by triangle id.
    mesh_triangles: Vec<Vec<Triangle>>,
    mesh_materials: Vec<Vec<u32>>,
    /// Each mesh's vertex normals by triangle id (object space), or empty.
    mesh_normals: Vec<Vec<[Vec3; 3]>>,
    /// Each mesh's texture coordinates by triangle id, or empty (as for a scene without
    /// textures).
    mesh_uvs: Vec<Vec<[Vec2; 3]>>,
    cutouts: Option<Cutouts>,
    /// Each object's material override.
    instance_material: Vec<Option<u32>>,
    /// Each object's first light id, or `INVALID_INDEX` when none of its triangles emits.
    light_base: Vec<u32>,
}

/// The scene's geometry, flat or instanced (module docs).
#[derive(Debug)]
pub enum Geometry {
    Flat(Flat),
    Instanced(Instanced),
}

/// Whether `scene` is rendered with two levels: when it is animated, or when flattening would
/// store over 2^20 triangles and more than twice the triangles its distinct meshes hold.
pub fn wants_instancing(scene: &Scene) -> bool {
    if scene.is_animated() {
        return true;
    }
    let world: usize = scene.objects.iter().map(|o| scene.meshes[o.mesh].mesh.indices.len()).sum();
    let distinct: usize = scene.meshes.iter().map(|m| m.mesh.indices.len()).sum();
    world > 1 << 20 && world > 2 * distinct
}

impl Instanced {
    /// Instances of `meshes` (BVHs built over each scene mesh's object-space triangles, in
    /// scene order) placed as the scene's objects are at `time`.
    pub fn new(scene: &Scene, materials: &[RenderMaterial], meshes: Vec<MeshBvh>, time: f32) -> Self {
        let instances = scene
            .objects
            .iter()
            .map(|o| Instance::new(o.mesh as u32, Affine3A::from_mat4(o.world_from_object_at(time))))
            .collect();
        let mesh_triangles: Vec<Vec<Triangle>> = scene.meshes.iter().map(|m| m.mesh.triangles()).collect();
        let mesh_materials = scene.meshes.iter().map(|m| m.material_ids.clone()).collect();
        let mesh_normals = scene
            .meshes
            .iter()
            .map(|m| {
                let n = &m.mesh.normals;
                if n.is_empty() {
                    return Vec::new();
                }
                m.mesh.indices.iter().map(|t| t.map(|i| n[i as usize])).collect()
            })
            .collect();
        let instance_material = scene.objects.iter().map(|o| o.material).collect();
        let mesh_uvs = scene
            .meshes
            .iter()
            .map(|m| {
                if m.mesh.uvs.is_empty() || scene.textures.is_empty() {
                    return Vec::new();
                }
                m.mesh.indices.iter().map(|t| t.map(|i| m.mesh.uvs[i as usize])).collect()
            })
            .collect();
        Self {
            two_level: TwoLevel::new(meshes, instances),
            mesh_triangles,
            mesh_materials,
            mesh_normals,
            mesh_uvs,
            cutouts: Cutouts::of(materials, &scene.textures),
            instance_material,
            light_base: Vec::new(),
        }
    }

    /// Each mesh's object-space triangles by triangle id.
    pub fn mesh_triangles(&self) -> &[Vec<Triangle>] {
        &self.mesh_triangles
    }

    /// Each mesh's material ids by triangle id (`u32::MAX` where an object overrides them).
    pub fn mesh_materials(&self) -> &[Vec<u32>] {
        &self.mesh_materials
    }

    /// Each mesh's object-space vertex normals by triangle id, or empty.
    pub fn mesh_normals(&self) -> &[Vec<[Vec3; 3]>] {
        &self.mesh_normals
    }

    /// Each mesh's texture coordinates by triangle id, or empty.
    pub fn mesh_uvs(&self) -> &[Vec<[Vec2; 3]>] {
        &self.mesh_uvs
    }

    /// Each object's material override.
    pub fn instance_materials(&self) -> &[Option<u32>] {
        &self.instance_material
    }

    /// Each object's first light id ([`Instanced::lights`]; `INVALID_INDEX`: none of its
    /// triangles emits): its triangle `p` is light `base + p`.
    pub fn light_bases(&self) -> &[u32] {
        &self.light_base
    }

    fn material(&self, instance: usize, prim: u32) -> u32 {
        let mesh = self.two_level.instances()[instance].mesh as usize;
        self.instance_material[instance].unwrap_or(self.mesh_materials[mesh][prim as usize])
    }

    /// The lights: the world-space triangles of every object with an emissive triangle.
    pub fn lights(&mut self, materials: &[RenderMaterial], textures: &[Arc<Texture>]) -> Lights {
        let mut world = Vec::new();
        let mut emission = Vec::new();
        let mut light_base = vec![INVALID_INDEX; self.instance_material.len()];
        let emissive = |m: u32| materials[m as usize].emission.is_some();
        // A mesh's own ids may be `u32::MAX` (an OBJ triangle without an MTL material); every
        // object using such a mesh overrides its material, so those ids are never looked up.
        let mesh_emits: Vec<bool> =
            self.mesh_materials.iter().map(|ms| ms.iter().any(|&m| m != u32::MAX && emissive(m))).collect();
        for (i, inst) in self.two_level.instances().iter().enumerate() {
            let any = self.instance_material[i].map_or(mesh_emits[inst.mesh as usize], emissive);
            if !any {
                continue;
            }
            let tris = &self.mesh_triangles[inst.mesh as usize];
            let uvs = &self.mesh_uvs[inst.mesh as usize];
            light_base[i] = world.len() as u32;
            for (p, t) in tris.iter().enumerate() {
                world.push(t.placed(&inst.world_from_object, inst.mirrors));
                // In the placed triangle's vertex order, as `placed` gives it.
                let uvs = uvs.get(p).map(|&[a, b, c]| if inst.mirrors { [a, c, b] } else { [a, b, c] });
                emission.push(emitter(&materials[self.material(i, p as u32) as usize], uvs));
            }
        }
        self.light_base = light_base;
        Lights::new(&world, textures, |k| emission[k])
    }

    /// Moves the animated objects to their places at `time`.
    pub fn set_time(&mut self, scene: &Scene, time: f32, how: &TopLevelUpdate) -> UpdateStats {
        let changes: Vec<(u32, Affine3A)> = scene
            .objects
            .par_iter()
            .enumerate()
            .filter(|(_, o)| o.is_animated())
            .map(|(i, o)| (i as u32, Affine3A::from_mat4(o.world_from_object_at(time))))
            .collect();
        self.two_level.set_transforms(&changes, how)
    }

    /// Whether any animated object has an emissive triangle (its lights move with it). Known
    /// once [`Instanced::lights`] has run.
    pub fn moves_lights(&self, scene: &Scene) -> bool {
        scene.objects.iter().zip(&self.light_base).any(|(o, &base)| o.is_animated() && base != INVALID_INDEX)
    }
}

impl Geometry {
    /// The closest hit along `ray`.
    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Option<SurfaceHit> {
        self.intersect_from(ray, None)
    }

    /// The closest hit along `ray`, spawned from surface `from` (which it skips).
    #[inline]
    pub fn intersect_from(&self, ray: &Ray, from: Option<Surface>) -> Option<SurfaceHit> {
        match self {
            Geometry::Flat(f) => f.closest_hit(ray, from).map(|h| SurfaceHit {
                t: h.t,
                triangle: f.triangles[h.prim_id as usize],
                u: h.u,
                v: h.v,
                material: f.material_of[h.prim_id as usize],
                light: h.prim_id,
                surface: Surface { instance: 0, prim: h.prim_id },
                normals: f.normals.get(h.prim_id as usize).copied().unwrap_or([Vec3::ZERO; 3]),
                uvs: f.uvs.get(h.prim_id as usize).copied().unwrap_or([Vec2::ZERO; 3]),
            }),
            Geometry::Instanced(g) => g.closest_hit(ray, from).map(|h| {
                let inst = &g.two_level.instances()[h.instance as usize];
                let local = &g.mesh_triangles[inst.mesh as usize][h.prim_id as usize];
                let base = g.light_base.get(h.instance as usize).copied().unwrap_or(INVALID_INDEX);
                // A mirrored instance's triangle is placed with two vertices swapped, and the
                // hit's barycentrics with them.
                let mirrored = inst.mirrors;
                let (u, v) = if mirrored { (h.v, h.u) } else { (h.u, h.v) };
                let normals = match g.mesh_normals[inst.mesh as usize].get(h.prim_id as usize) {
                    Some(n) => {
                        // The inverse transpose of the placement: its inverse's linear part,
                        // transposed.
                        let m = inst.object_from_world.matrix3.transpose();
                        let [a, b, c] = n.map(|n| (m * n).normalize_or_zero());
                        if mirrored { [a, c, b] } else { [a, b, c] }
                    }
                    None => [Vec3::ZERO; 3],
                };
                let uvs = match g.mesh_uvs[inst.mesh as usize].get(h.prim_id as usize) {
                    Some(&[a, b, c]) if mirrored => [a, c, b],
                    Some(&uvs) => uvs,
                    None => [Vec2::ZERO; 3],
                };
                SurfaceHit {
                    t: h.t,
                    triangle: local.placed(&inst.world_from_object, mirrored),
                    u,
                    v,
                    material: g.material(h.instance as usize, h.prim_id),
                    light: if base == INVALID_INDEX { INVALID_INDEX } else { base + h.prim_id },
                    surface: Surface { instance: h.instance, prim: h.prim_id },
                    normals,
                    uvs,
                }
            }),
        }
    }

    /// Whether anything blocks `ray` with `0 < t <= t_max`.
    #[inline]
    pub fn occluded(&self, ray: &Ray, t_max: f32) -> bool {
        self.occluded_from(ray, t_max, None)
    }

    /// [`Geometry::occluded`] for a ray spawned from surface `from` (which it skips).
    #[inline]
    pub fn occluded_from(&self, ray: &Ray, t_max: f32, from: Option<Surface>) -> bool {
        match self {
            Geometry::Flat(f) => match &f.cutouts {
                None => f.mesh.any_hit_skipping(ray, t_max, skip_prim(from)),
                Some(c) => {
                    f.mesh.any_hit_filtered(ray, t_max, &SkipReject(skip_prim(from), |prim, u, v| f.cut(c, prim, u, v)))
                }
            },
            Geometry::Instanced(g) => match &g.cutouts {
                None => g.two_level.any_hit_skipping(ray, t_max, skip_pair(from)),
                Some(c) => {
                    g.two_level.any_hit_filtered(ray, t_max, skip_pair(from), &|i, prim, u, v| g.cut(c, i, prim, u, v))
                }
            },
        }
    }

    /// Triangles in the world (instances counted as many times as they are placed).
    pub fn world_triangle_count(&self) -> usize {
        match self {
            Geometry::Flat(f) => f.triangles.len(),
            Geometry::Instanced(g) => {
                g.two_level.instances().iter().map(|i| g.mesh_triangles[i.mesh as usize].len()).sum()
            }
        }
    }

    /// Bounds of the whole scene.
    pub fn bounds(&self) -> crate::geometry::Aabb {
        match self {
            Geometry::Flat(f) => f.mesh.bvh.bounds(),
            Geometry::Instanced(g) => g.two_level.top_level().bvh().bounds(),
        }
    }
}

impl Flat {
    fn closest_hit(&self, ray: &Ray, from: Option<Surface>) -> Option<crate::bvh::Hit> {
        let skip = skip_prim(from);
        match &self.cutouts {
            None => self.mesh.closest_hit_skipping(ray, f32::INFINITY, skip),
            Some(c) => self.mesh.closest_hit_filtered(
                ray,
                f32::INFINITY,
                &SkipReject(skip, |prim, u, v| self.cut(c, prim, u, v)),
            ),
        }
    }

    #[inline]
    fn cut(&self, c: &Cutouts, prim: u32, u: f32, v: f32) -> bool {
        let uvs = self.uvs.get(prim as usize).unwrap_or(&[Vec2::ZERO; 3]);
        c.cut(self.material_of[prim as usize], uvs, u, v)
    }
}

impl Instanced {
    fn closest_hit(&self, ray: &Ray, from: Option<Surface>) -> Option<crate::bvh::dynamic::instances::InstanceHit> {
        let skip = skip_pair(from);
        match &self.cutouts {
            None => self.two_level.closest_hit_skipping(ray, f32::INFINITY, skip),
            Some(c) => self
                .two_level
                .closest_hit_filtered(ray, f32::INFINITY, skip, &|i, prim, u, v| self.cut(c, i, prim, u, v)),
        }
    }

    /// Whether instance `i`'s triangle `prim` is cut out at `(u, v)`: barycentrics of the mesh's
    /// own vertex order, the one its texture coordinates are in.
    #[inline]
    fn cut(&self, c: &Cutouts, i: u32, prim: u32, u: f32, v: f32) -> bool {
        let mesh = self.two_level.instances()[i as usize].mesh as usize;
        let uvs = self.mesh_uvs[mesh].get(prim as usize).unwrap_or(&[Vec2::ZERO; 3]);
        c.cut(self.material(i as usize, prim), uvs, u, v)
    }
}

#[inline]
fn skip_prim(from: Option<Surface>) -> u32 {
    from.map_or(INVALID_INDEX, |s| s.prim)
}

#[inline]
fn skip_pair(from: Option<Surface>) -> Option<(u32, u32)> {
    from.map(|s| (s.instance, s.prim))
}

/// What a triangle of material `m` with texture coordinates `uvs` (if any) emits.
fn emitter(m: &RenderMaterial, uvs: Option<[Vec2; 3]>) -> Option<Emitter> {
    let texture = m.emission_tex.map(|r| (r, uvs.unwrap_or_default()));
    m.emission.map(|radiance| Emitter { radiance, two_sided: m.two_sided, texture })
}

/// The lights of a flat scene: its triangles, their materials and texture coordinates (empty
/// where no mesh has any).
pub(crate) fn flat_lights(
    triangles: &[Triangle],
    material_of: &[u32],
    uvs: &[[Vec2; 3]],
    materials: &[RenderMaterial],
    textures: &[Arc<Texture>],
) -> Lights {
    Lights::new(triangles, textures, |i| emitter(&materials[material_of[i] as usize], uvs.get(i).copied()))
}
