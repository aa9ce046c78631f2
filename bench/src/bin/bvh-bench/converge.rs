//! `--converge`: image error against wall time, per builder and device.

use anyhow::{Context, Result, bail};
use arbor::scene::RenderSettings;
use std::io::Write;

use crate::Args;
use crate::cli::outln;
use crate::plot::Series;
use crate::report::{ConvergeReport, NotCompared, ReferenceInfo, write_outputs};

/// `--converge`.
pub(crate) fn run_converge(args: &Args, tracing: arbor::bvh::Tracing) -> Result<()> {
    use arbor::device::{BuilderChoice, Device, DeviceChoice};
    use arbor_bench::converge::{self, ConvergeConfig};
    let path = args.converge.as_ref().expect("checked by the caller");
    let mut devices = Vec::new();
    for d in args.devices.as_deref().unwrap_or(&["cpu".to_string()]) {
        devices.push(match d.trim() {
            "cpu" => Device::Cpu,
            "gpu" => DeviceChoice::Gpu.select().context("--devices gpu")?.0,
            other => bail!("--devices: unknown device `{other}`; known: cpu, gpu"),
        });
    }
    let names = args
        .builders
        .clone()
        .unwrap_or_else(|| ["lbvh", "lbvh+prbvh", "binned-sah", "auto"].map(String::from).to_vec());
    let choices =
        names.iter().map(|b| b.trim().parse::<BuilderChoice>()).collect::<Result<Vec<_>, _>>().context("--builders")?;
    let max_spp = args.max_spp.unwrap_or(64);
    if max_spp == 0 {
        bail!("--max-spp must be at least 1");
    }
    let mut scene = arbor::scene::Scene::load(path)?;
    if let Some((w, h)) = args.image_size {
        (scene.camera.width, scene.camera.height) = (w, h);
    }
    let render = RenderSettings { spp: max_spp, time: None, clamp: None, ..scene.render };
    let config = ConvergeConfig { render, tracing, ..Default::default() };
    let (w, h) = (scene.camera.width, scene.camera.height);
    let (reference, reference_info) = match &args.reference {
        Some(file) => {
            let image = arbor::image_io::read_exr(file)?;
            if (image.width, image.height) != (w, h) {
                bail!(
                    "--reference {}: {}x{} pixels, but the render is {w}x{h} (see --image-size)",
                    file.display(),
                    image.width,
                    image.height
                );
            }
            (image, ReferenceInfo::File { path: file.display().to_string() })
        }
        None => {
            let spp = args.reference_spp.unwrap_or(max_spp.saturating_mul(8));
            if spp == 0 {
                bail!("--reference-spp must be at least 1");
            }
            let seed = config.render.seed ^ 0x5eed_0f5e;
            eprintln!("rendering the reference: {w}x{h}, {spp} spp ...");
            let (image, secs) = converge::render_reference(&scene, spp, config.render.max_depth, seed, tracing)?;
            eprintln!("  {secs:.1} s");
            (image, ReferenceInfo::Rendered { spp, seed, time_s: secs })
        }
    };
    eprintln!(
        "{}: {w}x{h}, max depth {}, {} threads",
        path.display(),
        config.render.max_depth,
        rayon::current_num_threads()
    );
    // Runs interleave the builders, so that a slow spell of a shared machine falls on all.
    let mut runs = Vec::new();
    for run in 0..args.runs {
        let mut curves = Vec::new();
        for &device in &devices {
            for choice in &choices {
                let curve = converge::measure_curve(&scene, choice, device, &reference, &config, &mut |p| {
                    eprintln!(
                        "  run {}: {choice} on {} {} spp: {:.3} s, rel MSE {:.4e}",
                        run + 1,
                        device.name(),
                        p.spp,
                        p.time_s,
                        p.rel_mse
                    );
                })?;
                curves.push(curve);
            }
        }
        runs.push(curves);
    }
    let curves = converge::median_of_runs(runs);
    outln!(
        "{:<14} {:>6} {:>6} {:>10} {:>10} {:>12} {:>10}",
        "builder",
        "device",
        "spp",
        "time s",
        "build s",
        "rel MSE",
        "MAE"
    );
    for c in &curves {
        for p in &c.points {
            outln!(
                "{:<14} {:>6} {:>6} {:>10.3} {:>10.3} {:>12.4e} {:>10.4e}",
                c.builder,
                c.device,
                p.spp,
                p.time_s,
                p.build_s,
                p.rel_mse,
                p.mae
            );
        }
    }
    if args.runs > 1 {
        outln!("(times: the median of {} runs)", args.runs);
    }
    let auto = converge::compare_auto(&curves);
    for a in &auto {
        outln!(
            "{}: auto against the best fixed builder at equal time ({:.3} to {:.3} s): worst rel MSE ratio {:.3} at {:.3} s ({} best there), worst MAE ratio {:.3}",
            a.device,
            a.compared_from_s,
            a.compared_to_s,
            a.worst_ratio_rel_mse,
            a.worst_at_time_s,
            a.best_fixed_there,
            a.worst_ratio_mae
        );
        let walls: Vec<String> =
            a.wall_ratios.iter().map(|w| format!("{} spp {:.2}x ({})", w.spp, w.ratio, w.best_fixed)).collect();
        outln!("{}: auto's build + render time over the fastest fixed builder's: {}", a.device, walls.join(", "));
    }
    let not_compared = converge::auto_not_compared(&curves);
    for (device, why) in &not_compared {
        outln!("{device}: auto not compared with the fixed builders: {why}");
    }
    let non_finite: u64 = curves.iter().flat_map(|c| &c.points).map(|p| p.non_finite).sum();
    let report = ConvergeReport {
        scene: path.display().to_string(),
        width: w,
        height: h,
        max_depth: config.render.max_depth,
        threads: rayon::current_num_threads(),
        reference: reference_info,
        curves: &curves,
        auto: &auto,
        auto_not_compared: not_compared
            .iter()
            .map(|(device, reason)| NotCompared { device: device.clone(), reason })
            .collect(),
    };
    let series: Vec<Series> = curves
        .iter()
        .map(|c| (format!("{} ({})", c.builder, c.device), c.points.iter().map(|p| (p.time_s, p.rel_mse)).collect()))
        .collect();
    let name = path.file_name().map_or(path.display().to_string(), |n| n.to_string_lossy().into_owned());
    let plot = (format!("Error against time: {name}"), ("wall time incl. BVH build (s)", "relative MSE"));
    let csv = |f: &mut dyn Write| -> Result<()> {
        writeln!(f, "builder,device,spp,time_s,build_s,rel_mse,mae,non_finite")?;
        for c in &curves {
            for p in &c.points {
                writeln!(
                    f,
                    "{},{},{},{},{},{},{},{}",
                    c.builder, c.device, p.spp, p.time_s, p.build_s, p.rel_mse, p.mae, p.non_finite
                )?;
            }
        }
        Ok(())
    };
    write_outputs(args, &report, csv, plot, &series, true)?;
    if non_finite > 0 {
        bail!("{non_finite} NaN or infinite samples were dropped: a bug");
    }
    Ok(())
}
