//! A wide tree over a mesh's triangles, ready to trace: the nodes of a [`WideBvh`] whose leaf
//! lanes point to packets of four triangles ([`TrianglePacket`]) instead of `prim_ids`
//! positions, traced by one [`SimdPath`]'s kernels.
//!
//! A leaf lane keeps its triangle count in `count`, and `child` becomes the index of its first
//! packet; a leaf of `n` triangles owns `ceil(n / 4)` consecutive packets. Memory: 160 bytes per
//! packet, so 40 bytes per triangle in full packets; the collapse leaves of up to 8 triangles,
//! so a leaf of 5 wastes three lanes.
//!
//! The traversal is written once, over [`Kernel`], and instantiated inside one function per
//! path compiled with that path's target features, so the kernels inline into it. It is the
//! traversal of [`WideBvh::closest_hit`] (hit lanes visited near to far, the same culling slack,
//! ties to the lowest primitive id), with the leaves tested four triangles at a time: the kernel
//! rejects the lanes the scalar watertight test would reject, accepts those it would hit with
//! the same `t`, `u`, `v`, and leaves the rest to the scalar test ([`crate::bvh::trace::simd`]), so every
//! path returns exactly the hits of [`crate::bvh::Bvh::closest_hit_triangles`].
//!
//! `skip` names a primitive to leave out: a ray spawned from a triangle never needs to test it
//! (its origin is offset to the side of the plane the ray leaves to, so the plane lies behind
//! it), and that test was the costly one, since its `t` is within its error bound of zero and
//! goes to the f64 path.

use rayon::prelude::*;

use crate::geometry::{Aabb, Ray, Triangle, WatertightRay};

use crate::bvh::trace::simd::{BoxRay, Kernel, PacketRay, Scalar, SimdPath, TrianglePacket};
use crate::bvh::trace::wide::{
    Entry, WideNode, WideValidationError, collapse, far_to_near, nodes_bounds, nodes_sah, validate_nodes,
};
use crate::bvh::trace::{HitFilter, Skip, Stack, cull_limit, cull_slack};
use crate::bvh::{Bvh, BvhNode, Hit, INVALID_INDEX, SahCosts};

#[cfg(doc)]
use crate::bvh::trace::wide::WideBvh;

/// Entries a traversal keeps before spilling to the heap.
const STACK_SIZE: usize = 128;

/// A wide tree with its triangles in packets, and the path that traces it (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct WideMesh<const N: usize> {
    nodes: Vec<WideNode<N>>,
    packets: Vec<TrianglePacket>,
    bounds: Aabb,
    simd: SimdPath,
}

impl<const N: usize> WideMesh<N> {
    /// Collapses `bvh` into `N`-wide nodes (the pull-up of [`WideBvh::from_binary`]) and packs
    /// its leaves from `leaf_ordered` (the triangle at each `prim_ids` position, as
    /// [`crate::bvh::MeshBvh`] keeps them), for tracing on `simd`; a path this CPU lacks is replaced
    /// by the best one it has.
    ///
    /// A subtree of at most four triangles becomes one leaf lane, one packet: testing four
    /// triangles at once costs about what one box test does, and the binary tree's leaves,
    /// sized for one triangle at a time, would leave most lanes of their packets empty.
    pub fn from_binary(bvh: &Bvh, leaf_ordered: &[Triangle], simd: SimdPath) -> Self {
        const { assert!(N == 4 || N == 8, "the SIMD kernels test 4 or 8 lanes") };
        let nodes: &[BvhNode] = &bvh.nodes;
        let prim_ids = &bvh.prim_ids;
        // First the nodes, each leaf lane given its packets' place; then the packets, filled in
        // parallel: most of the time goes to faulting in their memory and gathering triangles.
        // Each leaf: its first `prim_ids` position (a binary leaf) or the first child of the
        // subtree it merges, its triangle count, and whether it is merged.
        let mut leaves: Vec<(u32, u32, bool)> = Vec::with_capacity(prim_ids.len() / 2 + 1);
        let mut total = 0usize;
        let small = small_subtrees(nodes);
        let leaf = |i: u32, n: &BvhNode| {
            if n.is_leaf() {
                return Some((n.first, n.prim_count));
            }
            let count = small[i as usize];
            (count <= 4).then_some((INVALID_INDEX, u32::from(count)))
        };
        let place = |n: &BvhNode, (first, count): (u32, u32)| {
            let merged = first == INVALID_INDEX;
            leaves.push((if merged { n.first } else { first }, count, merged));
            let index = total as u32;
            total += count.div_ceil(4) as usize;
            (index, count)
        };
        let wide = collapse::<N>(bvh, leaf, place);
        let mut packets: Vec<TrianglePacket> = Vec::with_capacity(total);
        let mut rest = &mut packets.spare_capacity_mut()[..total];
        let mut jobs = Vec::with_capacity(leaves.len());
        for &(first, count, merged) in &leaves {
            let (mine, tail) = rest.split_at_mut(count.div_ceil(4) as usize);
            jobs.push((first, count, merged, mine));
            rest = tail;
        }
        jobs.into_par_iter().with_min_len(1024).for_each(|(first, count, merged, out)| {
            let mut merged_positions = [0u32; 4];
            if merged {
                leaf_positions(nodes, first, &mut merged_positions);
            }
            let position = |k: usize| if merged { merged_positions[k] as usize } else { first as usize + k };
            for (j, slot) in out.iter_mut().enumerate() {
                let lanes = (count as usize - 4 * j).min(4);
                let mut p = TrianglePacket { v: [[[0.0; 4]; 3]; 3], prim: [INVALID_INDEX; 4] };
                for i in 0..4 {
                    // Lanes past the leaf's count repeat the packet's first triangle (never tested).
                    let pos = position(4 * j + if i < lanes { i } else { 0 });
                    let t = &leaf_ordered[pos];
                    for (k, v) in [t.v0, t.v1, t.v2].into_iter().enumerate() {
                        (p.v[k][0][i], p.v[k][1][i], p.v[k][2][i]) = (v.x, v.y, v.z);
                    }
                    if i < lanes {
                        p.prim[i] = prim_ids[pos];
                    }
                }
                slot.write(p);
            }
        });
        // SAFETY: the jobs' slices partition the first `total` slots of the spare capacity, and
        // every job wrote each slot of its slice.
        unsafe { packets.set_len(total) };
        let bounds = nodes_bounds(&wide);
        let simd = if simd.is_available() { simd } else { SimdPath::best() };
        Self { nodes: wide, packets, bounds, simd }
    }

    /// The path this tree is traced with.
    pub fn simd(&self) -> SimdPath {
        self.simd
    }

    /// The box of everything in the tree.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// Bytes of the nodes and packets, by length.
    pub fn memory_bytes(&self) -> usize {
        size_of_val(self.nodes.as_slice()) + size_of_val(self.packets.as_slice())
    }

    /// The wide tree's SAH ([`WideBvh::sah`]).
    pub fn sah(&self, costs: &SahCosts) -> f64 {
        nodes_sah(&self.nodes, costs)
    }

    /// The nodes (leaf lanes index packets).
    pub fn nodes(&self) -> &[WideNode<N>] {
        &self.nodes
    }

    /// The triangle packets.
    pub fn packets(&self) -> &[TrianglePacket] {
        &self.packets
    }

    /// Checks the tree's invariants ([`WideBvh::validate`]) with leaves read from the packets:
    /// every packet range inside `packets`, every primitive in exactly one lane, each packed
    /// triangle's box equal to its primitive's box in `prim_aabbs`, and each leaf box exactly the
    /// union of its packed triangles.
    pub fn validate(&self, prim_aabbs: &[Aabb]) -> Result<(), WideValidationError> {
        use WideValidationError as E;
        let mut seen = vec![0u32; prim_aabbs.len()];
        validate_nodes(&self.nodes, |node, lane, first, count| {
            let end = u64::from(first) + u64::from(count.div_ceil(4));
            if end > self.packets.len() as u64 {
                return Err(E::PacketRange { node, lane, first, end, len: self.packets.len() });
            }
            let mut b = Aabb::EMPTY;
            for j in 0..count as usize {
                let p = &self.packets[first as usize + j / 4];
                let prim = p.prim[j % 4];
                let expected = *prim_aabbs.get(prim as usize).ok_or(E::PrimOutOfRange { node, lane, prim })?;
                let found = p.triangle(j % 4).aabb();
                if found != expected {
                    return Err(E::PackedTriangle { node, lane, prim, found, expected });
                }
                seen[prim as usize] += 1;
                b = b.union(found);
            }
            Ok(b)
        })?;
        if let Some((prim, &c)) = seen.iter().enumerate().find(|(_, c)| **c != 1) {
            return Err(E::Primitive(prim as u32, c));
        }
        Ok(())
    }

    /// The closest triangle hit with `0 < t <= t_max`, leaving out primitive `skip`
    /// ([`INVALID_INDEX`] for none); ties go to the lowest primitive id.
    #[inline]
    pub fn closest_hit(&self, ray: &Ray, t_max: f32, skip: u32) -> Option<Hit> {
        self.closest_hit_filtered(ray, t_max, &Skip(skip))
    }

    /// [`WideMesh::closest_hit`] leaving out every hit `(prim, u, v)` that `reject` refuses
    /// (the skipped primitive, cut-out texels): the nearest hit it keeps.
    #[inline]
    pub fn closest_hit_filtered<R: HitFilter>(&self, ray: &Ray, t_max: f32, skip: &R) -> Option<Hit> {
        match self.simd {
            // SAFETY: `simd` is a path this CPU has (checked in `from_binary`).
            #[cfg(target_arch = "x86_64")]
            SimdPath::Avx2 => unsafe { self.closest_avx2(ray, t_max, skip) },
            // SAFETY: as above.
            #[cfg(target_arch = "x86_64")]
            SimdPath::Sse4 => unsafe { self.closest_sse4(ray, t_max, skip) },
            // SAFETY: as above.
            #[cfg(target_arch = "aarch64")]
            SimdPath::Neon => unsafe { self.closest_neon(ray, t_max, skip) },
            // SAFETY: portable code.
            _ => unsafe { self.closest::<Scalar, R>(ray, t_max, skip) },
        }
    }

    /// Whether any triangle but `skip` is hit with `0 < t <= t_max`; stops at the first found.
    #[inline]
    pub fn any_hit(&self, ray: &Ray, t_max: f32, skip: u32) -> bool {
        self.any_hit_filtered(ray, t_max, &Skip(skip))
    }

    /// [`WideMesh::any_hit`] counting only hits `(prim, u, v)` that `reject` does not refuse.
    #[inline]
    pub fn any_hit_filtered<R: HitFilter>(&self, ray: &Ray, t_max: f32, skip: &R) -> bool {
        match self.simd {
            // SAFETY: `simd` is a path this CPU has (checked in `from_binary`).
            #[cfg(target_arch = "x86_64")]
            SimdPath::Avx2 => unsafe { self.any_avx2(ray, t_max, skip) },
            // SAFETY: as above.
            #[cfg(target_arch = "x86_64")]
            SimdPath::Sse4 => unsafe { self.any_sse4(ray, t_max, skip) },
            // SAFETY: as above.
            #[cfg(target_arch = "aarch64")]
            SimdPath::Neon => unsafe { self.any_neon(ray, t_max, skip) },
            // SAFETY: portable code.
            _ => unsafe { self.any::<Scalar, R>(ray, t_max, skip) },
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn closest_avx2<R: HitFilter>(&self, ray: &Ray, t_max: f32, skip: &R) -> Option<Hit> {
        // SAFETY: this function is compiled for the kernel's features and called only where
        // the CPU has them.
        unsafe { self.closest::<crate::bvh::trace::simd::Avx2, R>(ray, t_max, skip) }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "sse4.1")]
    unsafe fn closest_sse4<R: HitFilter>(&self, ray: &Ray, t_max: f32, skip: &R) -> Option<Hit> {
        // SAFETY: this function is compiled for the kernel's features and called only where
        // the CPU has them.
        unsafe { self.closest::<crate::bvh::trace::simd::Sse4, R>(ray, t_max, skip) }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn any_avx2<R: HitFilter>(&self, ray: &Ray, t_max: f32, skip: &R) -> bool {
        // SAFETY: this function is compiled for the kernel's features and called only where
        // the CPU has them.
        unsafe { self.any::<crate::bvh::trace::simd::Avx2, R>(ray, t_max, skip) }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "sse4.1")]
    unsafe fn any_sse4<R: HitFilter>(&self, ray: &Ray, t_max: f32, skip: &R) -> bool {
        // SAFETY: this function is compiled for the kernel's features and called only where
        // the CPU has them.
        unsafe { self.any::<crate::bvh::trace::simd::Sse4, R>(ray, t_max, skip) }
    }

    #[cfg(target_arch = "aarch64")]
    #[target_feature(enable = "neon")]
    unsafe fn closest_neon<R: HitFilter>(&self, ray: &Ray, t_max: f32, skip: &R) -> Option<Hit> {
        // SAFETY: this function is compiled for the kernel's features and called only where
        // the CPU has them.
        unsafe { self.closest::<crate::bvh::trace::simd::Neon, R>(ray, t_max, skip) }
    }

    #[cfg(target_arch = "aarch64")]
    #[target_feature(enable = "neon")]
    unsafe fn any_neon<R: HitFilter>(&self, ray: &Ray, t_max: f32, skip: &R) -> bool {
        // SAFETY: this function is compiled for the kernel's features and called only where
        // the CPU has them.
        unsafe { self.any::<crate::bvh::trace::simd::Neon, R>(ray, t_max, skip) }
    }

    /// # Safety
    /// The CPU has `K`'s instruction set.
    #[inline(always)]
    unsafe fn closest<K: Kernel, R: HitFilter>(&self, ray: &Ray, t_max: f32, skip: &R) -> Option<Hit> {
        if self.nodes.is_empty() {
            return None;
        }
        let br = BoxRay::new(ray.inv());
        // Set up at the first leaf and the first hit: most primary rays miss everything, and
        // for them this set-up (three divisions and a permutation; the slack's division) was a
        // large part of the cost.
        let mut pr: Option<PacketRay> = None;
        let mut slack: Option<f32> = None;
        let mut limit = if t_max == f32::INFINITY {
            f32::INFINITY
        } else {
            cull_limit(t_max, *slack.insert(cull_slack(&self.bounds, ray)))
        };
        let mut best: Option<Hit> = None;
        let mut stack = Stack::<Entry, STACK_SIZE>::new();
        let mut dist = [0.0f32; N];
        let mut current = Entry::default();
        loop {
            if current.count > 0 {
                let pr = pr.get_or_insert_with(|| PacketRay::new(WatertightRay::new(ray)));
                for j in 0..current.count.div_ceil(4) {
                    let p = &self.packets[(current.child + j) as usize];
                    let valid = (1u32 << (current.count - 4 * j).min(4)) - 1;
                    // SAFETY: the caller's contract.
                    let hits = unsafe { K::triangles(p, pr, best.map_or(t_max, |b| b.t), valid) };
                    let mut lanes = hits.accept | hits.check;
                    while lanes != 0 {
                        let i = lanes.trailing_zeros() as usize;
                        lanes &= lanes - 1;
                        let prim = p.prim[i];
                        if skip.skips(prim) {
                            continue;
                        }
                        let t_limit = best.map_or(t_max, |b| b.t);
                        let h = if hits.accept & (1 << i) != 0 {
                            // Known hit, at most the limit the kernel was given; a nearer hit
                            // found since may have lowered it.
                            if hits.t[i] > t_limit {
                                continue;
                            }
                            Hit { t: hits.t[i], prim_id: prim, u: hits.u[i], v: hits.v[i] }
                        } else {
                            let Some(h) = p.triangle(i).intersect(&pr.wr, t_limit) else { continue };
                            Hit { t: h.t, prim_id: prim, u: h.u, v: h.v }
                        };
                        if R::USES_UV && skip.reject(prim, h.u, h.v) {
                            continue;
                        }
                        if best.is_none_or(|b| h.t < b.t || (h.t == b.t && prim < b.prim_id)) {
                            limit = cull_limit(h.t, *slack.get_or_insert_with(|| cull_slack(&self.bounds, ray)));
                            best = Some(h);
                        }
                    }
                }
            } else {
                let node = &self.nodes[current.child as usize];
                // SAFETY: the caller's contract.
                let mask = unsafe { K::boxes(node, &br, limit, &mut dist) };
                if mask != 0 {
                    let entry = |i: usize| Entry { child: node.child[i], count: node.count[i], t: dist[i] };
                    if mask & (mask - 1) == 0 {
                        current = entry(mask.trailing_zeros() as usize);
                        continue;
                    }
                    // Several: farthest first onto the stack, the nearest visited next.
                    let (hits, n) = far_to_near(node, mask, &dist);
                    for &e in &hits[..n - 1] {
                        stack.push(e);
                    }
                    current = hits[n - 1];
                    continue;
                }
            }
            loop {
                let Some(e) = stack.pop() else { return best };
                if e.t <= limit {
                    current = e;
                    break;
                }
            }
        }
    }

    /// # Safety
    /// The CPU has `K`'s instruction set.
    #[inline(always)]
    unsafe fn any<K: Kernel, R: HitFilter>(&self, ray: &Ray, t_max: f32, skip: &R) -> bool {
        if self.nodes.is_empty() {
            return false;
        }
        let br = BoxRay::new(ray.inv());
        let mut pr: Option<PacketRay> = None;
        let limit = cull_limit(t_max, cull_slack(&self.bounds, ray));
        let mut stack = Stack::<Entry, STACK_SIZE>::new();
        let mut dist = [0.0f32; N];
        let mut current = Entry::default();
        loop {
            if current.count > 0 {
                let pr = pr.get_or_insert_with(|| PacketRay::new(WatertightRay::new(ray)));
                for j in 0..current.count.div_ceil(4) {
                    let p = &self.packets[(current.child + j) as usize];
                    let valid = (1u32 << (current.count - 4 * j).min(4)) - 1;
                    // SAFETY: the caller's contract.
                    let hits = unsafe { K::triangles(p, pr, t_max, valid) };
                    let mut lanes = hits.accept | hits.check;
                    while lanes != 0 {
                        let i = lanes.trailing_zeros() as usize;
                        lanes &= lanes - 1;
                        if skip.skips(p.prim[i]) {
                            continue;
                        }
                        if !R::USES_UV {
                            // The barycentrics unread, the kernel's are left uncomputed.
                            if hits.accept & (1 << i) != 0 || p.triangle(i).intersect(&pr.wr, t_max).is_some() {
                                return true;
                            }
                            continue;
                        }
                        let (u, v) = if hits.accept & (1 << i) != 0 {
                            (hits.u[i], hits.v[i])
                        } else {
                            let Some(h) = p.triangle(i).intersect(&pr.wr, t_max) else { continue };
                            (h.u, h.v)
                        };
                        if !skip.reject(p.prim[i], u, v) {
                            return true;
                        }
                    }
                }
            } else {
                let node = &self.nodes[current.child as usize];
                // SAFETY: the caller's contract.
                let mut mask = unsafe { K::boxes(node, &br, limit, &mut dist) };
                if mask != 0 {
                    // Any order finds a blocker; the first lane is visited next, the rest wait.
                    let i = mask.trailing_zeros() as usize;
                    mask &= mask - 1;
                    while mask != 0 {
                        let k = mask.trailing_zeros() as usize;
                        mask &= mask - 1;
                        stack.push(Entry { child: node.child[k], count: node.count[k], t: dist[k] });
                    }
                    current = Entry { child: node.child[i], count: node.count[i], t: dist[i] };
                    continue;
                }
            }
            let Some(e) = stack.pop() else { return false };
            current = e;
        }
    }
}

/// Each node's primitive count, capped at 5 (all a caller asks is whether it is at most four):
/// one pass over the nodes, backwards where every inner node's children come after it (the
/// layout of the leaf collapse and of most builders), else depth first.
fn small_subtrees(nodes: &[BvhNode]) -> Vec<u8> {
    let mut count = vec![0u8; nodes.len()];
    let own = |n: &BvhNode| n.prim_count.min(5) as u8;
    // The padding node (`PAD_INDEX`) is neither leaf nor parent.
    let ordered = nodes
        .iter()
        .enumerate()
        .all(|(i, n)| i == crate::bvh::PAD_INDEX as usize || n.is_leaf() || n.first as usize > i);
    if ordered {
        for i in (0..nodes.len()).rev() {
            let n = &nodes[i];
            count[i] =
                if n.is_leaf() { own(n) } else { (count[n.first as usize] + count[n.first as usize + 1]).min(5) };
        }
        return count;
    }
    let mut stack = vec![(0u32, false)];
    while let Some((i, expanded)) = stack.pop() {
        let n = &nodes[i as usize];
        if n.is_leaf() {
            count[i as usize] = own(n);
        } else if expanded {
            count[i as usize] = (count[n.first as usize] + count[n.first as usize + 1]).min(5);
        } else {
            stack.extend([(i, true), (n.first, false), (n.first + 1, false)]);
        }
    }
    count
}

/// The `prim_ids` positions of every leaf under the inner node whose children start at `first`,
/// a subtree [`small_subtrees`] found small (at most four primitives, so at most seven nodes),
/// depth first.
fn leaf_positions(nodes: &[BvhNode], first: u32, out: &mut [u32; 4]) {
    let mut stack = [0u32; 8];
    let (mut len, mut n) = (2, 0);
    (stack[0], stack[1]) = (first, first + 1);
    while len > 0 {
        len -= 1;
        let c = &nodes[stack[len] as usize];
        if c.is_leaf() {
            for pos in c.first..c.first + c.prim_count {
                out[n] = pos;
                n += 1;
            }
        } else {
            (stack[len], stack[len + 1]) = (c.first, c.first + 1);
            len += 2;
        }
    }
}
