//! Ray traversal: closest hit and any hit, plus brute-force references. This module traverses
//! the binary tree; [`wide`] and [`wide_mesh`] the 4- and 8-wide trees collapsed from it, with the
//! kernels of each instruction set in [`simd`]; [`MeshBvh`] pairs a mesh's tree with the form
//! it is traced in.
//!
//! Stack-based, near child first: at an internal node both children's boxes are tested (they are
//! adjacent in memory), the nearer is visited next and the farther pushed with its entry
//! distance, so it can be skipped on pop once a closer hit is known.
//!
//! Exactness against brute force: among hits at equal `t` the lowest primitive id wins, in both
//! traversal and brute force, so duplicate triangles give one answer. A box is skipped only when
//! its entry distance exceeds the best `t` by more than a slack ([`cull_limit`]): the box entry
//! and a triangle's `t` come from different formulas, and the triangle's `t` carries an absolute
//! error proportional to its vertices' distance from the ray origin (the watertight test
//! computes `t` as a weighted mean of the vertices' sheared depths). So the slack has a relative
//! term, and an absolute term of [`CULL_ABS_ULPS`] ULPs of the farthest scene point seen from
//! the origin. The slack only decides which boxes are opened, never which hits are accepted;
//! only triangles hit at grazing angles, whose `t` has no useful error bound, may still differ.

mod mesh_bvh;
pub mod simd;
pub mod wide;
pub mod wide_mesh;

pub use mesh_bvh::MeshBvh;
pub use simd::{SimdPath, TraceLayout, Tracing};

use glam::Vec3;

use crate::bvh::{Bvh, BvhNode};
use crate::geometry::{Ray, RayInv, Triangle, WatertightRay, intersect_ray_packed};

/// Relative slack on the best hit distance when culling boxes.
pub const CULL_SCALE: f32 = 1.0 + 1.0 / 65536.0;
/// Absolute slack when culling boxes, in ULPs of the distance from the ray origin to the farthest
/// corner of the tree's bounds.
pub const CULL_ABS_ULPS: f32 = 64.0;

/// How far past `t` a box may begin and still be opened, for `ray` and a tree bounded by
/// `bounds`: `CULL_ABS_ULPS` ULPs of the distance from the origin to the tree's farthest corner,
/// in units of the direction's length. Computed in f32 with norms that bound the Euclidean ones
/// from the safe side (the sum of the corner's coordinates, the direction's largest coordinate,
/// and 1% on top for the rounding), so it is never below the exact value and costs no square
/// root; it only decides which boxes are opened. Where that quotient leaves f32's normal range
/// (scenes and directions of very different scales), it is computed as before, from Euclidean
/// lengths in f64, whose squares neither overflow nor underflow.
#[inline]
pub(super) fn cull_slack(bounds: &crate::geometry::Aabb, ray: &Ray) -> f32 {
    let far = (bounds.min - ray.origin).abs().max((bounds.max - ray.origin).abs());
    let slack = CULL_ABS_ULPS * f32::EPSILON * 1.01 * ((far.x + far.y + far.z) / ray.dir.abs().max_element());
    if slack.is_normal() {
        return slack;
    }
    let exact =
        (f64::from(CULL_ABS_ULPS * f32::EPSILON) * far.as_dvec3().length() / ray.dir.as_dvec3().length()) as f32;
    // Undefined (a zero direction): open every box.
    if exact.is_nan() { f32::INFINITY } else { exact }
}

/// The box-culling limit for a best distance `t` (see the module docs).
#[inline]
pub(super) fn cull_limit(t: f32, slack: f32) -> f32 {
    t * CULL_SCALE + slack
}

/// Entries the stack holds before spilling to the heap: LBVH trees are at most 60 + 32 deep, but
/// the optimiser can deepen a tree without bound, so depth is not capped here.
const STACK_SIZE: usize = 64;

/// The closest hit on a triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f32,
    pub prim_id: u32,
    /// Barycentric coordinates of `v1` and `v2`.
    pub u: f32,
    pub v: f32,
}

/// What a mesh traversal leaves out ([`crate::bvh::MeshBvh::closest_hit_filtered`]): the primitive a
/// spawned ray leaves ([`Skip`]), and with it every hit a predicate refuses ([`SkipReject`]:
/// cut-out texels).
pub trait HitFilter {
    /// Whether [`HitFilter::reject`] reads the barycentrics: where it does not, a shadow ray's
    /// test need not compute them.
    const USES_UV: bool;
    /// Whether primitive `prim` is left out before it is intersected (the surface a ray
    /// leaves: it cannot hit it, and that test is the costliest it would make).
    fn skips(&self, prim: u32) -> bool;
    /// Whether the hit on primitive `prim` at barycentrics `(u, v)` does not count; asked only
    /// where [`HitFilter::USES_UV`].
    fn reject(&self, prim: u32, u: f32, v: f32) -> bool;
}

/// Leaves out one primitive ([`crate::bvh::INVALID_INDEX`]: none).
#[derive(Clone, Copy, Debug)]
pub struct Skip(pub u32);

impl HitFilter for Skip {
    const USES_UV: bool = false;
    #[inline(always)]
    fn skips(&self, prim: u32) -> bool {
        prim == self.0
    }
    #[inline(always)]
    fn reject(&self, _: u32, _: f32, _: f32) -> bool {
        false
    }
}

/// Leaves out primitive `.0` ([`crate::bvh::INVALID_INDEX`]: none), and every hit `(prim, u, v)` for
/// which the function holds.
#[derive(Clone, Copy, Debug)]
pub struct SkipReject<F>(pub u32, pub F);

impl<F: Fn(u32, f32, f32) -> bool> HitFilter for SkipReject<F> {
    const USES_UV: bool = true;
    #[inline(always)]
    fn skips(&self, prim: u32) -> bool {
        prim == self.0
    }
    #[inline(always)]
    fn reject(&self, prim: u32, u: f32, v: f32) -> bool {
        (self.1)(prim, u, v)
    }
}

/// A traversal stack of `SIZE` entries in place, spilling to the heap only for unusually deep
/// trees, so that no traversal allocates in the common case. Shared by the binary and the wide
/// traversal.
pub(super) struct Stack<T: Copy, const SIZE: usize> {
    fixed: [std::mem::MaybeUninit<T>; SIZE],
    len: usize,
    spill: Vec<T>,
}

impl<T: Copy, const SIZE: usize> Stack<T, SIZE> {
    /// An empty stack. Its slots are left uninitialised: filling them cost as much as a
    /// short traversal.
    #[inline]
    pub(super) fn new() -> Self {
        Self { fixed: [const { std::mem::MaybeUninit::uninit() }; SIZE], len: 0, spill: Vec::new() }
    }

    #[inline]
    pub(super) fn push(&mut self, entry: T) {
        if self.len < SIZE {
            self.fixed[self.len].write(entry);
            self.len += 1;
        } else {
            self.spill.push(entry);
        }
    }

    #[inline]
    pub(super) fn pop(&mut self) -> Option<T> {
        if let Some(e) = self.spill.pop() {
            return Some(e);
        }
        if self.len == 0 {
            return None;
        }
        self.len -= 1;
        // SAFETY: every slot below `len` was written by `push` (`len` only grows there).
        Some(unsafe { self.fixed[self.len].assume_init() })
    }
}

/// One leaf of a closest-hit traversal: intersects the primitives at `range` of `prim_ids` and
/// keeps the closest hit in `best` (`t` below the best so far, or equal with a lower id), the
/// culling `limit` following it; `(t_max, slack)` are the ray's. Shared by the binary and the
/// wide traversal, so that both resolve ties alike.
#[inline(always)]
pub(super) fn closest_in_leaf<H>(
    range: std::ops::Range<u32>,
    prim_ids: &[u32],
    (t_max, slack): (f32, f32),
    best: &mut Option<(u32, f32, H)>,
    limit: &mut f32,
    intersect: &mut impl FnMut(u32, u32, f32) -> Option<(f32, H)>,
) {
    for pos in range {
        let prim = prim_ids[pos as usize];
        let t_limit = best.as_ref().map_or(t_max, |b| b.1);
        let Some((t, payload)) = intersect(pos, prim, t_limit) else { continue };
        let better = best.as_ref().is_none_or(|&(bp, bt, _)| t < bt || (t == bt && prim < bp));
        if better {
            *best = Some((prim, t, payload));
            *limit = cull_limit(t, slack);
        }
    }
}

/// The watertight test on `triangles` (indexed by primitive id) as a traversal's `intersect`,
/// with the barycentrics as payload.
pub(super) fn triangle_by_id<'a>(
    triangles: &'a [Triangle],
    wr: &'a WatertightRay,
) -> impl FnMut(u32, u32, f32) -> Option<(f32, (f32, f32))> + 'a {
    |_, prim, t_limit| triangles[prim as usize].intersect(wr, t_limit).map(|h| (h.t, (h.u, h.v)))
}

impl Hit {
    /// The hit a traversal with [`triangle_by_id`]'s payload returns.
    pub(super) fn from_traversal((prim_id, t, (u, v)): (u32, f32, (f32, f32))) -> Self {
        Hit { t, prim_id, u, v }
    }
}

impl Bvh {
    /// Closest primitive hit by `ray` with `0 < t <= t_max`, ties going to the lowest id.
    ///
    /// `intersect(leaf_pos, prim_id, t_limit)` returns the hit distance on primitive `prim_id`
    /// (which sits at `prim_ids[leaf_pos]`; primitives stored in leaf order are indexed by
    /// `leaf_pos`) and any payload, if it is hit with `0 < t <= t_limit`; it must compute `t`
    /// independently of `t_limit`. Returns `(prim_id, t, payload)`.
    pub fn closest_hit<H>(
        &self,
        ray: &Ray,
        t_max: f32,
        mut intersect: impl FnMut(u32, u32, f32) -> Option<(f32, H)>,
    ) -> Option<(u32, f32, H)> {
        let inv = ray.inv();
        let mut best: Option<(u32, f32, H)> = None;
        let slack = cull_slack(&self.bounds(), ray);
        let mut limit = cull_limit(t_max, slack);
        self.traverse(&inv, &mut limit, |n, bvh, limit| {
            let range = n.first..n.first + n.prim_count;
            closest_in_leaf(range, &bvh.prim_ids, (t_max, slack), &mut best, limit, &mut intersect);
            false
        });
        best
    }

    /// Whether any primitive is hit with `0 < t <= t_max`; stops at the first one found.
    /// `intersect(leaf_pos, prim_id, t_max)` as for [`Bvh::closest_hit`].
    pub fn any_hit(&self, ray: &Ray, t_max: f32, mut intersect: impl FnMut(u32, u32, f32) -> bool) -> bool {
        let inv = ray.inv();
        let mut limit = cull_limit(t_max, cull_slack(&self.bounds(), ray));
        let mut found = false;
        self.traverse(&inv, &mut limit, |n, bvh, _| {
            found = n.prim_range().any(|pos| intersect(pos as u32, bvh.prim_ids[pos], t_max));
            found
        });
        found
    }

    /// The shared loop: calls `leaf(node, self, &mut limit)` for every leaf whose box the ray
    /// enters before `limit`, nearer boxes first; stops when `leaf` returns true.
    #[inline(always)]
    fn traverse(&self, ray: &RayInv, limit: &mut f32, mut leaf: impl FnMut(&BvhNode, &Bvh, &mut f32) -> bool) {
        // Dereferenced once: each `Nodes` dereference rebuilds the slice.
        let nodes: &[BvhNode] = &self.nodes;
        let Some(root) = nodes.first() else { return };
        if root.aabb().intersect_ray(ray, *limit).is_none() {
            return;
        }
        let mut stack = Stack::<(u32, f32), STACK_SIZE>::new();
        let mut node = root;
        loop {
            if node.is_leaf() {
                if leaf(node, self, limit) {
                    return;
                }
            } else {
                let (l, r) = (node.first as usize, node.first as usize + 1);
                let (nl, nr) = (&nodes[l], &nodes[r]);
                let tl = intersect_ray_packed(nl.as_floats(), ray, *limit);
                let tr = intersect_ray_packed(nr.as_floats(), ray, *limit);
                match (tl, tr) {
                    (Some(tl), Some(tr)) => {
                        let (near, far, t_far) = if tl <= tr { (nl, r, tr) } else { (nr, l, tl) };
                        stack.push((far as u32, t_far));
                        node = near;
                        continue;
                    }
                    (Some(_), None) => {
                        node = nl;
                        continue;
                    }
                    (None, Some(_)) => {
                        node = nr;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            // Pop the next node still in range.
            loop {
                let Some((i, t_enter)) = stack.pop() else { return };
                if t_enter <= *limit {
                    node = &nodes[i as usize];
                    break;
                }
            }
        }
    }

    /// Closest triangle hit: [`Bvh::closest_hit`] with the watertight triangle test, over the
    /// triangles the tree was built on (indexed by primitive id).
    pub fn closest_hit_triangles(&self, triangles: &[Triangle], ray: &Ray, t_max: f32) -> Option<Hit> {
        let wr = WatertightRay::new(ray);
        self.closest_hit(ray, t_max, triangle_by_id(triangles, &wr)).map(Hit::from_traversal)
    }

    /// Whether any triangle is hit with `0 < t <= t_max` (shadow rays).
    pub fn any_hit_triangles(&self, triangles: &[Triangle], ray: &Ray, t_max: f32) -> bool {
        let wr = WatertightRay::new(ray);
        self.any_hit(ray, t_max, |_, prim, t_limit| triangles[prim as usize].intersect(&wr, t_limit).is_some())
    }
}

/// Closest hit by testing every triangle: the reference traversal is checked against.
pub fn brute_force_closest(triangles: &[Triangle], ray: &Ray, t_max: f32) -> Option<Hit> {
    let wr = WatertightRay::new(ray);
    let mut best: Option<Hit> = None;
    for (i, tri) in triangles.iter().enumerate() {
        if let Some(h) = tri.intersect(&wr, t_max) {
            if best.is_none_or(|b| h.t < b.t) {
                best = Some(Hit { t: h.t, prim_id: i as u32, u: h.u, v: h.v });
            }
        }
    }
    best
}

/// Whether any triangle is hit, by testing every one.
pub fn brute_force_any(triangles: &[Triangle], ray: &Ray, t_max: f32) -> bool {
    let wr = WatertightRay::new(ray);
    triangles.iter().any(|t| t.intersect(&wr, t_max).is_some())
}

/// A hit's position from barycentrics (more accurate than `ray.at(t)`), a bound on its rounding
/// error ([`Triangle::point_with_error`]), and the unit geometric normal.
pub fn hit_point_and_normal(triangles: &[Triangle], hit: &Hit) -> (Vec3, Vec3, Vec3) {
    let tri = &triangles[hit.prim_id as usize];
    let (p, err) = tri.point_with_error(hit.u, hit.v);
    (p, err, tri.unit_normal())
}
