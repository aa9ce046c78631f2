//! The GPU's compressed 8-wide BVH, after Ylitie, Karras & Laine 2017 ("Efficient Incoherent
//! Ray Traversal on GPUs Through Compressed Wide BVHs"; the collapse is their section 3), traced by
//! `shaders/bvh_wide8.wgsl`.
//!
//! **Shape.** The binary tree (any builder's; on the GPU path the one its LBVH and PRBVH made)
//! is collapsed by the SAH-optimal dynamic programme of [`crate::bvh::wide_sah`], with leaf
//! lanes of at most [`WIDE_MAX_LEAF`] triangles, so a node's leaves hold at most 24.
//!
//! **Node: 80 bytes, five `vec4<u32>`.**
//!
//! ```text
//!   word 0..2   p: the node box's lower corner (f32)
//!   word 3      ex | ey << 8 | ez << 16 | imask << 24
//!               e*: biased exponents of the per-axis scales 2^(e - 127);
//!               imask: bit s set where slot s is an inner node
//!   word 4      child_base: index of the first inner child (inner children are contiguous,
//!               in slot order: slot s is child_base + popcount(imask below s))
//!   word 5      tri_base: position of the first triangle of the node's leaves (contiguous,
//!               in slot order)
//!   word 6..7   meta[8], a byte per slot:
//!               0 empty; inner 0b001_00000 | (24 + s); leaf (unary count) << 5 | offset
//!   word 8..19  qlo_x[8] qlo_y[8] qlo_z[8] qhi_x[8] qhi_y[8] qhi_z[8], a byte each
//! ```
//!
//! A lane's box is `p + q * 2^e` per axis and plane, which is exact in f32 (q has 8 bits and
//! the scale is a power of two) up to the one rounding of the sum; each `q` is chosen, and
//! checked in f32, so that the decoded box contains the lane's exact box. Culling by decoded
//! boxes can only visit more, never less, so the wide form finds the binary form's hits.
//!
//! **Slots by octant.** Slot `s` holds the lane whose centre lies farthest from the node's
//! centre along the direction whose signs are `s`'s bits (bit set: negative), assigned
//! greedily (largest first). A ray whose direction has signs `o` visits hit lanes in order of
//! `s ^ o ^ 7`, nearest corner first, with no sort: the hit mask's inner bits are placed at
//! `24 + (s ^ o ^ 7)` and popped lowest first.

use rayon::prelude::*;

use crate::bvh::Bvh;
use crate::bvh::wide_sah::{self, Lane, WideCosts};
use crate::geometry::Aabb;

/// Words of one compressed node.
pub const WIDE_NODE_WORDS: usize = 20;

/// The most triangles of a leaf lane: its count is unary in three bits of its `meta` byte.
pub const WIDE_MAX_LEAF: u32 = 3;

/// A compressed 8-wide BVH ready for upload.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CompressedBvh {
    /// Node 0 is the root.
    pub nodes: Vec<[u32; WIDE_NODE_WORDS]>,
    /// The primitive at each triangle position.
    pub prim_ids: Vec<u32>,
    /// Nodes on the longest root-to-leaf path.
    pub depth: usize,
    /// The wide tree's SAH cost ([`crate::bvh::wide_sah::WideSah::cost`]).
    pub cost: f64,
}

/// What [`CompressedBvh::validate`] finds wrong.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CompressedError {
    #[error("node {node}, slot {slot}: decoded box {decoded:?} does not contain {exact:?}")]
    Box { node: usize, slot: usize, decoded: Aabb, exact: Aabb },
    #[error("node {node}, slot {slot}: child {child} out of range")]
    Child { node: usize, slot: usize, child: usize },
    #[error("node {0} is referenced {1} times, expected once (the root never)")]
    References(usize, u32),
    #[error("triangle position {0} is in {1} leaves, expected exactly one")]
    Position(usize, u32),
    #[error("node {node}, slot {slot}: bad meta byte {meta:#04x}")]
    Meta { node: usize, slot: usize, meta: u8 },
}

/// The power of two `2^(b - 127)` of a biased exponent `b` in 1..=254.
fn scale_of(biased: u32) -> f32 {
    f32::from_bits(biased << 23)
}

/// The biased exponent for one axis of a node spanning `lo..=hi`: the smallest scale with
/// `lo + 255 * scale >= hi` in f32.
fn axis_exponent(lo: f32, hi: f32) -> u32 {
    let extent = f64::from(hi) - f64::from(lo);
    let mut e = if extent > 0.0 { (extent / 255.0).log2().ceil() as i32 } else { -126 };
    e = e.clamp(-126, 127);
    // The estimate, settled by the decoder's own arithmetic (the condition is monotonic in e),
    // as `shaders/collapse.wgsl` settles its f32 estimate: both find the same exponent.
    while e > -126 && lo + 255.0 * scale_of((e + 126) as u32) >= hi {
        e -= 1;
    }
    while e < 127 && lo + 255.0 * scale_of((e + 127) as u32) < hi {
        e += 1;
    }
    (e + 127) as u32
}

/// The lower plane's byte: the largest `q` with `lo + q * s <= x`.
fn quantize_lo(lo: f32, s: f32, x: f32) -> u32 {
    let mut q = ((x - lo) / s).floor().clamp(0.0, 255.0) as u32;
    while q > 0 && lo + q as f32 * s > x {
        q -= 1;
    }
    q
}

/// The upper plane's byte: the smallest `q` with `lo + q * s >= x`.
fn quantize_hi(lo: f32, s: f32, x: f32) -> u32 {
    let mut q = ((x - lo) / s).ceil().clamp(0.0, 255.0) as u32;
    while q < 255 && lo + (q as f32) * s < x {
        q += 1;
    }
    q
}

/// Slot of each lane: the lane farthest along each octant's direction, largest first (ties to
/// the lower lane, then the lower slot).
fn assign_slots(boxes: &[Aabb], node: Aabb) -> [Option<usize>; 8] {
    let centre = node.center();
    let mut cost = [[0f32; 8]; 8];
    for (lane, b) in boxes.iter().enumerate() {
        let d = b.center() - centre;
        for (s, c) in cost[lane].iter_mut().enumerate() {
            let sign = |bit: usize| if s & bit != 0 { -1.0 } else { 1.0 };
            *c = d.x * sign(1) + d.y * sign(2) + d.z * sign(4);
        }
    }
    let mut slots = [None; 8];
    let mut placed = [false; 8];
    for _ in 0..boxes.len() {
        let mut pick: Option<(f32, usize, usize)> = None;
        for (lane, row) in cost.iter().enumerate().take(boxes.len()) {
            if placed[lane] {
                continue;
            }
            for (s, &c) in row.iter().enumerate() {
                if slots[s].is_none() && pick.is_none_or(|(best, _, _)| c > best) {
                    pick = Some((c, lane, s));
                }
            }
        }
        let (_, lane, s) = pick.expect("a free slot for every lane");
        slots[s] = Some(lane);
        placed[lane] = true;
    }
    slots
}

/// One node encoded, but for its child and triangle bases (words 4 and 5): its inner children
/// (wide node indices) and its leaves' runs of [`wide_sah::WideSah::prim_ids`], in slot order.
struct Encoded {
    words: [u32; WIDE_NODE_WORDS],
    children: Vec<u32>,
    leaves: Vec<(u32, u32)>,
}

/// Encodes a node with `lanes` (see the module docs).
fn encode(lanes: &[(Aabb, Lane)]) -> Encoded {
    let mut boxes = [Aabb::EMPTY; 8];
    for (b, (lane_box, _)) in boxes.iter_mut().zip(lanes) {
        *b = *lane_box;
    }
    let boxes = &boxes[..lanes.len()];
    let node_box = boxes.iter().fold(Aabb::EMPTY, |acc, b| acc.union(*b));
    let slots = assign_slots(boxes, node_box);
    let (lo, hi) = (node_box.min.to_array(), node_box.max.to_array());
    let exps: [u32; 3] = std::array::from_fn(|a| axis_exponent(lo[a], hi[a]));
    let scales = exps.map(scale_of);
    let mut e = Encoded { words: [0; WIDE_NODE_WORDS], children: Vec::new(), leaves: Vec::new() };
    e.words[0..3].copy_from_slice(&node_box.min.to_array().map(f32::to_bits));
    let mut imask = 0u32;
    let mut meta = [0u8; 8];
    let mut q = [[0u8; 8]; 6];
    let mut offset = 0u32;
    for (s, lane) in slots.iter().enumerate() {
        let Some(lane) = *lane else {
            // Empty: an inverted box, and no bits.
            (0..3).for_each(|a| q[a][s] = 255);
            continue;
        };
        let (b, kind) = lanes[lane];
        let (bl, bh) = (b.min.to_array(), b.max.to_array());
        for a in 0..3 {
            q[a][s] = quantize_lo(lo[a], scales[a], bl[a]) as u8;
            q[3 + a][s] = quantize_hi(lo[a], scales[a], bh[a]) as u8;
        }
        match kind {
            Lane::Node(child) => {
                imask |= 1 << s;
                meta[s] = 0b0010_0000 | (24 + s as u8);
                e.children.push(child);
            }
            Lane::Leaf { first, count } => {
                debug_assert!((1..=WIDE_MAX_LEAF).contains(&count) && offset + count <= 24);
                meta[s] = (((1u8 << count) - 1) << 5) | offset as u8;
                e.leaves.push((first, count));
                offset += count;
            }
        }
    }
    e.words[3] = exps[0] | exps[1] << 8 | exps[2] << 16 | imask << 24;
    e.words[6] = u32::from_le_bytes(meta[0..4].try_into().expect("4 bytes"));
    e.words[7] = u32::from_le_bytes(meta[4..8].try_into().expect("4 bytes"));
    for (plane, bytes) in q.iter().enumerate() {
        e.words[8 + 2 * plane] = u32::from_le_bytes(bytes[0..4].try_into().expect("4 bytes"));
        e.words[9 + 2 * plane] = u32::from_le_bytes(bytes[4..8].try_into().expect("4 bytes"));
    }
    e
}

impl CompressedBvh {
    /// Collapses `bvh` (see the module docs) and encodes it; `prim_aabbs` are the primitives'
    /// boxes by id. An empty tree gives one node with no lanes, which every ray misses.
    pub fn new(bvh: &Bvh, prim_aabbs: &[Aabb]) -> CompressedBvh {
        let wide = wide_sah::collapse(bvh, prim_aabbs, 8, WIDE_MAX_LEAF, WideCosts::default());
        if wide.nodes.is_empty() {
            return CompressedBvh { nodes: vec![[0; WIDE_NODE_WORDS]], depth: 1, ..Default::default() };
        }
        let mut out = CompressedBvh {
            nodes: vec![[0; WIDE_NODE_WORDS]],
            prim_ids: Vec::with_capacity(wide.prim_ids.len()),
            depth: 0,
            cost: wide.cost,
        };
        // Level by level: the nodes of a level are encoded in parallel, then given their
        // children's indices and triangle positions in order, so that each node's inner
        // children, and its leaves' triangles, are contiguous and in slot order.
        // (wide node, its encoded index)
        let mut level = vec![(0usize, 0usize)];
        while !level.is_empty() {
            out.depth += 1;
            let encoded: Vec<Encoded> = level.par_iter().map(|&(w, _)| encode(&wide.nodes[w])).collect();
            let mut next = Vec::new();
            for (&(_, at), mut e) in level.iter().zip(encoded) {
                e.words[4] = out.nodes.len() as u32;
                e.words[5] = out.prim_ids.len() as u32;
                for child in e.children {
                    next.push((child as usize, out.nodes.len()));
                    out.nodes.push([0; WIDE_NODE_WORDS]);
                }
                for (first, count) in e.leaves {
                    out.prim_ids.extend_from_slice(&wide.prim_ids[first as usize..(first + count) as usize]);
                }
                out.nodes[at] = e.words;
            }
            level = next;
        }
        out
    }

    /// Bytes of the nodes and the triangle order.
    pub fn memory_bytes(&self) -> usize {
        size_of_val(self.nodes.as_slice()) + size_of_val(self.prim_ids.as_slice())
    }

    /// The decoded box of `slot` of node `node`, as the shader computes it.
    pub fn lane_box(&self, node: usize, slot: usize) -> Aabb {
        let w = &self.nodes[node];
        let p = [0, 1, 2].map(|a| f32::from_bits(w[a]));
        let byte = |plane: usize| (w[8 + 2 * plane + slot / 4] >> (8 * (slot % 4))) & 0xff;
        let corner = |base: usize| {
            glam::Vec3::from_array(std::array::from_fn(|a| {
                p[a] + byte(base + a) as f32 * scale_of((w[3] >> (8 * a)) & 0xff)
            }))
        };
        Aabb::new(corner(0), corner(3))
    }

    /// The meta byte of `slot` of node `node`.
    fn meta(&self, node: usize, slot: usize) -> u8 {
        (self.nodes[node][6 + slot / 4] >> (8 * (slot % 4))) as u8
    }

    /// Box of the triangle whose position is `pos`, from `prim_aabbs` by id.
    fn contents(
        &self,
        node: usize,
        slot: usize,
        prim_aabbs: &[Aabb],
        seen: &mut [u32],
    ) -> Result<Aabb, CompressedError> {
        let w = &self.nodes[node];
        let meta = self.meta(node, slot);
        let offset = u32::from(meta & 31);
        let count = (meta >> 5).count_ones();
        if meta >> 5 != (1 << count) - 1 || offset + count > 24 {
            return Err(CompressedError::Meta { node, slot, meta });
        }
        let mut b = Aabb::EMPTY;
        for pos in w[5] + offset..w[5] + offset + count {
            let Some(&prim) = self.prim_ids.get(pos as usize) else {
                return Err(CompressedError::Meta { node, slot, meta });
            };
            seen[pos as usize] += 1;
            b = b.union(prim_aabbs[prim as usize]);
        }
        Ok(b)
    }

    /// Checks that every inner slot names a node referenced once, every triangle position is
    /// in exactly one leaf, and every decoded box contains the exact box of its contents
    /// (`prim_aabbs` by primitive id).
    pub fn validate(&self, prim_aabbs: &[Aabb]) -> Result<(), CompressedError> {
        let mut refs = vec![0u32; self.nodes.len()];
        let mut seen = vec![0u32; self.prim_ids.len()];
        // Exact boxes bottom-up: children have larger indices than their parents.
        let mut exact = vec![Aabb::EMPTY; self.nodes.len()];
        for node in (0..self.nodes.len()).rev() {
            let w = &self.nodes[node];
            let imask = w[3] >> 24;
            for slot in 0..8 {
                let meta = self.meta(node, slot);
                if meta == 0 {
                    continue;
                }
                let content = if imask & (1 << slot) != 0 {
                    if meta != 0b0010_0000 | (24 + slot as u8) {
                        return Err(CompressedError::Meta { node, slot, meta });
                    }
                    let child = w[4] as usize + (imask & ((1 << slot) - 1)).count_ones() as usize;
                    if child >= self.nodes.len() || child <= node {
                        return Err(CompressedError::Child { node, slot, child });
                    }
                    refs[child] += 1;
                    exact[child]
                } else {
                    self.contents(node, slot, prim_aabbs, &mut seen)?
                };
                let decoded = self.lane_box(node, slot);
                if !decoded.contains_box(&content) {
                    return Err(CompressedError::Box { node, slot, decoded, exact: content });
                }
                exact[node] = exact[node].union(content);
            }
        }
        if let Some((i, &r)) = refs.iter().enumerate().find(|&(i, &r)| r != u32::from(i != 0)) {
            return Err(CompressedError::References(i, r));
        }
        if let Some((pos, &c)) = seen.iter().enumerate().find(|(_, c)| **c != 1) {
            return Err(CompressedError::Position(pos, c));
        }
        Ok(())
    }
}

/// The compressed wide tree made on the device by [`collapse_on_device`]: its nodes stay there,
/// ready to trace.
pub struct DeviceWide {
    /// The nodes, [`WIDE_NODE_WORDS`] words each.
    pub nodes: wgpu::Buffer,
    pub node_count: usize,
    /// The primitive at each triangle position, read back (the scene's per-triangle arrays are
    /// laid out by it on the host).
    pub prim_ids: Vec<u32>,
    pub depth: usize,
    /// Device time of the collapse (its dispatches and the per-level reads of one counter).
    pub seconds: f64,
}

impl DeviceWide {
    /// The nodes read back, as [`CompressedBvh`] (for checks and tests).
    pub fn read(&self, ctx: &super::GpuContext) -> Result<CompressedBvh, super::GpuError> {
        let words: Vec<[u32; WIDE_NODE_WORDS]> = ctx.read_buffer("wide nodes", &self.nodes, self.node_count)?;
        Ok(CompressedBvh { nodes: words, prim_ids: self.prim_ids.clone(), depth: self.depth, cost: 0.0 })
    }
}

/// The source of the GPU collapse's kernels.
pub fn collapse_source() -> String {
    super::layout::with_prelude(include_str!("../../shaders/collapse.wgsl"))
}

/// [`CompressedBvh::new`] on the device, from the GPU's binary tree as its LBVH and PRBVH leave
/// it (one primitive a leaf): the SAH table bottom-up in one dispatch (boxes and tables passed
/// between threads through atomics, as the refit passes boxes), then the wide nodes top-down, one
/// dispatch a level. The tree chosen is the host's up to the rounding of the table's costs (f32
/// here, areas in f64 there), so ties may go otherwise. A tree whose buffers would be over the
/// adapter's binding size is refused with [`super::GpuError::BufferTooLarge`].
pub fn collapse_on_device(ctx: &super::GpuContext, bvh: &super::lbvh::GpuBvh) -> Result<DeviceWide, super::GpuError> {
    use super::layout::CollapseParams;
    let n = bvh.prim_count as usize;
    if n < 2 {
        return Err(super::GpuError::Other("the GPU collapse needs at least 2 primitives".into()));
    }
    let node_count = 2 * n;
    let root: Vec<crate::bvh::BvhNode> = ctx.read_buffer("BVH root", &bvh.nodes, 1)?;
    let root_box = root[0].aabb();
    let scale = root_box.area_scale();
    let e = (root_box.extent() * scale).as_dvec3();
    let root_area = (e.x * e.y + e.y * e.z + e.z * e.x).max(f64::MIN_POSITIVE);
    let costs = WideCosts::default();
    let mut params = CollapseParams {
        node_count: node_count as u32,
        max_leaf: WIDE_MAX_LEAF,
        queue_len: 1,
        pad: 0,
        cost_node: costs.node,
        cost_prim: costs.prim,
        inv_root_area: (1.0 / root_area) as f32,
        area_scale: scale,
    };
    let params_buffer = ctx.storage_buffer("collapse parameters", std::slice::from_ref(&params))?;
    let u32s = |what: &str, count: usize| ctx.storage_buffer_zeroed(what, (count.max(1) * 4) as u64);
    let visits = u32s("collapse visits", node_count)?;
    let published = u32s("collapse tables", node_count * 9)?;
    let decisions = u32s("collapse decisions", node_count * 2)?;
    // At most n - 1 wide nodes (each takes at least one inner binary node), and usually about
    // n / 8: room for what the adapter's binding allows, the rest refused after the fact.
    let binding = ctx.limits.max_storage_buffer_binding_size.min(ctx.limits.max_buffer_size);
    let max_nodes = (n - 1).min((binding / (WIDE_NODE_WORDS as u64 * 4)) as usize).max(1);
    let queues = [u32s("collapse queue", (n - 1) * 2)?, u32s("collapse queue", (n - 1) * 2)?];
    ctx.queue.write_buffer(&queues[0], 0, bytemuck::cast_slice(&[0u32, 0u32]));
    let counters = ctx.storage_buffer("collapse counters", &[1u32, 0, 0, 0])?;
    let out_nodes = ctx.storage_buffer_zeroed("wide nodes", (max_nodes * WIDE_NODE_WORDS * 4) as u64)?;
    let out_prims = u32s("wide triangle order", n)?;
    let costs_pipeline = ctx.pipeline("collapse", collapse_source, "collapse_costs");
    let expand_pipeline = ctx.pipeline("collapse", collapse_source, "collapse_expand");
    let costs_group = ctx.bind_group(
        &costs_pipeline,
        &[(0, &params_buffer), (1, &bvh.nodes), (2, &bvh.parents), (3, &visits), (4, &published), (5, &decisions)],
    );
    let dispatch = |pipeline: &wgpu::ComputePipeline, group: &wgpu::BindGroup, items: u32| {
        let mut encoder = ctx.device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, group, &[]);
            let (x, y) = ctx.dispatch_size(items);
            pass.dispatch_workgroups(x, y, 1);
        }
        ctx.queue.submit([encoder.finish()]);
    };
    let timed = std::time::Instant::now();
    dispatch(&costs_pipeline, &costs_group, node_count as u32);
    let mut len = 1u32;
    let mut depth = 0;
    let mut from = 0;
    while len > 0 {
        depth += 1;
        params.queue_len = len;
        ctx.queue.write_buffer(&params_buffer, 0, bytemuck::bytes_of(&params));
        ctx.queue.write_buffer(&counters, 8, bytemuck::bytes_of(&0u32));
        let group = ctx.bind_group(
            &expand_pipeline,
            &[
                (0, &params_buffer),
                (1, &bvh.nodes),
                (5, &decisions),
                (6, &queues[from]),
                (7, &queues[1 - from]),
                (8, &counters),
                (9, &out_nodes),
                (10, &out_prims),
                (11, &bvh.prim_ids),
            ],
        );
        dispatch(&expand_pipeline, &group, len);
        let c: Vec<u32> = ctx.read_buffer("collapse counters", &counters, 3)?;
        len = c[2];
        from = 1 - from;
        if depth > n {
            return Err(super::GpuError::Other("the GPU collapse did not end".into()));
        }
    }
    let c: Vec<u32> = ctx.read_buffer("collapse counters", &counters, 3)?;
    let seconds = timed.elapsed().as_secs_f64();
    let prim_ids: Vec<u32> = ctx.read_buffer("wide triangle order", &out_prims, n)?;
    if c[0] as usize > max_nodes {
        return Err(super::GpuError::BufferTooLarge {
            what: "the GPU collapse's wide nodes".into(),
            bytes: u64::from(c[0]) * WIDE_NODE_WORDS as u64 * 4,
            limit_name: "max_storage_buffer_binding_size",
            limit: binding,
        });
    }
    if c[1] as usize != n {
        return Err(super::GpuError::Other(format!("the GPU collapse placed {} of {n} triangles", c[1])));
    }
    Ok(DeviceWide { nodes: out_nodes, node_count: c[0] as usize, prim_ids, depth, seconds })
}
