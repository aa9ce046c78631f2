//! A triangle mesh's BVH with the triangles stored in leaf order, and the form it is traced in.
//!
//! Traversal through `prim_ids` fetches each triangle of a leaf from wherever it sits in the
//! mesh; storing them in leaf order makes a leaf's triangles contiguous, one or two cache lines
//! instead of one miss each. Hits still report the mesh's own triangle ids.
//!
//! The binary tree stays what builders, PRBVH and refits work on. The caller says how a mesh is
//! traced ([`Tracing`], chosen once at the edge: `render --trace`, `ARBOR_SIMD`): through the
//! binary tree, or through a wide tree collapsed from it, with its triangles in packets
//! ([`WideMesh`]): by default 8 wide on AVX2, 4 wide on SSE4.1 and NEON, and the binary tree on
//! the portable path ([`Tracing::best`]). Every form returns the same hits, bit for bit.

use rayon::prelude::*;

use crate::bvh::trace::simd::{TraceLayout, Tracing};
use crate::bvh::trace::wide_mesh::WideMesh;
use crate::bvh::trace::{HitFilter, Skip};
use crate::bvh::{Bvh, Hit, INVALID_INDEX, SahCosts};
use crate::geometry::{Ray, Triangle, WatertightRay};

/// A [`Bvh`] over triangles, with `triangles[k]` the triangle whose id is `bvh.prim_ids[k]`, and
/// the wide form it is traced through, if any.
#[derive(Clone, Debug)]
pub struct MeshBvh {
    pub bvh: Bvh,
    pub triangles: Vec<Triangle>,
    wide: Wide,
    collapse_seconds: f64,
}

#[derive(Clone, Debug, PartialEq)]
enum Wide {
    None,
    Four(WideMesh<4>),
    Eight(WideMesh<8>),
}

/// Equal trees, triangles and traced forms; the collapse's timing is not compared.
impl PartialEq for MeshBvh {
    fn eq(&self, other: &Self) -> bool {
        (&self.bvh, &self.triangles, &self.wide) == (&other.bvh, &other.triangles, &other.wide)
    }
}

/// The empty tree, traced as the binary form (there is nothing to collapse).
impl Default for MeshBvh {
    fn default() -> Self {
        Self::new(Bvh::default(), &[], Tracing::gpu())
    }
}

impl MeshBvh {
    /// Pairs `bvh`, built over `triangles` (indexed by id), with a leaf-ordered copy of them, and
    /// derives the form `tracing` names (a path this CPU lacks is replaced by the best one it
    /// has).
    pub fn new(bvh: Bvh, triangles: &[Triangle], tracing: Tracing) -> Self {
        let ordered: Vec<Triangle> =
            bvh.prim_ids.par_iter().with_min_len(4096).map(|&p| triangles[p as usize]).collect();
        let start = std::time::Instant::now();
        let wide = match tracing.layout {
            TraceLayout::Binary => Wide::None,
            TraceLayout::Wide4 => Wide::Four(WideMesh::from_binary(&bvh, &ordered, tracing.simd)),
            TraceLayout::Wide8 => Wide::Eight(WideMesh::from_binary(&bvh, &ordered, tracing.simd)),
        };
        let collapse_seconds = start.elapsed().as_secs_f64();
        Self { bvh, triangles: ordered, wide, collapse_seconds }
    }

    /// How this mesh is traced: its form and SIMD path (scalar for the binary form).
    pub fn tracing(&self) -> Tracing {
        let (layout, simd) = match &self.wide {
            Wide::None => (TraceLayout::Binary, crate::bvh::SimdPath::Scalar),
            Wide::Four(w) => (TraceLayout::Wide4, w.simd()),
            Wide::Eight(w) => (TraceLayout::Wide8, w.simd()),
        };
        Tracing { layout, simd }
    }

    /// Seconds spent collapsing the binary tree into the wide one and packing its triangles
    /// (zero for the binary form): part of every render's BVH time.
    pub fn collapse_seconds(&self) -> f64 {
        self.collapse_seconds
    }

    /// The SAH of the traced form: the wide tree's ([`crate::bvh::trace::wide::WideBvh::sah`]) or the binary
    /// tree's.
    pub fn traced_sah(&self, costs: &SahCosts) -> f64 {
        match &self.wide {
            Wide::None => crate::bvh::sah_cost_with(&self.bvh, costs),
            Wide::Four(w) => w.sah(costs),
            Wide::Eight(w) => w.sah(costs),
        }
    }

    /// Bytes of the wide form (nodes and triangle packets); zero for the binary form.
    pub fn wide_memory_bytes(&self) -> usize {
        match &self.wide {
            Wide::None => 0,
            Wide::Four(w) => w.memory_bytes(),
            Wide::Eight(w) => w.memory_bytes(),
        }
    }

    /// Bytes of everything kept to trace: the binary tree, the leaf-ordered triangles and the
    /// wide form.
    pub fn memory_bytes(&self) -> usize {
        self.bvh.memory_bytes() + size_of_val(self.triangles.as_slice()) + self.wide_memory_bytes()
    }

    /// Checks the wide form against the triangles' boxes (by id); `Ok` for the binary form.
    pub fn validate_wide(
        &self,
        prim_aabbs: &[crate::geometry::Aabb],
    ) -> Result<(), crate::bvh::trace::wide::WideValidationError> {
        match &self.wide {
            Wide::None => Ok(()),
            Wide::Four(w) => w.validate(prim_aabbs),
            Wide::Eight(w) => w.validate(prim_aabbs),
        }
    }

    /// [`MeshBvh::closest_hit`] through the binary tree, whatever form the mesh traces (for
    /// comparisons of the two: the answer is the same).
    pub fn closest_hit_binary(&self, ray: &Ray, t_max: f32) -> Option<Hit> {
        self.binary_closest(ray, t_max, INVALID_INDEX)
    }

    /// [`MeshBvh::any_hit`] through the binary tree, whatever form the mesh traces.
    pub fn any_hit_binary(&self, ray: &Ray, t_max: f32) -> bool {
        self.binary_any(ray, t_max, INVALID_INDEX)
    }

    fn binary_closest(&self, ray: &Ray, t_max: f32, skip: u32) -> Option<Hit> {
        self.binary_closest_filtered(ray, t_max, &Skip(skip))
    }

    fn binary_closest_filtered<R: HitFilter>(&self, ray: &Ray, t_max: f32, reject: &R) -> Option<Hit> {
        let wr = WatertightRay::new(ray);
        self.bvh
            .closest_hit(ray, t_max, |pos, prim, t_limit| {
                if reject.skips(prim) {
                    return None;
                }
                let h = self.triangles[pos as usize].intersect(&wr, t_limit)?;
                (!(R::USES_UV && reject.reject(prim, h.u, h.v))).then_some((h.t, (h.u, h.v)))
            })
            .map(Hit::from_traversal)
    }

    fn binary_any(&self, ray: &Ray, t_max: f32, skip: u32) -> bool {
        self.binary_any_filtered(ray, t_max, &Skip(skip))
    }

    fn binary_any_filtered<R: HitFilter>(&self, ray: &Ray, t_max: f32, reject: &R) -> bool {
        let wr = WatertightRay::new(ray);
        self.bvh.any_hit(ray, t_max, |pos, prim, t_limit| {
            if reject.skips(prim) {
                return false;
            }
            if !R::USES_UV {
                return self.triangles[pos as usize].intersect(&wr, t_limit).is_some();
            }
            self.triangles[pos as usize].intersect(&wr, t_limit).is_some_and(|h| !reject.reject(prim, h.u, h.v))
        })
    }

    /// Closest hit with `0 < t <= t_max`; the same answer as [`Bvh::closest_hit_triangles`].
    #[inline]
    pub fn closest_hit(&self, ray: &Ray, t_max: f32) -> Option<Hit> {
        self.closest_hit_skipping(ray, t_max, INVALID_INDEX)
    }

    /// [`MeshBvh::closest_hit`] without testing triangle `skip` (the one a spawned ray leaves,
    /// which it cannot hit: see [`crate::bvh::trace::wide_mesh`]); [`INVALID_INDEX`] skips none.
    #[inline]
    pub fn closest_hit_skipping(&self, ray: &Ray, t_max: f32, skip: u32) -> Option<Hit> {
        match &self.wide {
            Wide::Eight(w) => w.closest_hit(ray, t_max, skip),
            Wide::Four(w) => w.closest_hit(ray, t_max, skip),
            Wide::None => self.binary_closest(ray, t_max, skip),
        }
    }

    /// [`MeshBvh::closest_hit`] leaving out what `reject` leaves out: the triangle it skips
    /// (before intersecting it), and the hits `(prim, u, v)` it refuses (cut-out texels).
    #[inline]
    pub fn closest_hit_filtered<R: HitFilter>(&self, ray: &Ray, t_max: f32, reject: &R) -> Option<Hit> {
        match &self.wide {
            Wide::Eight(w) => w.closest_hit_filtered(ray, t_max, reject),
            Wide::Four(w) => w.closest_hit_filtered(ray, t_max, reject),
            Wide::None => self.binary_closest_filtered(ray, t_max, reject),
        }
    }

    /// [`MeshBvh::any_hit`] counting only hits `(prim, u, v)` that `reject` does not refuse.
    #[inline]
    pub fn any_hit_filtered<R: HitFilter>(&self, ray: &Ray, t_max: f32, reject: &R) -> bool {
        match &self.wide {
            Wide::Eight(w) => w.any_hit_filtered(ray, t_max, reject),
            Wide::Four(w) => w.any_hit_filtered(ray, t_max, reject),
            Wide::None => self.binary_any_filtered(ray, t_max, reject),
        }
    }

    /// Whether any triangle is hit with `0 < t <= t_max`.
    #[inline]
    pub fn any_hit(&self, ray: &Ray, t_max: f32) -> bool {
        self.any_hit_skipping(ray, t_max, INVALID_INDEX)
    }

    /// [`MeshBvh::any_hit`] without testing triangle `skip`.
    #[inline]
    pub fn any_hit_skipping(&self, ray: &Ray, t_max: f32, skip: u32) -> bool {
        match &self.wide {
            Wide::Eight(w) => w.any_hit(ray, t_max, skip),
            Wide::Four(w) => w.any_hit(ray, t_max, skip),
            Wide::None => self.binary_any(ray, t_max, skip),
        }
    }
}
