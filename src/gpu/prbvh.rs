//! Parallel reinsertion on the GPU: Meister & Bittner 2018, section 5, the six kernels of
//! `shaders/prbvh.wgsl` per iteration (find best node, lock, check, reinsert, refit, SAH), the
//! algorithm of the CPU optimiser ([`crate::bvh::build::prbvh`]) with its μ/ε schedule.
//!
//! - Only the SAH (4 bytes) is read back per iteration, for the termination test.
//! - Locks: with `SHADER_INT64_ATOMIC_MIN_MAX`, one 64-bit `atomicMax` of
//!   `(decrease bits << 32) | index` per node, as on the CPU ([`LockScheme::Atomic64`]).
//!   Otherwise the portable scheme ([`LockScheme::Portable32`]): a 32-bit `atomicMax` of the
//!   decrease's bits (positive floats order as their bits), then a second pass in which the
//!   claims holding that maximum take an `atomicMax` of their index. Both give every node to the
//!   same claim, the one with the highest (decrease, index).
//! - Only the aggressive strategy (the paper's GPU choice); the conservative one is CPU-only.
//! - Lock and visit counters are cleared by `clear_buffer` once per iteration (on the GPU a
//!   memset of the whole array is cheaper than the CPU's claim-by-claim reset).
//! - The leaf collapse runs on the CPU after the tree is read back (it is a sequential pass).
//!
//! The search reads the same boxes and makes the same comparisons as the CPU's, but GPU
//! compilers may fuse its arithmetic, so a near-tie can go the other way and the trees differ;
//! the tests hold the SAH to within 2% of the CPU optimiser's on the same input.

use std::time::Instant;

use super::context::{GpuContext, GpuError};
use super::layout::{BvhNode, PrbvhParams, REFIT_BOX_WORDS, with_prelude};
use super::lbvh::GpuBvh;
use crate::bvh::build::prbvh::{IterationStats, PrbvhConfig, PrbvhStats};
use crate::bvh::{Bvh, collapse_leaves};

/// How reinsertions claim their nodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LockScheme {
    /// One 64-bit atomic max per node; needs `SHADER_INT64_ATOMIC_MIN_MAX`.
    Atomic64,
    /// Two 32-bit passes; runs everywhere.
    Portable32,
}

impl LockScheme {
    /// The 64-bit scheme where the device has it, else the portable one.
    pub fn best_for(ctx: &GpuContext) -> LockScheme {
        if ctx.features.contains(wgpu::Features::SHADER_INT64_ATOMIC_MIN_MAX) {
            LockScheme::Atomic64
        } else {
            LockScheme::Portable32
        }
    }
}

/// The PRBVH shader with the shared refit, and the 64-bit lock kernels appended when asked.
pub fn source(int64: bool) -> String {
    let mut kernel = [include_str!("../../shaders/prbvh.wgsl"), include_str!("../../shaders/_refit.wgsl")].concat();
    if int64 {
        kernel += include_str!("../../shaders/_prbvh_lock64.wgsl");
    }
    with_prelude(&kernel)
}

/// Optimises the tree on the device in place (one primitive per leaf in, one out; no collapse).
pub fn optimize_on_device(
    ctx: &GpuContext,
    bvh: &GpuBvh,
    config: &PrbvhConfig,
    scheme: LockScheme,
) -> Result<PrbvhStats, GpuError> {
    assert!(config.mu >= 1, "PRBVH needs mu >= 1");
    if scheme == LockScheme::Atomic64 {
        ctx.require(wgpu::Features::SHADER_INT64_ATOMIC_MIN_MAX)?;
    }
    let node_count = 2 * bvh.prim_count;
    let start = Instant::now();
    let mut stats = PrbvhStats::default();
    if node_count <= 3 {
        return Ok(stats);
    }
    let (key, int64) = match scheme {
        LockScheme::Atomic64 => ("prbvh64", true),
        LockScheme::Portable32 => ("prbvh32", false),
    };
    let u32s = |what: &str| ctx.storage_buffer_zeroed(what, u64::from(node_count) * 4);
    let best_out = u32s("PRBVH outputs")?;
    let best_d = u32s("PRBVH decreases")?;
    let lock_bits = u32s("PRBVH locks (decrease)")?;
    let lock_idx = u32s("PRBVH locks (index)")?;
    let winners = u32s("PRBVH winners")?;
    let visits = u32s("refit visits")?;
    // REFIT_BOX_WORDS words per node, zero between refits (the refit clears what it reads: `_refit.wgsl`).
    let refit_boxes = ctx.storage_buffer_zeroed("refit boxes", u64::from(node_count * REFIT_BOX_WORDS) * 4)?;
    let locks64 = ctx.storage_buffer_zeroed("PRBVH locks (64-bit)", u64::from(node_count) * 8)?;
    let grid = ctx.dispatch_size(node_count);
    let partial_count = grid.0 * grid.1;
    let sah_partial = ctx.storage_buffer_zeroed("SAH partial sums", u64::from(partial_count) * 4)?;
    let root = ctx.read_buffer::<BvhNode>("root", &bvh.nodes, 1)?[0];
    let mut params = PrbvhParams {
        node_count,
        mu: 1,
        phase: 0,
        partial_count,
        cost_traversal: config.costs.traversal,
        cost_intersection: config.costs.intersection,
        area_scale: crate::bvh::build::prbvh::search_scale(Some(&root)),
        ..Default::default()
    };
    let params_buf = ctx.uniform_buffer("PRBVH parameters", &params);
    let (nodes, parents) = (&bvh.nodes, &bvh.parents);
    let all: Vec<(u32, &wgpu::Buffer)> = vec![
        (0, &params_buf),
        (1, nodes),
        (2, parents),
        (3, &best_out),
        (4, &best_d),
        (5, &lock_bits),
        (6, &lock_idx),
        (7, &winners),
        (8, &visits),
        (9, &sah_partial),
        (10, &locks64),
        (11, &locks64),
        (12, &refit_boxes),
    ];
    // Each kernel gets the bindings its entry point uses (the layouts are derived per entry).
    let pass = |encoder: &mut wgpu::CommandEncoder, entry: &str, bindings: &[u32], groups: (u32, u32)| {
        let chosen: Vec<(u32, &wgpu::Buffer)> = all.iter().filter(|(b, _)| bindings.contains(b)).copied().collect();
        encode_pass(ctx, encoder, (key, int64), entry, &chosen, groups);
    };
    let sah = |encoder: &mut wgpu::CommandEncoder| {
        pass(encoder, "sah_partial", &[0, 1, 9], grid);
        pass(encoder, "sah_final", &[0, 1, 9], (1, 1));
    };
    let read_sah = || -> Result<f64, GpuError> { Ok(f64::from(ctx.read_buffer::<f32>("SAH", &sah_partial, 1)?[0])) };

    let mut encoder = ctx.device.create_command_encoder(&Default::default());
    sah(&mut encoder);
    ctx.queue.submit([encoder.finish()]);
    stats.initial_sah = read_sah()?;
    let mut mu = config.mu;
    let mut previous = stats.initial_sah;
    let mut iteration = 0u32;
    while iteration < config.max_iterations {
        params.mu = mu;
        params.phase = iteration % mu;
        ctx.queue.write_buffer(&params_buf, 0, bytemuck::bytes_of(&params));
        let mut encoder = ctx.device.create_command_encoder(&Default::default());
        pass(&mut encoder, "find_best", &[0, 1, 2, 3, 4, 7], grid);
        match scheme {
            LockScheme::Atomic64 => {
                encoder.clear_buffer(&locks64, 0, None);
                pass(&mut encoder, "lock64", &[0, 2, 3, 4, 10], grid);
                pass(&mut encoder, "check64", &[0, 2, 3, 4, 7, 11], grid);
            }
            LockScheme::Portable32 => {
                encoder.clear_buffer(&lock_bits, 0, None);
                encoder.clear_buffer(&lock_idx, 0, None);
                pass(&mut encoder, "lock_max", &[0, 2, 3, 4, 5], grid);
                pass(&mut encoder, "lock_tie", &[0, 2, 3, 4, 5, 6], grid);
                pass(&mut encoder, "check", &[0, 2, 3, 4, 5, 6, 7], grid);
            }
        }
        pass(&mut encoder, "reinsert", &[0, 1, 2, 3, 7], grid);
        encoder.clear_buffer(&visits, 0, None);
        pass(&mut encoder, "refit", &[0, 1, 2, 8, 12], grid);
        sah(&mut encoder);
        ctx.queue.submit([encoder.finish()]);
        let current = read_sah()?;
        stats.iterations.push(IterationStats {
            mu,
            searched: 0,
            candidates: 0,
            reinsertions: 0,
            sah: current,
            elapsed: start.elapsed(),
        });
        iteration += 1;
        match crate::bvh::build::prbvh::next_mu(previous, current, mu, config.epsilon) {
            Some(next) => mu = next,
            None => break,
        }
        previous = current;
    }
    stats.optimize_time = start.elapsed();
    stats.sah_before_collapse = stats.iterations.last().map_or(stats.initial_sah, |i| i.sah);
    stats.final_sah = stats.sah_before_collapse;
    Ok(stats)
}

/// Algorithm 1 alone, on the device: every node's best output and decrease in `bvh` as it is
/// (one `find_best` pass, every node searching), read back; `(sibling, 0.0)` where nothing
/// decreases the area, and for the root and the padding node. The decreases are half areas at
/// the search's scale ([`crate::bvh::build::prbvh::find_best_output`] divides the scale out). For
/// comparing the device's search with the CPU's node by node.
pub fn search_on_device(ctx: &GpuContext, bvh: &Bvh) -> Result<Vec<(u32, f32)>, GpuError> {
    let node_count = bvh.nodes.len() as u32;
    if bvh.prim_ids.len() <= 1 {
        return Ok(vec![(0, 0.0); node_count as usize]);
    }
    let gpu = upload(ctx, bvh)?;
    let u32s = |what: &str| ctx.storage_buffer_zeroed(what, u64::from(node_count) * 4);
    let (best_out, best_d, winners) = (u32s("PRBVH outputs")?, u32s("PRBVH decreases")?, u32s("PRBVH winners")?);
    let params = PrbvhParams {
        node_count,
        mu: 1,
        phase: 0,
        area_scale: crate::bvh::build::prbvh::search_scale(bvh.nodes.first()),
        ..Default::default()
    };
    let params_buf = ctx.uniform_buffer("PRBVH parameters", &params);
    let bindings = [(0, &params_buf), (1, &gpu.nodes), (2, &gpu.parents), (3, &best_out), (4, &best_d), (7, &winners)];
    let mut encoder = ctx.device.create_command_encoder(&Default::default());
    encode_pass(ctx, &mut encoder, ("prbvh32", false), "find_best", &bindings, ctx.dispatch_size(node_count));
    ctx.queue.submit([encoder.finish()]);
    let outs = ctx.read_buffer::<u32>("PRBVH outputs", &best_out, node_count as usize)?;
    let ds = ctx.read_buffer::<f32>("PRBVH decreases", &best_d, node_count as usize)?;
    Ok((0..node_count as usize).map(|i| if ds[i] > 0.0 { (outs[i], ds[i]) } else { (i as u32 ^ 1, 0.0) }).collect())
}

/// Records one dispatch of the PRBVH shader's `entry` (the shader's pipeline cache key, and
/// whether it has the 64-bit lock kernels) over `groups` workgroups, with `bindings`.
fn encode_pass(
    ctx: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    (key, int64): (&str, bool),
    entry: &str,
    bindings: &[(u32, &wgpu::Buffer)],
    groups: (u32, u32),
) {
    let pipeline = ctx.pipeline(key, || source(int64), entry);
    let bind_group = ctx.bind_group(&pipeline, bindings);
    let mut p = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some(entry), timestamp_writes: None });
    p.set_pipeline(&pipeline);
    p.set_bind_group(0, &bind_group, &[]);
    p.dispatch_workgroups(groups.0, groups.1, 1);
}

/// `bvh`'s nodes, parents and primitive ids in device buffers (no Morton codes or primitive
/// boxes: the optimiser does not read them).
fn upload(ctx: &GpuContext, bvh: &Bvh) -> Result<GpuBvh, GpuError> {
    let nodes: Vec<BvhNode> = bvh.nodes.to_vec();
    Ok(GpuBvh {
        prim_count: bvh.prim_ids.len() as u32,
        code_hi: ctx.storage_buffer_zeroed("unused", 4)?,
        code_lo: ctx.storage_buffer_zeroed("unused", 4)?,
        nodes: ctx.storage_buffer("BVH nodes", &nodes)?,
        parents: ctx.storage_buffer("BVH parents", &bvh.parents)?,
        prim_ids: ctx.storage_buffer("BVH primitive ids", &bvh.prim_ids)?,
        prim_aabbs: ctx.storage_buffer_zeroed("unused", 4)?,
    })
}

/// Uploads `bvh` (one primitive per leaf, e.g. the CPU LBVH), optimises it on the GPU, reads it
/// back, and applies the leaf collapse of `config` on the CPU.
pub fn optimize(
    ctx: &GpuContext,
    bvh: &Bvh,
    config: &PrbvhConfig,
    scheme: LockScheme,
) -> Result<(Bvh, PrbvhStats), GpuError> {
    let n = bvh.prim_ids.len();
    if n <= 1 {
        return Ok((bvh.clone(), PrbvhStats::default()));
    }
    let gpu = upload(ctx, bvh)?;
    let mut stats = optimize_on_device(ctx, &gpu, config, scheme)?;
    let mut out = gpu.read(ctx)?;
    if let Some(collapse) = &config.collapse {
        let t = Instant::now();
        out = collapse_leaves(&out, collapse);
        stats.collapse_time = t.elapsed();
        stats.final_sah = crate::bvh::sah_cost_with(&out, &config.costs);
    }
    Ok((out, stats))
}
