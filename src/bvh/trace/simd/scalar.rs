//! The portable kernels, a lane at a time: every CPU has them, and the SIMD kernels are checked
//! against them.

use super::BoxRay;
use super::{Kernel, PacketHits, PacketRay, TrianglePacket};
use crate::bvh::trace::wide::WideNode;

/// Portable kernels: a lane at a time.
pub(crate) struct Scalar;

// SAFETY: portable code, for every CPU.
unsafe impl Kernel for Scalar {
    #[inline(always)]
    unsafe fn boxes<const N: usize>(node: &WideNode<N>, ray: &BoxRay, limit: f32, dist: &mut [f32; N]) -> u32 {
        let mut mask = 0;
        for (i, d) in dist.iter_mut().enumerate().take(node.lanes()) {
            if let Some(t) = node.intersect_lane(i, &ray.inv, limit) {
                *d = t;
                mask |= 1 << i;
            }
        }
        mask
    }

    /// Only rejects: the lanes it keeps go to the scalar test whole.
    #[inline(always)]
    unsafe fn triangles(p: &TrianglePacket, ray: &PacketRay, t_max: f32, valid: u32) -> PacketHits {
        let mut check = 0;
        for i in 0..4 {
            if valid & (1 << i) != 0 && scalar_candidate(p, i, ray, t_max) {
                check |= 1 << i;
            }
        }
        PacketHits { check, ..Default::default() }
    }
}

/// The triangle filter for one lane (module docs).
#[inline(always)]
pub(super) fn scalar_candidate(p: &TrianglePacket, i: usize, r: &PacketRay, t_max: f32) -> bool {
    let [kx, ky, kz] = r.k;
    let rel = |vertex: usize, axis: usize, o: f32| p.v[vertex][axis][i] - o;
    let (az, bz, cz) = (rel(0, kz, r.o[2]), rel(1, kz, r.o[2]), rel(2, kz, r.o[2]));
    let ax = rel(0, kx, r.o[0]) - r.sx * az;
    let ay = rel(0, ky, r.o[1]) - r.sy * az;
    let bx = rel(1, kx, r.o[0]) - r.sx * bz;
    let by = rel(1, ky, r.o[1]) - r.sy * bz;
    let cx = rel(2, kx, r.o[0]) - r.sx * cz;
    let cy = rel(2, ky, r.o[1]) - r.sy * cz;
    let u = cx * by - cy * bx;
    let v = ax * cy - ay * cx;
    let w = bx * ay - by * ax;
    if !(u.is_normal() && v.is_normal() && w.is_normal()) {
        return true;
    }
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return false;
    }
    let det = u + v + w;
    let t_scaled = u * (r.sz * az) + v * (r.sz * bz) + w * (r.sz * cz);
    let rcp = 1.0 / det;
    if !(t_scaled.is_normal() && rcp.is_normal()) {
        return true;
    }
    // Not `<=`: an infinite `t` past an infinite `t_max` is the scalar test's to judge.
    #[allow(clippy::neg_cmp_op_on_partial_ord)]
    let keep = !(t_scaled * rcp > t_max);
    keep
}
