//! The builder comparison, the default mode: build time, SAH and trace speed.

use anyhow::{Context, Result, bail};
use arbor::bvh::build::prbvh::PrbvhConfig;
use arbor_bench::compare::{self as bench, BenchBuilder, BenchConfig, Report};
use indicatif::ProgressBar;
use std::io::{IsTerminal, Write};

use crate::cli::outln;
use crate::options::load_input;
use crate::plot::Series;
use crate::report::write_outputs;
use crate::{Args, default_builders};

/// The builder comparison (the default mode): every builder builds the same triangles and
/// traces the same rays; a table, and JSON, CSV and a plot where asked.
pub(crate) fn run(args: &Args, tracing: arbor::bvh::Tracing) -> Result<()> {
    let (name, report) = measure(args, tracing, None)?;
    // Embree's tree is opaque: it has no SAH curve to plot.
    let series: Vec<Series> = report
        .builders
        .iter()
        .filter(|b| !b.sah_curve.is_empty())
        .map(|b| (b.name.clone(), b.sah_curve.iter().map(|p| (p[0], p[1])).collect()))
        .collect();
    let plot = (format!("SAH against time: {name}"), ("build + optimisation time (ms)", "SAH, one primitive per leaf"));
    write_outputs(args, &report, |f| write_csv(f, &report), plot, &series, false)?;
    check(&report)
}

/// Fails where the builders' hits disagree.
pub(crate) fn check(report: &Report) -> Result<()> {
    if !report.mismatches.is_empty() {
        bail!("builders disagree on hits:\n  {}", report.mismatches.join("\n  "));
    }
    Ok(())
}

/// Runs the comparison (with the ray sets also traced on `gpu` where given) and prints its
/// table; returns the input's name and the report.
pub(crate) fn measure(
    args: &Args,
    tracing: arbor::bvh::Tracing,
    gpu: Option<&'static arbor::gpu::GpuContext>,
) -> Result<(String, Report)> {
    let builders = args
        .builders
        .clone()
        .unwrap_or_else(default_builders)
        .iter()
        .map(|b| b.trim().parse::<BenchBuilder>())
        .collect::<Result<Vec<_>, _>>()
        .context("--builders")?;
    let (name, mesh) = load_input(args)?;
    let triangles = mesh.triangles();
    eprintln!("{name}: {} triangles, {} threads", triangles.len(), rayon::current_num_threads());
    let config = BenchConfig {
        builders,
        runs: args.runs,
        resolution: args.resolution,
        prbvh: PrbvhConfig { mu: args.mu, epsilon: args.epsilon, ..Default::default() },
        tracing,
        gpu,
        ..Default::default()
    };
    // On a terminal, a spinner says what runs: large meshes take minutes.
    let spinner = if std::io::stderr().is_terminal() { ProgressBar::new_spinner() } else { ProgressBar::hidden() };
    spinner.enable_steady_tick(std::time::Duration::from_millis(200));
    let report = bench::run_with_progress(&triangles, &config, |what| spinner.set_message(what.to_owned()));
    spinner.finish_and_clear();
    let report = report?;
    print_table(&report);
    Ok((name, report))
}

pub(crate) fn print_table(r: &Report) {
    outln!(
        "{} triangles, {} threads; rays: {} primary, {} shadow, {} diffuse",
        r.triangles,
        r.threads,
        r.rays.primary,
        r.rays.shadow,
        r.rays.diffuse
    );
    outln!(
        "{:<26} {:>10} {:>12} {:>10} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9}",
        "builder",
        "build ms",
        "optimize ms",
        "SAH leaf1",
        "SAH",
        "nodes",
        "leaves",
        "primary",
        "shadow",
        "diffuse"
    );
    let speed = |v: Option<f64>| v.map_or_else(|| "n/a".to_string(), |v| format!("{v:.2}"));
    // Fields Embree's opaque tree does not have: `-`.
    let ms = |v: Option<f64>| v.map_or_else(|| "-".to_string(), |v| format!("{v:.1}"));
    let sah = |v: Option<f64>| v.map_or_else(|| "-".to_string(), |v| format!("{v:.2}"));
    let count = |v: Option<usize>| v.map_or_else(|| "-".to_string(), |v| v.to_string());
    for b in &r.builders {
        outln!(
            "{:<26} {:>10.1} {:>12} {:>10} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9}",
            b.name,
            b.build_ms,
            ms(b.optimize_ms),
            sah(b.sah_leaf1),
            sah(b.sah),
            count(b.nodes),
            count(b.leaves),
            speed(b.primary_mrays),
            speed(b.shadow_mrays),
            speed(b.diffuse_mrays)
        );
    }
    outln!(
        "(trace speeds in Mrays/s, Arbor's through its {} tree on the {} path; SAH after Arbor's leaf collapse, max 8 per leaf)",
        r.trace,
        r.simd
    );
    if r.builders.iter().any(|b| b.binary_primary_mrays.is_some()) {
        outln!(
            "{:<26} {:>10} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}",
            "binary tree against wide",
            "wide ms",
            "wide SAH",
            "primary",
            "shadow",
            "diffuse",
            "w/b prim",
            "w/b diff"
        );
        let ratio = |w: Option<f64>, b: Option<f64>| match (w, b) {
            (Some(w), Some(b)) if b > 0.0 => format!("{:.2}x", w / b),
            _ => "-".to_string(),
        };
        for b in r.builders.iter().filter(|b| b.binary_primary_mrays.is_some()) {
            outln!(
                "{:<26} {:>10} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}",
                b.name,
                ms(b.wide_collapse_ms),
                sah(b.wide_sah),
                speed(b.binary_primary_mrays),
                speed(b.binary_shadow_mrays),
                speed(b.binary_diffuse_mrays),
                ratio(b.primary_mrays, b.binary_primary_mrays),
                ratio(b.diffuse_mrays, b.binary_diffuse_mrays)
            );
        }
        outln!("(binary: the leaf-collapsed binary tree, scalar code; wide ms: its collapse into the traced form)");
    }
    if r.builders.iter().any(|b| b.gpu_primary_mrays.is_some()) {
        outln!(
            "{:<26} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}",
            "on the GPU",
            "primary",
            "shadow",
            "diffuse",
            "bin prim",
            "bin shad",
            "bin diff",
            "w/b diff",
            "mismatch",
            "wide ms"
        );
        let ratio = |w: Option<f64>, b: Option<f64>| match (w, b) {
            (Some(w), Some(b)) if b > 0.0 => format!("{:.2}x", w / b),
            _ => "-".to_string(),
        };
        for b in r.builders.iter().filter(|b| b.gpu_primary_mrays.is_some()) {
            outln!(
                "{:<26} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}",
                b.name,
                speed(b.gpu_primary_mrays),
                speed(b.gpu_shadow_mrays),
                speed(b.gpu_diffuse_mrays),
                speed(b.gpu_binary_primary_mrays),
                speed(b.gpu_binary_shadow_mrays),
                speed(b.gpu_binary_diffuse_mrays),
                ratio(b.gpu_diffuse_mrays, b.gpu_binary_diffuse_mrays),
                count(b.gpu_hit_mismatches),
                ms(b.gpu_wide_collapse_ms)
            );
        }
        outln!(
            "(GPU: device time of one dispatch a set, Mrays/s; wide8 the compressed 8-wide tree, bin its binary tree; mismatch: rays hit otherwise than on the CPU; wide ms: the collapse into the wide form, on the CPU)"
        );
    }
    if let Some(reference) = &r.peer_reference {
        outln!("(embree-*: Embree's own trees and traversal; `-`: does not apply to them)");
        for b in r.builders.iter().filter(|b| b.differing_rays.is_some()) {
            let differing = b.differing_rays.unwrap_or_default();
            let reference_hits = r.builders.iter().find(|x| &x.name == reference).map(|x| x.hits);
            let sets = ["primary", "shadow", "diffuse"].iter().zip([r.rays.primary, r.rays.shadow, r.rays.diffuse]);
            let per_set: Vec<String> = sets
                .enumerate()
                .map(|(k, (set, rays))| {
                    let hits = match reference_hits {
                        Some(theirs) => format!("hits {}, reference {}", b.hits[k], theirs[k]),
                        None => format!("hits {}", b.hits[k]),
                    };
                    format!("{set} {} of {rays} ({hits})", differing[k])
                })
                .collect();
            outln!("{} against {reference}: rays hitting differently (grazing): {}", b.name, per_set.join("; "));
        }
    }
    if r.rays.shadow == 0 {
        outln!(
            "(no primary ray hit the mesh, so there are no shadow or diffuse rays: n/a, null in the JSON; a thin or flat mesh seen edge-on)"
        );
    }
}

pub(crate) fn write_csv(f: &mut dyn Write, r: &Report) -> Result<()> {
    writeln!(
        f,
        "name,build_ms,optimize_ms,collapse_ms,sah,sah_leaf1,nodes,leaves,depth,primary_mrays,shadow_mrays,diffuse_mrays,binary_primary_mrays,binary_shadow_mrays,binary_diffuse_mrays,wide_collapse_ms,wide_sah"
    )?;
    for b in &r.builders {
        writeln!(
            f,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            b.name,
            b.build_ms,
            csv_value(b.optimize_ms),
            csv_value(b.collapse_ms),
            csv_value(b.sah),
            csv_value(b.sah_leaf1),
            csv_value(b.nodes),
            csv_value(b.leaves),
            csv_value(b.depth),
            csv_value(b.primary_mrays),
            csv_value(b.shadow_mrays),
            csv_value(b.diffuse_mrays),
            csv_value(b.binary_primary_mrays),
            csv_value(b.binary_shadow_mrays),
            csv_value(b.binary_diffuse_mrays),
            csv_value(b.wide_collapse_ms),
            csv_value(b.wide_sah)
        )?;
    }
    Ok(())
}

/// A value in the CSV: empty where it does not apply, or for a set of no rays.
pub(crate) fn csv_value(v: Option<impl ToString>) -> String {
    v.map_or_else(String::new, |v| v.to_string())
}
