//! Checks of the command line before any work, and the inputs: a mesh, a scene, or a procedural mesh.

use anyhow::{Context, Result, bail};
use arbor::atomic_file::{self};
use arbor::bvh::build::Builder;
use arbor::geometry::{TriangleMesh, procedural};
use arbor_bench::compare::{BenchBuilder, EMBREE_PREFIX};

use crate::Args;
use crate::plot::plot_format;

/// Peak bytes per triangle of the builder comparison with its default builders, each tree kept
/// in its binary and wide forms: the peak measured on a large hairball (docs/benchmarks.md,
/// "Memory"), with room for the builders that keep more.
const BENCH_BYTES_PER_TRIANGLE: f64 = 1400.0;

/// Most runs a benchmark may repeat, and the largest --resolution: beyond them a mistyped number
/// would run for days or ask for more memory than any machine has.
pub(crate) const MAX_RUNS: usize = 10_000;

pub(crate) const MAX_RESOLUTION: u32 = 8192;

/// Checks of the options all modes share, before any work: numbers in range, builders listed
/// once, and the output files writable (`atomic_file::prepare`).
pub(crate) fn check_options(args: &Args) -> Result<()> {
    if !(1..=MAX_RUNS).contains(&args.runs) {
        bail!("--runs must be from 1 to {MAX_RUNS}, not {}", args.runs);
    }
    if !(1..=MAX_RESOLUTION).contains(&args.resolution) {
        bail!("--resolution must be from 1 to {MAX_RESOLUTION}, not {}", args.resolution);
    }
    if args.mu == 0 {
        bail!("--mu must be at least 1");
    }
    if !(args.epsilon.is_finite() && args.epsilon >= 0.0) {
        bail!("--epsilon must be a finite number >= 0, not {}", args.epsilon);
    }
    if let Some(names) = &args.builders {
        // By the name each builds as: `prbvh` is `lbvh+prbvh`.
        let mut seen = std::collections::HashMap::new();
        for name in names.iter().map(|n| n.trim()) {
            let canonical = name.parse::<Builder>().map_or(name.to_string(), |b| b.to_string());
            if let Some(first) = seen.insert(canonical.clone(), name) {
                if first == name {
                    bail!("--builders: `{name}` is listed twice");
                }
                bail!("--builders: `{first}` and `{name}` are the same builder, `{canonical}`");
            }
        }
        // Embree's builders exist only with the feature, and only in the builder comparison.
        for name in names.iter().map(|n| n.trim()).filter(|n| n.starts_with(EMBREE_PREFIX)) {
            name.parse::<BenchBuilder>().context("--builders")?;
            if args.converge.is_some() || args.memory {
                bail!(
                    "--builders: `{name}` (Embree) is measured by the builder comparison only, not by --converge or --memory"
                );
            }
        }
    }
    if let Some(devices) = &args.devices {
        let mut seen = std::collections::HashSet::new();
        if let Some(twice) = devices.iter().map(|d| d.trim()).find(|d| !seen.insert(*d)) {
            bail!("--devices: `{twice}` is listed twice");
        }
    }
    check_mode_options(args)?;
    if let Some(plot) = &args.plot {
        plot_format(plot)?;
    }
    let outputs = [("--json", &args.json), ("--csv", &args.csv), ("--plot", &args.plot)];
    let inputs = [
        ("the input", &args.input),
        ("--converge", &args.converge),
        ("--animated", &args.animated),
        ("--reference", &args.reference),
    ];
    for (k, &(flag, out)) in outputs.iter().enumerate() {
        let Some(out) = out else { continue };
        for &(name, input) in &inputs {
            if input.as_deref().is_some_and(|i| atomic_file::replaces(out, i)) {
                bail!("{flag} {}: that is the file of {name}, which the report would replace", out.display());
            }
        }
        for &(other_flag, other) in &outputs[k + 1..] {
            if other.as_deref().is_some_and(|o| atomic_file::replaces(out, o)) {
                bail!("{flag} and {other_flag} name the same file, {}: one would replace the other", out.display());
            }
        }
        atomic_file::prepare(out).with_context(|| format!("cannot write {}", out.display()))?;
    }
    Ok(())
}

/// Options that belong to another mode than the one run are errors, not silently ignored.
pub(crate) fn check_mode_options(args: &Args) -> Result<()> {
    let converge = args.converge.is_some();
    let animation = args.animated.is_some() || args.procedural_animated.is_some();
    let mode_only: [(bool, &str, bool, &str); 8] = [
        (args.devices.is_some(), "--devices", converge, "--converge"),
        (args.reference.is_some(), "--reference", converge, "--converge"),
        (args.reference_spp.is_some(), "--reference-spp", converge, "--converge"),
        (args.max_spp.is_some(), "--max-spp", converge, "--converge"),
        (args.image_size.is_some(), "--image-size", converge, "--converge"),
        (args.frames.is_some(), "--frames", animation, "--animated and --procedural-animated"),
        (args.moving.is_some(), "--moving", args.procedural_animated.is_some(), "--procedural-animated"),
        (args.builders.is_some(), "--builders", !animation, "the builder comparison, --gpu, --converge and --memory"),
    ];
    for (given, option, applies, mode) in mode_only {
        if given && !applies {
            bail!("{option} applies to {mode}");
        }
    }
    if args.memory && args.plot.is_some() {
        bail!("--memory has no plot");
    }
    if args.gpu && (args.plot.is_some() || args.csv.is_some()) {
        bail!("--gpu writes a table and --json only (no --csv or --plot)");
    }
    if let Some(path) = &args.converge {
        if path.extension().is_some_and(|e| ["obj", "ply", "gltf", "glb"].iter().any(|m| e.eq_ignore_ascii_case(m))) {
            bail!("--converge {}: renders a scene (.toml), not a mesh", path.display());
        }
    }
    Ok(())
}

pub(crate) fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(|| format!("expected WIDTHxHEIGHT, as 128x128, not {s:?}"))?;
    let w: u32 = w.trim().parse().map_err(|e| format!("width {w:?}: {e}"))?;
    let h: u32 = h.trim().parse().map_err(|e| format!("height {h:?}: {e}"))?;
    if w == 0 || h == 0 || w > 65_536 || h > 65_536 {
        return Err(format!("{s}: each side must be 1 to 65536 pixels"));
    }
    Ok((w, h))
}

/// The mesh and a name for it; an error where it has no triangles, which no mode can measure.
pub(crate) fn load_input(args: &Args) -> Result<(String, TriangleMesh)> {
    let (name, mesh) = load_any_input(args)?;
    if mesh.indices.is_empty() {
        bail!("{}: no triangles", args.input.as_ref().map_or(name, |p| p.display().to_string()));
    }
    Ok((name, mesh))
}

/// [`load_input`], empty meshes included.
pub(crate) fn load_any_input(args: &Args) -> Result<(String, TriangleMesh)> {
    let input = match &args.input {
        Some(path) if path.extension().is_some_and(|e| e == "toml") => {
            // A scene: every object's triangles in world space, as the renderer builds over them.
            let scene = arbor::scene::Scene::load(path)?;
            scene.check_flat_fits(path, BENCH_BYTES_PER_TRIANGLE)?;
            let (triangles, _) = scene.world_triangles();
            let mesh = TriangleMesh {
                positions: triangles.iter().flat_map(|t| [t.v0, t.v1, t.v2]).collect(),
                indices: (0..triangles.len() as u32).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect(),
                ..Default::default()
            };
            Some((path.file_name().map_or(path.display().to_string(), |n| n.to_string_lossy().into_owned()), mesh))
        }
        Some(path) => {
            let is = |x: &str| path.extension().is_some_and(|e| e.eq_ignore_ascii_case(x));
            let mesh = if is("ply") {
                TriangleMesh::load_ply(path)?
            } else if is("gltf") || is("glb") {
                // Every mesh node's triangles in the file's world space, as a scene naming it places them.
                arbor::scene::gltf::GltfFile::open(path)?.world_mesh()?
            } else {
                TriangleMesh::load_obj(path)?
            };
            Some((path.file_name().map_or(path.display().to_string(), |n| n.to_string_lossy().into_owned()), mesh))
        }
        None => None,
    };
    let Some(spec) = &args.procedural else {
        return input.context("give a mesh (.obj, .ply, .gltf or .glb) or --procedural KIND:N");
    };
    let (kind, count) = spec.split_once(':').context("--procedural: expected KIND:N, e.g. city:1M")?;
    let n = parse_count(count).with_context(|| format!("--procedural: bad triangle count `{count}`"))?;
    arbor::memory::check_fits(&format!("--procedural {spec}"), n as f64 * BENCH_BYTES_PER_TRIANGLE)?;
    let mesh = match kind {
        "hairball" => procedural::hairball(n, args.seed),
        "city" => procedural::city(n, args.seed),
        "subdivided" => {
            let (_, base) = input.as_ref().context("--procedural subdivided:N needs an input mesh to subdivide")?;
            procedural::subdivide(base, n)
        }
        other => bail!("--procedural: unknown kind `{other}`; known: hairball, city, subdivided"),
    };
    let name = match &input {
        Some((base, _)) if kind == "subdivided" => format!("{base} subdivided"),
        _ => kind.to_string(),
    };
    Ok((name, mesh))
}

pub(crate) fn parse_count(s: &str) -> Result<usize> {
    let (digits, scale) = match s.chars().last() {
        Some('k' | 'K') => (&s[..s.len() - 1], 1_000.0),
        Some('m' | 'M') => (&s[..s.len() - 1], 1_000_000.0),
        _ => (s, 1.0),
    };
    let v: f64 = digits.parse()?;
    let n = v * scale;
    if !(n.is_finite() && n >= 1.0) {
        bail!("must be at least 1");
    }
    if n.fract() != 0.0 {
        bail!("must be a whole number");
    }
    // Beyond this no machine holds the mesh; `check_fits` judges the counts below it.
    if n > 1e12 {
        bail!("must be at most 10^12");
    }
    Ok(n as usize)
}
