//! The scene loader: the example scenes load, the Cornell box matches the reference's geometry,
//! MTL materials map as documented, and every kind of bad input is an error naming the file,
//! the line and the key.

mod common;

use std::path::{Path, PathBuf};

use arbor::geometry::TriangleMesh;
use arbor::scene::{ConductorFresnel, Scattering, Scene};
use glam::Vec3;

fn scenes_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes")
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("arbor-scene-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn every_example_scene_loads() {
    let mut count = 0;
    for entry in std::fs::read_dir(scenes_dir()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
            assert!(!scene.objects.is_empty(), "{}", path.display());
            count += 1;
        }
    }
    assert!(count >= 1);
}

/// Per shape: the same corners, the same total area and the same area-weighted normal (so the
/// same winding) as the reference's own OBJ of that shape.
#[test]
fn cornell_box_matches_the_reference_geometry() {
    let scene = Scene::load(scenes_dir().join("cornell-box.toml")).unwrap();
    assert_eq!(scene.objects.len(), 8);
    assert_eq!((scene.camera.width, scene.camera.height), (256, 256));
    assert_eq!(scene.camera.position, Vec3::new(0.0, 0.0, 3.9));
    assert!(scene.has_emitters() && scene.environment.is_none());
    let reference = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/reference/cornell-box");
    if !reference.exists() {
        assert!(std::env::var("CI").map_or(true, |v| v != "true"), "CI must have ../shared/reference");
        eprintln!("skipping the geometry comparison: {} not found", reference.display());
        return;
    }
    let names = ["light", "floor", "ceiling", "back", "green-wall", "red-wall", "small-box", "large-box"];
    for (object, name) in scene.objects.iter().zip(names) {
        let ours = scene.meshes[object.mesh].mesh.transformed(object.world_from_object);
        let theirs = TriangleMesh::load_obj(reference.join(format!("cornell__{name}.obj"))).unwrap();
        let summary = |m: &TriangleMesh| {
            let tris = m.triangles();
            let area: f32 = tris.iter().map(|t| t.area()).sum();
            let normal: Vec3 = tris.iter().map(|t| t.normal() * 0.5).sum();
            let mut corners: Vec<[i64; 3]> =
                m.positions.iter().map(|p| (*p * 1e5).round().as_i64vec3().to_array()).collect();
            corners.sort();
            corners.dedup();
            (area, normal, corners)
        };
        let (a1, n1, c1) = summary(&ours);
        let (a2, n2, c2) = summary(&theirs);
        assert!((a1 - a2).abs() < 1e-5, "{name}: area {a1} vs {a2}");
        assert!((n1 - n2).length() < 1e-5, "{name}: normal {n1} vs {n2}");
        assert_eq!(c1, c2, "{name}: corners");
    }
}

#[test]
fn mtl_materials_map_as_documented() {
    let dir = temp_dir("mtl");
    std::fs::write(
        dir.join("m.mtl"),
        "newmtl lamp\nKd 0.5 0.5 0.5\nKe 4 3 2\n\nnewmtl gold\nKd 0 0 0\nKs 1 0.8 0.3\nNs 98\n\nnewmtl glass\nKd 0 0 0\nNi 1.33\nd 0.2\n\nnewmtl paint\nKd 0.2 0.4 0.6\n",
    )
    .unwrap();
    let mut obj = String::from("mtllib m.mtl\n");
    for (k, name) in ["lamp", "gold", "glass", "paint"].iter().enumerate() {
        let z = k as f32;
        obj += &format!(
            "o {name}\nusemtl {name}\nv 0 0 {z}\nv 1 0 {z}\nv 0 1 {z}\nf {} {} {}\n",
            3 * k + 1,
            3 * k + 2,
            3 * k + 3
        );
    }
    std::fs::write(dir.join("m.obj"), obj).unwrap();
    let scene_path = dir.join("s.toml");
    std::fs::write(
        &scene_path,
        "[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n\n[[objects]]\nmesh = \"m.obj\"\n",
    )
    .unwrap();
    let scene = Scene::load(&scene_path).unwrap_or_else(|e| panic!("{e}"));
    let by_triangle: Vec<_> = scene.meshes[0].material_ids.iter().map(|&i| &scene.materials[i as usize]).collect();
    assert_eq!(by_triangle[0].emission, Some(Vec3::new(4.0, 3.0, 2.0)));
    assert_eq!(by_triangle[0].scattering, Scattering::Diffuse { albedo: Vec3::splat(0.5) });
    match &by_triangle[1].scattering {
        Scattering::Conductor { roughness, fresnel: ConductorFresnel::BaseColor(c) } => {
            assert!((roughness - 0.1414).abs() < 1e-3 && *c == Vec3::new(1.0, 0.8, 0.3));
        }
        other => panic!("gold: {other:?}"),
    }
    assert_eq!(by_triangle[2].scattering, Scattering::Dielectric { ior: 1.33, roughness: 0.0 });
    assert_eq!(by_triangle[3].scattering, Scattering::Diffuse { albedo: Vec3::new(0.2, 0.4, 0.6) });
    let (tris, mats) = scene.world_triangles();
    assert_eq!((tris.len(), mats.len()), (4, 4));
}

const BASE: &str = "[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]
fov = 40
resolution = [16, 16]

[materials.white]
type = \"diffuse\"
albedo = [0.5, 0.5, 0.5]
";

/// `(scene text, expected line, expected key, a word the message must hold)`.
fn bad_scenes() -> Vec<(String, usize, &'static str, &'static str)> {
    let obj = "\n[[objects]]\nshape = \"box\"\nmaterial = \"white\"\n";
    vec![
        (format!("{BASE}{obj}[camra]\nx = 1\n"), 14, "camra", "unknown field"),
        (BASE.replace("albedo = [0.5, 0.5, 0.5]", "albedoo = [0.5, 0.5, 0.5]"), 9, "materials.white", "albedoo"),
        (format!("{BASE}{obj}[render]\nspp = \"many\"\n"), 15, "render.spp:", "string"),
        (BASE.replace("fov = 40", "fov = nan"), 4, "camera.fov", "NaN"),
        (BASE.replace("fov = 40", "fov = 190"), 4, "camera.fov", "(0, 180)"),
        (BASE.replace("[0.5, 0.5, 0.5]", "[inf, 0.5, 0.5]"), 9, "materials.white.albedo", "finite"),
        (BASE.replace("[0.5, 0.5, 0.5]", "[-0.5, 0.5, 0.5]"), 9, "materials.white.albedo", "negative"),
        (BASE.replace("resolution = [16, 16]", "resolution = [-16, 16]"), 5, "camera.resolution[0]:", "-16"),
        (BASE.replace("resolution = [16, 16]", "resolution = [0, 16]"), 5, "camera.resolution", "1 to"),
        (format!("{BASE}{obj}scale = -2\n"), 14, "objects[0].scale", "> 0"),
        (format!("{BASE}{obj}scale = [1, 0, 1]\n"), 14, "objects[0].scale", "> 0"),
        (format!("{BASE}\n[[objects]]\nmesh = \"nope.obj\"\n"), 12, "objects[0].mesh", "nope.obj"),
        (format!("{BASE}\n[[objects]]\nshape = \"box\"\nmaterial = \"chalk\"\n"), 13, "objects[0].material", "chalk"),
        (format!("{BASE}\n[[objects]]\nshape = \"cone\"\nmaterial = \"white\"\n"), 12, "objects[0].shape", "cone"),
        (format!("{BASE}\n[[objects]]\nshape = \"box\"\n"), 11, "objects[0].material", "needs a material"),
        (
            format!("{BASE}\n[[objects]]\nshape = \"sphere\"\nsubdivisions = 20\nmaterial = \"white\"\n"),
            13,
            "objects[0].subdivisions",
            "20",
        ),
        (BASE.replace("[camera]", "[camera"), 1, "syntax", ""),
        (BASE.replace("fov = 40\n", ""), 1, "camera", "fov"),
        (BASE.replace("look_at = [0, 0, 0]", "look_at = [0, 0, 5]"), 3, "camera.look_at", "position"),
        (
            BASE.replace("type = \"diffuse\"", "type = \"diffuse\"\nior = 1.5"),
            9,
            "materials.white.ior",
            "not a key of a diffuse",
        ),
        (BASE.replace("type = \"diffuse\"", "type = \"plastic\""), 8, "materials.white.type", "plastic"),
        (
            BASE.replace("type = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]", "type = \"conductor\"\nroughness = 2"),
            9,
            "materials.white.roughness",
            "[0, 1]",
        ),
        (
            format!("{BASE}\n[materials.m]\ntype = \"conductor\"\nroughness = 0.1\n"),
            11,
            "materials.m.eta",
            "base_color",
        ),
        (
            format!("{BASE}{obj}matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]]\n"),
            14,
            "objects[0].matrix",
            "invertible",
        ),
        (
            format!(
                "{BASE}{obj}translate = [1, 2, 3]\nmatrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n"
            ),
            14,
            "objects[0].matrix",
            "either",
        ),
        (format!("{BASE}{obj}[render]\nmax_depth = 0\n"), 15, "render.max_depth", "at least 1"),
        (format!("{BASE}{obj}[environment]\nradiance = [1, 1]\n"), 15, "environment.radiance:", "length 3"),
    ]
}

#[test]
fn bad_input_names_file_line_and_key() {
    let dir = temp_dir("bad");
    let mut failures = Vec::new();
    for (k, (text, line, key, word)) in bad_scenes().into_iter().enumerate() {
        let path = dir.join(format!("bad{k}.toml"));
        std::fs::write(&path, &text).unwrap();
        let err = match Scene::load(&path) {
            Ok(_) => panic!("case {k} loaded:\n{text}"),
            Err(e) => e.to_string(),
        };
        let prefix = format!("{}:{line}: {key}", path.display());
        if !err.starts_with(&prefix) || !err.contains(word) {
            failures.push(format!("case {k}: expected `{prefix}` and `{word}`, got `{err}`"));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn a_missing_scene_file_is_an_error() {
    let err = Scene::load(Path::new("/nonexistent/scene.toml")).unwrap_err().to_string();
    assert!(err.starts_with("/nonexistent/scene.toml: cannot read"), "{err}");
}
