//! The NEON kernels: the SSE4.1 kernels' operations, in the same order, on the same four lanes.
//!
//! Where the instruction sets differ:
//! - `maxps(x, acc)` is `x > acc ? x : acc`, and the scalar code relies on it (a NaN `x` keeps
//!   the accumulator). NEON's `vmaxq_f32` returns NaN where either operand is, and `vmaxnmq_f32`
//!   returns the other operand, so it would also drop a NaN accumulator (a NaN `limit` or
//!   `t_max`) that the scalar and SSE4.1 code keep; and it orders `-0.0` below `+0.0`. So each
//!   `maxps`/`minps` becomes the compare and select it is defined as ([`max_ps`], [`min_ps`]).
//! - `movemask` has no single instruction: the comparison masks are all ones or all zeros per
//!   lane, so lane `i` ANDed with `1 << i` and the lanes summed across (`vaddvq_u32`) give the
//!   same bits ([`movemask`]).
//! - Subnormals: AArch64's Advanced SIMD honours FPCR as scalar code does (no flush to zero
//!   unless the process asks, as on x86 with MXCSR); AArch32 NEON, which always flushes, is not
//!   a target here.
//! - No fused multiply-adds: each `_mm_mul_ps` and `_mm_add_ps`/`_mm_sub_ps` pair is a
//!   `vmulq_f32` and a `vaddq_f32`/`vsubq_f32` (never `vfmaq_f32` or `vmlaq_f32`), and rustc does
//!   not contract them.

use std::arch::aarch64::*;

use super::{
    BOUND_FLOOR, BOUND_MARGIN, BoxRay, Kernel, MAXIMUM_FLOOR, PacketHits, PacketRay, ROBUST_SLAB_SCALE, TrianglePacket,
    planes,
};
use crate::bvh::INVALID_INDEX;
use crate::bvh::trace::wide::WideNode;
use crate::geometry::gamma;

/// NEON kernels. An 8-wide node is tested as two 4-wide halves, as `Sse4` does;
/// the default form on this path is the 4-wide tree ([`super::TraceLayout::default_for`]).
pub(crate) struct Neon;

// SAFETY: the methods run NEON (Advanced SIMD, in the aarch64 baseline) and require it.
unsafe impl Kernel for Neon {
    #[inline(always)]
    unsafe fn boxes<const N: usize>(node: &WideNode<N>, ray: &BoxRay, limit: f32, dist: &mut [f32; N]) -> u32 {
        let mut mask = 0;
        let mut offset = 0;
        while offset + 4 <= N {
            // SAFETY: `offset + 4 <= N`, so the store writes four floats inside `dist`; the
            // caller's contract (the CPU has NEON).
            unsafe {
                let (m, enter) = boxes_chunk(node, ray, limit, offset);
                vst1q_f32(dist.as_mut_ptr().add(offset), enter);
                mask |= m << offset;
            }
            offset += 4;
        }
        mask
    }

    #[inline(always)]
    unsafe fn triangles(p: &TrianglePacket, ray: &PacketRay, t_max: f32, valid: u32) -> PacketHits {
        // SAFETY: as for `boxes`.
        unsafe { triangles_neon(p, ray, t_max, valid) }
    }
}

/// x86's `maxps(a, b)`: `a > b ? a : b`, so `b` where either is NaN (module docs).
///
/// # Safety
/// The CPU has NEON.
#[inline(always)]
unsafe fn max_ps(a: float32x4_t, b: float32x4_t) -> float32x4_t {
    // SAFETY: the caller's contract.
    unsafe { vbslq_f32(vcgtq_f32(a, b), a, b) }
}

/// x86's `minps(a, b)`: `a < b ? a : b`, so `b` where either is NaN.
///
/// # Safety
/// The CPU has NEON.
#[inline(always)]
unsafe fn min_ps(a: float32x4_t, b: float32x4_t) -> float32x4_t {
    // SAFETY: the caller's contract.
    unsafe { vbslq_f32(vcltq_f32(a, b), a, b) }
}

/// x86's `movemask` of a comparison mask (every lane all ones or all zeros): lane `i` as
/// bit `i`.
///
/// # Safety
/// The CPU has NEON.
#[inline(always)]
unsafe fn movemask(m: uint32x4_t) -> u32 {
    const LANE_BITS: [u32; 4] = [1, 2, 4, 8];
    // SAFETY: the load reads the four `u32` of `LANE_BITS`; the caller's contract.
    unsafe { vaddvq_u32(vandq_u32(m, vld1q_u32(LANE_BITS.as_ptr()))) }
}

/// Four lanes from `offset` of a node's box test: the hit mask (bits 0..4) and the entry
/// distances.
///
/// # Safety
/// The CPU has NEON; `offset + 4 <= N`.
#[inline(always)]
unsafe fn boxes_chunk<const N: usize>(
    node: &WideNode<N>,
    ray: &BoxRay,
    limit: f32,
    offset: usize,
) -> (u32, float32x4_t) {
    let rows = planes(node);
    // SAFETY: `offset + 4 <= N` (callers step by 4 below N, and N is 4 or 8), so every load
    // reads four floats inside one row (or four child links inside `child`).
    unsafe {
        let row = |k: usize| vld1q_f32(rows[k].as_ptr().add(offset));
        let slab = |axis: usize, k: usize| {
            vmulq_f32(vsubq_f32(row(k), vdupq_n_f32(ray.inv.origin[axis])), vdupq_n_f32(ray.inv.inv_dir[axis]))
        };
        // `max_ps(x, acc)` is `x > acc ? x : acc`: NaN planes keep the accumulator.
        let mut enter = vdupq_n_f32(0.0);
        let mut exit = vdupq_n_f32(limit);
        for axis in 0..3 {
            enter = max_ps(slab(axis, ray.near[axis]), enter);
            exit = min_ps(slab(axis, ray.far[axis]), exit);
        }
        let hit = vcleq_f32(enter, vmulq_f32(exit, vdupq_n_f32(ROBUST_SLAB_SCALE)));
        let child = vld1q_u32(node.child.as_ptr().add(offset));
        let empty = vceqq_u32(child, vdupq_n_u32(INVALID_INDEX));
        (movemask(vbicq_u32(hit, empty)), enter)
    }
}

/// The triangle kernel on four lanes: `Sse4`'s, operation for operation (the module docs of
/// [`super`]; [`super::scalar::scalar_candidate`] and the scalar test's error bound lane by lane).
///
/// # Safety
/// The CPU has NEON.
#[inline(always)]
unsafe fn triangles_neon(p: &TrianglePacket, r: &PacketRay, t_max: f32, valid: u32) -> PacketHits {
    let [kx, ky, kz] = r.k;
    // SAFETY: every load reads one row of four floats of `p`; the stores write whole arrays
    // of four; the caller's contract (the CPU has NEON).
    unsafe {
        let rel = |vertex: usize, axis: usize, o: f32| vsubq_f32(vld1q_f32(p.v[vertex][axis].as_ptr()), vdupq_n_f32(o));
        let (sx, sy, sz) = (vdupq_n_f32(r.sx), vdupq_n_f32(r.sy), vdupq_n_f32(r.sz));
        let (az, bz, cz) = (rel(0, kz, r.o[2]), rel(1, kz, r.o[2]), rel(2, kz, r.o[2]));
        let ax = vsubq_f32(rel(0, kx, r.o[0]), vmulq_f32(sx, az));
        let ay = vsubq_f32(rel(0, ky, r.o[1]), vmulq_f32(sy, az));
        let bx = vsubq_f32(rel(1, kx, r.o[0]), vmulq_f32(sx, bz));
        let by = vsubq_f32(rel(1, ky, r.o[1]), vmulq_f32(sy, bz));
        let cx = vsubq_f32(rel(2, kx, r.o[0]), vmulq_f32(sx, cz));
        let cy = vsubq_f32(rel(2, ky, r.o[1]), vmulq_f32(sy, cz));
        let u = vsubq_f32(vmulq_f32(cx, by), vmulq_f32(cy, bx));
        let v = vsubq_f32(vmulq_f32(ax, cy), vmulq_f32(ay, cx));
        let w = vsubq_f32(vmulq_f32(bx, ay), vmulq_f32(by, ax));
        let zero = vdupq_n_f32(0.0);
        // Clears the sign bit, as SSE4.1's AND with 0x7fff_ffff does (NaN included).
        let abs = |x: float32x4_t| vabsq_f32(x);
        let (min_normal, inf) = (vdupq_n_f32(f32::MIN_POSITIVE), vdupq_n_f32(f32::INFINITY));
        // Normal: MIN_POSITIVE <= |x| < inf (NaN fails both).
        let normal = |x: float32x4_t| {
            let a = abs(x);
            vandq_u32(vcgeq_f32(a, min_normal), vcltq_f32(a, inf))
        };
        let all_normal = vandq_u32(vandq_u32(normal(u), normal(v)), normal(w));
        let any_neg = vorrq_u32(vorrq_u32(vcltq_f32(u, zero), vcltq_f32(v, zero)), vcltq_f32(w, zero));
        let any_pos = vorrq_u32(vorrq_u32(vcgtq_f32(u, zero), vcgtq_f32(v, zero)), vcgtq_f32(w, zero));
        let mixed = vandq_u32(any_neg, any_pos);
        let valid = valid & 0xf;
        // Most packets a ray reaches miss it on every lane: then the division and the error
        // bound are not needed.
        if movemask(vandq_u32(all_normal, mixed)) & valid == valid {
            return PacketHits::default();
        }
        let det = vaddq_f32(vaddq_f32(u, v), w);
        let (zs_a, zs_b, zs_c) = (vmulq_f32(sz, az), vmulq_f32(sz, bz), vmulq_f32(sz, cz));
        let t_scaled = vaddq_f32(vaddq_f32(vmulq_f32(u, zs_a), vmulq_f32(v, zs_b)), vmulq_f32(w, zs_c));
        let rcp = vdivq_f32(vdupq_n_f32(1.0), det);
        let t_ok = vandq_u32(normal(t_scaled), normal(rcp));
        let t = vmulq_f32(t_scaled, rcp);
        let beyond = vcgtq_f32(t, vdupq_n_f32(t_max));
        // The scalar test's bound on `t`'s error (`t_error_bound`), in f32, enlarged.
        let max3 = |a: float32x4_t, b: float32x4_t, c: float32x4_t| max_ps(max_ps(abs(a), abs(b)), abs(c));
        let (max_x, max_y) = (max3(ax, bx, cx), max3(ay, by, cy));
        let (max_z, shear_z) = (max3(zs_a, zs_b, zs_c), max3(az, bz, cz));
        let max_e = max3(u, v, w);
        let g = |n: u32| vdupq_n_f32(gamma(n));
        let delta_z = vmulq_f32(g(3), max_z);
        let delta_x = vmulq_f32(g(5), vaddq_f32(max_x, vmulq_f32(vdupq_n_f32(r.sx.abs()), shear_z)));
        let delta_y = vmulq_f32(g(5), vaddq_f32(max_y, vmulq_f32(vdupq_n_f32(r.sy.abs()), shear_z)));
        let delta_e = vmulq_f32(
            vdupq_n_f32(2.0),
            vaddq_f32(
                vaddq_f32(vmulq_f32(vmulq_f32(g(2), max_x), max_y), vmulq_f32(delta_y, max_x)),
                vmulq_f32(delta_x, max_y),
            ),
        );
        let inner = vmulq_f32(
            vdupq_n_f32(3.0),
            vaddq_f32(
                vaddq_f32(vmulq_f32(vmulq_f32(g(3), max_e), max_z), vmulq_f32(delta_e, max_z)),
                vmulq_f32(delta_z, max_e),
            ),
        );
        let bound = vmulq_f32(vmulq_f32(inner, abs(rcp)), vdupq_n_f32(BOUND_MARGIN));
        let floor = vdupq_n_f32(BOUND_FLOOR);
        let max_floor = vdupq_n_f32(MAXIMUM_FLOOR);
        let maxima_ok = vandq_u32(
            vandq_u32(vcgeq_f32(max_x, max_floor), vcgeq_f32(max_y, max_floor)),
            vandq_u32(vcgeq_f32(max_z, max_floor), vcgeq_f32(max_e, max_floor)),
        );
        let bound_ok = vandq_u32(
            vandq_u32(maxima_ok, vcgeq_f32(bound, floor)),
            vandq_u32(vcgeq_f32(inner, floor), vcltq_f32(bound, inf)),
        );
        // `vbicq_u32(a, b)` is `a & !b`: SSE's `andnot(b, a)`.
        let known = vandq_u32(vandq_u32(all_normal, vbicq_u32(t_ok, mixed)), bound_ok);
        let in_range = vbicq_u32(known, beyond);
        let accept = vandq_u32(in_range, vcgtq_f32(t, bound));
        let behind = vandq_u32(in_range, vcltq_f32(t, vsubq_f32(zero, bound)));
        // Rejected as the scalar test rejects: every edge function normal with mixed signs,
        // a normal distance past `t_max`, or one known to be behind the origin.
        let reject = vorrq_u32(vandq_u32(all_normal, vorrq_u32(mixed, vandq_u32(t_ok, beyond))), behind);
        let accept = movemask(accept) & valid;
        let check = !movemask(reject) & valid & !accept;
        let mut hits = PacketHits { accept, check, ..Default::default() };
        vst1q_f32(hits.t.as_mut_ptr(), t);
        vst1q_f32(hits.u.as_mut_ptr(), vmulq_f32(v, rcp));
        vst1q_f32(hits.v.as_mut_ptr(), vmulq_f32(w, rcp));
        hits
    }
}
