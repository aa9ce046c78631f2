//! `--memory`: what each builder keeps to trace, and the peak, one process per builder.

use anyhow::{Context, Result, bail};
use arbor::bvh::build::Builder;
use std::io::Write;

use crate::cli::outln;
use crate::options::load_input;
use crate::report::write_outputs;
use crate::report::{MemoryComparison, MemoryReport};
use crate::{Args, default_builders};

/// `--memory`: each builder in a fresh process, so that no peak hides another.
pub(crate) fn run_memory(args: &Args) -> Result<()> {
    let names = args.builders.clone().unwrap_or_else(default_builders);
    for n in &names {
        n.trim().parse::<Builder>().context("--builders")?;
    }
    let exe = std::env::current_exe().context("finding bvh-bench's own executable")?;
    let mut reports = Vec::new();
    for name in &names {
        let mut cmd = std::process::Command::new(&exe);
        cmd.args(args.input.iter()).args(["--seed", &args.seed.to_string(), "--memory-child", name.trim()]);
        if let Some(p) = &args.procedural {
            cmd.args(["--procedural", p]);
        }
        if let Some(n) = args.threads {
            cmd.args(["--threads", &n.to_string()]);
        }
        let out = cmd.stderr(std::process::Stdio::inherit()).output().context("running a --memory process")?;
        if !out.status.success() {
            bail!("--memory: the process building with {name} failed ({})", out.status);
        }
        let r: MemoryReport = serde_json::from_slice(&out.stdout).context("reading a --memory process's report")?;
        reports.push(r);
    }
    let triangles = reports.first().map_or(0, |r| r.triangles);
    outln!("{triangles} triangles; each builder in its own process");
    outln!(
        "{:<26} {:>10} {:>12} {:>12} {:>14} {:>14} {:>10}",
        "builder",
        "build ms",
        "kept MB",
        "peak MB",
        "kept B/tri",
        "peak B/tri",
        "wide B/tri"
    );
    for r in &reports {
        outln!(
            "{:<26} {:>10.1} {:>12.1} {:>12.1} {:>14.1} {:>14.1} {:>10.1}",
            r.name,
            r.build_ms,
            r.kept_bytes as f64 / 1e6,
            r.peak_bytes as f64 / 1e6,
            r.kept_bytes_per_triangle,
            r.peak_bytes_per_triangle,
            r.wide_bytes_per_triangle
        );
    }
    outln!(
        "(kept: what tracing needs, triangles included, Arbor's binary tree and the wide form it traces; wide: that form's part; peak: the whole process, mesh and input triangles included)"
    );
    let report = MemoryComparison { triangles, builders: &reports };
    let csv = |f: &mut dyn Write| -> Result<()> {
        writeln!(
            f,
            "name,build_ms,kept_bytes,peak_bytes,kept_bytes_per_triangle,peak_bytes_per_triangle,wide_bytes,wide_bytes_per_triangle"
        )?;
        for r in &reports {
            writeln!(
                f,
                "{},{},{},{},{},{},{},{}",
                r.name,
                r.build_ms,
                r.kept_bytes,
                r.peak_bytes,
                r.kept_bytes_per_triangle,
                r.peak_bytes_per_triangle,
                r.wide_bytes,
                r.wide_bytes_per_triangle
            )?;
        }
        Ok(())
    };
    write_outputs(args, &report, csv, (String::new(), ("", "")), &[], false)
}

/// One builder's `--memory` process: builds what tracing needs and prints a [`MemoryReport`].
/// Ours: the leaf-collapsed BVH and its leaf-ordered triangles (the renderer's `MeshBvh`).
/// obvhs: its `Bvh2` and triangles, built exactly as its preset ships.
pub(crate) fn memory_child(args: &Args, name: &str, tracing: arbor::bvh::Tracing) -> Result<()> {
    let builder: Builder = name.parse().context("--memory-child")?;
    let (_, mesh) = load_input(args)?;
    let triangles = mesh.triangles();
    drop(mesh);
    let t = std::time::Instant::now();
    let (kept, wide) = match builder.to_string().strip_prefix("obvhs-") {
        Some(preset) => {
            let (tris, bvh) = arbor_bench::peers::obvhs_native_bytes(preset, &triangles);
            (tris + bvh, 0)
        }
        _ => {
            // The binary tree, the leaf-ordered triangles and the wide form `render` traces.
            let m = builder.build_mesh(&triangles, tracing);
            (m.memory_bytes(), m.wide_memory_bytes())
        }
    };
    let (kept, wide) = (kept as u64, wide as u64);
    let build_ms = t.elapsed().as_secs_f64() * 1e3;
    let peak = arbor::memory::peak_rss_bytes().context("--memory needs /proc/self/status (Linux)")?;
    let n = triangles.len().max(1) as f64;
    let r = MemoryReport {
        name: builder.to_string(),
        triangles: triangles.len(),
        build_ms,
        kept_bytes: kept,
        peak_bytes: peak,
        kept_bytes_per_triangle: kept as f64 / n,
        wide_bytes: wide,
        wide_bytes_per_triangle: wide as f64 / n,
        peak_bytes_per_triangle: peak as f64 / n,
    };
    outln!("{}", serde_json::to_string(&r)?);
    Ok(())
}
