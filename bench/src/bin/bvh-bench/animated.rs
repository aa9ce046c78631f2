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

/// One way of keeping an animated scene on the GPU, measured over the frames.
#[derive(serde::Serialize)]
pub(crate) struct GpuAnimRow {
    /// `two-level dynamic` (the top level updated in place: delete, clean, reinsert),
    /// `two-level rebuild` (the top level rebuilt by binned SAH on the host), `two-level
    /// gpu-lbvh` (the top level rebuilt by the GPU's LBVH over the instances' boxes, read back),
    /// or `flatten` (every object's triangles in world space under one LBVH, rebuilt and
    /// uploaded).
    pub strategy: String,
    /// The GPU's tree form: `binary` or `wide8`.
    pub form: String,
    /// Median and largest per-frame update (host update and upload), the first frame's build
    /// left out, in milliseconds.
    pub update_ms: f64,
    pub update_ms_max: f64,
    /// Median render speed of a frame at `spp`, in Mrays/s.
    pub mrays: f64,
    /// Bytes on the device of the trees, triangle order and (two levels) instances.
    pub device_bytes: usize,
}

#[derive(serde::Serialize)]
pub(crate) struct GpuAnimReport {
    pub scene: String,
    pub adapter: String,
    pub frames: u32,
    pub spp: u32,
    pub instances: usize,
    pub world_triangles: usize,
    pub rows: Vec<GpuAnimRow>,
}

/// `--animated SCENE --gpu`: the scene's first `--frames` frames (default 8) on the GPU, kept
/// each way of [`GpuAnimRow::strategy`] in both forms; the frame rendered at 1 spp after each
/// update.
pub(crate) fn run_animated_gpu(args: &Args) -> Result<()> {
    use arbor::bvh::dynamic::instances::TopLevelUpdate;
    use arbor::gpu::trace::{self, GpuForm, GpuScene};
    use arbor::render::RenderScene;
    use std::time::Instant;
    let path = args.animated.as_ref().expect("checked by the caller");
    let scene = arbor::scene::Scene::load(path)?;
    if !scene.is_animated() {
        bail!("{}: nothing in the scene moves (no keyframes or orbiting scatter)", path.display());
    }
    let ctx = arbor::gpu::GpuContext::shared()?;
    let animation = scene.animation.as_ref().expect("an animated scene has [animation]");
    let frames = args.frames.unwrap_or(8).clamp(2, animation.frames.len().max(2) as u32);
    let first = animation.frames.start;
    let spp = 1;
    let depth = scene.render.max_depth;
    let builder: arbor::bvh::build::Builder = "lbvh+prbvh".parse().expect("a builder name");
    let lbvh: arbor::bvh::build::Builder = "lbvh".parse().expect("a builder name");
    eprintln!("{}: {frames} frames at {spp} spp on {}", path.display(), ctx.describe());
    let mut rows = Vec::new();
    let (mut instances, mut world) = (0, 0);
    for strategy in ["two-level dynamic", "two-level rebuild", "two-level gpu-lbvh", "flatten"] {
        for form in [GpuForm::Wide8, GpuForm::Binary] {
            let how = match strategy {
                "two-level rebuild" => TopLevelUpdate::Rebuild,
                // The boxes brought up to date, then the tree replaced by the GPU's.
                "two-level gpu-lbvh" => TopLevelUpdate::Refit,
                _ => TopLevelUpdate::Dynamic(Default::default()),
            };
            let (mut updates, mut speeds, mut bytes) = (Vec::new(), Vec::new(), 0);
            let mut state: Option<(RenderScene, GpuScene)> = None;
            for f in first..first + frames {
                let time = scene.frame_time(f);
                let t = Instant::now();
                let (rs, gpu) = match (strategy, state.take()) {
                    ("flatten", _) => {
                        let (rs, _) = trace::flatten(&scene, time, &lbvh);
                        let gpu = GpuScene::upload(ctx, &rs, form)?;
                        (rs, gpu)
                    }
                    (_, None) => {
                        let (mut rs, _) = RenderScene::build(&scene, &builder, arbor::bvh::Tracing::gpu());
                        rs.set_time(&scene, time, &how);
                        let gpu = GpuScene::upload(ctx, &rs, form)?;
                        (rs, gpu)
                    }
                    (_, Some((mut rs, mut gpu))) => {
                        rs.set_time(&scene, time, &how);
                        if strategy == "two-level gpu-lbvh"
                            && let arbor::render::geometry::Geometry::Instanced(g) = &mut rs.geometry
                        {
                            let (tree, _) = arbor::gpu::lbvh::build(ctx, g.two_level.instance_boxes())?;
                            g.two_level.replace_top_level(&tree);
                        }
                        gpu.update_instances(ctx, &rs)?;
                        (rs, gpu)
                    }
                };
                if f > first {
                    updates.push(t.elapsed().as_secs_f64() * 1e3);
                } else {
                    trace::compile(ctx, &gpu)?;
                    world = rs.geometry.world_triangle_count();
                    if let arbor::render::geometry::Geometry::Instanced(g) = &rs.geometry {
                        instances = g.two_level.instances().len();
                    }
                }
                bytes = gpu.tree_bytes + gpu.instance_bytes();
                let t = Instant::now();
                let out = trace::render(ctx, &gpu, 1, depth, spp)?;
                speeds.push(out.rays as f64 / t.elapsed().as_secs_f64() / 1e6);
                state = Some((rs, gpu));
            }
            let update_ms_max = updates.iter().copied().fold(0.0, f64::max);
            let row = GpuAnimRow {
                strategy: strategy.to_owned(),
                form: form.name().to_owned(),
                update_ms: arbor_bench::median(updates),
                update_ms_max,
                mrays: arbor_bench::median(speeds),
                device_bytes: bytes,
            };
            eprintln!("  {} {}: update {:.2} ms, {:.3} Mrays/s", row.strategy, row.form, row.update_ms, row.mrays);
            rows.push(row);
        }
    }
    let report = GpuAnimReport {
        scene: path.display().to_string(),
        adapter: ctx.describe(),
        frames,
        spp,
        instances,
        world_triangles: world,
        rows,
    };
    outln!(
        "{} instances, {} triangles in the world, {} frames at {} spp, {}",
        report.instances,
        report.world_triangles,
        report.frames,
        report.spp,
        report.adapter
    );
    outln!(
        "{:<18} {:>6} {:>10} {:>10} {:>10} {:>12}",
        "strategy",
        "form",
        "update ms",
        "max ms",
        "Mrays/s",
        "device MB"
    );
    for r in &report.rows {
        outln!(
            "{:<18} {:>6} {:>10.2} {:>10.2} {:>10.3} {:>12.1}",
            r.strategy,
            r.form,
            r.update_ms,
            r.update_ms_max,
            r.mrays,
            r.device_bytes as f64 / 1e6
        );
    }
    outln!("(update: median per frame after the first, host update and upload; render speed: median of the frames)");
    write_outputs(
        args,
        &report,
        |f| {
            writeln!(f, "strategy,form,update_ms,update_ms_max,mrays,device_bytes")?;
            for r in &report.rows {
                writeln!(
                    f,
                    "{},{},{},{},{},{}",
                    r.strategy, r.form, r.update_ms, r.update_ms_max, r.mrays, r.device_bytes
                )?;
            }
            Ok(())
        },
        (format!("GPU animation: {}", report.scene), ("frame", "")),
        &[],
        false,
    )
}
