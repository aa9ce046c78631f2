//! `bvh-bench` as a user runs it: outputs, their fields, and errors on bad input.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The repository's root, where the scenes are.
fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

#[path = "../../tests/common/tools.rs"]
mod common;
#[allow(dead_code)]
#[path = "../../tests/common/gltf.rs"]
mod gltf;
#[path = "../../tests/common/ply.rs"]
mod ply;

fn bench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bvh-bench"))
}

fn temp_dir(name: &str) -> PathBuf {
    common::fresh_temp_dir("arbor-bench", name)
}

/// A small closed mesh as OBJ.
fn write_obj(path: &Path) {
    common::write_obj(path, &arbor::geometry::TriangleMesh::torus(glam::Vec3::ZERO, 2.0, 0.7, 40, 20));
}

#[test]
fn writes_table_json_csv_and_plot() {
    let dir = temp_dir("outputs");
    let obj = dir.join("torus.obj");
    write_obj(&obj);
    let (json, csv, svg) = (dir.join("r.json"), dir.join("r.csv"), dir.join("r.svg"));
    let out = bench()
        .arg(&obj)
        .args([
            "--builders",
            "lbvh,lbvh+prbvh,binned-sah,obvhs-fastest,ploc,lbvh+rbvh",
            "--runs",
            "2",
            "--resolution",
            "64",
        ])
        .arg("--json")
        .arg(&json)
        .arg("--csv")
        .arg(&csv)
        .arg("--plot")
        .arg(&svg)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("lbvh+prbvh") && stdout.contains("SAH leaf1"), "{stdout}");

    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(report["triangles"], 1600);
    assert!(report["threads"].as_u64().unwrap() >= 1);
    let builders = report["builders"].as_array().unwrap();
    assert_eq!(builders.len(), 6);
    for b in builders {
        for key in
            ["name", "build_ms", "optimize_ms", "sah", "sah_leaf1", "primary_mrays", "shadow_mrays", "diffuse_mrays"]
        {
            assert!(!b[key].is_null(), "{key} missing from {b}");
        }
        assert!(b["sah"].as_f64().unwrap() <= b["sah_leaf1"].as_f64().unwrap() + 1e-9);
        assert!(b["primary_mrays"].as_f64().unwrap() > 0.0);
    }
    // PRBVH improves on its own LBVH.
    assert!(builders[1]["sah_leaf1"].as_f64().unwrap() < builders[0]["sah_leaf1"].as_f64().unwrap());
    assert!(builders[1]["sah_curve"].as_array().unwrap().len() > 2);
    // So does the sequential reference, batch by batch.
    assert!(builders[5]["sah_leaf1"].as_f64().unwrap() < builders[0]["sah_leaf1"].as_f64().unwrap());
    assert!(builders[5]["sah_curve"].as_array().unwrap().len() > 2);

    let csv = std::fs::read_to_string(&csv).unwrap();
    assert_eq!(csv.lines().count(), 7);
    assert!(csv.starts_with("name,build_ms,optimize_ms"));
    let svg = std::fs::read_to_string(&svg).unwrap();
    assert!(svg.contains("<svg") && svg.contains("lbvh+prbvh"));
    // No temporary files left behind.
    let leftovers: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.contains(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

#[test]
fn scenes_as_input() {
    let scene = root().join("scenes/showcase.toml");
    let out = bench()
        .arg(&scene)
        .args(["--builders", "lbvh,lbvh+prbvh", "--runs", "1", "--resolution", "32"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).contains("lbvh+prbvh"));
}

/// A `.ply` input (in any case) is read as PLY, binary or ASCII; its errors name its line.
#[test]
fn ply_meshes_as_input() {
    let dir = temp_dir("ply");
    let torus = arbor::geometry::TriangleMesh::torus(glam::Vec3::ZERO, 2.0, 0.7, 40, 20);
    let (binary, json) = (dir.join("torus.PLY"), dir.join("r.json"));
    std::fs::write(&binary, ply::ply_bytes(&torus, "binary_little_endian")).unwrap();
    let out = bench()
        .arg(&binary)
        .args(["--builders", "lbvh", "--runs", "1", "--resolution", "16", "--json"])
        .arg(&json)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(report["triangles"], 1600);
    let broken = dir.join("broken.ply");
    let text = String::from_utf8(ply::ply_bytes(&torus, "ascii")).unwrap();
    std::fs::write(&broken, text.replacen("property float y", "property real y", 1)).unwrap();
    let out = bench().arg(&broken).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("broken.ply:5: unknown type `real`"), "{stderr}");
}

/// A `.glb` or `.gltf` input is every mesh node's triangles in the file's world space; its errors
/// name the file and the place in it.
#[test]
fn gltf_files_as_input() {
    let dir = temp_dir("gltf");
    let mut d = gltf::triangle_doc();
    // Two nodes placing the one-triangle mesh: two triangles.
    d.node(serde_json::json!({ "mesh": 0 }), true);
    d.node(serde_json::json!({ "mesh": 0, "translation": [2, 0, 0] }), true);
    let (glb, embedded, json) = (dir.join("t.GLB"), dir.join("t.gltf"), dir.join("r.json"));
    std::fs::write(&glb, d.glb()).unwrap();
    std::fs::write(&embedded, d.gltf_embedded()).unwrap();
    for input in [&glb, &embedded] {
        let out = bench()
            .arg(input)
            .args(["--builders", "lbvh", "--runs", "1", "--resolution", "16", "--json"])
            .arg(&json)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert_eq!(report["triangles"], 2, "{}", input.display());
    }
    d.json["accessors"][0]["count"] = serde_json::json!(40);
    std::fs::write(&glb, d.glb()).unwrap();
    let out = bench().arg(&glb).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success()
            && stderr.contains("t.GLB: meshes[0].primitives[0].attributes.POSITION: accessor 0: reads past"),
        "{stderr}"
    );
}

#[test]
fn procedural_meshes() {
    for spec in ["hairball:3k", "city:2000"] {
        let out = bench()
            .args(["--procedural", spec, "--builders", "lbvh", "--runs", "1", "--resolution", "32"])
            .output()
            .unwrap();
        assert!(out.status.success(), "{spec}: {}", String::from_utf8_lossy(&out.stderr));
    }
}

/// `--threads` sets the worker count the report gives, and the same trees come out.
#[test]
fn threads_option() {
    let dir = temp_dir("threads");
    let mut sah = Vec::new();
    for threads in [1, 2] {
        let json = dir.join(format!("t{threads}.json"));
        let out = bench()
            .args(["--procedural", "city:3000", "--builders", "lbvh+prbvh,ploc", "--runs", "1", "--resolution", "32"])
            .args(["--threads", &threads.to_string(), "--json"])
            .arg(&json)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert_eq!(report["threads"], threads);
        sah.push([report["builders"][0]["sah_leaf1"].clone(), report["builders"][1]["sah_leaf1"].clone()]);
    }
    assert_eq!(sah[0], sah[1], "the trees depend on the thread count");
    let out = bench().args(["--procedural", "city:1000", "--threads", "0"]).output().unwrap();
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("--threads"));
}

/// Each bad input exits non-zero with a message naming what is wrong, and writes nothing.
#[test]
fn bad_input_is_a_clear_error() {
    let dir = temp_dir("errors");
    let obj = dir.join("torus.obj");
    write_obj(&obj);
    let json = dir.join("never.json");
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, SCATTER_SCENE.replace("COUNT", "2")).unwrap();
    // 10^4 spheres of 1.3 million triangles: the CPU renders them as instances; flattened, they
    // are more triangles than a BVH indexes.
    let huge = dir.join("huge.toml");
    std::fs::write(&huge, SCATTER_SCENE.replace("COUNT", "10000")).unwrap();
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec![obj.display().to_string(), "--builders".into(), "lbvh,fastest-ever".into()],
            "unknown builder `fastest-ever`",
        ),
        (vec!["scene.toml".into()], "scene.toml: cannot read"),
        (vec![dir.join("missing.obj").display().to_string()], "missing.obj"),
        (vec!["--procedural".into(), "donut:100".into()], "unknown kind `donut`"),
        (vec!["--procedural".into(), "city:lots".into()], "bad triangle count `lots`"),
        (vec!["--procedural".into(), "subdivided:1000".into()], "needs an input mesh"),
        (vec![obj.display().to_string(), "--plot".into(), "out.jpg".into()], "must end in .svg or .png"),
        (vec![obj.display().to_string(), "--runs".into(), "0".into()], "--runs must be from 1 to"),
        (vec![obj.display().to_string(), "--runs".into(), "99999999999".into()], "--runs must be from 1 to"),
        (vec![obj.display().to_string(), "--resolution".into(), "99999".into()], "--resolution must be from 1 to"),
        (vec![obj.display().to_string(), "--epsilon".into(), "nan".into()], "--epsilon must be a finite number"),
        (vec![obj.display().to_string(), "--builders".into(), "lbvh,ploc,lbvh".into()], "`lbvh` is listed twice"),
        (vec!["--procedural".into(), "hairball:99999999999999999999".into()], "must be at most 10^12"),
        (vec!["--procedural".into(), "hairball:1.5".into()], "must be a whole number"),
        (vec!["--procedural".into(), "city:1e11".into()], "GB of memory"),
        (vec!["--procedural-animated".into(), "1e11".into()], "GB of memory"),
        (vec![obj.display().to_string(), "--csv".into(), dir.display().to_string()], "it is a directory"),
        (vec![], "give a mesh"),
        (vec![obj.display().to_string(), "--threads".into(), "5000".into()], "--threads must be 1 to"),
        (vec![obj.display().to_string(), "--builders".into(), "lbvh+prbvh,prbvh".into()], "are the same builder"),
        (vec![obj.display().to_string(), "--frames".into(), "10".into()], "--frames applies to"),
        (vec![obj.display().to_string(), "--max-spp".into(), "8".into()], "--max-spp applies to --converge"),
        (vec![obj.display().to_string(), "--memory".into(), "--plot".into(), "m.svg".into()], "--memory has no plot"),
        (vec!["--converge".into(), obj.display().to_string()], "renders a scene (.toml), not a mesh"),
        (
            vec!["--converge".into(), scene.display().to_string(), "--devices".into(), "cpu,cpu".into()],
            "`cpu` is listed twice",
        ),
        (vec![huge.display().to_string()], "more than one BVH holds"),
        // An output over the input, or two outputs over each other (the CSV replaced the JSON).
        (vec![obj.display().to_string(), "--csv".into(), obj.display().to_string()], "that is the file of the input"),
        (
            vec![obj.display().to_string(), "--csv".into(), json.display().to_string()],
            "--json and --csv name the same file",
        ),
    ];
    for (args, expected) in cases {
        let out = bench().args(&args).arg("--json").arg(&json).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} should fail");
        assert!(stderr.contains(expected), "{args:?}: expected `{expected}` in: {stderr}");
        assert!(!json.exists(), "{args:?} wrote output");
        // Options and outputs are checked before the mesh is even loaded.
        assert!(!stderr.contains(" triangles, "), "{args:?}: work started before the error: {stderr}");
        // The reason once, not once per level of the error chain.
        let reason = "(os error 2)";
        assert!(stderr.matches(reason).count() <= 1, "{args:?}: repeated reason in: {stderr}");
    }
    // A run that fails leaves no folder made for its outputs.
    let _ = std::fs::remove_dir_all(dir.join("made"));
    let out = bench().arg(dir.join("missing.obj")).arg("--json").arg(dir.join("made/r.json")).output().unwrap();
    assert!(!out.status.success() && !dir.join("made").exists());
}

/// Outputs go where a user points them: through a symbolic link (which stays a link), into
/// folders made where missing; and a closed standard output (`| head`) neither panics nor
/// stops the report files.
#[cfg(unix)]
#[test]
fn outputs_follow_links_make_folders_and_survive_a_closed_stdout() {
    let dir = temp_dir("links");
    let obj = dir.join("torus.obj");
    write_obj(&obj);
    let (real, link) = (dir.join("real.json"), dir.join("link.json"));
    std::fs::write(&real, "{}").unwrap();
    let _ = std::fs::remove_file(&link);
    std::os::unix::fs::symlink(&real, &link).unwrap();
    let csv = dir.join("new/folder/r.csv");
    let _ = std::fs::remove_dir_all(dir.join("new"));
    let out = common::output_with_stdout_closed(
        bench()
            .arg(&obj)
            .args(["--builders", "lbvh", "--runs", "1", "--resolution", "16", "--json"])
            .arg(&link)
            .arg("--csv")
            .arg(&csv),
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink(), "the link was replaced by a file");
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&real).unwrap()).unwrap();
    assert_eq!(report["builders"][0]["name"], "lbvh");
    assert!(std::fs::read_to_string(&csv).unwrap().starts_with("name,"));
}

/// A sky and `COUNT` spheres of the finest subdivision, scattered.
const SCATTER_SCENE: &str = "[camera]
position = [0, 28, 70]
look_at = [0, 0, 5]
fov = 38
resolution = [16, 16]
[render]
spp = 1
[environment]
radiance = [1, 1, 1]
[materials.m]
type = \"diffuse\"
albedo = [0.5, 0.5, 0.5]
[[objects]]
shape = \"sphere\"
subdivisions = 8
material = \"m\"
scale = 0.3
[objects.scatter]
count = COUNT
min = [-50, 0, -50]
max = [50, 1, 50]
";

/// A standard output that fails other than by closing (`> /dev/full`) is an error, not a report
/// lost with exit 0; the files are written first.
#[cfg(target_os = "linux")]
#[test]
fn a_failing_stdout_is_an_error_after_the_files() {
    let dir = temp_dir("full");
    let obj = dir.join("torus.obj");
    write_obj(&obj);
    let json = dir.join("r.json");
    let _ = std::fs::remove_file(&json);
    let full = std::fs::OpenOptions::new().write(true).open("/dev/full").unwrap();
    let out = bench()
        .arg(&obj)
        .args(["--builders", "lbvh", "--runs", "1", "--resolution", "16", "--json"])
        .arg(&json)
        .stdout(full)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("writing to standard output: No space left on device"), "{stderr}");
    assert!(std::fs::read_to_string(&json).unwrap().contains("\"builders\""));
}

/// `--procedural-animated` and `--animated`: every strategy reported with the documented JSON
/// fields, the two-level strategies agreeing on every hit, refit drifting while rebuild stays at
/// the fresh build, and clear errors.
#[test]
fn animation_benchmark_reports_every_strategy() {
    let dir = temp_dir("animated");
    let (json, csv, svg) = (dir.join("a.json"), dir.join("a.csv"), dir.join("a.svg"));
    let out = bench()
        .args(["--procedural-animated", "2000", "--moving", "25", "--frames", "40", "--resolution", "64"])
        .arg("--json")
        .arg(&json)
        .arg("--csv")
        .arg(&csv)
        .arg("--plot")
        .arg(&svg)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(
        (v["instances"].as_u64(), v["moving"].as_u64(), v["frames"].as_u64()),
        (Some(2000), Some(500), Some(40))
    );
    assert_eq!(v["mismatches"].as_array().unwrap().len(), 0);
    let strategies = v["strategies"].as_array().unwrap();
    let names: Vec<&str> = strategies.iter().map(|s| s["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["reinsert+prbvh", "reinsert", "rebuild", "refit", "single-level"]);
    let get = |name: &str, key: &str| {
        strategies.iter().find(|s| s["name"] == name).unwrap()[key].as_f64().unwrap_or_else(|| panic!("{name}.{key}"))
    };
    for name in &names {
        for key in ["update_ms", "sah_ratio_final", "sah_ratio_max", "diffuse_mrays_final"] {
            assert!(get(name, key) > 0.0, "{name}.{key}");
        }
    }
    assert_eq!(get("rebuild", "sah_ratio_max"), 1.0);
    assert!(get("refit", "sah_ratio_final") > get("reinsert+prbvh", "sah_ratio_final"));
    assert!(std::fs::read_to_string(&csv).unwrap().lines().count() == 6);
    assert!(std::fs::read_to_string(&svg).unwrap().contains("<svg"));

    let scene = root().join("scenes/cornell-animated.toml");
    let out = bench().arg("--animated").arg(&scene).args(["--frames", "6", "--resolution", "32"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).contains("11 instances, 3 moving"));

    let furnace = root().join("scenes/furnace.toml");
    for (args, expected) in [
        (
            vec!["--animated".to_string(), scene.display().to_string(), "--moving".into(), "5".into()],
            "--moving applies",
        ),
        (vec!["--procedural-animated".into(), "100".into(), "--moving".into(), "150".into()], "percentage"),
        (vec!["--procedural-animated".into(), "100".into(), "--frames".into(), "0".into()], "--frames"),
        (vec!["--animated".into(), furnace.display().to_string()], "nothing in the scene moves"),
    ] {
        let out = bench().args(&args).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && stderr.contains(expected), "{args:?}: {stderr}");
    }
}

fn run_ok(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    stdout
}

fn manifest(rel: &str) -> PathBuf {
    root().join(rel)
}

/// `--converge`: one curve per builder (auto included), errors falling with the samples, the
/// auto comparison, and the outputs.
#[test]
fn convergence_benchmark_reports_error_against_time() {
    let dir = temp_dir("converge");
    let (json, csv, svg) = (dir.join("c.json"), dir.join("c.csv"), dir.join("c.svg"));
    let stdout = run_ok(
        bench()
            .arg("--converge")
            .arg(manifest("scenes/cornell-box.toml"))
            // Up to 64 spp, so that the curves overlap in time even when a build is slowed down
            // by a busy machine: at 16, a binned-SAH build of 8 ms ended after the LBVH's last
            // image, and auto could not be compared.
            .args(["--image-size", "24x24", "--max-spp", "64", "--reference-spp", "256", "--runs", "2"])
            .arg("--json")
            .arg(&json)
            .arg("--csv")
            .arg(&csv)
            .arg("--plot")
            .arg(&svg),
    );
    assert!(stdout.contains("auto against the best fixed builder"), "{stdout}");
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!((report["width"].as_u64(), report["height"].as_u64()), (Some(24), Some(24)));
    assert_eq!(report["reference"]["source"], "rendered");
    let curves = report["curves"].as_array().unwrap();
    let names: Vec<&str> = curves.iter().map(|c| c["builder"].as_str().unwrap()).collect();
    assert_eq!(names, ["lbvh", "lbvh+prbvh", "binned-sah", "auto"]);
    for c in curves {
        assert_eq!(c["device"], "cpu");
        let points = c["points"].as_array().unwrap();
        let spp: Vec<u64> = points.iter().map(|p| p["spp"].as_u64().unwrap()).collect();
        assert_eq!(spp, [1, 2, 4, 8, 16, 32, 64]);
        let field = |p: &serde_json::Value, k: &str| p[k].as_f64().unwrap_or_else(|| panic!("{k} missing in {p}"));
        // A fixed builder's points are one progressive render, so its times grow; auto's are
        // separate builds and renders, which grow only on the whole at this tiny size.
        if c["builder"] != "auto" {
            for w in points.windows(2) {
                assert!(field(&w[1], "time_s") > field(&w[0], "time_s"), "time must grow with spp: {c}");
            }
        }
        // 64 samples against 1: the mean absolute error falls by about 8; noise can't undo half.
        let (first, last) = (&points[0], &points[points.len() - 1]);
        assert!(field(last, "mae") < 0.5 * field(first, "mae"), "{c}");
        assert!(field(last, "rel_mse") < field(first, "rel_mse"), "{c}");
        assert!(points.iter().all(|p| p["non_finite"] == 0 && field(p, "build_s") <= field(p, "time_s")));
    }
    let auto = &report["auto"][0];
    assert_eq!(auto["device"], "cpu");
    assert_eq!(report["auto_not_compared"], serde_json::json!([]));
    assert!(auto["worst_ratio_rel_mse"].as_f64().unwrap() > 0.0, "{auto}");
    let csv_text = std::fs::read_to_string(&csv).unwrap();
    assert_eq!(csv_text.lines().count(), 1 + 4 * 7, "{csv_text}");
    assert!(std::fs::read_to_string(&svg).unwrap().contains("<svg"));
}

/// `--reference REF.exr`: the error is measured against the given image, which must match the
/// render's size; a GPU device is refused until the GPU backend lands.
#[test]
fn convergence_against_a_given_reference() {
    let dir = temp_dir("converge-ref");
    let reference = dir.join("ref.exr");
    let scene = manifest("scenes/furnace.toml");
    {
        use arbor::device::{BuilderChoice, Device, Renderer};
        let loaded = arbor::scene::Scene::load(&scene).unwrap();
        let settings = arbor::scene::RenderSettings { spp: 4, ..loaded.render };
        let builder = BuilderChoice::Fixed("lbvh+prbvh".parse().unwrap());
        let tracing = arbor::bvh::Tracing::from_env(None).unwrap();
        let mut renderer = Renderer::new(Device::Cpu, &loaded, &builder, tracing, &settings, 1, 0.0).unwrap();
        let frame = renderer.render(&settings, &|_| {}).unwrap();
        arbor::image_io::write_image(&reference, &frame.film.mean()).unwrap();
    }
    let json = dir.join("r.json");
    run_ok(
        bench()
            .arg("--converge")
            .arg(&scene)
            .arg("--reference")
            .arg(&reference)
            .args(["--builders", "lbvh,auto", "--max-spp", "2", "--runs", "1", "--json"])
            .arg(&json),
    );
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(report["reference"]["source"], "file");
    assert_eq!(report["curves"].as_array().unwrap().len(), 2);

    let out = bench()
        .arg("--converge")
        .arg(&scene)
        .arg("--reference")
        .arg(&reference)
        .args(["--image-size", "8x8", "--max-spp", "1"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("ref.exr") && stderr.contains("8x8"), "{stderr}");

    let out = bench().arg("--converge").arg(&scene).args(["--devices", "cpu,tpu"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("unknown device `tpu`"), "{stderr}");
}

/// `--converge --devices cpu,gpu`: a curve per builder and device, and auto compared with the
/// fixed builders of its own device. Skips without a GPU adapter, except under `CI=true`.
#[test]
fn convergence_on_both_devices() {
    if common::gpu_or_skip("bvh-bench on the GPU").is_none() {
        return;
    }
    let dir = temp_dir("converge-gpu");
    let json = dir.join("c.json");
    run_ok(
        bench()
            .arg("--converge")
            .arg(manifest("scenes/cornell-box.toml"))
            .args(["--devices", "cpu,gpu", "--builders", "lbvh,auto", "--image-size", "16x16", "--max-spp", "4"])
            .args(["--reference-spp", "64", "--runs", "1", "--json"])
            .arg(&json),
    );
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let curves: Vec<(String, String)> = report["curves"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| (c["builder"].as_str().unwrap().to_owned(), c["device"].as_str().unwrap().to_owned()))
        .collect();
    for b in ["lbvh", "auto"] {
        for d in ["cpu", "gpu"] {
            assert!(curves.contains(&(b.to_owned(), d.to_owned())), "no {b} curve on {d}: {curves:?}");
        }
    }
    // At this tiny size auto's and lbvh's time ranges need not overlap (then a device has no
    // comparison); where they do, each comparison is of one device's curves.
    let devices: Vec<&str> = report["auto"].as_array().unwrap().iter().map(|a| a["device"].as_str().unwrap()).collect();
    assert!(devices.iter().all(|d| ["cpu", "gpu"].contains(d)) && !(devices.len() == 2 && devices[0] == devices[1]));
    for c in report["curves"].as_array().unwrap() {
        assert!(c["points"].as_array().unwrap().iter().all(|p| p["non_finite"] == 0), "{c}");
    }
}

/// `--memory`: one process per builder, with kept and peak bytes per triangle.
#[test]
fn memory_report_per_builder() {
    let dir = temp_dir("memory");
    let json = dir.join("m.json");
    let stdout = run_ok(
        bench().args(["--memory", "--procedural", "city:20k", "--builders", "lbvh,obvhs-fastest", "--json"]).arg(&json),
    );
    assert!(stdout.contains("peak B/tri"), "{stdout}");
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let builders = report["builders"].as_array().unwrap();
    assert_eq!(builders.len(), 2);
    for b in builders {
        let kept = b["kept_bytes_per_triangle"].as_f64().unwrap();
        // At least the triangles themselves (36 bytes in ours, 48 in obvhs's), and sane.
        assert!((36.0..1000.0).contains(&kept), "{b}");
        assert!(b["peak_bytes"].as_u64().unwrap() >= b["kept_bytes"].as_u64().unwrap(), "{b}");
        assert_eq!(b["triangles"], report["triangles"]);
    }
}

/// `--gpu`: the GPU LBVH is the CPU's tree, and GPU PRBVH lowers the SAH like the CPU's. Skips
/// without an adapter, except under `CI=true`.
#[test]
fn gpu_builds_are_reported_beside_the_cpu() {
    if common::gpu_or_skip("bvh-bench on the GPU").is_none() {
        return;
    }
    let dir = temp_dir("gpu");
    let json = dir.join("g.json");
    run_ok(bench().args(["--gpu", "--procedural", "city:5k", "--runs", "1", "--json"]).arg(&json));
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let rows = report["rows"].as_array().unwrap();
    let row = |stage: &str, device: &str| rows.iter().find(|r| r["stage"] == stage && r["device"] == device).unwrap();
    assert_eq!(row("lbvh", "gpu")["same_tree_as_cpu"], true);
    let (lbvh, cpu, gpu) = (
        row("lbvh", "cpu")["sah"].as_f64().unwrap(),
        row("prbvh", "cpu")["sah"].as_f64().unwrap(),
        row("prbvh", "gpu")["sah"].as_f64().unwrap(),
    );
    assert!(gpu < lbvh && (gpu - cpu).abs() <= 0.02 * cpu, "SAH: LBVH {lbvh}, CPU PRBVH {cpu}, GPU PRBVH {gpu}");
    assert!(row("collapse", "cpu")["sah"].as_f64().unwrap() > 0.0);
    assert!(row("collapse", "gpu")["nodes"].as_u64().unwrap() > 0);
    // Every builder's rays on the GPU, through both forms, hitting what the CPU hits.
    let builders = report["builders"].as_array().unwrap();
    assert!(!builders.is_empty());
    for b in builders {
        for field in ["primary", "shadow", "diffuse"] {
            for form in ["gpu", "gpu_binary"] {
                let v = b[format!("{form}_{field}_mrays")].as_f64();
                assert!(v.is_some_and(|v| v > 0.0), "{}: {form}_{field}_mrays {v:?}", b["name"]);
            }
        }
        assert_eq!(b["gpu_hit_mismatches"], 0, "{}", b["name"]);
    }
}

/// `--animated SCENE --gpu`: two levels (top level updated or rebuilt) and flattening, each in
/// both forms, with an update time, a render speed and the device's bytes.
#[test]
fn gpu_animation_strategies_are_reported() {
    if common::gpu_or_skip("bvh-bench --animated --gpu").is_none() {
        return;
    }
    let dir = temp_dir("gpu-anim");
    let json = dir.join("a.json");
    let scene = root().join("scenes/cornell-animated.toml");
    run_ok(bench().arg("--animated").arg(&scene).args(["--gpu", "--frames", "2", "--json"]).arg(&json));
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let rows = report["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 8, "{report}");
    let row = |strategy: &str, form: &str| {
        rows.iter().find(|r| r["strategy"] == strategy && r["form"] == form).unwrap_or_else(|| panic!("{report}"))
    };
    for strategy in ["two-level dynamic", "two-level rebuild", "two-level gpu-lbvh", "flatten"] {
        for form in ["wide8", "binary"] {
            let r = row(strategy, form);
            assert!(r["update_ms"].as_f64().unwrap() >= 0.0 && r["mrays"].as_f64().unwrap() > 0.0, "{r}");
        }
    }
    let bytes = |strategy| row(strategy, "binary")["device_bytes"].as_u64().unwrap();
    assert!(report["instances"].as_u64().unwrap() > 1, "{report}");
    assert!(bytes("two-level dynamic") > 0 && bytes("flatten") > 0, "{report}");
}

/// Without the feature `embree`, naming an Embree builder says how to get it, before any work.
#[cfg(not(feature = "embree"))]
#[test]
fn embree_builders_need_the_feature() {
    let out = bench().args(["--procedural", "city:1000", "--builders", "lbvh,embree-medium"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("`embree-medium`") && stderr.contains("--features embree"), "{stderr}");
}
