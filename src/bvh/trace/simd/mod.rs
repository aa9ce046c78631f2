//! How rays are traced on the CPU: which tree form ([`TraceLayout`]) and which instruction set
//! ([`SimdPath`]), which the caller chooses and passes down ([`Tracing`]), plus the kernels each
//! path runs: one wide node's
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

use crate::bvh::trace::wide::WideNode;

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
/// it with its triangles in packets of four ([`crate::bvh::trace::wide_mesh::WideMesh`]).
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
    /// result down to every tree they build ([`crate::bvh::MeshBvh::new`], `device::Renderer::new`).
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
/// [`crate::bvh::trace::wide_mesh`] are written once over this trait and instantiated per path inside a
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

/// The factor the f32 evaluation of the error bound is enlarged by: its dozen roundings move it
/// by less than 2^-19 of itself (module docs).
pub(super) const BOUND_MARGIN: f32 = 1.0 + 1.0 / 65536.0;
/// The smallest f32 bound trusted, and the smallest coordinate, edge-function and depth maxima it
/// is computed from: with every maximum at least 2^-30, every product in the bound (at most
/// three maxima and a `γ` of about 2^-23) is at least 2^-113, a normal float, so no term loses
/// more to underflow than the margin covers. (A tiny maximum multiplied into a huge one lost its
/// term to underflow; such lanes go to the scalar test.)
pub(super) const BOUND_FLOOR: f32 = 1.0e-25;
pub(super) const MAXIMUM_FLOOR: f32 = 1.0 / (1u64 << 30) as f32;

/// The six plane rows of a node: `min_x min_y min_z max_x max_y max_z`, `N` lanes each.
#[cfg(any(target_arch = "x86_64", target_arch = "aarch64"))]
#[inline(always)]
pub(super) fn planes<const N: usize>(node: &WideNode<N>) -> &[[f32; N]; 6] {
    // SAFETY: `WideNode` is `repr(C)` and starts with six `[f32; N]` fields, which have no
    // padding between them, so its first `6 N` floats are those rows in that order.
    unsafe { &*(node as *const WideNode<N>).cast::<[[f32; N]; 6]>() }
}

#[cfg(target_arch = "aarch64")]
mod arm;
mod scalar;
#[cfg(target_arch = "x86_64")]
mod x86;

#[cfg(target_arch = "aarch64")]
pub(crate) use arm::Neon;
pub(crate) use scalar::Scalar;
#[cfg(target_arch = "x86_64")]
pub(crate) use x86::{Avx2, Sse4};

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
