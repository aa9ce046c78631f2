//! `--animated` and `--procedural-animated`: ways of keeping a top-level BVH up to date.

use anyhow::{Context, Result, bail};
use arbor_bench::anim::{self as anim_bench, AnimBenchConfig, AnimatedInstances};

use crate::Args;
use crate::cli::outln;
use crate::options::parse_count;
use crate::plot::Series;
use crate::report::write_outputs;

/// `--animated` / `--procedural-animated`.
pub(crate) fn run_animated(args: &Args, tracing: arbor::bvh::Tracing) -> Result<()> {
    let frames = args.frames.unwrap_or(300);
    if frames == 0 {
        bail!("--frames must be at least 1");
    }
    let (name, anim) = match (&args.animated, &args.procedural_animated) {
        (Some(path), _) => {
            let scene = arbor::scene::Scene::load(path)?;
            if !scene.is_animated() {
                bail!("{}: nothing in the scene moves (no keyframes or orbiting scatter)", path.display());
            }
            (path.display().to_string(), AnimatedInstances::from_scene(&scene))
        }
        (None, Some(n)) => {
            let spec = n;
            let n = parse_count(n).with_context(|| format!("--procedural-animated: bad instance count `{n}`"))?;
            // About 1.6 kB per instance at the peak (200k instances, 2 frames).
            arbor::memory::check_fits(&format!("--procedural-animated {spec}"), n as f64 * 2000.0)?;
            let moving = args.moving.unwrap_or(10.0);
            if !(0.0..=100.0).contains(&moving) {
                bail!("--moving must be a percentage from 0 to 100, not {moving}");
            }
            (format!("{n} instances, {moving}% moving"), AnimatedInstances::procedural(n, moving / 100.0, args.seed))
        }
        (None, None) => unreachable!("checked by the caller"),
    };
    eprintln!(
        "{name}: {} instances ({} moving), {} triangles, {} frames, {} threads",
        anim.instances.len(),
        anim.moving.len(),
        anim.world_triangle_count(),
        frames,
        rayon::current_num_threads()
    );
    let config = AnimBenchConfig { frames, resolution: args.resolution.min(256), tracing, ..Default::default() };
    let report = anim_bench::run(&anim, &config);
    outln!(
        "{} instances, {} moving, {} triangles, {} frames, {} threads",
        report.instances,
        report.moving,
        report.triangles,
        report.frames,
        report.threads
    );
    outln!(
        "{:<16} {:>10} {:>10} {:>10} {:>10} {:>10} {:>9} {:>9} {:>9}",
        "strategy",
        "update ms",
        "mean ms",
        "max ms",
        "SAH final",
        "SAH max",
        "rebuilds",
        "primary",
        "diffuse"
    );
    for s in &report.strategies {
        let v = strategy_values(s);
        outln!(
            "{:<16} {:>10.3} {:>10.3} {:>10.3} {:>10.3} {:>10.3} {:>9} {:>9.2} {:>9.2}",
            s.name,
            v[0],
            v[1],
            v[2],
            v[3],
            v[4],
            v[5],
            v[6],
            v[7]
        );
    }
    outln!(
        "(update: median per frame; SAH as a ratio to a fresh binned-SAH build; trace speeds in Mrays/s at the last frame)"
    );
    if report.single_level_differences > 0 {
        outln!(
            "({} rays hit another triangle through the single-level tree's world-space copies: rounding at shared edges)",
            report.single_level_differences
        );
    }
    let series: Vec<Series> = report
        .strategies
        .iter()
        .map(|s| (s.name.clone(), s.sah_ratio_curve.iter().map(|p| (p[0], p[1])).collect()))
        .collect();
    let plot = (format!("SAH ratio over the animation: {name}"), ("frame", "SAH / fresh build's SAH"));
    write_outputs(
        args,
        &report,
        |f| {
            writeln!(f, "name,{}", STRATEGY_COLUMNS.join(","))?;
            for s in &report.strategies {
                let v = strategy_values(s).map(|x| x.to_string());
                writeln!(f, "{},{}", s.name, v.join(","))?;
            }
            Ok(())
        },
        plot,
        &series,
        false,
    )?;
    if !report.mismatches.is_empty() {
        bail!("strategies disagree on hits:\n  {}", report.mismatches.join("\n  "));
    }
    Ok(())
}

/// The numeric columns of a strategy, in the table's and the CSV's order.
pub(crate) const STRATEGY_COLUMNS: [&str; 8] = [
    "update_ms",
    "update_ms_mean",
    "update_ms_max",
    "sah_ratio_final",
    "sah_ratio_max",
    "rebuilds",
    "primary_mrays_final",
    "diffuse_mrays_final",
];

pub(crate) fn strategy_values(s: &anim_bench::StrategyReport) -> [f64; 8] {
    [
        s.update_ms,
        s.update_ms_mean,
        s.update_ms_max,
        s.sah_ratio_final,
        s.sah_ratio_max,
        s.rebuilds as f64,
        s.primary_mrays_final,
        s.diffuse_mrays_final,
    ]
}
