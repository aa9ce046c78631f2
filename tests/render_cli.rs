//! `render` as a user runs it: outputs, the summary line, overrides, and clear errors with the
//! exit codes a scheduler reads (files that are not regular files: 2; scenes that do not fit in
//! the memory allowed: 3).

use std::path::PathBuf;
use std::process::Command;

use crate::common;

fn render() -> Command {
    Command::new(env!("CARGO_BIN_EXE_render"))
}

fn scene(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes").join(name)
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("arbor-render-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn renders_exr_and_png_with_a_summary() {
    let dir = temp_dir("outputs");
    for name in ["out.exr", "out.png"] {
        let out = dir.join(name);
        let o = render()
            .arg(scene("furnace.toml"))
            .arg("-o")
            .arg(&out)
            .args(["--spp", "2", "--threads", "2", "--builder", "binned-sah"])
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        for word in ["triangles", "BVH (binned-sah)", "SAH", "render", "Mrays/s", "2 spp"] {
            assert!(stdout.contains(word), "summary lacks `{word}`: {stdout}");
        }
        assert!(std::fs::metadata(&out).unwrap().len() > 0);
    }
    let image = arbor::image_io::read_exr(dir.join("out.exr")).unwrap();
    assert_eq!((image.width, image.height), (128, 128));
    let quiet = render()
        .arg(scene("furnace.toml"))
        .arg("-o")
        .arg(dir.join("q.exr"))
        .args(["--spp", "1", "--quiet"])
        .output()
        .unwrap();
    assert!(quiet.status.success() && quiet.stdout.is_empty() && quiet.stderr.is_empty());
}

/// Every tree form and every SIMD path this CPU has renders the same image, bit for bit, and
/// the summary names the form and path; a path the CPU lacks or a bad name is a clear error.
#[test]
fn every_trace_form_and_simd_path_renders_the_same_image() {
    let dir = temp_dir("trace-forms");
    let run = |trace: &str, simd: &str| {
        let out = dir.join(format!("{trace}-{simd}.exr"));
        let o = render()
            .arg(scene("cornell-box.toml"))
            .arg("-o")
            .arg(&out)
            .args(["--spp", "2", "--threads", "2", "--device", "cpu", "--builder", "lbvh", "--trace", trace])
            .env("ARBOR_SIMD", simd)
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
        assert!(o.status.success(), "{trace} on {simd}: {}", String::from_utf8_lossy(&o.stderr));
        let expected = format!("traced as a {trace} tree, {} kernels", if trace == "binary" { "scalar" } else { simd });
        assert!(stdout.contains(&expected), "summary lacks `{expected}`: {stdout}");
        std::fs::read(&out).unwrap()
    };
    let reference = run("binary", "scalar");
    for simd in arbor::bvh::SimdPath::available() {
        for trace in ["wide4", "wide8"] {
            assert!(run(trace, simd.name()) == reference, "{trace} on {} renders another image", simd.name());
        }
    }
    for (simd, trace, message) in [
        ("sve", "wide4", "ARBOR_SIMD=\"sve\" is not a SIMD path"),
        ("scalar", "wide16", "\"wide16\" is not a tree form"),
    ] {
        let o = render()
            .arg(scene("cornell-box.toml"))
            .arg("-o")
            .arg(dir.join("bad.exr"))
            .args(["--spp", "1", "--trace", trace])
            .env("ARBOR_SIMD", simd)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && stderr.contains(message), "{simd}, {trace}: {stderr}");
        assert!(!dir.join("bad.exr").exists());
    }
}

/// Each bad call exits non-zero with a message naming the problem, and writes no image.
#[test]
fn errors_are_clear_and_leave_nothing_behind() {
    let dir = temp_dir("errors");
    let bad_scene = dir.join("bad.toml");
    std::fs::write(&bad_scene, "[camera]\nposition = [0, 0, 1]\n").unwrap();
    // 65536² pixels need about 800 GB of film: more than any machine this runs on.
    let huge = dir.join("huge.toml");
    let furnace = std::fs::read_to_string(scene("furnace.toml")).unwrap();
    let line = furnace.lines().position(|l| l.starts_with("resolution")).expect("furnace sets resolution") + 1;
    let huge_text: Vec<String> = furnace
        .lines()
        .map(|l| if l.starts_with("resolution") { "resolution = [65536, 65536]".into() } else { l.to_string() })
        .collect();
    std::fs::write(&huge, huge_text.join("\n")).unwrap();
    let huge_says = format!("huge.toml:{line}: camera.resolution 65536x65536: the image needs about");
    let out = dir.join("never.exr");
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec![scene("furnace.toml").display().to_string(), "--builder".into(), "octree".into()],
            "unknown builder `octree`",
        ),
        (vec![bad_scene.display().to_string()], "bad.toml:1: camera"),
        (vec![huge.display().to_string()], &huge_says),
        (vec![dir.join("missing.toml").display().to_string()], "missing.toml: cannot read"),
        (vec![scene("furnace.toml").display().to_string(), "--spp".into(), "0".into()], "at least 1"),
        (vec![scene("furnace.toml").display().to_string(), "--time".into(), "-3".into()], "--time"),
        (
            vec![scene("furnace.toml").display().to_string(), "--threads".into(), "5000".into()],
            "--threads must be 1 to",
        ),
        // The last frame a range can hold is 2^32 - 2; 2^32 - 1 used to render nothing, with exit 0.
        (vec![scene("furnace.toml").display().to_string(), "--frame".into(), "4294967295".into()], "--frame"),
    ];
    for (args, expected) in cases {
        let o = render().args(&args).arg("-o").arg(&out).output().unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} should fail");
        assert!(stderr.contains(expected), "{args:?}: expected `{expected}` in {stderr}");
        assert!(!out.exists(), "{args:?} wrote an image");
        assert!(stderr.matches("(os error 2)").count() <= 1, "{args:?}: repeated reason in {stderr}");
    }
    let o = render().arg(scene("furnace.toml")).arg("-o").arg(dir.join("out.jpg")).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("supported: .exr, .png"));
    // An output that is a folder fails before the render (a million samples would take minutes).
    let folder = dir.join("folder.exr");
    std::fs::create_dir_all(&folder).unwrap();
    let o = render().arg(scene("furnace.toml")).arg("-o").arg(&folder).args(["--spp", "1000000"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && stderr.contains("it is a directory"), "{stderr}");
    // So does a name ending in /, which used to fail at the rename after the render.
    let slash = format!("{}/", dir.join("slash.exr").display());
    let o = render().arg(scene("furnace.toml")).args(["-o", &slash, "--spp", "1000000"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && stderr.contains("names a folder"), "{stderr}");
    assert!(!dir.join("slash.exr").exists());
}

#[test]
fn a_time_budget_stops_early() {
    let dir = temp_dir("time");
    let o = render()
        .arg(scene("cornell-box.toml"))
        .arg("-o")
        .arg(dir.join("t.exr"))
        .args(["--spp", "100000", "--time", "0.5"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let spp: u32 =
        stdout.split(", ").find_map(|f| f.strip_suffix(" spp\n").or(f.strip_suffix(" spp"))).unwrap().parse().unwrap();
    assert!((4..100_000).contains(&spp), "{stdout}");
}

/// `auto` optimises only while it pays: a tiny render keeps the LBVH and stops after at most two
/// iterations, a huge one runs on (on the LBVH or a binned-SAH tree, whichever traces faster)
/// and reaches a lower SAH.
#[test]
fn auto_builder_scales_optimisation_with_the_ray_budget() {
    use arbor::render::RenderScene;
    let showcase = arbor::scene::Scene::load(scene("showcase.toml")).unwrap();
    let iterations = |label: &str| -> usize {
        let after = label.split("+prbvh, ").nth(1).unwrap();
        after.split(' ').next().unwrap().parse().unwrap()
    };
    let (_, small) = RenderScene::build_auto(&showcase, 1.0, common::tracing());
    let (_, large) = RenderScene::build_auto(&showcase, 1e13, common::tracing());
    assert!(iterations(&small.builder) <= 2 && small.builder.starts_with("auto: lbvh+"), "{}", small.builder);
    assert!(iterations(&large.builder) > iterations(&small.builder), "{} / {}", small.builder, large.builder);
    assert!(large.sah < small.sah, "{} vs {}", large.sah, small.sah);

    let dir = temp_dir("auto");
    let o = render()
        .arg(scene("furnace.toml"))
        .arg("-o")
        .arg(dir.join("a.exr"))
        // The CPU's `auto`; on a hardware GPU (which `--device auto` would pick) a 1-spp render
        // is too short to time and keeps the LBVH (auto_builder_judges_another_device_by_its_own_time).
        .args(["--device", "cpu", "--spp", "1", "--builder", "auto"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The CPU starts on the LBVH, and the summary says what it decided (on a render this short,
    // to keep the LBVH).
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("BVH (auto: lbvh, optimised while it renders"), "{stdout}");
    assert!(stdout.contains("\nauto: lbvh"), "{stdout}");
}

/// `auto` for another device judges the render by the device's own time per sample, not the
/// CPU probe's: the same huge ray budget optimises when the device is slow and keeps the timed
/// LBVH scene when it is fast or under a short time budget; a render too short to time keeps
/// the LBVH. The device here is a stand-in that reports a fixed time, so the test runs without
/// a GPU.
#[test]
fn auto_builder_judges_another_device_by_its_own_time() {
    use arbor::render::{AutoDevice, RenderScene};
    let showcase = arbor::scene::Scene::load(scene("showcase.toml")).unwrap();
    let rays = 1e13;
    let mut calls = 0;
    let mut slow = |_: &RenderScene| {
        calls += 1;
        Some((10.0, std::time::Duration::ZERO))
    };
    let (_, optimised) = RenderScene::build_auto_for(
        &showcase,
        rays,
        AutoDevice::Measured { samples: 1024.0, budget: None, measure: &mut slow },
    );
    assert_eq!(calls, 1);
    assert!(optimised.builder.contains("timed at 10000.0 ms per sample"), "{}", optimised.builder);
    assert!(!optimised.builder.contains(", 0 iterations"), "{}", optimised.builder);
    let mut fast = |_: &RenderScene| Some((1e-9, std::time::Duration::ZERO));
    let (_, kept) = RenderScene::build_auto_for(
        &showcase,
        rays,
        AutoDevice::Measured { samples: 1024.0, budget: None, measure: &mut fast },
    );
    assert!(kept.builder.starts_with("auto: lbvh+prbvh, 0 iterations"), "{}", kept.builder);
    assert!(kept.sah > optimised.sah, "{} vs {}", kept.sah, optimised.sah);
    // The slow device under a time budget of 1 ms: a render no longer than that.
    let mut slow_again = |_: &RenderScene| Some((10.0, std::time::Duration::ZERO));
    let limited = AutoDevice::Measured { samples: 1024.0, budget: Some(1e-3), measure: &mut slow_again };
    let (_, limited) = RenderScene::build_auto_for(&showcase, rays, limited);
    assert!(limited.builder.starts_with("auto: lbvh+prbvh, 0 iterations"), "{}", limited.builder);
    let (_, short) = RenderScene::build_auto_for(&showcase, rays, AutoDevice::Unmeasured);
    assert!(short.builder.starts_with("auto: lbvh, a render too short"), "{}", short.builder);
    assert_eq!(short.sah, kept.sah);
}

/// The CPU's `auto` starts on the LBVH and optimises between passes where the rest of the
/// render repays it, and the image is the one the LBVH alone renders, bit for bit: a render of
/// 1024 spp optimises after its first passes, a render sliced into rows changes its tree in the
/// middle of a sample, and one stopped by a time limit of 1 ms never optimises.
#[test]
fn cpu_auto_optimises_while_it_renders() {
    use arbor::device::{BuilderChoice, Device, Renderer};
    let mut showcase = arbor::scene::Scene::load(scene("showcase.toml")).unwrap();
    (showcase.camera.width, showcase.camera.height) = (48, 32);
    let settings =
        |spp: u32, time: Option<f64>| arbor::scene::RenderSettings { spp, max_depth: 6, seed: 7, time, clamp: None };
    let run = |builder: &str, s: &arbor::scene::RenderSettings| {
        let choice: BuilderChoice = builder.parse().unwrap();
        let mut r = Renderer::new(Device::Cpu, &showcase, &choice, common::tracing(), s, 1, 0.0).unwrap();
        let frame = r.render(s, &|_| {}).unwrap();
        (frame.film.mean(), frame.samples, r.refine_report().cloned())
    };
    let long = settings(1024, None);
    let (auto_image, _, report) = run("auto", &long);
    let report = report.expect("auto on the CPU reports what it did");
    assert!(report.iterations >= 9, "{report}");
    // Decided early: after the untimed first slice (or sample, on an image this small) and
    // 20 ms of timed ones.
    assert!(report.after_samples > 0.0 && report.after_samples < 64.0, "{report}");
    assert!(report.estimate.is_some_and(|e| e > 0.0), "{report}");
    let (lbvh_image, _, none) = run("lbvh", &long);
    assert!(none.is_none());
    assert!(auto_image.pixels == lbvh_image.pixels, "auto's image differs from the LBVH's");

    let (one_image, _, _) = run("auto", &settings(1, None));
    assert!(one_image.pixels == run("lbvh", &settings(1, None)).0.pixels, "a 1-spp render differs");

    // On one thread a 64-row image is rendered in slices of 16 rows while `auto` decides, and
    // its tree changes between slices: the image is still the LBVH's.
    let one_thread = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let mut wide = showcase.clone();
    (wide.camera.width, wide.camera.height) = (256, 64);
    let sliced = one_thread.install(|| {
        let s = settings(64, None);
        let mut r = Renderer::new(Device::Cpu, &wide, &BuilderChoice::Auto, common::tracing(), &s, 1, 0.0).unwrap();
        let image = r.render(&s, &|_| {}).unwrap().film.mean();
        let lbvh: BuilderChoice = "lbvh".parse().unwrap();
        let mut fixed = Renderer::new(Device::Cpu, &wide, &lbvh, common::tracing(), &s, 1, 0.0).unwrap();
        (image, fixed.render(&s, &|_| {}).unwrap().film.mean(), r.refine_report().cloned().unwrap())
    });
    assert!(sliced.2.iterations > 0, "{}", sliced.2);
    assert!(sliced.0.pixels == sliced.1.pixels, "the image changed with the tree mid-sample");

    let (_, samples, limited) = run("auto", &settings(1 << 20, Some(1e-3)));
    let limited = limited.unwrap();
    assert!(samples < 1 << 20);
    assert_eq!(limited.iterations, 0, "{limited}");
}

/// `--frames` renders a numbered sequence, `--frame` one frame, and a sequence needs a pattern.
#[test]
fn frames_render_numbered_sequences() {
    let dir = temp_dir("frames");
    let run = |args: &[&str], out: &str| {
        render()
            .arg(scene("cornell-animated.toml"))
            .arg("-o")
            .arg(dir.join(out))
            // The CPU path, whose dynamic BVH reports an update for every frame; `auto` picks a
            // hardware GPU where there is one, which reports the first frame's build instead.
            .args(["--device", "cpu", "--spp", "1", "--max-depth", "2", "--threads", "2"])
            .args(args)
            .output()
            .unwrap()
    };
    let o = run(&["--frames", "5..8"], "seq/f_%04d.exr");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert_eq!(stdout.matches("BVH update").count(), 3, "{stdout}");
    let mut written: Vec<String> =
        std::fs::read_dir(dir.join("seq")).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into()).collect();
    written.sort();
    assert_eq!(written, ["f_0005.exr", "f_0006.exr", "f_0007.exr"]);
    // Frames differ where something moves.
    let a = arbor::image_io::read_exr(dir.join("seq/f_0005.exr")).unwrap();
    let b = arbor::image_io::read_exr(dir.join("seq/f_0007.exr")).unwrap();
    assert_ne!(a.pixels, b.pixels);

    let o = run(&["--frame", "7"], "one.exr");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The same seed, the same frame: the single frame equals the sequence's.
    let one = arbor::image_io::read_exr(dir.join("one.exr")).unwrap();
    assert_eq!(one.pixels, b.pixels);

    for (args, out, expected) in [
        (vec!["--frames", "0..3"], "nopattern.exr", "put a frame pattern"),
        (vec!["--frames", "3..1"], "x_%d.exr", "must be after"),
        (vec!["--frames", "3"], "x_%d.exr", "FIRST..END"),
        (vec!["--frames", "0..2", "--frame", "1"], "x_%d.exr", "cannot be used with"),
        (vec!["--frames", "0..2"], "x_%d_%04d.exr", "more than one frame pattern"),
    ] {
        let o = run(&args, out);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && stderr.contains(expected), "{args:?}: {stderr}");
    }
    assert!(!dir.join("nopattern.exr").exists());

    // A closed standard output (`render ... | head -1`) stops neither the sequence nor its files.
    let o = common::output_with_stdout_closed(
        render().arg(scene("cornell-animated.toml")).arg("-o").arg(dir.join("piped/p_%d.png")).args([
            "--device",
            "cpu",
            "--spp",
            "1",
            "--max-depth",
            "2",
            "--frames",
            "0..3",
        ]),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!((0..3).all(|f| dir.join(format!("piped/p_{f}.png")).exists()));
}

/// `--clamp R` bounds every sample, so every pixel, by R; without it the Cornell box's light
/// reads far above R. A clamp of 0 or less is refused.
#[test]
fn clamp_bounds_samples_only_when_asked() {
    let dir = temp_dir("clamp");
    let max_of = |args: &[&str]| {
        let out = dir.join("c.exr");
        let o = render().arg(scene("cornell-box.toml")).arg("-o").arg(&out).args(args).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let image = arbor::image_io::read_exr(&out).unwrap();
        image.pixels.iter().flatten().fold(0.0f32, |m, &v| m.max(v))
    };
    let common = ["--spp", "2", "--max-depth", "3", "--quiet"];
    assert!(max_of(&common) > 5.0, "the light is brighter than 5 unclamped");
    let clamped = max_of(&[&common[..], &["--clamp", "0.5"]].concat());
    assert!(clamped <= 0.5 + 1e-6, "clamped maximum {clamped}");
    let o = render().arg(scene("cornell-box.toml")).args(["-o", "x.exr", "--clamp", "0"]).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("--clamp"));
}

/// A scene whose buffers need more than the adapter's largest storage binding (128 MiB on
/// lavapipe: 2.8M triangles of 48 bytes, 2M primitives' BVH nodes) is refused on the GPU with a
/// message naming the buffer and the limit, and leaves no output; on an adapter with room it
/// renders. Skips without an
/// adapter, except under `CI=true`.
#[test]
fn gpu_scene_over_the_binding_limit_is_a_clear_error() {
    let Some(ctx) = common::gpu_or_skip("gpu_scene_over_the_binding_limit_is_a_clear_error") else { return };
    let triangles: u64 = 3_000_000;
    let dir = temp_dir("gpu-limit");
    std::fs::write(
        dir.join("big.toml"),
        format!(
            "[camera]\nposition = [-5, 20, -5]\nlook_at = [100, 0, 100]\nfov = 50\nresolution = [16, 16]\n\n\
             [environment]\nradiance = [1, 1, 1]\n\n[materials.grey]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\n\
             [[objects]]\nshape = \"city\"\ntriangles = {triangles}\nmaterial = \"grey\"\n"
        ),
    )
    .unwrap();
    let out = dir.join("big.exr");
    let o = render()
        .arg(dir.join("big.toml"))
        .arg("-o")
        .arg(&out)
        .args(["--device", "gpu", "--builder", "lbvh", "--spp", "1", "--quiet"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    let limit = ctx.limits.max_storage_buffer_binding_size.min(ctx.limits.max_buffer_size);
    if triangles * 48 > limit {
        assert!(!o.status.success(), "rendered a scene over the binding limit");
        // The first buffer over the limit is named (here the GPU LBVH's nodes, 32 bytes each).
        assert!(stderr.contains("is over the adapter's max_storage_buffer_binding_size"), "{stderr}");
        assert!(!out.exists(), "a failed render left {}", out.display());
    } else {
        assert!(o.status.success() && out.exists(), "{stderr}");
    }
}

/// On the GPU, `lbvh` and `lbvh+prbvh` build the BVH there, and the render is the CPU's within
/// noise (the furnace's sphere is exactly its albedo on either device). Skips without an
/// adapter, except under `CI=true`.
#[test]
fn gpu_builds_its_own_bvh_for_lbvh_builders() {
    if common::gpu_or_skip("gpu_builds_its_own_bvh_for_lbvh_builders").is_none() {
        return;
    }
    let dir = temp_dir("gpu-bvh");
    for b in ["lbvh", "lbvh+prbvh"] {
        let out = dir.join(format!("{b}.exr"));
        let o = render()
            .arg(scene("furnace.toml"))
            .arg("-o")
            .arg(&out)
            .args(["--device", "gpu", "--builder", b, "--spp", "2"])
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(stdout.contains(&format!("BVH ({b} on the GPU")), "{stdout}");
        let image = arbor::image_io::read_exr(&out).unwrap();
        let c = image.get(image.width / 2, image.height / 2).unwrap();
        assert!(c.iter().all(|v| (v - 0.8).abs() < 1e-5), "{b}: centre {c:?}");
    }
}

/// `render` with `args`, killed if it runs past `limit`: its exit code (`None` where it was
/// killed) and its standard error. A reader blocked on a FIFO that nobody writes never ends.
fn run_within(args: &[&std::ffi::OsStr], limit: std::time::Duration) -> (Option<i32>, String) {
    let mut child =
        render().args(args).stdout(std::process::Stdio::null()).stderr(std::process::Stdio::piped()).spawn().unwrap();
    let started = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if started.elapsed() > limit {
            child.kill().unwrap();
            let o = child.wait_with_output().unwrap();
            return (None, format!("killed after {limit:?}: {}", String::from_utf8_lossy(&o.stderr)));
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let o = child.wait_with_output().unwrap();
    (o.status.code(), String::from_utf8_lossy(&o.stderr).into_owned())
}

fn mkfifo(path: &std::path::Path) {
    let o = Command::new("mkfifo").arg(path).output().expect("mkfifo runs");
    assert!(o.status.success(), "mkfifo {}: {}", path.display(), String::from_utf8_lossy(&o.stderr));
}

const SMALL_CAMERA: &str = "[camera]\nposition = [0, 0, 4]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n";

/// A mesh, an MTL file, a glTF file, its buffers and images, a texture and a sky map that are
/// named pipes or devices are refused before they are opened (opening a FIFO waits for a writer
/// for ever; a glTF buffer of `/dev/zero` was read for 6 GB), with exit code 2 and the scene's
/// file, line and key; a scene file given as a folder is bad input too (it was an I/O error,
/// code 74), and a scene file that is itself a pipe (`render <(generate)`) still renders.
#[cfg(unix)]
#[test]
fn files_that_are_not_regular_files_are_refused_before_opening() {
    let dir = temp_dir("not-regular");
    for name in ["pipe.obj", "pipe.ply", "pipe.gltf", "pipe.mtl", "pipe.bin", "pipe.png", "pipe.exr", "pipe.hdr"] {
        let _ = std::fs::remove_file(dir.join(name));
        mkfifo(&dir.join(name));
    }
    std::fs::write(dir.join("m.obj"), "mtllib pipe.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n").unwrap();
    let gltf = |buffer: &str, image: Option<&str>| {
        let mut d = common::gltf::triangle_doc();
        d.node(serde_json::json!({ "mesh": 0 }), true);
        if let Some(uri) = image {
            d.push("images", serde_json::json!({ "uri": uri }));
            d.push("textures", serde_json::json!({ "source": 0 }));
            d.push("materials", serde_json::json!({ "pbrMetallicRoughness": { "baseColorTexture": { "index": 0 } } }));
            d.json["meshes"][0]["primitives"][0]["material"] = serde_json::json!(0);
        }
        let (text, bin) = d.gltf_external(buffer);
        if !buffer.starts_with('/') && !buffer.starts_with("pipe") {
            std::fs::write(dir.join(buffer), bin).unwrap();
        }
        text
    };
    std::fs::write(dir.join("zero.gltf"), gltf("/dev/zero", None)).unwrap();
    std::fs::write(dir.join("fifo-buffer.gltf"), gltf("pipe.bin", None)).unwrap();
    std::fs::write(dir.join("fifo-image.gltf"), gltf("tri.bin", Some("pipe.png"))).unwrap();
    let lamp = "[materials.lamp]\ntype = \"emissive\"\nradiance = [1, 1, 1]\n";
    let object = |mesh: &str| format!("{lamp}\n[[objects]]\nmesh = \"{mesh}\"\nmaterial = \"lamp\"\n");
    let quad = |material: &str| format!("{material}\n[[objects]]\nshape = \"quad\"\nmaterial = \"m\"\n");
    // (scene after the camera, the key at fault, the file it must name)
    let cases: Vec<(String, &str, &str)> = vec![
        (object("pipe.obj"), "objects[0].mesh", "pipe.obj"),
        (object("pipe.ply"), "objects[0].mesh", "pipe.ply"),
        (object("pipe.gltf"), "objects[0].mesh", "pipe.gltf"),
        (object("zero.gltf"), "objects[0].mesh", "/dev/zero"),
        (object("fifo-buffer.gltf"), "objects[0].mesh", "pipe.bin"),
        (object("fifo-image.gltf"), "objects[0].mesh", "pipe.png"),
        // The OBJ file's own material comes from the MTL file.
        ("[[objects]]\nmesh = \"m.obj\"\n".to_owned(), "objects[0].mesh", "pipe.mtl"),
        (quad("[materials.m]\ntype = \"diffuse\"\ntexture = \"pipe.png\"\n"), "materials.m.texture", "pipe.png"),
        (quad("[materials.m]\ntype = \"diffuse\"\ntexture = \"pipe.exr\"\n"), "materials.m.texture", "pipe.exr"),
        (format!("[environment]\nmap = \"pipe.exr\"\n\n{}", object("m.obj")), "environment.map", "pipe.exr"),
        (format!("[environment]\nmap = \"pipe.hdr\"\n\n{}", object("m.obj")), "environment.map", "pipe.hdr"),
        ("[camera]\nfrom = \"pipe.gltf\"\nresolution = [8, 8]\n".to_owned(), "camera.from", "pipe.gltf"),
    ];
    let out = dir.join("never.exr");
    for (i, (text, key, file)) in cases.iter().enumerate() {
        let scene = dir.join(format!("s{i}.toml"));
        let text = if text.starts_with("[camera]") { text.clone() } else { format!("{SMALL_CAMERA}\n{text}") };
        std::fs::write(&scene, &text).unwrap();
        let line = text
            .lines()
            .position(|l| {
                l.contains(file.trim_start_matches('/')) || (*key == "objects[0].mesh" && l.starts_with("mesh"))
            })
            .unwrap()
            + 1;
        let (code, stderr) =
            run_within(&[scene.as_os_str(), "-o".as_ref(), out.as_os_str()], std::time::Duration::from_secs(20));
        assert_eq!(code, Some(2), "{key} naming {file}: {stderr}");
        let at = format!("{}:{line}: {key}: ", scene.display());
        assert!(stderr.contains(&at) && stderr.contains(file), "{key}: want `{at}` and {file} in: {stderr}");
        assert!(stderr.contains("not a regular file"), "{key}: {stderr}");
        assert!(!out.exists());
    }

    // The scene file itself: a folder is bad input; a pipe renders.
    let (code, stderr) =
        run_within(&[dir.as_os_str(), "-o".as_ref(), out.as_os_str()], std::time::Duration::from_secs(20));
    assert_eq!(code, Some(2), "{stderr}");
    assert!(stderr.contains(&format!("{}: cannot read: is a directory", dir.display())), "{stderr}");
    let piped = dir.join("scene-pipe.toml");
    let _ = std::fs::remove_file(&piped);
    mkfifo(&piped);
    let image = dir.join("piped.exr");
    let child = std::thread::spawn({
        let (piped, image) = (piped.clone(), image.clone());
        move || run_within(&[piped.as_os_str(), "-o".as_ref(), image.as_os_str()], std::time::Duration::from_secs(60))
    });
    std::fs::write(&piped, format!("{SMALL_CAMERA}\n{lamp}\n[[objects]]\nshape = \"quad\"\nmaterial = \"lamp\"\n"))
        .unwrap();
    let (code, stderr) = child.join().unwrap();
    assert_eq!(code, Some(0), "{stderr}");
    assert!(image.exists());
}

/// `render` under an address-space limit of `bytes` (`ulimit -v`, which `available_bytes`
/// honours as it does a control group's limit), on the CPU.
#[cfg(unix)]
fn render_limited(bytes: u64, scene: &std::path::Path, out: &std::path::Path) -> std::process::Output {
    Command::new("sh")
        .arg("-c")
        .arg(format!("ulimit -v {} && exec \"$0\" \"$@\"", bytes / 1024))
        .arg(env!("CARGO_BIN_EXE_render"))
        .arg(scene)
        .arg("-o")
        .arg(out)
        .args(["--device", "cpu", "--spp", "1", "--threads", "2"])
        .output()
        .unwrap()
}

/// Under 200 MB, scenes that need more are refused before they allocate, with exit code 3
/// (retry with more memory) and the estimate, where they were killed or aborted: 3M and 10M
/// scattered instances, eight spheres of subdivision 8, four of subdivision 7 whose meshes fit
/// but not their instanced BVH, a glTF file of 10^6 nodes and one of 3·10^5 (whose text fits),
/// a city whose flattened BVH needs 0.3 GB (exit code 1, as the error hid its cause), 5M
/// procedural triangles, a texture and a sky map whose texels do not fit (exit code 2). A small
/// scene still renders under the same limit.
#[cfg(unix)]
#[test]
fn scenes_too_large_for_the_memory_limit_exit_3_with_the_estimate() {
    const LIMIT: u64 = 200_000_000;
    let dir = temp_dir("memory-limit");
    let grey =
        "[materials.grey]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\n[environment]\nradiance = [1, 1, 1]\n";
    let scatter = |count: u64| {
        format!(
            "{grey}\n[[objects]]\nshape = \"box\"\nmaterial = \"grey\"\n[objects.scatter]\ncount = {count}\nmin = [-9, 0, -9]\nmax = [9, 0, 9]\n"
        )
    };
    let spheres = |n: u32, level: u32| -> String {
        (0..n)
            .map(|i| {
                format!(
                    "\n[[objects]]\nshape = \"sphere\"\nsubdivisions = {level}\nmaterial = \"grey\"\ntranslate = [{i}, 0, 0]\n"
                )
            })
            .collect()
    };
    let procedural = |n: u64| format!("{grey}\n[[objects]]\nshape = \"city\"\ntriangles = {n}\nmaterial = \"grey\"\n");
    // 10^6 nodes placing one triangle: 18 MB of JSON, some 0.5 GB once parsed; 3·10^5 nodes,
    // 5 MB, which fit in memory as text but not parsed.
    let doc = common::gltf::triangle_doc();
    let (_, bin) = doc.gltf_external("tri.bin");
    std::fs::write(dir.join("tri.bin"), &bin).unwrap();
    let rest = serde_json::json!({
        "meshes": doc.json["meshes"], "accessors": doc.json["accessors"], "bufferViews": doc.json["bufferViews"],
        "buffers": [{ "byteLength": bin.len(), "uri": "tri.bin" }],
    });
    for (name, n) in [("nodes.gltf", 1_000_000), ("some-nodes.gltf", 300_000)] {
        let roots: Vec<String> = (0..n).map(|i| i.to_string()).collect();
        let nodes = vec!["{\"mesh\":0}"; n].join(",");
        let text = format!(
            "{{\"asset\":{{\"version\":\"2.0\"}},\"scene\":0,\"scenes\":[{{\"nodes\":[{}]}}],\"nodes\":[{nodes}],{}",
            roots.join(","),
            &rest.to_string()[1..]
        );
        std::fs::write(dir.join(name), text).unwrap();
    }
    // Radiance HDR headers: the size is read before the texels, which are not there.
    std::fs::write(dir.join("huge.hdr"), b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 16384 +X 16384\n").unwrap();
    let cases: Vec<(&str, String, &str)> = vec![
        ("scatter3m", scatter(3_000_000), "objects[0].scatter.count"),
        ("scatter10m", scatter(10_000_000), "objects[0].scatter.count"),
        ("spheres", format!("{grey}{}", spheres(8, 8)), "needs about"),
        // Four spheres of subdivision 7 fit as meshes; rendered as instances, their BVH does not.
        ("instanced", format!("{grey}{}", spheres(4, 7)), "the scene as 4 instances of 327680 triangles"),
        ("nodes", format!("{grey}\n[[objects]]\nmesh = \"nodes.gltf\"\nmaterial = \"grey\"\n"), "objects[0].mesh"),
        ("some-nodes", format!("{grey}\n[[objects]]\nmesh = \"some-nodes.gltf\"\n"), "objects), parsed, needs about"),
        ("flattened", procedural(600_000), "not enough memory: the scene flattened ("),
        ("procedural", procedural(5_000_000), "objects[0].triangles"),
        (
            "texture",
            "[materials.t]\ntype = \"diffuse\"\ntexture = \"huge.hdr\"\n\n[[objects]]\nshape = \"quad\"\nmaterial = \"t\"\n".into(),
            "materials.t.texture",
        ),
        (
            "sky",
            "[environment]\nmap = \"huge.hdr\"\n\n[materials.grey]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\n\
             [[objects]]\nshape = \"quad\"\nmaterial = \"grey\"\n"
                .into(),
            "environment.map",
        ),
    ];
    let out = dir.join("never.exr");
    for (name, text, says) in &cases {
        let scene = dir.join(format!("{name}.toml"));
        std::fs::write(&scene, format!("{SMALL_CAMERA}\n{text}")).unwrap();
        let o = render_limited(LIMIT, &scene, &out);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(3), "{name}: {stderr}");
        assert!(
            stderr.contains(&scene.display().to_string()) && stderr.contains(says),
            "{name}: want `{says}`: {stderr}"
        );
        assert!(stderr.contains("needs about") && stderr.contains("is available"), "{name}: {stderr}");
        assert!(!out.exists());
    }
    let small = render_limited(LIMIT, &scene("furnace.toml"), &dir.join("small.exr"));
    assert!(small.status.success(), "{}", String::from_utf8_lossy(&small.stderr));
}
