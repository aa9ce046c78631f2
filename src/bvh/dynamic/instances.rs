//! Two levels: one BVH per distinct mesh, built once in object space, and a top-level
//! [`DynamicBvh`] over the instances, each a mesh under its own affine transform.
//!
//! An instance stores only its mesh index and transforms, so a mesh placed many times is stored
//! once. A ray reaching an instance's leaf is carried into object space by the inverse transform
//! (its direction is not renormalised, so distances `t` are the same in both spaces) and traced
//! through that mesh's BVH with the best distance so far as its limit.
//!
//! Per frame, [`TwoLevel::set_transforms`] moves instances by one of three strategies (the
//! animation benchmark compares them): the dynamic update (delete, clean, reinsert, local PRBVH,
//! with the quality monitor), a full rebuild of the top level, or a refit that keeps the topology.

use glam::{Affine3A, Vec3};

use crate::bvh::dynamic::{DynamicBvh, DynamicConfig, UpdateStats};
use crate::bvh::trace::{HitFilter, Skip, SkipReject};
use crate::bvh::{Bvh, MeshBvh};
use crate::geometry::{Aabb, Ray};

/// A hit on an instance's triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InstanceHit {
    pub t: f32,
    pub instance: u32,
    /// The triangle's id in its mesh.
    pub prim_id: u32,
    /// Barycentric coordinates of `v1` and `v2`.
    pub u: f32,
    pub v: f32,
}

/// One placement of a mesh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Instance {
    pub mesh: u32,
    pub world_from_object: Affine3A,
    pub object_from_world: Affine3A,
    /// Whether the placement mirrors (negative determinant), which flips its triangles'
    /// winding as placed ([`crate::geometry::Triangle::placed`]).
    pub mirrors: bool,
}

impl Instance {
    pub fn new(mesh: u32, world_from_object: Affine3A) -> Self {
        Self {
            mesh,
            world_from_object,
            object_from_world: world_from_object.inverse(),
            mirrors: crate::geometry::mirrors(&world_from_object),
        }
    }
}

/// How [`TwoLevel::set_transforms`] brings the top level up to date.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TopLevelUpdate {
    /// Delete the moved instances, clean, reinsert, local PRBVH, quality monitor.
    Dynamic(DynamicConfig),
    /// Build the top level anew (binned SAH) every time.
    Rebuild,
    /// Keep the topology and recompute the boxes above the moved instances.
    Refit,
}

/// Meshes, their instances, and the top-level tree.
#[derive(Debug)]
pub struct TwoLevel {
    meshes: Vec<MeshBvh>,
    instances: Vec<Instance>,
    boxes: Vec<Aabb>,
    tlas: DynamicBvh,
}

impl TwoLevel {
    /// Builds the top level over `instances` of `meshes` (each a BVH in object space).
    pub fn new(meshes: Vec<MeshBvh>, instances: Vec<Instance>) -> Self {
        assert!(instances.iter().all(|i| (i.mesh as usize) < meshes.len()), "instance of a missing mesh");
        let boxes: Vec<Aabb> = instances.iter().map(|i| world_box(&meshes[i.mesh as usize].bvh, i)).collect();
        let tlas = DynamicBvh::build(&boxes);
        Self { meshes, instances, boxes, tlas }
    }

    pub fn meshes(&self) -> &[MeshBvh] {
        &self.meshes
    }

    pub fn instances(&self) -> &[Instance] {
        &self.instances
    }

    /// The top-level tree.
    pub fn top_level(&self) -> &DynamicBvh {
        &self.tlas
    }

    /// Each instance's world-space box.
    pub fn instance_boxes(&self) -> &[Aabb] {
        &self.boxes
    }

    /// Bytes of the meshes' BVHs (binary and wide) and triangles, the instances and the top
    /// level.
    pub fn memory_bytes(&self) -> usize {
        self.meshes.iter().map(MeshBvh::memory_bytes).sum::<usize>()
            + size_of_val(&self.instances[..])
            + size_of_val(&self.boxes[..])
            + self.tlas.bvh().memory_bytes()
    }

    /// Moves instances to new transforms and updates the top level by `how`. Instances whose
    /// world box did not change cost nothing.
    pub fn set_transforms(&mut self, changes: &[(u32, Affine3A)], how: &TopLevelUpdate) -> UpdateStats {
        let start = std::time::Instant::now();
        let mut moves = Vec::with_capacity(changes.len());
        for &(i, m) in changes {
            let inst = &mut self.instances[i as usize];
            *inst = Instance::new(inst.mesh, m);
            let b = world_box(&self.meshes[inst.mesh as usize].bvh, inst);
            if b != self.boxes[i as usize] {
                self.boxes[i as usize] = b;
                moves.push((i, b));
            }
        }
        let mut stats = match how {
            TopLevelUpdate::Dynamic(config) => self.tlas.update(&moves, &self.boxes, config),
            TopLevelUpdate::Rebuild => {
                self.tlas = DynamicBvh::build(&self.boxes);
                UpdateStats { moved: moves.len(), rebuilt: true, ..Default::default() }
            }
            TopLevelUpdate::Refit => {
                for &(i, b) in &moves {
                    self.tlas.refit_leaf(i, b);
                }
                let clean_visits = self.tlas.clean();
                UpdateStats { moved: moves.len(), clean_visits, ..Default::default() }
            }
        };
        stats.sah_estimate = self.tlas.sah_estimate(&Default::default());
        stats.seconds = start.elapsed().as_secs_f64();
        stats
    }

    /// Takes `bvh` (one instance a leaf, over every instance's current box, as
    /// [`TwoLevel::instance_boxes`] gives them; built elsewhere, by the GPU's LBVH say) as the
    /// top level, in place of the one kept.
    pub fn replace_top_level(&mut self, bvh: &Bvh) {
        self.tlas = DynamicBvh::from_bvh(bvh, self.instances.len());
    }

    /// The closest hit with `0 < t <= t_max`; ties go to the lowest instance, then triangle id.
    pub fn closest_hit(&self, ray: &Ray, t_max: f32) -> Option<InstanceHit> {
        self.closest_hit_skipping(ray, t_max, None)
    }

    /// [`TwoLevel::closest_hit`] without testing triangle `skip = (instance, triangle)`: the
    /// one a spawned ray leaves ([`MeshBvh::closest_hit_skipping`]).
    pub fn closest_hit_skipping(&self, ray: &Ray, t_max: f32, skip: Option<(u32, u32)>) -> Option<InstanceHit> {
        self.closest_hit_with(ray, t_max, |i| Skip(skipped(skip, i)))
    }

    /// Whether anything is hit with `0 < t <= t_max`.
    pub fn any_hit(&self, ray: &Ray, t_max: f32) -> bool {
        self.any_hit_skipping(ray, t_max, None)
    }

    /// [`TwoLevel::any_hit`] without testing triangle `skip = (instance, triangle)`.
    pub fn any_hit_skipping(&self, ray: &Ray, t_max: f32, skip: Option<(u32, u32)>) -> bool {
        self.any_hit_with(ray, t_max, |i| Skip(skipped(skip, i)))
    }

    /// [`TwoLevel::closest_hit_skipping`] leaving out as well every hit `(instance, prim, u, v)`
    /// that `reject` refuses (cut-out texels).
    pub fn closest_hit_filtered<R: Fn(u32, u32, f32, f32) -> bool>(
        &self,
        ray: &Ray,
        t_max: f32,
        skip: Option<(u32, u32)>,
        reject: &R,
    ) -> Option<InstanceHit> {
        self.closest_hit_with(ray, t_max, |i| SkipReject(skipped(skip, i), move |prim, u, v| reject(i, prim, u, v)))
    }

    /// [`TwoLevel::any_hit_skipping`] counting only hits `(instance, prim, u, v)` that `reject`
    /// does not refuse.
    pub fn any_hit_filtered<R: Fn(u32, u32, f32, f32) -> bool>(
        &self,
        ray: &Ray,
        t_max: f32,
        skip: Option<(u32, u32)>,
        reject: &R,
    ) -> bool {
        self.any_hit_with(ray, t_max, |i| SkipReject(skipped(skip, i), move |prim, u, v| reject(i, prim, u, v)))
    }

    /// The closest hit, each instance `i` traced with the filter `filter(i)`.
    fn closest_hit_with<F: HitFilter>(&self, ray: &Ray, t_max: f32, filter: impl Fn(u32) -> F) -> Option<InstanceHit> {
        let bvh = self.tlas.bvh();
        if bvh.is_empty() {
            return None;
        }
        bvh.closest_hit(ray, t_max, |_, i, t_limit| {
            let inst = &self.instances[i as usize];
            let local = to_object(inst, ray);
            self.meshes[inst.mesh as usize]
                .closest_hit_filtered(&local, t_limit, &filter(i))
                .map(|h| (h.t, (h.prim_id, h.u, h.v)))
        })
        .map(|(instance, t, (prim_id, u, v))| InstanceHit { t, instance, prim_id, u, v })
    }

    /// Whether anything is hit, each instance `i` traced with the filter `filter(i)`.
    fn any_hit_with<F: HitFilter>(&self, ray: &Ray, t_max: f32, filter: impl Fn(u32) -> F) -> bool {
        let bvh = self.tlas.bvh();
        !bvh.is_empty()
            && bvh.any_hit(ray, t_max, |_, i, t_limit| {
                let inst = &self.instances[i as usize];
                self.meshes[inst.mesh as usize].any_hit_filtered(&to_object(inst, ray), t_limit, &filter(i))
            })
    }
}

/// The triangle of instance `i` to skip: `skip`'s, where `skip` names that instance.
#[inline]
fn skipped(skip: Option<(u32, u32)>, i: u32) -> u32 {
    skip.filter(|&(instance, _)| instance == i).map_or(crate::bvh::INVALID_INDEX, |(_, prim)| prim)
}

fn to_object(inst: &Instance, ray: &Ray) -> Ray {
    Ray::new(inst.object_from_world.transform_point3(ray.origin), inst.object_from_world.transform_vector3(ray.dir))
}

/// The world box of an instance: its mesh's root box with the eight corners transformed, grown
/// by a few ULPs of its coordinates so that rounding in the transform can never leave a point of
/// the mesh outside it. An instance of an empty mesh gets the point box at its origin.
pub fn world_box(mesh: &Bvh, inst: &Instance) -> Aabb {
    let b = mesh.bounds();
    if b.is_empty() {
        return Aabb::from_point(inst.world_from_object.translation.into());
    }
    let w = (0..8).fold(Aabb::EMPTY, |acc, k| acc.grow(inst.world_from_object.transform_point3(b.corner(k))));
    let pad = Vec3::splat(w.min.abs().max(w.max.abs()).max_element() * 8.0 * f32::EPSILON);
    Aabb::new(w.min - pad, w.max + pad)
}
