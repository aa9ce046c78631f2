//! Axis-aligned bounding boxes and the conservative ray/box slab test.
//!
//! The slab test follows Ize, "Robust BVH Ray Traversal" (JCGT 2013): the far distance of the
//! slab interval is scaled up by `1 + 2γ₃` so that rounding in the three subtract-multiply steps
//! can never make a box that the exact ray touches look missed. No scene-scale epsilon is used.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// An axis-aligned box. `min <= max` on every axis for a non-empty box; [`Aabb::EMPTY`] has
/// `min = +inf`, `max = -inf` so that it is the identity of [`Aabb::union`].
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Aabb {
    pub min: Vec3,
    pub max: Vec3,
}

const _: () = assert!(size_of::<Aabb>() == 24);

impl Default for Aabb {
    fn default() -> Self {
        Self::EMPTY
    }
}

/// The power of two `2^-⌊log2 x⌋` that brings a normal `x` below 2^127 into [1, 2), from `x`'s
/// exponent bits, kept a normal f32: `x` of 2^127 or more gets 2^-126 (into [2, 4)), subnormal
/// `x` and zero 2^127. Multiplying by a power of two is exact, so it changes no comparison,
/// only where overflow and underflow set in. The GPU's copy is `pow2_normalizer` in
/// shaders/trace.wgsl, the same bits.
pub(crate) fn pow2_normalizer(x: f32) -> f32 {
    let biased = ((x.to_bits() >> 23) & 0xff) as i32;
    f32::from_bits(((254 - biased).clamp(1, 254) as u32) << 23)
}

impl Aabb {
    /// The empty box: the identity of `union`, with zero surface area.
    pub const EMPTY: Aabb = Aabb { min: Vec3::INFINITY, max: Vec3::NEG_INFINITY };

    pub fn new(min: Vec3, max: Vec3) -> Self {
        Self { min, max }
    }

    pub fn from_point(p: Vec3) -> Self {
        Self { min: p, max: p }
    }

    pub fn from_points(points: &[Vec3]) -> Self {
        points.iter().fold(Self::EMPTY, |b, &p| b.grow(p))
    }

    #[inline]
    pub fn grow(self, p: Vec3) -> Self {
        Self { min: self.min.min(p), max: self.max.max(p) }
    }

    #[inline]
    pub fn union(self, other: Aabb) -> Self {
        Self { min: self.min.min(other.min), max: self.max.max(other.max) }
    }

    #[inline]
    pub fn is_empty(&self) -> bool {
        !(self.min.cmple(self.max).all())
    }

    #[inline]
    pub fn center(&self) -> Vec3 {
        // Halve before adding so that boxes near f32::MAX do not overflow.
        self.min * 0.5 + self.max * 0.5
    }

    #[inline]
    pub fn extent(&self) -> Vec3 {
        self.max - self.min
    }

    /// Surface area; 0 for an empty box.
    #[inline]
    pub fn surface_area(&self) -> f32 {
        if self.is_empty() {
            return 0.0;
        }
        let e = self.extent();
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }

    /// The power of two to multiply coordinates by before computing f32 areas of boxes inside
    /// this one, so that they neither overflow nor underflow: 1 (no change at all) while the
    /// largest extent is within 2^-32..2^32, and otherwise about its inverse. Scaling by a power
    /// of two is exact, so it changes no comparison between areas. Without it, a scene of extent
    /// 1e20 has infinite areas, and one of extent 1e-30 has zero areas, so area heuristics see
    /// ties everywhere.
    pub fn area_scale(&self) -> f32 {
        let extent = self.extent().max_element();
        if !extent.is_finite() || extent <= 0.0 || (2f32.powi(-32)..=2f32.powi(32)).contains(&extent) {
            return 1.0;
        }
        pow2_normalizer(extent)
    }

    /// The box with both corners multiplied by `s` (by [`Aabb::area_scale`], exactly).
    #[inline]
    pub fn scaled(self, s: f32) -> Self {
        Self { min: self.min * s, max: self.max * s }
    }

    /// Half the surface area: what the SAH ratios need, one multiply cheaper.
    #[inline]
    pub fn half_area(&self) -> f32 {
        if self.is_empty() {
            return 0.0;
        }
        self.half_area_nonempty()
    }

    /// [`Aabb::half_area`] without the emptiness test, for boxes known to be non-empty (a node's
    /// box, or a union with one): `(x y + y z) + z x`, summed in that order.
    #[inline(always)]
    pub fn half_area_nonempty(&self) -> f32 {
        let e = self.extent();
        e.x * e.y + e.y * e.z + e.z * e.x
    }

    /// Corner `k` in 0..8: bit 0 picks max x, bit 1 max y, bit 2 max z.
    pub fn corner(&self, k: usize) -> Vec3 {
        Vec3::select(glam::BVec3::new(k & 1 != 0, k & 2 != 0, k & 4 != 0), self.max, self.min)
    }

    pub fn contains_box(&self, other: &Aabb) -> bool {
        self.min.cmple(other.min).all() && self.max.cmpge(other.max).all()
    }

    /// Entry distance of `ray` into this box if the ray's segment `[0, t_max]` touches it.
    ///
    /// Conservative (Ize 2013): a box the exact ray touches is never reported as missed.
    ///
    /// The near and far planes are chosen by the direction's sign, as Ize does, rather than by
    /// comparing the two slab distances. When the origin lies on a slab plane and the direction
    /// component is zero, that distance is `0 * inf = NaN`, and it must count as "inside the
    /// slab": the running max/min below start from values that are never NaN (0 and `t_max`) and
    /// keep the running value whenever the comparison with NaN fails. That is both the right
    /// answer and a single `maxss`/`minss` each, unlike `f32::max`, which spends three more
    /// instructions on NaN.
    #[inline(always)]
    pub fn intersect_ray(&self, ray: &RayInv, t_max: f32) -> Option<f32> {
        let near_plane = Vec3::select(ray.negative, self.max, self.min);
        let far_plane = Vec3::select(ray.negative, self.min, self.max);
        let near = (near_plane - ray.origin) * ray.inv_dir;
        let far = (far_plane - ray.origin) * ray.inv_dir;
        let t_enter = nan_ignoring_max(nan_ignoring_max(nan_ignoring_max(0.0, near.x), near.y), near.z);
        let t_exit = nan_ignoring_min(nan_ignoring_min(nan_ignoring_min(t_max, far.x), far.y), far.z);
        (t_enter <= t_exit * ROBUST_SLAB_SCALE).then_some(t_enter)
    }
}

/// [`Aabb::intersect_ray`] on a box given as `[min.x, min.y, min.z, _, max.x, max.y, max.z, _]`,
/// picking planes by index instead of by select: the same arithmetic, so the same result to the
/// bit, in fewer instructions. This is how traversal tests BVH nodes.
#[inline(always)]
pub fn intersect_ray_packed(b: &[f32; 8], ray: &RayInv, t_max: f32) -> Option<f32> {
    let [ix, iy, iz] = ray.near_index;
    // `& 7` lets the compiler drop the bounds checks.
    let near_x = (b[ix & 7] - ray.origin.x) * ray.inv_dir.x;
    let near_y = (b[iy & 7] - ray.origin.y) * ray.inv_dir.y;
    let near_z = (b[iz & 7] - ray.origin.z) * ray.inv_dir.z;
    let far_x = (b[(ix ^ 4) & 7] - ray.origin.x) * ray.inv_dir.x;
    let far_y = (b[(iy ^ 4) & 7] - ray.origin.y) * ray.inv_dir.y;
    let far_z = (b[(iz ^ 4) & 7] - ray.origin.z) * ray.inv_dir.z;
    slab_interval(near_x, near_y, near_z, far_x, far_y, far_z, t_max)
}

/// The end of every slab test: given the distances to a box's near and far planes on each
/// axis, its entry distance if the ray enters it within `[0, t_max]`, with Ize's conservative
/// widening ([`ROBUST_SLAB_SCALE`]) and NaN planes ignored (see [`Aabb::intersect_ray`]). Shared
/// by the binary and the wide traversal, so that both open the same boxes.
#[inline(always)]
pub fn slab_interval(
    near_x: f32,
    near_y: f32,
    near_z: f32,
    far_x: f32,
    far_y: f32,
    far_z: f32,
    t_max: f32,
) -> Option<f32> {
    let t_enter = nan_ignoring_max(nan_ignoring_max(nan_ignoring_max(0.0, near_x), near_y), near_z);
    let t_exit = nan_ignoring_min(nan_ignoring_min(nan_ignoring_min(t_max, far_x), far_y), far_z);
    (t_enter <= t_exit * ROBUST_SLAB_SCALE).then_some(t_enter)
}

/// `max(acc, x)`, keeping `acc` when `x` is NaN. `acc` must not be NaN.
#[inline(always)]
fn nan_ignoring_max(acc: f32, x: f32) -> f32 {
    if x > acc { x } else { acc }
}

/// `min(acc, x)`, keeping `acc` when `x` is NaN. `acc` must not be NaN.
#[inline(always)]
fn nan_ignoring_min(acc: f32, x: f32) -> f32 {
    if x < acc { x } else { acc }
}

/// `1 + 2γ₃` with `γₙ = nε / (1 - nε)`, `ε = 2⁻²⁴` (Ize 2013, section 3).
pub const ROBUST_SLAB_SCALE: f32 = 1.0 + 2.0 * GAMMA3;
const GAMMA3: f32 = (3.0 * f32::EPSILON * 0.5) / (1.0 - 3.0 * f32::EPSILON * 0.5);

/// A ray prepared for slab tests: origin, per-axis reciprocal direction (±inf where the
/// direction component is zero: `-0.0` maps to `-inf`), and which components are negative.
#[derive(Clone, Copy, Debug)]
pub struct RayInv {
    pub origin: Vec3,
    pub inv_dir: Vec3,
    pub negative: glam::BVec3,
    /// For a box read as 8 floats `[min.xyz, _, max.xyz, _]` (the layout of a BVH node): the
    /// index of the near plane on each axis; the far plane is at `index ^ 4`.
    pub near_index: [usize; 3],
}

impl RayInv {
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        let inv_dir = dir.recip();
        let negative = inv_dir.cmplt(Vec3::ZERO);
        let near_index = [negative.x as usize * 4, 1 + negative.y as usize * 4, 2 + negative.z as usize * 4];
        Self { origin, inv_dir, negative, near_index }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pow2_normalizer_brings_values_into_one_to_two() {
        for x in [1.0f32, 1.5, 2.0, 3.0, 0.7, 1e-30, 1e30, 1e-37, f32::MIN_POSITIVE, 2f32.powi(126)] {
            let p = pow2_normalizer(x);
            assert!(p.is_normal() && p.to_bits() & 0x007f_ffff == 0, "{x:e}: {p:e} is no power of two");
            assert!((1.0..2.0).contains(&(p * x)), "{x:e}: scaled to {:e}", p * x);
        }
        assert_eq!(pow2_normalizer(f32::MAX), 2f32.powi(-126));
        assert_eq!(pow2_normalizer(1e-40), 2f32.powi(127));
        assert_eq!(pow2_normalizer(0.0), 2f32.powi(127));
    }

    #[test]
    fn empty_box_is_union_identity_and_has_no_area() {
        let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
        assert_eq!(Aabb::EMPTY.union(b), b);
        assert_eq!(Aabb::EMPTY.surface_area(), 0.0);
        assert_eq!(b.surface_area(), 6.0);
        assert!(Aabb::EMPTY.is_empty());
        assert!(!Aabb::from_point(Vec3::ONE).is_empty());
    }

    #[test]
    fn slab_hits_and_misses() {
        let b = Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0));
        let r = RayInv::new(Vec3::new(-5.0, 0.0, 0.0), Vec3::X);
        assert_eq!(b.intersect_ray(&r, f32::INFINITY), Some(4.0));
        assert_eq!(b.intersect_ray(&r, 3.0), None);
        let miss = RayInv::new(Vec3::new(-5.0, 2.0, 0.0), Vec3::X);
        assert_eq!(b.intersect_ray(&miss, f32::INFINITY), None);
        // Origin inside: entry clamps to 0.
        let inside = RayInv::new(Vec3::ZERO, Vec3::new(0.3, -0.2, 0.9));
        assert_eq!(b.intersect_ray(&inside, f32::INFINITY), Some(0.0));
    }

    #[test]
    fn slab_keeps_rays_lying_on_a_face() {
        // The ray runs inside the plane y = 1 of the box face with dy = 0: (1 - 1) * inf = NaN,
        // which must not cull the box.
        let b = Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0));
        let r = RayInv::new(Vec3::new(-5.0, 1.0, 0.0), Vec3::X);
        assert!(b.intersect_ray(&r, f32::INFINITY).is_some());
        for origin in [Vec3::new(-1.0, 0.0, -5.0), Vec3::new(1.0, 0.0, -5.0)] {
            for dir in [Vec3::new(0.0, 0.1, 1.0), Vec3::new(-0.0, -0.1, 1.0)] {
                let r = RayInv::new(origin, dir);
                assert_eq!(b.intersect_ray(&r, f32::INFINITY), Some(4.0), "{origin} {dir}");
            }
        }
    }

    #[test]
    fn packed_slab_test_equals_the_plain_one() {
        let mut seed = 1u32;
        let mut next = || {
            seed = seed.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
            (seed >> 8) as f32 / (1 << 24) as f32 * 4.0 - 2.0
        };
        for k in 0..100_000 {
            let (a, b) = (Vec3::new(next(), next(), next()), Vec3::new(next(), next(), next()));
            let bx = Aabb::new(a.min(b), a.max(b));
            let mut dir = Vec3::new(next(), next(), next());
            if k % 7 == 0 {
                dir.y = if k % 2 == 0 { 0.0 } else { -0.0 }; // zero components: NaN slabs
            }
            let origin =
                if k % 11 == 0 { Vec3::new(bx.min.x, next(), next()) } else { Vec3::new(next(), next(), next()) };
            let r = RayInv::new(origin, dir);
            let packed = [bx.min.x, bx.min.y, bx.min.z, 0.0, bx.max.x, bx.max.y, bx.max.z, 0.0];
            let t_max = if k % 3 == 0 { f32::INFINITY } else { next().abs() * 3.0 };
            assert_eq!(
                bx.intersect_ray(&r, t_max).map(f32::to_bits),
                intersect_ray_packed(&packed, &r, t_max).map(f32::to_bits),
                "{bx:?} {r:?}"
            );
        }
    }

    #[test]
    fn slab_is_conservative_for_flat_boxes() {
        // A zero-thickness box (an axis-aligned triangle's bounds) hit along a diagonal.
        let b = Aabb::new(Vec3::new(0.1, 0.2, 3.0), Vec3::new(0.7, 0.9, 3.0));
        let o = Vec3::new(0.3, 0.4, 0.0);
        let target = Vec3::new(0.7, 0.9, 3.0);
        let r = RayInv::new(o, target - o);
        assert!(b.intersect_ray(&r, f32::INFINITY).is_some());
    }
}
