//! A triangle mesh's BVH with the triangles stored in leaf order.
//!
//! Traversal through `prim_ids` fetches each triangle of a leaf from wherever it sits in the
//! mesh; storing them in leaf order makes a leaf's triangles contiguous, one or two cache lines
//! instead of one miss each. Hits still report the mesh's own triangle ids.

use rayon::prelude::*;

use super::{Bvh, Hit};
use crate::geometry::{Ray, Triangle, WatertightRay};

/// A [`Bvh`] over triangles, with `triangles[k]` the triangle whose id is `bvh.prim_ids[k]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MeshBvh {
    pub bvh: Bvh,
    pub triangles: Vec<Triangle>,
}

impl MeshBvh {
    /// Pairs `bvh`, built over `triangles` (indexed by id), with a leaf-ordered copy of them.
    pub fn new(bvh: Bvh, triangles: &[Triangle]) -> Self {
        let ordered = bvh.prim_ids.par_iter().with_min_len(4096).map(|&p| triangles[p as usize]).collect();
        Self { bvh, triangles: ordered }
    }

    /// Closest hit with `0 < t <= t_max`; the same answer as [`Bvh::closest_hit_triangles`].
    pub fn closest_hit(&self, ray: &Ray, t_max: f32) -> Option<Hit> {
        let wr = WatertightRay::new(ray);
        self.bvh
            .closest_hit(ray, t_max, |pos, _, t_limit| {
                self.triangles[pos as usize].intersect(&wr, t_limit).map(|h| (h.t, (h.u, h.v)))
            })
            .map(|(prim_id, t, (u, v))| Hit { t, prim_id, u, v })
    }

    /// Whether any triangle is hit with `0 < t <= t_max`.
    pub fn any_hit(&self, ray: &Ray, t_max: f32) -> bool {
        let wr = WatertightRay::new(ray);
        self.bvh.any_hit(ray, t_max, |pos, _, t_limit| self.triangles[pos as usize].intersect(&wr, t_limit).is_some())
    }
}
