//! How rays are traced on the CPU: which tree form ([`TraceLayout`]) and which instruction set
//! ([`SimdPath`]), chosen once per process, plus the kernels each path runs: one wide node's
//! child boxes against a ray, and one packet of four triangles against a ray.
//!
//! Dispatch is at run time, so the release build stays for plain x86-64 as users get it: the
//! SSE4.1 and AVX2 kernels are compiled with those features enabled for their functions only,
//! and taken only where the CPU reports them. On aarch64 the NEON kernel (four lanes, like
//! SSE4.1) is the baseline's, still checked at run time the same way.
//! `ARBOR_SIMD=scalar|sse4|avx2|neon` forces a path (for tests and benchmarks); a path the CPU
//! lacks is refused, not emulated.
//!
//! Every kernel computes what the scalar code computes, operation for operation (no fused
//! multiply-adds, the same order of operations, IEEE division), so each path gives the same
//! floats:
//! - the box test is the slab test of [`crate::geometry::slab_interval`] lane by lane. `maxps`
//!   and `minps` return their second operand when the first is NaN, which is the scalar code's
//!   NaN-ignoring `max`/`min` with the accumulator second. NEON's `fmax`/`fmin` propagate NaN
//!   instead, so the NEON kernel spells the same choice as a compare and a select;
//! - the triangle kernel runs the watertight test's f32 part (the shear, the edge functions, `T`,
//!   `det` and `t`) on four triangles and sorts the lanes three ways. *Rejected*: where
//!   [`crate::geometry::Triangle::intersect`] would return no hit on the same floats (edge
//!   functions of mixed sign, a distance past `t_max`, or one below minus its error bound).
//!   *Accepted*: where it would return this `t`, `u`, `v`, which the kernel computed with the
//!   same operations: every quantity a normal float and `t` above its error bound. The bound is
//!   the scalar test's (`t_error_bound`, evaluated there in f64), evaluated here in f32 and
//!   enlarged by a factor that covers the f32 rounding of its dozen operations, and trusted only
//!   where it and every maximum it is made of are well above the subnormal range (no term lost
//!   to underflow); so `t` above it is above the scalar bound too. *Checked*: every other lane (a ray through an edge, a `t` near zero: the
//!   scalar test's f64 paths) goes to the scalar test. Hits are exactly the scalar test's.


use crate::geometry::{ROBUST_SLAB_SCALE, RayInv, WatertightRay};

use super::wide::WideNode;

/// The instruction set the CPU traversal uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SimdPath {
    /// Portable Rust, one lane at a time: every CPU.
    Scalar,
    /// SSE4.1: four boxes or four triangles per instruction (x86-64).
    Sse4,
    /// AVX2: eight boxes per instruction, triangles four at a time (x86-64).
    Avx2,
    /// NEON (Advanced SIMD): four boxes or four triangles per instruction (aarch64).
    Neon,
}

/// `ARBOR_SIMD` names no path, or one this CPU lacks.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SimdError {
    #[error("ARBOR_SIMD={0:?} is not a SIMD path: expected scalar, sse4, avx2 or neon")]
    Unknown(String),
    #[error("ARBOR_SIMD={0}: this CPU does not support it (available: {1})")]
    Unavailable(&'static str, String),
}

impl SimdPath {
    /// Every path, slowest first among those of one architecture.
    pub const ALL: [SimdPath; 4] = [SimdPath::Scalar, SimdPath::Sse4, SimdPath::Avx2, SimdPath::Neon];

    /// The name `ARBOR_SIMD` and reports use.
    pub fn name(self) -> &'static str {
        match self {
            SimdPath::Scalar => "scalar",
            SimdPath::Sse4 => "sse4",
            SimdPath::Avx2 => "avx2",
            SimdPath::Neon => "neon",
        }
    }

    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|p| p.name() == name)
    }

    /// Whether this CPU runs the path.
    pub fn is_available(self) -> bool {
        match self {
            SimdPath::Scalar => true,
            #[cfg(target_arch = "x86_64")]
            SimdPath::Sse4 => std::arch::is_x86_feature_detected!("sse4.1"),
            #[cfg(target_arch = "x86_64")]
            SimdPath::Avx2 => std::arch::is_x86_feature_detected!("avx2"),
            // Part of the aarch64 baseline, so always there in practice; asked all the same, as
            // the x86 paths are.
            #[cfg(target_arch = "aarch64")]
            SimdPath::Neon => std::arch::is_aarch64_feature_detected!("neon"),
            // Every architecture leaves some path out: the other one's.
            _ => false,
        }
    }

    /// The paths this CPU runs, slowest first.
    pub fn available() -> Vec<SimdPath> {
        Self::ALL.into_iter().filter(|p| p.is_available()).collect()
    }

    /// The fastest path this CPU runs.
    pub fn best() -> Self {
        Self::ALL.into_iter().rev().find(|p| p.is_available()).unwrap_or(SimdPath::Scalar)
    }

    /// The path `ARBOR_SIMD` asks for, or the best one when it is unset or empty.
    pub fn from_env() -> Result<Self, SimdError> {
        match std::env::var("ARBOR_SIMD") {
            Ok(name) if !name.trim().is_empty() => Self::from_name(&name),
            _ => Ok(Self::best()),
        }
    }

    /// The path `name` (an `ARBOR_SIMD` value) names, if this CPU runs it.
    pub fn from_name(name: &str) -> Result<Self, SimdError> {
        let path = Self::parse(name.trim()).ok_or_else(|| SimdError::Unknown(name.to_string()))?;
        if !path.is_available() {
            let names: Vec<_> = Self::available().iter().map(|p| p.name()).collect();
            return Err(SimdError::Unavailable(path.name(), names.join(", ")));
        }
        Ok(path)
    }
}

/// The tree form the CPU traces: the binary tree itself, or a 4- or 8-wide tree collapsed from
/// it with its triangles in packets of four ([`super::wide_mesh::WideMesh`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TraceLayout {
    Binary,
    Wide4,
    Wide8,
}

impl TraceLayout {
    pub const ALL: [TraceLayout; 3] = [TraceLayout::Binary, TraceLayout::Wide4, TraceLayout::Wide8];

    /// The name `render --trace` and reports use.
    pub fn name(self) -> &'static str {
        match self {
            TraceLayout::Binary => "binary",
            TraceLayout::Wide4 => "wide4",
            TraceLayout::Wide8 => "wide8",
        }
    }

    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|l| l.name() == name)
    }

    /// The form that traces fastest on a path: 8-wide where one instruction tests eight boxes,
    /// 4-wide on SSE4.1 and NEON, and the binary tree for portable code, where a wide node's lanes are
    /// tested one at a time and the wide tree measured no faster (docs/benchmarks.md, "Wide
    /// trees and SIMD traversal").
    pub fn default_for(path: SimdPath) -> Self {
        match path {
            SimdPath::Avx2 => TraceLayout::Wide8,
            SimdPath::Sse4 | SimdPath::Neon => TraceLayout::Wide4,
            SimdPath::Scalar => TraceLayout::Binary,
        }
    }
}

/// A tree form and the path that traces it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Tracing {
    pub layout: TraceLayout,
    pub simd: SimdPath,
}

impl std::fmt::Display for Tracing {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} tree, {} kernels", self.layout.name(), self.simd.name())
    }
}

impl Tracing {
    /// The best path this CPU has with its layout.
    pub fn best() -> Self {
        let simd = SimdPath::best();
        Self { layout: TraceLayout::default_for(simd), simd }
    }

    /// What a scene rendered on a GPU keeps on the CPU: the binary tree alone (the GPU traces
    /// its own copy of it), so no time goes into a wide form nobody traces.
    pub fn gpu() -> Self {
        Self { layout: TraceLayout::Binary, simd: SimdPath::Scalar }
    }

    /// `layout` (or the path's default) on the path `ARBOR_SIMD` names (or the best). The
    /// library never calls it: the tools read the environment once, at their edge, and pass the
    /// result down to every tree they build ([`super::MeshBvh::new`], `device::Renderer::new`).
    pub fn from_env(layout: Option<TraceLayout>) -> Result<Self, SimdError> {
        let simd = SimdPath::from_env()?;
        Ok(Self { layout: layout.unwrap_or(TraceLayout::default_for(simd)), simd })
    }
}

/// A ray prepared for the box kernels: its origin and reciprocal direction per axis, and where
/// each axis's near and far planes sit among a node's six plane arrays
/// (`min_x min_y min_z max_x max_y max_z`).
#[derive(Clone, Copy, Debug)]
pub struct BoxRay {
    pub(crate) near: [usize; 3],
    pub(crate) far: [usize; 3],
    pub(crate) inv: RayInv,
}

impl BoxRay {
    #[inline(always)]
    pub fn new(inv: RayInv) -> Self {
        let neg = [inv.negative.x, inv.negative.y, inv.negative.z].map(usize::from);
        Self {
            near: [neg[0] * 3, 1 + neg[1] * 3, 2 + neg[2] * 3],
            far: [(1 - neg[0]) * 3, 1 + (1 - neg[1]) * 3, 2 + (1 - neg[2]) * 3],
            inv,
        }
    }
}

/// Four triangles by vertex, axis and lane, laid out for the watertight test: each of the nine
/// coordinate rows loads as one vector. 160 bytes: the rows (144) and the lanes' primitive ids
/// (16). A leaf holds `ceil(count / 4)` packets; the lanes past its count repeat the packet's
/// first triangle and are masked off by the count, never tested.
#[repr(C, align(16))]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrianglePacket {
    /// `v[vertex][axis][lane]`.
    pub v: [[[f32; 4]; 3]; 3],
    /// The lanes' primitive ids.
    pub prim: [u32; 4],
}

const _: () = assert!(size_of::<TrianglePacket>() == 160);

impl TrianglePacket {
    /// Lane `i`'s triangle, the same floats it was packed from.
    #[inline(always)]
    pub fn triangle(&self, i: usize) -> crate::geometry::Triangle {
        let vertex = |k: usize| glam::Vec3::new(self.v[k][0][i], self.v[k][1][i], self.v[k][2][i]);
        crate::geometry::Triangle::new(vertex(0), vertex(1), vertex(2))
    }
}

/// A ray prepared for the triangle kernel: the watertight test's permutation and shear, with the
/// origin's coordinates in the permuted order.
#[derive(Clone, Copy, Debug)]
pub struct PacketRay {
    pub(crate) wr: WatertightRay,
    /// `[kx, ky, kz]`.
    pub(crate) k: [usize; 3],
    /// The origin's coordinates on `kx`, `ky`, `kz`.
    pub(crate) o: [f32; 3],
    pub(crate) sx: f32,
    pub(crate) sy: f32,
    pub(crate) sz: f32,
}

impl PacketRay {
    #[inline(always)]
    pub fn new(wr: WatertightRay) -> Self {
        let (k, [sx, sy, sz]) = wr.permutation();
        Self { wr, k, o: k.map(|a| wr.origin[a]), sx, sy, sz }
    }
}

/// What [`Kernel::triangles`] makes of a packet's lanes (module docs): bit masks of the lanes
/// whose hit is known (`t`, `u`, `v` hold it) and of those the scalar test must decide; the
/// lanes in neither are rejected.
#[derive(Clone, Copy, Debug, Default)]
pub struct PacketHits {
    pub accept: u32,
    pub check: u32,
    pub t: [f32; 4],
    pub u: [f32; 4],
    pub v: [f32; 4],
}

/// One node's box test on `path`, for benchmarks of the kernels alone: the mask of the lanes
/// the ray enters before `limit`, their entry distances in `dist`. A path this CPU lacks runs
/// the scalar kernel.
pub fn test_boxes<const N: usize>(
    path: SimdPath,
    node: &WideNode<N>,
    ray: &BoxRay,
    limit: f32,
    dist: &mut [f32; N],
) -> u32 {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2")]
        unsafe fn avx2<const N: usize>(node: &WideNode<N>, ray: &BoxRay, limit: f32, dist: &mut [f32; N]) -> u32 {
            // SAFETY: compiled for AVX2 and called only where the CPU has it.
            unsafe { Avx2::boxes(node, ray, limit, dist) }
        }
        #[target_feature(enable = "sse4.1")]
        unsafe fn sse4<const N: usize>(node: &WideNode<N>, ray: &BoxRay, limit: f32, dist: &mut [f32; N]) -> u32 {
            // SAFETY: compiled for SSE4.1 and called only where the CPU has it.
            unsafe { Sse4::boxes(node, ray, limit, dist) }
        }
        match path {
            // SAFETY: taken only where the CPU has the path's features.
            SimdPath::Avx2 if path.is_available() => return unsafe { avx2(node, ray, limit, dist) },
            // SAFETY: as above.
            SimdPath::Sse4 if path.is_available() => return unsafe { sse4(node, ray, limit, dist) },
            _ => {}
        }
    }
    #[cfg(target_arch = "aarch64")]
    {
        #[target_feature(enable = "neon")]
        unsafe fn neon<const N: usize>(node: &WideNode<N>, ray: &BoxRay, limit: f32, dist: &mut [f32; N]) -> u32 {
            // SAFETY: compiled for NEON and called only where the CPU has it.
            unsafe { Neon::boxes(node, ray, limit, dist) }
        }
        if path == SimdPath::Neon && path.is_available() {
            // SAFETY: taken only where the CPU has NEON.
            return unsafe { neon(node, ray, limit, dist) };
        }
    }
    let _ = path;
    // SAFETY: portable code.
    unsafe { Scalar::boxes(node, ray, limit, dist) }
}

/// One packet's triangle test on `path`, for benchmarks of the kernels alone (a path this CPU
/// lacks runs the scalar kernel, which accepts nothing and leaves its candidates checked).
pub fn test_triangles(path: SimdPath, packet: &TrianglePacket, ray: &PacketRay, t_max: f32) -> PacketHits {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2")]
        unsafe fn avx2(packet: &TrianglePacket, ray: &PacketRay, t_max: f32) -> PacketHits {
            // SAFETY: compiled for AVX2 and called only where the CPU has it.
            unsafe { Avx2::triangles(packet, ray, t_max, 0xf) }
        }
        #[target_feature(enable = "sse4.1")]
        unsafe fn sse4(packet: &TrianglePacket, ray: &PacketRay, t_max: f32) -> PacketHits {
            // SAFETY: compiled for SSE4.1 and called only where the CPU has it.
            unsafe { Sse4::triangles(packet, ray, t_max, 0xf) }
        }
        match path {
            // SAFETY: taken only where the CPU has the path's features.
            SimdPath::Avx2 if path.is_available() => return unsafe { avx2(packet, ray, t_max) },
            // SAFETY: as above.
            SimdPath::Sse4 if path.is_available() => return unsafe { sse4(packet, ray, t_max) },
            _ => {}
        }
    }
    #[cfg(target_arch = "aarch64")]
    {
        #[target_feature(enable = "neon")]
        unsafe fn neon(packet: &TrianglePacket, ray: &PacketRay, t_max: f32) -> PacketHits {
            // SAFETY: compiled for NEON and called only where the CPU has it.
            unsafe { Neon::triangles(packet, ray, t_max, 0xf) }
        }
        if path == SimdPath::Neon && path.is_available() {
            // SAFETY: taken only where the CPU has NEON.
            return unsafe { neon(packet, ray, t_max) };
        }
    }
    let _ = path;
    // SAFETY: portable code.
    unsafe { Scalar::triangles(packet, ray, t_max, 0xf) }
}

/// A path's kernels. Each method is the whole of one test; the traversals in
/// [`super::wide_mesh`] are written once over this trait and instantiated per path inside a
/// function compiled for that path's features. The kernels are `inline(always)` functions
/// without target features of their own (a `target_feature` function cannot be
/// `inline(always)`, and as a plain `inline` one it stayed a call), so they compile into that
/// function with its features.
///
/// # Safety
/// A kernel's methods run its instruction set: call them only where the CPU has it
/// ([`SimdPath::is_available`]).
pub(crate) unsafe trait Kernel {
    /// Lanes of `node` (in use) whose box the ray enters before `limit`, as a bit mask, with
    /// every lane's entry distance in `dist`. `N` is 4 or 8.
    ///
    /// # Safety
    /// The CPU has the kernel's instruction set.
    unsafe fn boxes<const N: usize>(node: &WideNode<N>, ray: &BoxRay, limit: f32, dist: &mut [f32; N]) -> u32;
    /// The lanes of `p` among `valid`, sorted by whether the watertight test hits them within
    /// `t_max`.
    ///
    /// # Safety
    /// The CPU has the kernel's instruction set.
    unsafe fn triangles(p: &TrianglePacket, ray: &PacketRay, t_max: f32, valid: u32) -> PacketHits;
}

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

/// The factor the f32 evaluation of the error bound is enlarged by: its dozen roundings move it
/// by less than 2^-19 of itself (module docs).
const BOUND_MARGIN: f32 = 1.0 + 1.0 / 65536.0;
/// The smallest f32 bound trusted, and the smallest coordinate, edge-function and depth maxima it
/// is computed from: with every maximum at least 2^-30, every product in the bound (at most
/// three maxima and a `γ` of about 2^-23) is at least 2^-113, a normal float, so no term loses
/// more to underflow than the margin covers. (A tiny maximum multiplied into a huge one lost its
/// term to underflow; such lanes go to the scalar test.)
const BOUND_FLOOR: f32 = 1.0e-25;
const MAXIMUM_FLOOR: f32 = 1.0 / (1u64 << 30) as f32;

/// The triangle filter for one lane (module docs).
#[inline(always)]
fn scalar_candidate(p: &TrianglePacket, i: usize, r: &PacketRay, t_max: f32) -> bool {
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

/// The six plane rows of a node: `min_x min_y min_z max_x max_y max_z`, `N` lanes each.
#[cfg(any(target_arch = "x86_64", target_arch = "aarch64"))]
#[inline(always)]
fn planes<const N: usize>(node: &WideNode<N>) -> &[[f32; N]; 6] {
    // SAFETY: `WideNode` is `repr(C)` and starts with six `[f32; N]` fields, which have no
    // padding between them, so its first `6 N` floats are those rows in that order.
    unsafe { &*(node as *const WideNode<N>).cast::<[[f32; N]; 6]>() }
}

#[cfg(target_arch = "aarch64")]
pub(crate) use arm::Neon;
#[cfg(target_arch = "x86_64")]
pub(crate) use x86::{Avx2, Sse4};

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    use super::{
        BOUND_FLOOR, BOUND_MARGIN, BoxRay, Kernel, MAXIMUM_FLOOR, PacketHits, PacketRay, ROBUST_SLAB_SCALE,
        TrianglePacket, planes,
    };
    use crate::bvh::INVALID_INDEX;
    use crate::bvh::wide::WideNode;
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

    /// The triangle kernel on four lanes (the module docs; [`super::scalar_candidate`] and the
    /// scalar test's error bound lane by lane, with the same operations in the same order).
    #[inline(always)]
    unsafe fn triangles_sse(p: &TrianglePacket, r: &PacketRay, t_max: f32, valid: u32) -> PacketHits {
        let [kx, ky, kz] = r.k;
        // SAFETY: every load reads one 16-byte-aligned row of `p` (`TrianglePacket` is
        // `align(16)` and its rows are 16 bytes each); the stores write whole arrays of four.
        unsafe {
            let rel = |vertex: usize, axis: usize, o: f32| {
                _mm_sub_ps(_mm_load_ps(p.v[vertex][axis].as_ptr()), _mm_set1_ps(o))
            };
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
}

/// The NEON kernels: the SSE4.1 kernels' operations, in the same order, on the same four lanes.
///
/// Where the instruction sets differ:
/// - `maxps(x, acc)` is `x > acc ? x : acc`, and the scalar code relies on it (a NaN `x` keeps
///   the accumulator). NEON's `vmaxq_f32` returns NaN where either operand is, and `vmaxnmq_f32`
///   returns the other operand, so it would also drop a NaN accumulator (a NaN `limit` or
///   `t_max`) that the scalar and SSE4.1 code keep; and it orders `-0.0` below `+0.0`. So each
///   `maxps`/`minps` becomes the compare and select it is defined as ([`max_ps`], [`min_ps`]).
/// - `movemask` has no single instruction: the comparison masks are all ones or all zeros per
///   lane, so lane `i` ANDed with `1 << i` and the lanes summed across (`vaddvq_u32`) give the
///   same bits ([`movemask`]).
/// - Subnormals: AArch64's Advanced SIMD honours FPCR as scalar code does (no flush to zero
///   unless the process asks, as on x86 with MXCSR); AArch32 NEON, which always flushes, is not
///   a target here.
/// - No fused multiply-adds: each `_mm_mul_ps` and `_mm_add_ps`/`_mm_sub_ps` pair is a
///   `vmulq_f32` and a `vaddq_f32`/`vsubq_f32` (never `vfmaq_f32` or `vmlaq_f32`), and rustc does
///   not contract them.
#[cfg(target_arch = "aarch64")]
mod arm {
    use std::arch::aarch64::*;

    use super::{
        BOUND_FLOOR, BOUND_MARGIN, BoxRay, Kernel, MAXIMUM_FLOOR, PacketHits, PacketRay, ROBUST_SLAB_SCALE,
        TrianglePacket, planes,
    };
    use crate::bvh::INVALID_INDEX;
    use crate::bvh::wide::WideNode;
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
    /// [`super`]; [`super::scalar_candidate`] and the scalar test's error bound lane by lane).
    ///
    /// # Safety
    /// The CPU has NEON.
    #[inline(always)]
    unsafe fn triangles_neon(p: &TrianglePacket, r: &PacketRay, t_max: f32, valid: u32) -> PacketHits {
        let [kx, ky, kz] = r.k;
        // SAFETY: every load reads one row of four floats of `p`; the stores write whole arrays
        // of four; the caller's contract (the CPU has NEON).
        unsafe {
            let rel =
                |vertex: usize, axis: usize, o: f32| vsubq_f32(vld1q_f32(p.v[vertex][axis].as_ptr()), vdupq_n_f32(o));
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
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Ray, Triangle};
    use glam::Vec3;

    /// A small deterministic generator, enough for test inputs.
    struct Lcg(u64);

    impl Lcg {
        fn f32(&mut self) -> f32 {
            self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (self.0 >> 40) as f32 / (1u64 << 24) as f32
        }

        fn vec3(&mut self) -> Vec3 {
            Vec3::new(self.f32(), self.f32(), self.f32()) * 2.0 - 1.0
        }
    }

    fn pack(tris: &[Triangle]) -> TrianglePacket {
        let mut p = TrianglePacket { v: [[[0.0; 4]; 3]; 3], prim: [0, 1, 2, 3] };
        for (i, t) in tris.iter().enumerate() {
            for (k, v) in [t.v0, t.v1, t.v2].into_iter().enumerate() {
                (p.v[k][0][i], p.v[k][1][i], p.v[k][2][i]) = (v.x, v.y, v.z);
            }
        }
        p
    }

    /// Each architecture's paths, and only those, are available; another's is refused by name.
    #[test]
    fn paths_follow_the_architecture() {
        for path in SimdPath::ALL {
            assert_eq!(SimdPath::parse(path.name()), Some(path));
        }
        let foreign: &[SimdPath] = if cfg!(target_arch = "aarch64") {
            assert!(SimdPath::Neon.is_available(), "NEON is in the aarch64 baseline");
            assert_eq!(SimdPath::best(), SimdPath::Neon);
            assert_eq!(TraceLayout::default_for(SimdPath::best()), TraceLayout::Wide4);
            &[SimdPath::Sse4, SimdPath::Avx2]
        } else {
            &[SimdPath::Neon]
        };
        for &path in foreign {
            assert!(!path.is_available(), "{}", path.name());
            let err = SimdPath::from_name(path.name()).unwrap_err();
            assert!(matches!(err, SimdError::Unavailable(..)), "{err}");
            assert!(err.to_string().contains("does not support"), "{err}");
        }
        assert!(matches!(SimdPath::from_name("altivec"), Err(SimdError::Unknown(_))));
        assert_eq!(SimdPath::from_name(" scalar "), Ok(SimdPath::Scalar));
    }

    /// One random `N`-wide node: boxes of every kind, some planes NaN or infinite, and now and
    /// then its last lanes empty (with boxes left in them that the kernels must not report).
    fn random_node<const N: usize>(r: &mut Lcg) -> WideNode<N> {
        let mut rows = [[0.0f32; N]; 6];
        let mut child = [0u32; N];
        let used = if r.f32() < 0.3 { 1 + (r.f32() * N as f32) as usize % N } else { N };
        for i in 0..N {
            let (a, b) = (r.vec3(), r.vec3());
            let (lo, hi) = (a.min(b), a.max(b));
            (rows[0][i], rows[1][i], rows[2][i]) = (lo.x, lo.y, lo.z);
            (rows[3][i], rows[4][i], rows[5][i]) = (hi.x, hi.y, hi.z);
            // A NaN, an infinite or a zero-thickness plane now and then.
            let k = (r.f32() * 6.0) as usize % 6;
            match (r.f32() * 8.0) as u32 {
                0 => rows[k][i] = f32::NAN,
                1 => rows[k][i] = if k < 3 { f32::NEG_INFINITY } else { f32::INFINITY },
                2 => rows[k][i] = rows[(k + 3) % 6][i],
                _ => {}
            }
            child[i] = if i < used { i as u32 } else { crate::bvh::INVALID_INDEX };
        }
        let [min_x, min_y, min_z, max_x, max_y, max_z] = rows;
        WideNode { min_x, min_y, min_z, max_x, max_y, max_z, child, count: [0; N] }
    }

    /// Every box kernel this CPU runs gives the scalar slab test's mask and entry distances to
    /// the bit, NaN planes included: rays with zero direction components (infinite reciprocals,
    /// NaN slabs where the origin lies on a plane), infinite and NaN limits.
    #[test]
    fn box_kernels_match_the_scalar_slab_test() {
        fn check<const N: usize>(r: &mut Lcg, case: usize) {
            let node = random_node::<N>(r);
            let mut dir = r.vec3();
            if case % 3 == 0 {
                dir[(case / 3) % 3] = if case % 2 == 0 { 0.0 } else { -0.0 };
            }
            let mut origin = r.vec3() * 2.0;
            if case % 5 == 0 {
                // On a plane of the first lane, where a zero direction makes `0 × inf` NaN.
                origin.x = node.min_x[0];
                dir.x = 0.0;
            }
            let limit = [f32::INFINITY, 1.5, f32::NAN, 0.0][case % 4];
            let ray = BoxRay::new(Ray::new(origin, dir).inv());
            let mut expected = [0.0f32; N];
            // SAFETY: portable code.
            let mask = unsafe { Scalar::boxes(&node, &ray, limit, &mut expected) };
            for path in SimdPath::available() {
                let mut dist = [0.0f32; N];
                let m = test_boxes(path, &node, &ray, limit, &mut dist);
                assert_eq!(m, mask, "{}, case {case}, N = {N}", path.name());
                for i in (0..N).filter(|i| mask & (1 << i) != 0) {
                    assert_eq!(dist[i].to_bits(), expected[i].to_bits(), "{}, case {case}, lane {i}", path.name());
                }
            }
        }
        let mut r = Lcg(11);
        for case in 0..20_000 {
            check::<4>(&mut r, case);
            check::<8>(&mut r, case);
        }
    }

    /// Every kernel this CPU runs sorts every lane as the scalar watertight test decides it:
    /// an accepted lane carries exactly the scalar hit, a rejected lane is one the scalar test
    /// misses. Rays aimed at vertices and edges (the f64 paths), rays leaving a triangle's
    /// surface (`t` within its bound of zero), at scales from 10^-6 to 10^6.
    #[test]
    fn kernels_sort_lanes_as_the_scalar_test_does() {
        let mut r = Lcg(7);
        let (mut accepted, mut checked) = (0, 0);
        for case in 0..40_000 {
            let scale = [1e-6f32, 1.0, 1e3, 1e6][case % 4];
            let offset = Vec3::splat([0.0f32, 0.0, 1e5, 0.0][case % 4]);
            let tris: Vec<Triangle> = (0..4)
                .map(|_| {
                    let c = r.vec3();
                    Triangle::new(c + r.vec3() * 0.3, c + r.vec3() * 0.3, c + r.vec3() * 0.3)
                })
                .map(|t| Triangle::new(t.v0 * scale + offset, t.v1 * scale + offset, t.v2 * scale + offset))
                .collect();
            let target = match case % 3 {
                0 => tris[case % 4].v1,
                1 => tris[case % 4].v0.lerp(tris[case % 4].v2, r.f32()),
                _ => tris[case % 4].point(r.f32() * 0.5, r.f32() * 0.5),
            };
            let origin = if case % 5 == 0 { target } else { offset + r.vec3() * 3.0 * scale };
            let dir = if case % 5 == 0 { r.vec3() } else { target - origin };
            let ray = Ray::new(origin, dir);
            let t_max = if case % 7 == 0 { r.f32() * 2.0 } else { f32::INFINITY };
            let p = pack(&tris);
            let pr = PacketRay::new(WatertightRay::new(&ray));
            let kernels: Vec<(&str, PacketHits)> = SimdPath::available()
                .into_iter()
                .map(|path| (path.name(), test_triangles(path, &p, &pr, t_max)))
                .collect();
            for (name, hits) in kernels {
                for (i, tri) in tris.iter().enumerate() {
                    let scalar = tri.intersect(&pr.wr, t_max);
                    if hits.accept & (1 << i) != 0 {
                        let h =
                            scalar.unwrap_or_else(|| panic!("{name}, case {case}: lane {i} accepted, scalar misses"));
                        let bits = |h: (f32, f32, f32)| (h.0.to_bits(), h.1.to_bits(), h.2.to_bits());
                        assert_eq!(
                            bits((hits.t[i], hits.u[i], hits.v[i])),
                            bits((h.t, h.u, h.v)),
                            "{name}, case {case}"
                        );
                        accepted += 1;
                    } else if hits.check & (1 << i) != 0 {
                        checked += 1;
                    } else {
                        assert_eq!(scalar, None, "{name}, case {case}: lane {i} rejected, scalar hits");
                    }
                }
            }
        }
        // On aarch64 the NEON kernel was among those compared.
        #[cfg(target_arch = "aarch64")]
        assert!(SimdPath::available().contains(&SimdPath::Neon));
        // Both kinds of lane occur, so the comparison above tested something.
        assert!(accepted > 1000 && checked > 1000, "accepted {accepted}, checked {checked}");
        // Coordinates of very different scales on one triangle: the f32 bound's terms underflow
        // where the f64 bound's do not (found by a reading of the kernel). The kernel must then
        // defer, not accept its own `t`.
        let anisotropic =
            Triangle::new(Vec3::new(-1e-40, -1e30, 1.0), Vec3::new(1e-40, -1e30, 1.0), Vec3::new(0.0, 1e30, -0.999998));
        let ray = Ray::new(Vec3::ZERO, Vec3::Z);
        let pr = PacketRay::new(WatertightRay::new(&ray));
        let p = pack(&[anisotropic; 4]);
        for path in SimdPath::available() {
            let hits = test_triangles(path, &p, &pr, f32::INFINITY);
            let scalar = anisotropic.intersect(&pr.wr, f32::INFINITY);
            if hits.accept & 1 != 0 {
                let h = scalar.expect("accepted, so the scalar test hits");
                assert_eq!((hits.t[0], hits.u[0], hits.v[0]), (h.t, h.u, h.v), "{}", path.name());
            } else if hits.check & 1 == 0 {
                assert_eq!(scalar, None, "{}", path.name());
            }
        }
    }
}
