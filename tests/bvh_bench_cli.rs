//! `bvh-bench` as a user runs it: outputs, their fields, and errors on bad input.

use std::path::{Path, PathBuf};
use std::process::Command;

fn bench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bvh-bench"))
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("arbor-bench-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A small closed mesh as OBJ.
fn write_obj(path: &Path) {
    let mesh = arbor::geometry::TriangleMesh::torus(glam::Vec3::ZERO, 2.0, 0.7, 40, 20);
    let mut s = String::new();
    for p in &mesh.positions {
        s += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for t in &mesh.indices {
        s += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    std::fs::write(path, s).unwrap();
}

#[test]
fn writes_table_json_csv_and_plot() {
    let dir = temp_dir("outputs");
    let obj = dir.join("torus.obj");
    write_obj(&obj);
    let (json, csv, svg) = (dir.join("r.json"), dir.join("r.csv"), dir.join("r.svg"));
    let out = bench()
        .arg(&obj)
        .args(["--builders", "lbvh,lbvh+prbvh,binned-sah,obvhs-fastest", "--runs", "2", "--resolution", "64"])
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
    assert_eq!(builders.len(), 4);
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

    let csv = std::fs::read_to_string(&csv).unwrap();
    assert_eq!(csv.lines().count(), 5);
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
    let scene = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/showcase.toml");
    let out = bench()
        .arg(&scene)
        .args(["--builders", "lbvh,lbvh+prbvh", "--runs", "1", "--resolution", "32"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).contains("lbvh+prbvh"));
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

/// Each bad input exits non-zero with a message naming what is wrong, and writes nothing.
#[test]
fn bad_input_is_a_clear_error() {
    let dir = temp_dir("errors");
    let obj = dir.join("torus.obj");
    write_obj(&obj);
    let json = dir.join("never.json");
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
        (vec![obj.display().to_string(), "--runs".into(), "0".into()], "--runs must be at least 1"),
        (vec![], "give a mesh"),
    ];
    for (args, expected) in cases {
        let out = bench().args(&args).arg("--json").arg(&json).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} should fail");
        assert!(stderr.contains(expected), "{args:?}: expected `{expected}` in: {stderr}");
        assert!(!json.exists(), "{args:?} wrote output");
    }
}
