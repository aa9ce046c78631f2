//! LBVH on the GPU: the CPU builder's algorithm ([`crate::bvh::build::lbvh`], Karras 2012), kernel by
//! kernel in `shaders/lbvh.wgsl`, building the same tree bit for bit as the CPU's
//! [`crate::bvh::build::lbvh::build_karras`] (tested), Karras' algorithm as published: without the CPU
//! default's refinement of runs of equal Morton codes.
//!
//! 1. Centroid bounds by a two-stage workgroup reduction. The 24 bytes of bounds are read back,
//!    and the Morton quantizer (origin and scale) is computed on the host exactly as the CPU
//!    computes it: WGSL division is not correctly rounded (2.5 ULP in Vulkan), and one ULP of
//!    scale would change codes, and with them the tree.
//! 2. 63-bit Morton codes as two u32 halves, from centroids stored by step 1: a kernel boundary,
//!    so that no compiler fuses the centroid's sum with the quantizer's subtraction (lavapipe's
//!    does, within one kernel); with the quantizer's power-of-two scale
//!    ([`MortonQuantizer`]), what remains rounds once however it is fused.
//! 3. Sort of `(code, index)`: lampshade's stable LSD radix sort of `(u32 key, u32 value)`
//!    pairs, twice: by the low half, then (stably) by the high half. Stability makes the order
//!    that of `(code, index)`, the CPU's. lampshade's kernels do not wait on other workgroups, so
//!    they need no forward-progress guarantee.
//! 4. The radix tree, one thread per internal node, each writing its own sibling pair.
//! 5. Boxes bottom-up, one thread per leaf, with atomic visit counters (Karras, section 4.2).
//!    The second thread to reach a node reads its children's boxes, written by another thread
//!    before its atomic increment; WGSL atomics are relaxed, so this relies on the device making
//!    those writes visible by then, as every GPU we know does. `validate()` in the tests checks
//!    every box, so a device that did not would fail them.

use std::time::{Duration, Instant};

use super::context::{GpuContext, GpuError};
use super::layout::{BvhNode, GpuAabb, LbvhParams, REFIT_BOX_WORDS, with_prelude};
use crate::bvh::{Bvh, Nodes};
use crate::geometry::Aabb;
use crate::geometry::morton::MortonQuantizer;

/// The LBVH shader with the shared refit (`_refit.wgsl`) appended.
pub fn source() -> String {
    with_prelude(&[include_str!("../../shaders/lbvh.wgsl"), include_str!("../../shaders/_refit.wgsl")].concat())
}

/// What a GPU build cost: upload, the kernels (sort included), readback.
#[derive(Clone, Debug, Default)]
pub struct GpuBuildTimes {
    pub upload: Duration,
    /// From the first kernel to the last one's completion.
    pub build: Duration,
    pub readback: Duration,
}

/// The tree's buffers on the device, as [`build_on_device`] leaves them.
pub struct GpuBvh {
    pub prim_count: u32,
    /// The Morton codes in key order, high and low halves.
    pub code_hi: wgpu::Buffer,
    pub code_lo: wgpu::Buffer,
    pub nodes: wgpu::Buffer,
    pub parents: wgpu::Buffer,
    pub prim_ids: wgpu::Buffer,
    pub prim_aabbs: wgpu::Buffer,
}

impl GpuBvh {
    /// The sorted Morton codes and the primitive of each, read back.
    pub fn read_codes(&self, ctx: &GpuContext) -> Result<(Vec<u64>, Vec<u32>), GpuError> {
        let n = self.prim_count as usize;
        let hi: Vec<u32> = ctx.read_buffer("codes", &self.code_hi, n)?;
        let lo: Vec<u32> = ctx.read_buffer("codes", &self.code_lo, n)?;
        let codes = hi.iter().zip(&lo).map(|(&h, &l)| (u64::from(h) << 32) | u64::from(l)).collect();
        Ok((codes, ctx.read_buffer("primitive ids", &self.prim_ids, n)?))
    }

    /// Reads the tree back into host memory.
    pub fn read(&self, ctx: &GpuContext) -> Result<Bvh, GpuError> {
        let n = self.prim_count as usize;
        let node_list: Vec<BvhNode> = ctx.read_buffer("BVH nodes", &self.nodes, 2 * n)?;
        let mut nodes = Nodes::default();
        nodes.fill_pairs(n, 2 * n, |pair| [node_list[2 * pair], node_list[2 * pair + 1]]);
        Ok(Bvh {
            nodes,
            parents: ctx.read_buffer("BVH parents", &self.parents, 2 * n)?,
            prim_ids: ctx.read_buffer("BVH primitive ids", &self.prim_ids, n)?,
        })
    }
}

/// The sorted Morton codes and the primitive of each, as the GPU build computes them: the
/// counterpart of [`crate::bvh::build::lbvh::sorted_morton_codes`], for tests of that stage.
pub fn sorted_morton_codes(ctx: &GpuContext, prim_aabbs: &[Aabb]) -> Result<(Vec<u64>, Vec<u32>), GpuError> {
    build_on_device(ctx, prim_aabbs)?.0.read_codes(ctx)
}

/// Builds the LBVH over `prim_aabbs` on the GPU and reads it back: the same tree as
/// [`crate::bvh::build::lbvh::build_karras`].
pub fn build(ctx: &GpuContext, prim_aabbs: &[Aabb]) -> Result<(Bvh, GpuBuildTimes), GpuError> {
    if prim_aabbs.len() <= 1 {
        return Ok((Bvh::single_leaf(prim_aabbs), GpuBuildTimes::default()));
    }
    let (gpu, mut times) = build_on_device(ctx, prim_aabbs)?;
    let t = Instant::now();
    let bvh = gpu.read(ctx)?;
    times.readback = t.elapsed();
    Ok((bvh, times))
}

/// Builds the LBVH over `prim_aabbs` (at least 2) and leaves it on the device.
pub fn build_on_device(ctx: &GpuContext, prim_aabbs: &[Aabb]) -> Result<(GpuBvh, GpuBuildTimes), GpuError> {
    let n = prim_aabbs.len();
    assert!(n >= 2, "the GPU LBVH needs at least 2 primitives");
    let n32 = u32::try_from(n)
        .ok()
        .filter(|&n| n < (1 << 30))
        .ok_or_else(|| GpuError::Other(format!("the GPU LBVH takes fewer than 2^30 primitives, not {n}")))?;
    let mut times = GpuBuildTimes::default();
    let t = Instant::now();
    let boxes: Vec<GpuAabb> = prim_aabbs.iter().map(|&b| b.into()).collect();
    let u32s = |what: &str, count: usize| ctx.storage_buffer_zeroed(what, (count * 4) as u64);
    let prim_buf = ctx.storage_buffer("primitive boxes", &boxes)?;
    let (groups_x, groups_y) = ctx.dispatch_size(n32);
    let partial_count = groups_x * groups_y;
    let partial = ctx.storage_buffer_zeroed("partial bounds", u64::from(partial_count) * 32)?;
    let hi_codes = u32s("Morton codes (high)", n)?;
    let lo_codes = u32s("Morton codes (low)", n)?;
    let keys = u32s("sort keys", 2 * n)?;
    let sorted = u32s("sorted keys", 2 * n)?;
    let prim_ids = u32s("primitive ids", n)?;
    let code_hi = u32s("sorted codes (high)", n)?;
    let code_lo = u32s("sorted codes (low)", n)?;
    let nodes = ctx.storage_buffer_zeroed("BVH nodes", (2 * n * size_of::<BvhNode>()) as u64)?;
    let parents = u32s("BVH parents", 2 * n)?;
    let leaf_slots = u32s("leaf slots", n)?;
    let visits = u32s("visit counters", 2 * n)?;
    let refit_boxes = u32s("refit boxes", REFIT_BOX_WORDS as usize * 2 * n)?;
    let centroids = ctx.storage_buffer_zeroed("centroids", (n * 16) as u64)?;
    let mut params = LbvhParams { prim_count: n32, pad: partial_count, ..Default::default() };
    let params_buf = ctx.uniform_buffer("LBVH parameters", &params);
    ctx.wait()?;
    times.upload = t.elapsed();

    let t = Instant::now();
    let key = "lbvh";
    let run =
        |encoder: &mut wgpu::CommandEncoder, entry: &str, bindings: &[(u32, &wgpu::Buffer)], groups: (u32, u32)| {
            let pipeline = ctx.pipeline(key, source, entry);
            let bind_group = ctx.bind_group(&pipeline, bindings);
            let mut pass =
                encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some(entry), timestamp_writes: None });
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            pass.dispatch_workgroups(groups.0, groups.1, 1);
        };
    let grid = (groups_x, groups_y);
    let mut encoder = ctx.device.create_command_encoder(&Default::default());
    run(&mut encoder, "bounds_partial", &[(0, &params_buf), (1, &prim_buf), (2, &partial), (14, &centroids)], grid);
    run(&mut encoder, "bounds_final", &[(0, &params_buf), (2, &partial)], (1, 1));
    ctx.queue.submit([encoder.finish()]);
    let bounds: Vec<GpuAabb> = ctx.read_buffer("centroid bounds", &partial, 1)?;
    let q = MortonQuantizer::new(&Aabb::new(bounds[0].min, bounds[0].max));
    (params.origin, params.scale) = q.parts();
    ctx.queue.write_buffer(&params_buf, 0, bytemuck::bytes_of(&params));

    let mut encoder = ctx.device.create_command_encoder(&Default::default());
    run(
        &mut encoder,
        "morton",
        &[(0, &params_buf), (3, &hi_codes), (4, &lo_codes), (5, &keys), (14, &centroids)],
        grid,
    );
    ctx.queue.submit([encoder.finish()]);
    let sort = || {
        ctx.with_sorter(|sorter| sorter.sort_gpu_to_gpu(&keys, &sorted, n32))
            .map_err(|e| GpuError::Other(format!("GPU radix sort: {e}")))
    };
    sort()?;
    let mut encoder = ctx.device.create_command_encoder(&Default::default());
    run(&mut encoder, "gather_hi", &[(0, &params_buf), (3, &hi_codes), (5, &keys), (6, &sorted)], grid);
    ctx.queue.submit([encoder.finish()]);
    sort()?;
    let mut encoder = ctx.device.create_command_encoder(&Default::default());
    run(
        &mut encoder,
        "unpack",
        &[(0, &params_buf), (3, &hi_codes), (4, &lo_codes), (6, &sorted), (7, &prim_ids), (8, &code_hi), (9, &code_lo)],
        grid,
    );
    run(
        &mut encoder,
        "radix_tree",
        &[
            (0, &params_buf),
            (1, &prim_buf),
            (7, &prim_ids),
            (8, &code_hi),
            (9, &code_lo),
            (10, &nodes),
            (11, &parents),
            (12, &leaf_slots),
        ],
        grid,
    );
    run(
        &mut encoder,
        "refit",
        &[(0, &params_buf), (10, &nodes), (11, &parents), (12, &leaf_slots), (13, &visits), (15, &refit_boxes)],
        grid,
    );
    ctx.queue.submit([encoder.finish()]);
    ctx.wait()?;
    times.build = t.elapsed();
    Ok((GpuBvh { prim_count: n32, code_hi, code_lo, nodes, parents, prim_ids, prim_aabbs: prim_buf }, times))
}
