//! Embree as a peer (feature `embree`): its hits agree with Arbor's on the benchmark's own ray
//! sets, and `bvh-bench` reports it beside Arbor's builders.
//!
//! Tolerance: Embree's robust triangle test and Arbor's watertight one compute `t` and the edge
//! functions with different arithmetic, and break ties between triangles at the same `t`
//! differently (Arbor takes the lowest primitive id). So a ray through a shared edge or vertex
//! may hit the other triangle of the edge, and a ray grazing a silhouette may hit in one and
//! miss in the other. Measured here, that is a handful of rays per 10^5; the tests allow 1 in
//! 10^4 of each set (at least 3) and check that where the two name different triangles they hit
//! the same point along the ray, which is what a shared edge means. Every other ray must name
//! the same triangle at the same `t`, up to rounding.

#![cfg(feature = "embree")]

use std::path::PathBuf;
use std::process::Command;

use glam::Vec3;

use arbor::bvh::{CollapseConfig, MeshBvh, build::lbvh, collapse_leaves};
use arbor::geometry::{Aabb, Ray, Triangle, TriangleMesh, procedural};
use arbor_bench::compare::{self, BenchConfig};
use arbor_bench::embree::{Device, Quality, Scene};
use arbor_bench::rays;

// The tools' test helpers; the GPU ones go unused here.
#[allow(dead_code)]
#[path = "../../tests/common/tools.rs"]
mod common;

/// One triangle in the z = 0 plane: a ray from above hits it at its own `t` (the direction is
/// not unit length), misses past `t_max`, and a ray starting on the plane does not hit it at
/// `t = 0` (Embree's robust mode would with `tnear = 0`).
#[test]
fn one_triangle_hits_in_the_rays_parametrisation() {
    let device = Device::new(1).unwrap();
    let triangles = [Triangle::new(Vec3::ZERO, Vec3::X, Vec3::Y)];
    let (scene, _) = Scene::build(&device, &triangles, Quality::Medium).unwrap();
    let down = Ray::new(Vec3::new(0.25, 0.25, 4.0), Vec3::new(0.0, 0.0, -2.0));
    let (prim, t) = scene.closest_hit(&down, f32::INFINITY).unwrap();
    assert_eq!(prim, 0);
    assert!((t - 2.0).abs() < 1e-6, "t = {t}");
    assert!(scene.any_hit(&down, 2.0));
    assert!(!scene.any_hit(&down, 1.9));
    assert_eq!(scene.closest_hit(&down, 1.9), None);
    let on_plane = Ray::new(Vec3::new(0.25, 0.25, 0.0), Vec3::new(0.0, 0.0, 1.0));
    assert_eq!(scene.closest_hit(&on_plane, f32::INFINITY), None);
    assert!(!scene.any_hit(&on_plane, f32::INFINITY));
}

#[test]
fn quality_names_round_trip() {
    for q in Quality::ALL {
        assert_eq!(Quality::from_name(q.name()), Some(q));
    }
    assert_eq!(Quality::from_name("embree-refit"), None);
}

/// An empty scene builds and misses everything.
#[test]
fn empty_scene_misses() {
    let device = Device::new(1).unwrap();
    let (scene, _) = Scene::build(&device, &[], Quality::Low).unwrap();
    let ray = Ray::new(Vec3::ZERO, Vec3::X);
    assert_eq!(scene.closest_hit(&ray, f32::INFINITY), None);
    assert!(!scene.any_hit(&ray, f32::INFINITY));
}

/// The rays of one set whose hits differ, and how many rays the set has.
#[derive(Debug)]
struct Differing {
    set: &'static str,
    rays: usize,
    differing: usize,
}

impl Differing {
    /// The tolerance of the module docs.
    fn check(&self, mesh: &str) {
        let allowed = (self.rays / 10_000).max(3);
        assert!(
            self.differing <= allowed,
            "{mesh}, {} rays: {} of {} hit differently in Embree and Arbor (at most {allowed} allowed)",
            self.set,
            self.differing,
            self.rays
        );
    }
}

/// Whether `t_a` and `t_b` give the same point of `ray`, within 10^-5 of the largest coordinate
/// of its origin and that point (some tens of ulps).
fn same_point(ray: &Ray, t_a: f32, t_b: f32) -> bool {
    let scale = ray.origin.abs().max_element().max(ray.at(t_a).abs().max_element());
    (t_a - t_b).abs() * ray.dir.length() <= 1e-5 * scale
}

/// Traces the benchmark's three ray sets with Arbor (an LBVH, leaves collapsed) and with Embree
/// at `quality`, comparing every ray; panics on a hit that differs beyond a grazing one.
fn compare_hits(mesh_name: &str, triangles: &[Triangle], quality: Quality) -> [Differing; 3] {
    let prim_aabbs: Vec<Aabb> = triangles.iter().map(Triangle::aabb).collect();
    let bvh = lbvh::build(&prim_aabbs);
    let bounds = bvh.bounds();
    let primary = rays::primary_rays(&bounds, 256, 256);
    let shadow = rays::shadow_rays(&bvh, triangles, &primary, rays::light_position(&bounds));
    let diffuse = rays::diffuse_rays(&bvh, triangles, &primary);
    let arbor = MeshBvh::new(
        collapse_leaves(&bvh, &CollapseConfig::default()),
        triangles,
        arbor::bvh::Tracing::from_env(None).expect("ARBOR_SIMD names a path this CPU has"),
    );
    let device = Device::new(2).unwrap();
    let (embree, _) = Scene::build(&device, triangles, quality).unwrap();
    assert!(primary.len() == 65_536 && shadow.len() > 1000 && diffuse.len() > 1000, "{mesh_name}: the camera misses");

    let closest = |set: &'static str, rays: &[Ray]| {
        let mut differing = 0;
        for (i, ray) in rays.iter().enumerate() {
            let ours = arbor.closest_hit(ray, f32::INFINITY).map(|h| (h.prim_id, h.t));
            let theirs = embree.closest_hit(ray, f32::INFINITY);
            match (ours, theirs) {
                (Some((a, ta)), Some((b, tb))) => {
                    // The same surface point, up to rounding: a few ulps of the coordinates, since
                    // `t` of a ray starting near the surface is a difference of nearly equal ones.
                    assert!(
                        same_point(ray, ta, tb),
                        "{mesh_name}, {set} ray {i}: t {ta} (triangle {a}) against {tb} (triangle {b})"
                    );
                    differing += (a != b) as usize;
                }
                (None, None) => {}
                _ => differing += 1,
            }
        }
        Differing { set, rays: rays.len(), differing }
    };
    let any = |set: &'static str, rays: &[Ray]| {
        let differing = rays.iter().filter(|r| arbor.any_hit(r, 1.0) != embree.any_hit(r, 1.0)).count();
        Differing { set, rays: rays.len(), differing }
    };
    let result = [closest("primary", &primary), any("shadow", &shadow), closest("diffuse", &diffuse)];
    for d in &result {
        d.check(mesh_name);
    }
    eprintln!("{mesh_name}, embree {quality:?}: {result:?}");
    result
}

/// A city of boxes: thousands of shared edges, coplanar faces, and axis-aligned rays' worst
/// cases (faces seen edge-on).
#[test]
fn embree_agrees_with_arbor_on_a_procedural_city() {
    let triangles = procedural::city(30_000, 3).triangles();
    for quality in Quality::ALL {
        compare_hits("city:30k", &triangles, quality);
    }
}

/// A scanned mesh, loaded as `bvh-bench` loads it. Skips where the shared meshes are missing,
/// except under `CI=true`.
#[test]
fn embree_agrees_with_arbor_on_the_bunny() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/models/bunny.obj");
    if !path.exists() {
        let ci = std::env::var("CI").is_ok_and(|v| v == "true");
        assert!(!ci, "{} is missing; CI must have ../shared/models", path.display());
        eprintln!("skipping: {} not found (the shared test meshes live beside the repository)", path.display());
        return;
    }
    let triangles = TriangleMesh::load_obj(&path).unwrap().triangles();
    compare_hits("bunny", &triangles, Quality::Medium);
}

/// The comparison with Embree in its rounds: its row has speeds, checksums and hit counts, null
/// where a field belongs to Arbor's trees only, and its differing rays counted against the
/// first of Arbor's builders; with Embree alone, against the LBVH the rays were made with.
#[test]
fn the_comparison_reports_embree_beside_arbor() {
    let triangles = procedural::city(20_000, 5).triangles();
    let config = BenchConfig {
        builders: vec!["binned-sah".parse().unwrap(), "embree-medium".parse().unwrap(), "lbvh".parse().unwrap()],
        runs: 2,
        resolution: 128,
        ..Default::default()
    };
    let report = compare::run(&triangles, &config).unwrap();
    assert!(report.mismatches.is_empty(), "{:?}", report.mismatches);
    assert_eq!(report.peer_reference.as_deref(), Some("binned-sah"));
    let names: Vec<&str> = report.builders.iter().map(|b| b.name.as_str()).collect();
    assert_eq!(names, ["binned-sah", "embree-medium", "lbvh"]);
    let (arbor, embree) = (&report.builders[0], &report.builders[1]);
    assert_eq!((arbor.engine, embree.engine), ("arbor", "embree"));
    assert!(embree.build_ms > 0.0 && embree.primary_mrays.is_some_and(|v| v > 0.0), "{embree:?}");
    assert!(embree.shadow_mrays.is_some() && embree.diffuse_mrays.is_some());
    assert_eq!((embree.sah, embree.nodes, embree.optimize_ms), (None, None, None));
    assert!(embree.sah_curve.is_empty());
    assert_eq!(arbor.differing_rays, None);
    let differing = embree.differing_rays.expect("Embree's differing rays are counted");
    let counts = [report.rays.primary, report.rays.shadow, report.rays.diffuse];
    for k in 0..3 {
        assert!(differing[k] <= (counts[k] / 10_000).max(3), "set {k}: {differing:?} of {counts:?}");
        // A ray that hits differently changes the hit count by at most one.
        assert!(embree.hits[k].abs_diff(arbor.hits[k]) <= differing[k], "{:?} against {:?}", embree.hits, arbor.hits);
        if differing[k] == 0 {
            assert_eq!(embree.checksums[k], arbor.checksums[k]);
        }
    }
    assert!(arbor.hits[0] > 1000);

    let alone = BenchConfig { builders: vec!["embree-low".parse().unwrap()], runs: 1, resolution: 64, ..config };
    let report = compare::run(&triangles, &alone).unwrap();
    assert_eq!(report.peer_reference.as_deref(), Some("lbvh"));
    assert!(report.builders[0].differing_rays.is_some());
}

fn temp_dir(name: &str) -> PathBuf {
    common::fresh_temp_dir("arbor-bench-embree", name)
}

/// `bvh-bench MESH --builders lbvh+prbvh,embree-medium`, as the README runs it: a JSON row for
/// Embree, and the differing rays printed per set.
#[test]
fn the_cli_compares_with_embree_medium() {
    let dir = temp_dir("cli");
    let (obj, json, csv) = (dir.join("torus.obj"), dir.join("r.json"), dir.join("r.csv"));
    common::write_obj(&obj, &TriangleMesh::torus(glam::Vec3::ZERO, 2.0, 0.7, 60, 30));
    let out = Command::new(env!("CARGO_BIN_EXE_bvh-bench"))
        .arg(&obj)
        .args(["--builders", "lbvh+prbvh,embree-medium", "--runs", "2", "--resolution", "96", "--threads", "2"])
        .arg("--json")
        .arg(&json)
        .arg("--csv")
        .arg(&csv)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("embree-medium against lbvh+prbvh: rays hitting differently"), "{stdout}");

    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(report["peer_reference"], "lbvh+prbvh");
    let builders = report["builders"].as_array().unwrap();
    let row = builders.iter().find(|b| b["name"] == "embree-medium").expect("an embree-medium row");
    assert_eq!(row["engine"], "embree");
    for key in ["build_ms", "primary_mrays", "shadow_mrays", "diffuse_mrays"] {
        assert!(row[key].as_f64().is_some_and(|v| v > 0.0), "{key} in {row}");
    }
    for key in ["optimize_ms", "collapse_ms", "sah", "sah_leaf1", "nodes", "leaves", "depth"] {
        assert!(row[key].is_null(), "{key} in {row}");
    }
    assert_eq!(row["differing_rays"].as_array().map(Vec::len), Some(3), "{row}");
    assert_eq!(row["hits"].as_array().map(Vec::len), Some(3), "{row}");
    assert!(builders[0]["differing_rays"].is_null());
    // The CSV leaves what does not apply empty.
    let csv = std::fs::read_to_string(&csv).unwrap();
    let line = csv.lines().find(|l| l.starts_with("embree-medium,")).unwrap();
    assert_eq!(line.split(',').nth(4), Some(""), "{line}");

    // Embree in a mode that does not measure it is an error before any work.
    let out = Command::new(env!("CARGO_BIN_EXE_bvh-bench"))
        .args(["--memory", "--procedural", "city:1000", "--builders", "lbvh,embree-medium"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("builder comparison only"), "{stderr}");
    let out = Command::new(env!("CARGO_BIN_EXE_bvh-bench"))
        .args(["--procedural", "city:1000", "--builders", "embree-ultra"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("unknown Embree builder `embree-ultra`"), "{stderr}");
}
