//! The x86-64 kernels: SSE4.1 (four lanes) and AVX2 (eight boxes a test, triangles four at a
//! time), each the scalar kernels' operations in the same order (the [`super`] module docs).

use std::arch::x86_64::*;

use super::{
    BOUND_FLOOR, BOUND_MARGIN, BoxRay, Kernel, MAXIMUM_FLOOR, PacketHits, PacketRay, ROBUST_SLAB_SCALE, TrianglePacket,
    planes,
};
use crate::bvh::INVALID_INDEX;
use crate::bvh::trace::wide::WideNode;
use crate::geometry::gamma;

/// SSE4.1 kernels.
pub(crate) struct Sse4;
/// AVX2 kernels: the box test eight lanes at once; triangles as [`Sse4`] (VEX-encoded).
pub(crate) struct Avx2;

// SAFETY: the methods run SSE4.1 (x86-64's SSE2 baseline, in fact) and require it.
unsafe impl Kernel for Sse4 {
    #[inline(always)]
    unsafe fn boxes<const N: usize>(node: &WideNode<N>, ray: &BoxRay, limit: f32, dist: &mut [f32; N]) -> u32 {
        // SAFETY: the caller's contract (the CPU has SSE4.1); N is 4 or 8.
        unsafe { boxes_sse(node, ray, limit, dist) }
    }

    #[inline(always)]
    unsafe fn triangles(p: &TrianglePacket, ray: &PacketRay, t_max: f32, valid: u32) -> PacketHits {
        // SAFETY: as for `boxes`.
        unsafe { triangles_sse(p, ray, t_max, valid) }
    }
}

// SAFETY: the methods run AVX2 and require it; AVX2 implies SSE4.1.
unsafe impl Kernel for Avx2 {
    #[inline(always)]
    unsafe fn boxes<const N: usize>(node: &WideNode<N>, ray: &BoxRay, limit: f32, dist: &mut [f32; N]) -> u32 {
        // SAFETY: the caller's contract (the CPU has AVX2), under which the AVX intrinsics
        // inline into the AVX2-compiled caller; N is 4 or 8.
        unsafe { if N == 8 { boxes_avx2(node, ray, limit, dist) } else { boxes_sse(node, ray, limit, dist) } }
    }

    #[inline(always)]
    unsafe fn triangles(p: &TrianglePacket, ray: &PacketRay, t_max: f32, valid: u32) -> PacketHits {
        // SAFETY: as for `boxes`.
        unsafe { triangles_sse(p, ray, t_max, valid) }
    }
}

/// Four lanes from `offset` of a node's box test: the hit mask (bits 0..4) and the entry
/// distances.
#[inline(always)]
unsafe fn boxes_sse4_chunk<const N: usize>(
    node: &WideNode<N>,
    ray: &BoxRay,
    limit: f32,
    offset: usize,
) -> (u32, __m128) {
    let rows = planes(node);
    // SAFETY: `offset + 4 <= N` (callers step by 4 below N, and N is 4 or 8), so every load
    // reads four floats inside one row.
    unsafe {
        let row = |k: usize| _mm_loadu_ps(rows[k].as_ptr().add(offset));
        let slab = |axis: usize, k: usize| {
            _mm_mul_ps(_mm_sub_ps(row(k), _mm_set1_ps(ray.inv.origin[axis])), _mm_set1_ps(ray.inv.inv_dir[axis]))
        };
        // `max(x, acc)` is `x > acc ? x : acc`: NaN planes keep the accumulator.
        let mut enter = _mm_setzero_ps();
        let mut exit = _mm_set1_ps(limit);
        for axis in 0..3 {
            enter = _mm_max_ps(slab(axis, ray.near[axis]), enter);
            exit = _mm_min_ps(slab(axis, ray.far[axis]), exit);
        }
        let hit = _mm_cmple_ps(enter, _mm_mul_ps(exit, _mm_set1_ps(ROBUST_SLAB_SCALE)));
        let child = _mm_loadu_si128(node.child.as_ptr().add(offset).cast());
        let empty = _mm_cmpeq_epi32(child, _mm_set1_epi32(INVALID_INDEX as i32));
        let mask = _mm_movemask_ps(_mm_andnot_ps(_mm_castsi128_ps(empty), hit)) as u32;
        (mask, enter)
    }
}

#[inline(always)]
unsafe fn boxes_sse<const N: usize>(node: &WideNode<N>, ray: &BoxRay, limit: f32, dist: &mut [f32; N]) -> u32 {
    let mut mask = 0;
    let mut offset = 0;
    while offset + 4 <= N {
        // SAFETY: `offset + 4 <= N`, and the caller runs with SSE4.1.
        unsafe {
            let (m, enter) = boxes_sse4_chunk(node, ray, limit, offset);
            _mm_storeu_ps(dist.as_mut_ptr().add(offset), enter);
            mask |= m << offset;
        }
        offset += 4;
    }
    mask
}

#[inline(always)]
unsafe fn boxes_avx2<const N: usize>(node: &WideNode<N>, ray: &BoxRay, limit: f32, dist: &mut [f32; N]) -> u32 {
    debug_assert_eq!(N, 8);
    let rows = planes(node);
    // SAFETY: N is 8 here, so each load reads one whole row of eight floats (or the eight
    // child links), and the store writes all of `dist`.
    unsafe {
        let row = |k: usize| _mm256_loadu_ps(rows[k].as_ptr());
        let slab = |axis: usize, k: usize| {
            _mm256_mul_ps(
                _mm256_sub_ps(row(k), _mm256_set1_ps(ray.inv.origin[axis])),
                _mm256_set1_ps(ray.inv.inv_dir[axis]),
            )
        };
        let mut enter = _mm256_setzero_ps();
        let mut exit = _mm256_set1_ps(limit);
        for axis in 0..3 {
            enter = _mm256_max_ps(slab(axis, ray.near[axis]), enter);
            exit = _mm256_min_ps(slab(axis, ray.far[axis]), exit);
        }
        let hit = _mm256_cmp_ps::<_CMP_LE_OQ>(enter, _mm256_mul_ps(exit, _mm256_set1_ps(ROBUST_SLAB_SCALE)));
        let child = _mm256_loadu_si256(node.child.as_ptr().cast());
        let empty = _mm256_cmpeq_epi32(child, _mm256_set1_epi32(INVALID_INDEX as i32));
        _mm256_storeu_ps(dist.as_mut_ptr(), enter);
        _mm256_movemask_ps(_mm256_andnot_ps(_mm256_castsi256_ps(empty), hit)) as u32
    }
}

/// The triangle kernel on four lanes (the module docs; [`super::scalar::scalar_candidate`] and the
/// scalar test's error bound lane by lane, with the same operations in the same order).
#[inline(always)]
unsafe fn triangles_sse(p: &TrianglePacket, r: &PacketRay, t_max: f32, valid: u32) -> PacketHits {
    let [kx, ky, kz] = r.k;
    // SAFETY: every load reads one 16-byte-aligned row of `p` (`TrianglePacket` is
    // `align(16)` and its rows are 16 bytes each); the stores write whole arrays of four.
    unsafe {
        let rel =
            |vertex: usize, axis: usize, o: f32| _mm_sub_ps(_mm_load_ps(p.v[vertex][axis].as_ptr()), _mm_set1_ps(o));
        let (sx, sy, sz) = (_mm_set1_ps(r.sx), _mm_set1_ps(r.sy), _mm_set1_ps(r.sz));
        let (az, bz, cz) = (rel(0, kz, r.o[2]), rel(1, kz, r.o[2]), rel(2, kz, r.o[2]));
        let ax = _mm_sub_ps(rel(0, kx, r.o[0]), _mm_mul_ps(sx, az));
        let ay = _mm_sub_ps(rel(0, ky, r.o[1]), _mm_mul_ps(sy, az));
        let bx = _mm_sub_ps(rel(1, kx, r.o[0]), _mm_mul_ps(sx, bz));
        let by = _mm_sub_ps(rel(1, ky, r.o[1]), _mm_mul_ps(sy, bz));
        let cx = _mm_sub_ps(rel(2, kx, r.o[0]), _mm_mul_ps(sx, cz));
        let cy = _mm_sub_ps(rel(2, ky, r.o[1]), _mm_mul_ps(sy, cz));
        let u = _mm_sub_ps(_mm_mul_ps(cx, by), _mm_mul_ps(cy, bx));
        let v = _mm_sub_ps(_mm_mul_ps(ax, cy), _mm_mul_ps(ay, cx));
        let w = _mm_sub_ps(_mm_mul_ps(bx, ay), _mm_mul_ps(by, ax));
        let zero = _mm_setzero_ps();
        let abs_mask = _mm_castsi128_ps(_mm_set1_epi32(0x7fff_ffff));
        let abs = |x: __m128| _mm_and_ps(x, abs_mask);
        let (min_normal, inf) = (_mm_set1_ps(f32::MIN_POSITIVE), _mm_set1_ps(f32::INFINITY));
        // Normal: MIN_POSITIVE <= |x| < inf (NaN fails both).
        let normal = |x: __m128| {
            let a = abs(x);
            _mm_and_ps(_mm_cmpge_ps(a, min_normal), _mm_cmplt_ps(a, inf))
        };
        let all_normal = _mm_and_ps(_mm_and_ps(normal(u), normal(v)), normal(w));
        let any_neg = _mm_or_ps(_mm_or_ps(_mm_cmplt_ps(u, zero), _mm_cmplt_ps(v, zero)), _mm_cmplt_ps(w, zero));
        let any_pos = _mm_or_ps(_mm_or_ps(_mm_cmpgt_ps(u, zero), _mm_cmpgt_ps(v, zero)), _mm_cmpgt_ps(w, zero));
        let mixed = _mm_and_ps(any_neg, any_pos);
        let valid = valid & 0xf;
        // Most packets a ray reaches miss it on every lane: then the division and the error
        // bound are not needed.
        if _mm_movemask_ps(_mm_and_ps(all_normal, mixed)) as u32 & valid == valid {
            return PacketHits::default();
        }
        let det = _mm_add_ps(_mm_add_ps(u, v), w);
        let (zs_a, zs_b, zs_c) = (_mm_mul_ps(sz, az), _mm_mul_ps(sz, bz), _mm_mul_ps(sz, cz));
        let t_scaled = _mm_add_ps(_mm_add_ps(_mm_mul_ps(u, zs_a), _mm_mul_ps(v, zs_b)), _mm_mul_ps(w, zs_c));
        let rcp = _mm_div_ps(_mm_set1_ps(1.0), det);
        let t_ok = _mm_and_ps(normal(t_scaled), normal(rcp));
        let t = _mm_mul_ps(t_scaled, rcp);
        let beyond = _mm_cmpgt_ps(t, _mm_set1_ps(t_max));
        // The scalar test's bound on `t`'s error (`t_error_bound`), in f32, enlarged.
        let max3 = |a: __m128, b: __m128, c: __m128| _mm_max_ps(_mm_max_ps(abs(a), abs(b)), abs(c));
        let (max_x, max_y) = (max3(ax, bx, cx), max3(ay, by, cy));
        let (max_z, shear_z) = (max3(zs_a, zs_b, zs_c), max3(az, bz, cz));
        let max_e = max3(u, v, w);
        let g = |n: u32| _mm_set1_ps(gamma(n));
        let delta_z = _mm_mul_ps(g(3), max_z);
        let delta_x = _mm_mul_ps(g(5), _mm_add_ps(max_x, _mm_mul_ps(_mm_set1_ps(r.sx.abs()), shear_z)));
        let delta_y = _mm_mul_ps(g(5), _mm_add_ps(max_y, _mm_mul_ps(_mm_set1_ps(r.sy.abs()), shear_z)));
        let delta_e = _mm_mul_ps(
            _mm_set1_ps(2.0),
            _mm_add_ps(
                _mm_add_ps(_mm_mul_ps(_mm_mul_ps(g(2), max_x), max_y), _mm_mul_ps(delta_y, max_x)),
                _mm_mul_ps(delta_x, max_y),
            ),
        );
        let inner = _mm_mul_ps(
            _mm_set1_ps(3.0),
            _mm_add_ps(
                _mm_add_ps(_mm_mul_ps(_mm_mul_ps(g(3), max_e), max_z), _mm_mul_ps(delta_e, max_z)),
                _mm_mul_ps(delta_z, max_e),
            ),
        );
        let bound = _mm_mul_ps(_mm_mul_ps(inner, abs(rcp)), _mm_set1_ps(BOUND_MARGIN));
        let floor = _mm_set1_ps(BOUND_FLOOR);
        let max_floor = _mm_set1_ps(MAXIMUM_FLOOR);
        let maxima_ok = _mm_and_ps(
            _mm_and_ps(_mm_cmpge_ps(max_x, max_floor), _mm_cmpge_ps(max_y, max_floor)),
            _mm_and_ps(_mm_cmpge_ps(max_z, max_floor), _mm_cmpge_ps(max_e, max_floor)),
        );
        let bound_ok = _mm_and_ps(
            _mm_and_ps(maxima_ok, _mm_cmpge_ps(bound, floor)),
            _mm_and_ps(_mm_cmpge_ps(inner, floor), _mm_cmplt_ps(bound, inf)),
        );
        let known = _mm_and_ps(_mm_and_ps(all_normal, _mm_andnot_ps(mixed, t_ok)), bound_ok);
        let in_range = _mm_andnot_ps(beyond, known);
        let accept = _mm_and_ps(in_range, _mm_cmpgt_ps(t, bound));
        let behind = _mm_and_ps(in_range, _mm_cmplt_ps(t, _mm_sub_ps(zero, bound)));
        // Rejected as the scalar test rejects: every edge function normal with mixed signs,
        // a normal distance past `t_max`, or one known to be behind the origin.
        let reject = _mm_or_ps(_mm_and_ps(all_normal, _mm_or_ps(mixed, _mm_and_ps(t_ok, beyond))), behind);
        let accept = _mm_movemask_ps(accept) as u32 & valid;
        let check = !(_mm_movemask_ps(reject) as u32) & valid & !accept;
        let mut hits = PacketHits { accept, check, ..Default::default() };
        _mm_storeu_ps(hits.t.as_mut_ptr(), t);
        _mm_storeu_ps(hits.u.as_mut_ptr(), _mm_mul_ps(v, rcp));
        _mm_storeu_ps(hits.v.as_mut_ptr(), _mm_mul_ps(w, rcp));
        hits
    }
}
