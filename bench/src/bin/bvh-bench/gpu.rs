//! `--gpu`: the LBVH and PRBVH on the CPU and the GPU, timed on the same primitives, the
//! collapse into the GPU's wide form, and the builder comparison's ray sets traced on the GPU
//! through both of its forms.

use anyhow::{Result, bail};

use crate::Args;
use crate::cli::outln;
use crate::options::load_input;
use crate::report::{GpuComparison, GpuRow, write_atomic, write_json};
use crate::{compare, default_builders};
use arbor_bench::median;

/// `--gpu`: GPU LBVH and PRBVH times, beside the CPU's on the same input, the wide collapse, and
/// the builders' ray sets on the GPU.
pub(crate) fn run_gpu(args: &Args, tracing: arbor::bvh::Tracing) -> Result<()> {
    use arbor::bvh::build::prbvh::{self, PrbvhConfig};
    use arbor::gpu::prbvh::{self as gpu_prbvh, LockScheme};
    use std::time::Instant;
    let ctx = arbor::gpu::GpuContext::shared()?;
    let (name, mesh) = load_input(args)?;
    let prims: Vec<arbor::geometry::Aabb> = mesh.triangles().iter().map(arbor::geometry::Triangle::aabb).collect();
    if prims.len() < 2 {
        bail!("{name}: --gpu needs at least 2 triangles");
    }
    eprintln!("{name}: {} triangles on {}", prims.len(), ctx.describe());
    let config = PrbvhConfig { mu: args.mu, epsilon: args.epsilon, collapse: None, ..Default::default() };
    let mut rows = Vec::new();
    let (mut cpu_ms, mut gpu_ms, mut upload_ms) = (Vec::new(), Vec::new(), Vec::new());
    let mut cpu_tree = None;
    let mut gpu_tree = None;
    // A first, untimed build compiles the pipelines (seconds on lavapipe).
    arbor::gpu::lbvh::build(ctx, &prims)?;
    for _ in 0..args.runs {
        let t = Instant::now();
        // Karras' algorithm as published, which the GPU builds (the CPU's default also refines
        // runs of equal codes).
        cpu_tree = Some(arbor::bvh::build::lbvh::build_karras(&prims));
        cpu_ms.push(t.elapsed().as_secs_f64() * 1e3);
        let (tree, times) = arbor::gpu::lbvh::build(ctx, &prims)?;
        gpu_ms.push(times.build.as_secs_f64() * 1e3);
        upload_ms.push(times.upload.as_secs_f64() * 1e3);
        gpu_tree = Some(tree);
    }
    let (cpu_tree, gpu_tree) = (cpu_tree.expect("runs >= 1"), gpu_tree.expect("runs >= 1"));
    let same = cpu_tree.nodes[..] == gpu_tree.nodes[..] && cpu_tree.prim_ids == gpu_tree.prim_ids;
    rows.push(GpuRow::new("lbvh", "cpu", median(cpu_ms), arbor::bvh::sah_cost(&cpu_tree)));
    rows.push(GpuRow {
        upload_ms: Some(median(upload_ms)),
        same_tree_as_cpu: Some(same),
        ..GpuRow::new("lbvh", "gpu", median(gpu_ms), arbor::bvh::sah_cost(&gpu_tree))
    });
    let mut times = Vec::new();
    let mut sah = 0.0;
    for _ in 0..args.runs {
        let mut tree = cpu_tree.clone();
        let stats = prbvh::optimize(&mut tree, &config);
        times.push(stats.optimize_time.as_secs_f64() * 1e3);
        sah = stats.sah_before_collapse;
    }
    rows.push(GpuRow::new("prbvh", "cpu", median(times), sah));
    let mut schemes = vec![LockScheme::Portable32];
    if LockScheme::best_for(ctx) == LockScheme::Atomic64 {
        schemes.push(LockScheme::Atomic64);
    }
    for scheme in schemes {
        let mut times = Vec::new();
        let mut iterations = 0;
        let warm = PrbvhConfig { max_iterations: 1, ..config };
        gpu_prbvh::optimize(ctx, &cpu_tree, &warm, scheme)?;
        for _ in 0..args.runs {
            let (_, stats) = gpu_prbvh::optimize(ctx, &cpu_tree, &config, scheme)?;
            times.push(stats.optimize_time.as_secs_f64() * 1e3);
            sah = stats.sah_before_collapse;
            iterations = stats.iterations.len();
        }
        let lock = if scheme == LockScheme::Atomic64 { "64-bit" } else { "32-bit" };
        rows.push(GpuRow {
            locks: Some(lock),
            iterations: Some(iterations),
            ..GpuRow::new("prbvh", "gpu", median(times), sah)
        });
    }
    // The GPU's wide form of its optimised tree: collapsed on the GPU, and on the CPU beside it.
    let (device_tree, _) = arbor::gpu::lbvh::build_on_device(ctx, &prims)?;
    gpu_prbvh::optimize_on_device(ctx, &device_tree, &config, LockScheme::best_for(ctx))?;
    let optimised = device_tree.read(ctx)?;
    // A first, untimed collapse compiles its kernels.
    arbor::gpu::wide::collapse_on_device(ctx, &device_tree)?;
    let (mut gpu_times, mut cpu_times) = (Vec::new(), Vec::new());
    let mut wide_cost = 0.0;
    let mut gpu_nodes = 0;
    for _ in 0..args.runs {
        let made = arbor::gpu::wide::collapse_on_device(ctx, &device_tree)?;
        gpu_times.push(made.seconds * 1e3);
        gpu_nodes = made.node_count;
        let t = Instant::now();
        let wide = arbor::gpu::wide::CompressedBvh::new(&optimised, &prims);
        cpu_times.push(t.elapsed().as_secs_f64() * 1e3);
        wide_cost = wide.cost;
    }
    rows.push(GpuRow { nodes: Some(gpu_nodes), ..GpuRow::new("collapse", "gpu", median(gpu_times), wide_cost) });
    rows.push(GpuRow::new("collapse", "cpu", median(cpu_times), wide_cost));
    outln!(
        "{} triangles; {}; medians of {} runs (GPU times exclude pipeline compilation, upload and readback)",
        prims.len(),
        ctx.describe(),
        args.runs
    );
    outln!("{:<8} {:<6} {:<8} {:>12} {:>10}", "stage", "device", "locks", "ms", "SAH");
    for r in &rows {
        outln!("{:<8} {:<6} {:<8} {:>12.2} {:>10.2}", r.stage, r.device, r.locks.unwrap_or("-"), r.ms, r.sah);
    }
    if !same {
        bail!("the GPU LBVH differs from the CPU LBVH on {name}");
    }
    // The builders' trees on the GPU (the default builders unless --builders names others).
    let builders = args.builders.clone().unwrap_or_else(default_builders);
    let gpu_args = Args { builders: Some(builders), ..args.clone() };
    let (_, comparison) = compare::measure(&gpu_args, tracing, Some(ctx))?;
    let report = GpuComparison { adapter: ctx.describe(), runs: args.runs, rows, comparison };
    if let Some(path) = &args.json {
        write_atomic(path, |f| write_json(f, &report))?;
    }
    compare::check(&report.comparison)?;
    if let Some(b) = report.comparison.builders.iter().find(|b| b.gpu_hit_mismatches.is_some_and(|m| m > 0)) {
        eprintln!(
            "bvh-bench: note: {} rays hit otherwise on the GPU than on the CPU ({}; the GPU's f32 triangle test)",
            b.gpu_hit_mismatches.unwrap_or_default(),
            b.name
        );
    }
    Ok(())
}
