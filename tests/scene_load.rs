//! The scene loader: the example scenes load, the Cornell box matches the reference's geometry,
//! MTL materials map as documented, objects share meshes, keyframes and orbits move objects as
//! documented, scatter makes its instances by the documented rule, and every kind of bad input is
//! an error naming the file, the line and the key.

use crate::common;

use std::path::{Path, PathBuf};

use arbor::geometry::TriangleMesh;
use arbor::scene::{Animation, ConductorFresnel, Scattering, Scene};
use glam::{Mat4, Quat, Vec3};

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
        "newmtl lamp\nKd 0.5 0.5 0.5\nKe 4 3 2\n\nnewmtl gold\nKd 0 0 0\nKs 1 0.8 0.3\nNs 98\n\nnewmtl glass\nKd 0 0 0\nNi 1.33\nd 0.2\n\nnewmtl paint\nKd 0.2 0.4 0.6\n\n\
         newmtl plastic\nKd 0.8 0.1 0.1\nKs 0.5 0.5 0.5\nNs 48\n\nnewmtl pbr\nKd 0.9 0.6 0.2\nKs 0.5 0.5 0.5\nNs 48\nPr 0.5\nPm 1\n\n\
         newmtl rough\nKd 0.3 0.3 0.3\nPr 2\nPm x\n",
    )
    .unwrap();
    let mut obj = String::from("mtllib m.mtl\n");
    for (k, name) in ["lamp", "gold", "glass", "paint", "plastic", "pbr", "rough"].iter().enumerate() {
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
    // Kd and Ks: a coated plastic, GGX α = sqrt(2 / (Ns + 2)) = 0.2 as for the conductor.
    assert_eq!(
        by_triangle[4].scattering,
        Scattering::Coated { base_color: Vec3::new(0.8, 0.1, 0.1), metallic: 0.0, alpha: 0.2, ior: 1.5 }
    );
    // The PBR extension: Pm the metallic, Pr the perceptual roughness (α = Pr²) over Ns.
    assert_eq!(
        by_triangle[5].scattering,
        Scattering::Coated { base_color: Vec3::new(0.9, 0.6, 0.2), metallic: 1.0, alpha: 0.25, ior: 1.5 }
    );
    // Pr out of range is clamped, an unreadable Pm ignored; Pr alone makes it coated.
    assert_eq!(
        by_triangle[6].scattering,
        Scattering::Coated { base_color: Vec3::splat(0.3), metallic: 0.0, alpha: 1.0, ior: 1.5 }
    );
    let (tris, mats) = scene.world_triangles();
    assert_eq!((tris.len(), mats.len()), (7, 7));
}

/// `BASE` plus an `[animation]` clock of 24 fps.
fn animated(objects: &str) -> Scene {
    let text = format!("{BASE}{ANIMATION}{objects}");
    Scene::parse(&text, "anim.toml").unwrap_or_else(|e| panic!("{e}\n{text}"))
}

const ANIMATION: &str = "\n[animation]\nfps = 24\nframes = [0, 96]\n";

fn close(a: Vec3, b: Vec3) -> bool {
    (a - b).length() < 1e-5
}

#[test]
fn keyframes_interpolate_and_clamp() {
    let scene = animated(
        "
[[objects]]
shape = \"sphere\"
material = \"white\"
scale = 0.5
translate = [1, 0, 0]
[[objects.keyframes]]
time = 1.0
[[objects.keyframes]]
time = 3.0
translate = [2, 4, 0]
rotate = [0, 90, 0]
scale = [3, 1, 1]
",
    );
    assert!(scene.is_animated() && scene.objects[0].is_animated());
    assert_eq!(scene.frame_time(12), 0.5);
    let anim = scene.objects[0].animation.as_ref().unwrap();
    let Animation::Keyframes(keys) = anim else { panic!("{anim:?}") };
    assert_eq!(keys.len(), 2);

    let (scale, rotation, translation) = anim.transform_at(2.0).to_scale_rotation_translation();
    assert!(close(translation, Vec3::new(1.0, 2.0, 0.0)), "{translation}");
    assert!(close(scale, Vec3::new(2.0, 1.0, 1.0)), "{scale}");
    let yaw_45 = Quat::from_rotation_y(45f32.to_radians());
    assert!(rotation.angle_between(yaw_45) < 1e-3, "{rotation}");
    // A quarter of the way: 22.5° by slerp (normalised lerp would give 21.6°).
    let (_, quarter, _) = anim.transform_at(1.5).to_scale_rotation_translation();
    assert!(quarter.angle_between(Quat::from_rotation_y(22.5f32.to_radians())) < 1e-3, "{quarter}");

    // Clamped: before the first key it holds the first, after the last the last.
    assert_eq!(anim.transform_at(-5.0), anim.transform_at(1.0));
    assert_eq!(anim.transform_at(1.0), Mat4::IDENTITY);
    assert_eq!(anim.transform_at(50.0), keys[1].matrix());
    let (s3, r3, t3) = anim.transform_at(3.0).to_scale_rotation_translation();
    assert!(close(s3, Vec3::new(3.0, 1.0, 1.0)) && close(t3, Vec3::new(2.0, 4.0, 0.0)));
    assert!(r3.angle_between(Quat::from_rotation_y(90f32.to_radians())) < 1e-3);

    // The static placement first: (0, 0, 1) -> scale 0.5, +x -> (1, 0, 0.5); then the key at
    // t = 2: scale (2, 1, 1) -> (2, 0, 0.5), yaw 45° -> c (2.5, 0, -1.5), + (1, 2, 0).
    let c = std::f32::consts::FRAC_1_SQRT_2;
    let p = scene.objects[0].world_from_object_at(2.0).transform_point3(Vec3::Z);
    assert!((p - Vec3::new(1.0 + 2.5 * c, 2.0, -1.5 * c)).length() < 1e-4, "{p}");
}

#[test]
fn slerp_takes_the_short_way() {
    let scene = animated(
        "
[[objects]]
shape = \"box\"
material = \"white\"
[[objects.keyframes]]
time = 0
rotate = [0, -80, 0]
[[objects.keyframes]]
time = 1
rotate = [0, 250, 0]
",
    );
    // -80° to 250° (= -110°) is 30° the short way: the midpoint is -95°, not 85°.
    let (_, r, _) = scene.objects[0].animation.as_ref().unwrap().transform_at(0.5).to_scale_rotation_translation();
    assert!(r.angle_between(Quat::from_rotation_y((-95f32).to_radians())) < 1e-3, "{r}");
}

#[test]
fn orbit_leaves_and_returns_to_rest() {
    let (radius, period) = (0.5, 4.0);
    let offset =
        |phase: f32, t: f32| Animation::Orbit { radius, period, phase }.transform_at(t).transform_point3(Vec3::ZERO);
    assert!(close(offset(0.0, 0.0), Vec3::ZERO));
    // Phase 0 starts at θ = 0; half a period later θ = π, the far side: (-2r, 0, 0).
    assert!(close(offset(0.0, period / 2.0), Vec3::new(-2.0 * radius, 0.0, 0.0)), "{}", offset(0.0, 2.0));
    assert!(close(offset(0.0, period), Vec3::ZERO));
    // Phase π/2: a quarter period later θ = π, so cos θ − cos phase = −1, sin θ − sin phase = −1.
    let half_pi = std::f32::consts::FRAC_PI_2;
    assert!(close(offset(half_pi, 0.0), Vec3::ZERO));
    assert!(close(offset(half_pi, period / 4.0), Vec3::new(-radius, 0.0, -radius)));
    assert!(close(offset(half_pi, period / 2.0), Vec3::new(0.0, 0.0, -2.0 * radius)));
    assert!(close(offset(half_pi, period), Vec3::ZERO));
    // A period too short for f32 (`t / period` overflows) still gives a finite place on the orbit.
    for period in [1e-40, f32::from_bits(1)] {
        let p = Animation::Orbit { radius, period, phase: 0.0 }.transform_at(1.0).transform_point3(Vec3::ZERO);
        assert!(p.is_finite() && p.length() <= 2.0 * radius + 1e-6, "period {period:e}: {p}");
    }
}

fn scatter_scene(seed: u64, count: u32, extra: &str) -> Scene {
    animated(&format!(
        "
[[objects]]
shape = \"sphere\"
material = \"white\"
scale = 0.1
[objects.scatter]
count = {count}
seed = {seed}
min = [-10, 0, -10]
max = [10, 1, 10]
{extra}"
    ))
}

#[test]
fn scatter_makes_seeded_instances_of_one_mesh() {
    let scene = scatter_scene(7, 1000, "moving = 0.25\nradius = 0.5\nperiod = 2\n");
    assert_eq!(scene.objects.len(), 1000);
    assert_eq!(scene.meshes.len(), 1);
    assert!(scene.objects.iter().all(|o| o.mesh == 0 && o.material == Some(0)));
    let (min, max) = (Vec3::new(-10.0, 0.0, -10.0), Vec3::new(10.0, 1.0, 10.0));
    let mut lo = Vec3::INFINITY;
    let mut hi = Vec3::NEG_INFINITY;
    for o in &scene.objects {
        let (scale, _, at) = o.world_from_object.to_scale_rotation_translation();
        assert!(at.cmpge(min).all() && at.cmple(max).all(), "{at}");
        assert!(close(scale, Vec3::splat(0.1)), "{scale}");
        (lo, hi) = (lo.min(at), hi.max(at));
    }
    assert!(lo.cmplt(min + 0.1).all() && hi.cmpgt(max - 0.1).all(), "positions span {lo}..{hi}");
    // round(0.25 · 1000) move, each on an orbit with the scatter's radius and period.
    let moving: Vec<_> = scene.objects.iter().filter_map(|o| o.animation.as_ref()).collect();
    assert_eq!(moving.len(), 250);
    for a in moving {
        let &Animation::Orbit { radius, period, phase } = a else { panic!("{a:?}") };
        assert!(radius == 0.5 && period == 2.0 && (0.0..std::f32::consts::TAU).contains(&phase));
    }
    assert_eq!(scatter_scene(7, 1000, "moving = 0.25\nradius = 0.5\nperiod = 2\n"), scene);
    let other = scatter_scene(8, 1000, "moving = 0.25\nradius = 0.5\nperiod = 2\n");
    assert_ne!(other.objects[0].world_from_object, scene.objects[0].world_from_object);
}

#[test]
fn scatter_moves_the_rounded_fraction() {
    let animated_count = |s: Scene| s.objects.iter().filter(|o| o.is_animated()).count();
    // round(0.25 · 10) = round(2.5) = 3: halves round away from zero.
    assert_eq!(animated_count(scatter_scene(1, 10, "moving = 0.25\nradius = 1\n")), 3);
    assert_eq!(animated_count(scatter_scene(1, 10, "moving = 0.24\nradius = 1\n")), 2);
    // `moving` defaults to 1 with a radius, and nothing moves without one.
    assert_eq!(animated_count(scatter_scene(1, 10, "radius = 1\n")), 10);
    assert_eq!(animated_count(scatter_scene(1, 10, "moving = 1\n")), 0);
    // Which ones move changes nothing else: the placements are the same.
    let (a, b) = (scatter_scene(3, 50, "radius = 1\n"), scatter_scene(3, 50, ""));
    assert!(a.objects.iter().zip(&b.objects).all(|(a, b)| a.world_from_object == b.world_from_object));
    // A scatter that does not move needs no [animation].
    let text = format!(
        "{BASE}\n[[objects]]\nshape = \"box\"\nmaterial = \"white\"\n[objects.scatter]\ncount = 3\nmin = [0, 0, 0]\nmax = [1, 1, 1]\n"
    );
    let scene = Scene::parse(&text, "s.toml").unwrap();
    assert!(!scene.is_animated() && scene.objects.len() == 3 && scene.animation.is_none());
    assert_eq!(scene.frame_time(10), 0.0);
}

#[test]
fn objects_share_a_mesh_per_shape_and_obj_file() {
    let scene = animated(
        "
[[objects]]
shape = \"sphere\"
material = \"white\"
[[objects]]
shape = \"sphere\"
subdivisions = 3
material = \"white\"
translate = [2, 0, 0]
[[objects]]
shape = \"sphere\"
subdivisions = 2
material = \"white\"
[[objects]]
shape = \"box\"
material = \"white\"
[[objects]]
shape = \"box\"
material = \"white\"
",
    );
    let meshes: Vec<usize> = scene.objects.iter().map(|o| o.mesh).collect();
    assert_eq!(meshes, [0, 0, 1, 2, 2]);
    assert_eq!(scene.meshes.len(), 3);
    assert_ne!(scene.meshes[0].mesh.triangle_count(), scene.meshes[1].mesh.triangle_count());

    let dir = temp_dir("dedup");
    std::fs::create_dir_all(dir.join("models")).unwrap();
    std::fs::write(dir.join("models/m.mtl"), "newmtl red\nKd 1 0 0\n").unwrap();
    std::fs::write(dir.join("models/m.obj"), "mtllib m.mtl\nusemtl red\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    std::fs::write(dir.join("models/bare.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let obj = |mesh: &str, material: &str| format!("\n[[objects]]\nmesh = \"{mesh}\"\n{material}");
    let text = format!(
        "{BASE}{}{}{}{}",
        obj("models/m.obj", ""),
        obj("./models/../models/m.obj", "material = \"white\"\n"),
        obj("models/bare.obj", "material = \"white\"\n"),
        obj("models/bare.obj", "material = \"white\"\n"),
    );
    let scene = Scene::parse(&text, dir.join("s.toml")).unwrap_or_else(|e| panic!("{e}"));
    let meshes: Vec<usize> = scene.objects.iter().map(|o| o.mesh).collect();
    assert_eq!(meshes, [0, 0, 1, 1]);
    // `white`, then m.mtl's `red` once.
    let names: Vec<&str> = scene.materials.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(names, ["white", "m/red"]);
    // A shared mesh without MTL materials still needs each object's own material.
    let text = format!("{text}{}", obj("models/bare.obj", ""));
    let err = Scene::parse(&text, dir.join("s.toml")).unwrap_err().to_string();
    assert!(err.contains(":27: objects[4].mesh") && err.contains("no MTL material"), "{err}");
}

/// A `mesh` whose extension is `.ply` (in any case) is read as PLY, in each encoding: the same
/// mesh as the file, normals and texture coordinates kept, polygons triangulated, shared by
/// the objects naming the file. A PLY file has no materials, so each object needs its own; and a
/// broken PLY file is an error naming the scene's line and key, then the PLY file and its line
/// (or, binary, its byte offset).
#[test]
fn ply_meshes_load_and_need_a_material() {
    let dir = temp_dir("ply");
    let mut mesh = TriangleMesh::icosphere(1);
    mesh.normals = mesh.positions.iter().map(|p| p.normalize()).collect();
    mesh.uvs = mesh.positions.iter().map(|p| glam::Vec2::new(p.x * 0.5 + 0.5, p.y)).collect();
    let formats = ["ascii", "binary_little_endian", "binary_big_endian"];
    for (name, format) in ["a.ply", "b.PLY", "c.Ply"].iter().zip(formats) {
        std::fs::write(dir.join(name), common::ply::ply_bytes(&mesh, format)).unwrap();
    }
    // A quad and an L-shaped hexagon, in the ASCII encoding.
    let polygons = "ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\nproperty float z\n\
                    element face 2\nproperty list uchar int vertex_indices\nend_header\n\
                    0 0 0\n2 0 0\n2 1 0\n1 1 0\n1 2 0\n0 2 0\n4 0 1 2 5\n6 0 1 2 3 4 5\n";
    std::fs::write(dir.join("polygons.ply"), polygons).unwrap();
    let object = |mesh: &str, material: &str| format!("\n[[objects]]\nmesh = \"{mesh}\"\n{material}");
    let white = "material = \"white\"\n";
    let text = format!(
        "{BASE}{}{}{}{}{}",
        object("a.ply", white),
        object("b.PLY", white),
        object("c.Ply", white),
        object("./sub/../a.ply", white),
        object("polygons.ply", white),
    );
    std::fs::create_dir_all(dir.join("sub")).unwrap();
    let scene = Scene::parse(&text, dir.join("s.toml")).unwrap_or_else(|e| panic!("{e}"));
    let meshes: Vec<usize> = scene.objects.iter().map(|o| o.mesh).collect();
    assert_eq!(meshes, [0, 1, 2, 0, 3]);
    for m in &scene.meshes[..3] {
        let loaded = &m.mesh;
        assert_eq!((&loaded.positions, &loaded.indices, &loaded.uvs), (&mesh.positions, &mesh.indices, &mesh.uvs));
        let normals = loaded.normals.iter().zip(&mesh.normals).all(|(a, b)| (*a - *b).length() < 1e-6);
        assert!(normals && loaded.normals.len() == mesh.normals.len(), "{}", m.source);
        assert!(m.material_ids.iter().all(|&id| id == u32::MAX));
    }
    assert!(scene.objects.iter().all(|o| o.material == Some(0)));
    let area: f32 = scene.meshes[3].mesh.triangles().iter().map(|t| t.area()).sum();
    assert_eq!((scene.meshes[3].mesh.triangle_count(), area), (2 + 4, 3.0 + 3.0));
    assert_eq!(scene.materials.len(), 1, "a PLY file adds no materials");

    // Without an object material, and broken files: errors at the object's `mesh`.
    let err = |mesh: &str, file: Option<&[u8]>| {
        if let Some(bytes) = file {
            std::fs::write(dir.join(mesh), bytes).unwrap();
        }
        let text = format!("{BASE}{}", object(mesh, if mesh == "a.ply" { "" } else { white }));
        let err = Scene::parse(&text, dir.join("s.toml")).unwrap_err().to_string();
        let prefix = format!("{}:12: objects[0].mesh: {}", dir.join("s.toml").display(), dir.join(mesh).display());
        assert!(err.starts_with(&prefix), "{err}");
        err[prefix.len()..].to_owned()
    };
    assert_eq!(err("a.ply", None), ": a PLY file has no materials; give the object a `material`");
    let cut = polygons.replace("6 0 1 2 3 4 5", "6 0 1 2 3 4 9");
    assert_eq!(
        err("bad.ply", Some(cut.as_bytes())),
        ":17: face 1, `vertex_indices`: vertex index 9 is past the last vertex (the file has 6)"
    );
    let binary = common::ply::ply_bytes(&mesh, "binary_little_endian");
    let said = err("cut.ply", Some(&binary[..binary.len() - 1]));
    let face = mesh.triangle_count() - 1;
    let offset = binary.len() - 4;
    assert_eq!(said, format!(": byte {offset}: the file ends in face {face} (of {}), at `vertex_indices`", face + 1));
    let points = polygons.replace("element face 2", "element face 0");
    assert_eq!(err("points.ply", Some(points.as_bytes())), ": no faces (a `face` element with `vertex_indices`)");
    assert!(err("missing.ply", None).starts_with(": cannot read: "));
}

/// The animated example in docs/scene-format.md loads and does what its comments say.
/// `city` and `hairball` make at least the triangles asked for, the same for the same seed, and
/// objects asking for the same one share it.
#[test]
fn procedural_shapes_are_seeded_and_shared() {
    let dir = temp_dir("procedural");
    let path = dir.join("p.toml");
    let text = |seed: u64| {
        format!(
            "{BASE}\n[[objects]]\nshape = \"city\"\ntriangles = 1000\nseed = {seed}\nmaterial = \"white\"\n\
             \n[[objects]]\nshape = \"city\"\ntriangles = 1000\nseed = {seed}\nmaterial = \"white\"\ntranslate = [50, 0, 0]\n\
             \n[[objects]]\nshape = \"hairball\"\ntriangles = 500\nmaterial = \"white\"\n"
        )
    };
    std::fs::write(&path, text(7)).unwrap();
    let a = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(a.meshes.len(), 2, "the two identical cities share a mesh");
    assert!(a.meshes[0].mesh.triangle_count() >= 1000 && a.meshes[1].mesh.triangle_count() == 500);
    let again = Scene::load(&path).unwrap();
    assert_eq!(a.meshes[0].mesh.positions, again.meshes[0].mesh.positions);
    std::fs::write(&path, text(8)).unwrap();
    let other = Scene::load(&path).unwrap();
    assert_ne!(a.meshes[0].mesh.positions, other.meshes[0].mesh.positions, "another seed, another city");
}

/// The metallic-roughness type: perceptual roughness squared to GGX α, metallic and ior
/// defaulting to 0 and 1.5.
#[test]
fn metallic_roughness_materials_load() {
    let text = format!(
        "{BASE}\n[materials.gold]\ntype = \"metallic-roughness\"\nbase_color = [1, 0.8, 0.3]\nmetallic = 1\nroughness = 0.5\n\
         \n[materials.plastic]\ntype = \"metallic-roughness\"\nbase_color = [0.2, 0.4, 0.6]\nior = 1.4\n"
    );
    let scene = Scene::parse(&text, "s.toml").unwrap_or_else(|e| panic!("{e}"));
    let by_name = |n: &str| &scene.materials.iter().find(|m| m.name == n).unwrap().scattering;
    assert_eq!(
        by_name("gold"),
        &Scattering::Coated { base_color: Vec3::new(1.0, 0.8, 0.3), metallic: 1.0, alpha: 0.25, ior: 1.5 }
    );
    assert_eq!(
        by_name("plastic"),
        &Scattering::Coated { base_color: Vec3::new(0.2, 0.4, 0.6), metallic: 0.0, alpha: 0.0, ior: 1.4 }
    );
}

#[test]
fn the_documented_animation_example_loads() {
    let doc = std::fs::read_to_string(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("docs/scene-format.md")).unwrap();
    let example =
        doc.split("```toml\n").find(|block| block.starts_with("[animation]")).expect("an [animation] example");
    let example = &example[..example.find("```").unwrap()];
    let scene = Scene::parse(&format!("{BASE}{example}"), "doc.toml").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.animation.as_ref().map(|a| (a.fps, a.frames.clone())), Some((24.0, 0..120)));
    assert_eq!(scene.objects.len(), 1 + 10_000);
    assert_eq!(scene.meshes.len(), 1);
    assert_eq!(scene.objects.iter().filter(|o| o.is_animated()).count(), 1 + 2000);
    let start = scene.objects[0].world_from_object_at(-1.0).transform_point3(Vec3::ZERO);
    assert!(close(start, Vec3::new(0.0, -0.7, 0.0)), "{start}");
}

#[test]
fn at_time_bakes_the_animation() {
    let scene = animated(
        "
[[objects]]
shape = \"box\"
material = \"white\"
rotate = [10, 0, 0]
[[objects.keyframes]]
time = 0
[[objects.keyframes]]
time = 2
translate = [1, 1, 0]
rotate = [0, 60, 0]
scale = 2

[[objects]]
shape = \"sphere\"
subdivisions = 1
material = \"white\"
[objects.scatter]
count = 20
min = [-1, -1, -1]
max = [1, 1, 1]
moving = 0.5
radius = 0.3
",
    );
    let t = scene.frame_time(31);
    let baked = scene.at_time(t);
    assert!(!baked.is_animated() && baked.animation.is_none());
    assert_eq!(baked.objects.len(), scene.objects.len());
    assert_eq!(baked.world_triangles(), scene.world_triangles_at(t));
    assert_ne!(scene.world_triangles_at(t), scene.world_triangles_at(0.0));
    assert_eq!(scene.world_triangles(), scene.world_triangles_at(0.0));
    assert_eq!(scene.at_time(0.0).world_triangles(), scene.world_triangles());
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
        (format!("{BASE}{obj}scale = 0\n"), 14, "objects[0].scale", "not 0"),
        (format!("{BASE}{obj}scale = [1, 0, 1]\n"), 14, "objects[0].scale", "not 0"),
        (format!("{BASE}\n[[objects]]\nmesh = \"nope.obj\"\n"), 12, "objects[0].mesh", "nope.obj"),
        (format!("{BASE}\n[[objects]]\nshape = \"box\"\nmaterial = \"chalk\"\n"), 13, "objects[0].material", "chalk"),
        (format!("{BASE}\n[[objects]]\nshape = \"cone\"\nmaterial = \"white\"\n"), 12, "objects[0].shape", "cone"),
        (format!("{BASE}\n[[objects]]\nshape = \"box\"\n"), 11, "objects[0].material", "needs a material"),
        (format!("{BASE}\n[[objects]]\nshape = \"city\"\nmaterial = \"white\"\n"), 12, "objects[0].triangles", "needs"),
        (
            format!("{BASE}\n[[objects]]\nshape = \"hairball\"\ntriangles = 0\nmaterial = \"white\"\n"),
            13,
            "objects[0].triangles",
            "1 to",
        ),
        (
            format!("{BASE}\n[[objects]]\nshape = \"city\"\ntriangles = 100000001\nmaterial = \"white\"\n"),
            13,
            "objects[0].triangles",
            "100000001",
        ),
        (format!("{BASE}{obj}triangles = 10\n"), 14, "objects[0].triangles", "procedural"),
        (format!("{BASE}{obj}seed = 3\n"), 14, "objects[0].seed", "procedural"),
        (
            format!("{BASE}\n[[objects]]\nshape = \"sphere\"\nsubdivisions = 20\nmaterial = \"white\"\n"),
            13,
            "objects[0].subdivisions",
            "20",
        ),
        (BASE.replace("[camera]", "[camera"), 1, "syntax", ""),
        (BASE.replace("fov = 40\n", ""), 1, "camera", "fov"),
        (BASE.replace("look_at = [0, 0, 0]", "look_at = [0, 0, 5]"), 3, "camera.look_at", "equals"),
        (BASE.replace("position = [0, 0, 5]", "position = [0, 0, 1e-23]"), 3, "camera.look_at", "1.00e-23 from"),
        (BASE.replace("fov = 40", "fov = 40\nfov = 50"), 5, "syntax", "duplicate key `fov`"),
        (format!("{BASE}\n[[objects]]\nmesh = \"\"\nmaterial = \"white\"\n"), 12, "objects[0].mesh", "is empty"),
        (
            BASE.replace("type = \"diffuse\"", "type = \"diffuse\"\nior = 1.5"),
            9,
            "materials.white.ior",
            "not a key of the `diffuse` material type",
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
            format!("{BASE}\n[materials.m]\ntype = \"conductor\"\neta = [1, 1, 1]\nk = [1e10, 1, 1]\n"),
            14,
            "materials.m.k",
            "real metals",
        ),
        (
            format!("{BASE}{obj}matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]]\n"),
            14,
            "objects[0].matrix",
            "invertible",
        ),
        (
            // Columns within rounding of each other: singular, at any scale.
            format!("{BASE}{obj}matrix = [[1e-6, 1e-6, 0, 0], [0, 1e-12, 0, 0], [0, 0, 1e-6, 0], [0, 0, 0, 1]]\n"),
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
        (
            format!("{BASE}\n[materials.m]\ntype = \"metallic-roughness\"\nbase_color = [1, 1, 1]\nmetallic = 1.5\n"),
            14,
            "materials.m.metallic",
            "[0, 1]",
        ),
        (
            format!("{BASE}\n[materials.m]\ntype = \"metallic-roughness\"\nbase_color = [1, 1, 1]\nroughness = -0.1\n"),
            14,
            "materials.m.roughness",
            "[0, 1]",
        ),
        (
            format!("{BASE}\n[materials.m]\ntype = \"metallic-roughness\"\nmetallic = 0.5\n"),
            11,
            "materials.m.base_color",
            "needs",
        ),
        (
            format!("{BASE}\n[materials.m]\ntype = \"metallic-roughness\"\nbase_color = [1, 1, 1]\neta = [1, 1, 1]\n"),
            14,
            "materials.m.eta",
            "not a key of the `metallic-roughness` material type",
        ),
        (
            format!("{BASE}\n[materials.m]\ntype = \"diffuse\"\nalbedo = [1, 1, 1]\nmetallic = 1\n"),
            14,
            "materials.m.metallic",
            "not a key of the `diffuse` material type",
        ),
        (
            format!("{BASE}\n[materials.m]\ntype = \"metallic-roughness\"\nbase_color = [1, 1, 1]\nior = 0\n"),
            14,
            "materials.m.ior",
            "> 0",
        ),
        (format!("{BASE}{obj}[render]\nmax_depth = 0\n"), 15, "render.max_depth", "at least 1"),
        (format!("{BASE}{obj}[environment]\nradiance = [1, 1]\n"), 15, "environment.radiance:", "length 3"),
        // [animation]
        (format!("{BASE}{obj}{ANIMATION}").replace("fps = 24", "fps = 0"), 16, "animation.fps", "> 0"),
        (format!("{BASE}{obj}{ANIMATION}").replace("fps = 24", "fps = -inf"), 16, "animation.fps", "inf"),
        (format!("{BASE}{obj}{ANIMATION}").replace("fps = 24\n", ""), 15, "animation.fps", "needs"),
        (format!("{BASE}{obj}{ANIMATION}").replace("[0, 96]", "[10, 10]"), 17, "animation.frames", "after the start"),
        (format!("{BASE}{obj}{ANIMATION}").replace("[0, 96]", "[10, -1]"), 17, "animation.frames[1]", "-1"),
        (format!("{BASE}{obj}{ANIMATION}speed = 2\n"), 18, "animation", "speed"),
        // keyframes
        (format!("{BASE}{obj}[[objects.keyframes]]\ntime = 0\n"), 14, "objects[0].keyframes", "[animation]"),
        (format!("{BASE}{obj}keyframes = []\n{ANIMATION}"), 14, "objects[0].keyframes", "empty"),
        (
            format!("{BASE}{obj}[[objects.keyframes]]\ntime = nan\n{ANIMATION}"),
            15,
            "objects[0].keyframes[0].time",
            "NaN",
        ),
        (
            format!("{BASE}{obj}[[objects.keyframes]]\ntranslate = [0, 1, 0]\n{ANIMATION}"),
            14,
            "objects[0].keyframes[0].time",
            "needs a `time`",
        ),
        (
            format!("{BASE}{obj}[[objects.keyframes]]\ntime = 2\n[[objects.keyframes]]\ntime = 1\n{ANIMATION}"),
            17,
            "objects[0].keyframes[1].time",
            "keyframe times must increase (previous 2, this 1)",
        ),
        (
            format!("{BASE}{obj}[[objects.keyframes]]\ntime = 2\n[[objects.keyframes]]\ntime = 2\n{ANIMATION}"),
            17,
            "objects[0].keyframes[1].time",
            "(previous 2, this 2)",
        ),
        (
            format!("{BASE}{obj}[[objects.keyframes]]\ntime = 0\nscale = [1, 0, 1]\n{ANIMATION}"),
            16,
            "objects[0].keyframes[0].scale",
            "not 0",
        ),
        (
            format!("{BASE}{obj}[[objects.keyframes]]\ntime = 0\nscale = 0\n{ANIMATION}"),
            16,
            "objects[0].keyframes[0].scale",
            "not 0",
        ),
        (
            format!(
                "{BASE}{obj}[[objects.keyframes]]\ntime = 0\nscale = [-1, 1, 1]\n[[objects.keyframes]]\ntime = 1\nscale = [1, 1, 1]\n{ANIMATION}"
            ),
            19,
            "objects[0].keyframes[1].scale",
            "mirrors differently from keyframes[0]'s",
        ),
        (
            format!(
                "{BASE}{obj}[[objects.keyframes]]\ntime = 0\nscale = -1\n[[objects.keyframes]]\ntime = 1\n{ANIMATION}"
            ),
            17,
            "objects[0].keyframes[1].scale",
            "a factor would pass through 0",
        ),
        (
            format!("{BASE}{obj}[[objects.keyframes]]\ntime = 0\ntranslate = [0, inf, 0]\n{ANIMATION}"),
            16,
            "objects[0].keyframes[0].translate",
            "finite",
        ),
        (
            format!("{BASE}{obj}[[objects.keyframes]]\ntime = 0\nrotate = [nan, 0, 0]\n{ANIMATION}"),
            16,
            "objects[0].keyframes[0].rotate",
            "finite",
        ),
        (
            format!("{BASE}{obj}[[objects.keyframes]]\ntime = 0\nspin = 1\n{ANIMATION}"),
            16,
            "objects[0].keyframes[0]",
            "spin",
        ),
        // scatter
        (scatter("count = 0\n"), 15, "objects[0].scatter.count", "1 to 10000000"),
        (scatter("count = 10000001\n"), 15, "objects[0].scatter.count", "1 to 10000000"),
        (scatter("count = -3\n"), 15, "objects[0].scatter.count", "-3"),
        (scatter("count = 5\nmax = [1, 1, 1]\n"), 14, "objects[0].scatter.min", "needs `min`"),
        (scatter("count = 5\nmin = [0, 2, 0]\nmax = [1, 1, 1]\n"), 16, "objects[0].scatter.min", "above max"),
        (scatter("count = 5\nmin = [0, nan, 0]\nmax = [1, 1, 1]\n"), 16, "objects[0].scatter.min", "finite"),
        (scatter(&format!("{SCATTER_BOX}moving = 1.5\n{ANIMATION}")), 18, "objects[0].scatter.moving", "[0, 1]"),
        (scatter(&format!("{SCATTER_BOX}moving = -0.1\n{ANIMATION}")), 18, "objects[0].scatter.moving", "[0, 1]"),
        (scatter(&format!("{SCATTER_BOX}period = 0\n{ANIMATION}")), 18, "objects[0].scatter.period", "> 0"),
        (scatter(&format!("{SCATTER_BOX}radius = -1\n{ANIMATION}")), 18, "objects[0].scatter.radius", ">= 0"),
        (scatter(&format!("{SCATTER_BOX}radius = inf\n{ANIMATION}")), 18, "objects[0].scatter.radius", "inf"),
        (scatter(&format!("{SCATTER_BOX}radius = 0.5\n")), 18, "objects[0].scatter.radius", "[animation]"),
        (scatter(&format!("{SCATTER_BOX}spread = 2\n")), 18, "objects[0].scatter", "spread"),
        (
            format!("{BASE}{obj}[[objects.keyframes]]\ntime = 0\n[objects.scatter]\ncount = 2\n{ANIMATION}"),
            16,
            "objects[0].scatter",
            "either `keyframes` or `scatter`",
        ),
    ]
}

/// `BASE`, a box, and its `[objects.scatter]` table (line 14) holding `keys` from line 15.
fn scatter(keys: &str) -> String {
    format!("{BASE}\n[[objects]]\nshape = \"box\"\nmaterial = \"white\"\n[objects.scatter]\n{keys}")
}

/// Scatter keys for lines 15 to 17.
const SCATTER_BOX: &str = "count = 5\nmin = [0, 0, 0]\nmax = [1, 1, 1]\n";

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

/// NaN and infinite vertex coordinates in an OBJ: `Scene::load` fails, and the message names
/// the scene file with the line and key of the object's `mesh`, the OBJ file, and the vertex
/// (by OBJ line and vertex number, or by object name and index).
#[test]
fn non_finite_obj_vertices_are_named() {
    for bad in ["nan", "inf", "-inf"] {
        let dir = common::temp_dir("nan-obj");
        // The bad vertex is the 7th `v` line of the file, the 4th of object `broken`.
        let obj = format!(
            "o good\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n\
             o broken\nv 0 0 1\nv 1 0 1\nv 0 1 1\nv 1 {bad} 1\nf 4 5 6\nf 5 7 6\nf 5 7 6\n"
        );
        std::fs::write(dir.join("broken.obj"), &obj).unwrap();
        let text = "[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n\n\
                    [materials.m]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\n\
                    [[objects]]\nmesh = \"broken.obj\"\nmaterial = \"m\"\n";
        let path = dir.join("scene.toml");
        std::fs::write(&path, text).unwrap();
        let e = Scene::load(&path).expect_err("a non-finite vertex must not load").to_string();
        eprintln!("{bad}: {e}");
        let scene_key = format!("{}:12: objects[0].mesh: ", path.display());
        assert!(e.starts_with(&scene_key), "{bad}: the error must start with {scene_key:?}: {e}");
        assert!(e.contains(&dir.join("broken.obj").display().to_string()), "{bad}: the error must name the OBJ: {e}");
        // Either form names the vertex unambiguously: the OBJ's line and the file's 1-based
        // vertex number, or the object's name and the vertex's 0-based index within it (in the
        // order its faces first use them).
        let by_line = e.contains("broken.obj:10: vertex 7");
        let by_object = e.contains("object `broken`") && e.contains("vertex 3");
        assert!(by_line || by_object, "{bad}: the error must locate the vertex: {e}");
    }
}

/// `nan` and `inf` (TOML allows both) in an object's transform: the error names the file, the
/// line and the key.
#[test]
fn non_finite_toml_numbers_are_named() {
    let base = "[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n\n\
                [materials.m]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\n\
                [[objects]]\nshape = \"box\"\nmaterial = \"m\"\n";
    let cases = [
        ("translate = [nan, 0, 0]", "objects[0].translate"),
        ("translate = [0, -inf, 0]", "objects[0].translate"),
        ("rotate = [0, 0, nan]", "objects[0].rotate"),
        ("scale = inf", "objects[0].scale"),
        ("scale = [1, nan, 1]", "objects[0].scale"),
        ("matrix = [[1, 0, 0, 0], [0, 1, 0, inf], [0, 0, 1, 0], [0, 0, 0, 1]]", "objects[0].matrix"),
    ];
    for (line, key) in cases {
        let dir = common::temp_dir("nan-toml");
        let path = dir.join("scene.toml");
        std::fs::write(&path, format!("{base}{line}\n")).unwrap();
        let e = Scene::load(&path).expect_err("a non-finite number must not load").to_string();
        eprintln!("{line}: {e}");
        let want = format!("{}:14: {key}:", path.display());
        assert!(e.starts_with(&want), "{line}: expected an error starting {want:?}, got {e}");
    }
}

/// Matrices are judged invertible by their shape, not their size: the Cornell box with every
/// matrix scaled by 10^-4 (determinants near 10^-13) loads, and places the same triangles scaled.
#[test]
fn small_objects_load_whatever_their_scale() {
    let text = std::fs::read_to_string(scenes_dir().join("cornell-box.toml")).unwrap();
    // Each matrix's first three rows, every entry times 10^-4 (the last row stays 0 0 0 1).
    let mut scaled = String::new();
    let mut rows_left = 0;
    for line in text.lines() {
        if line.starts_with("matrix = [") {
            rows_left = 3;
            scaled += line;
        } else if rows_left > 0 {
            rows_left -= 1;
            let inner = line.trim().trim_start_matches('[').trim_end_matches("],");
            let nums: Vec<String> =
                inner.split(',').map(|x| format!("{:e}", x.trim().parse::<f64>().unwrap() * 1e-4)).collect();
            scaled += &format!("  [{}],", nums.join(", "));
        } else {
            scaled += line;
        }
        scaled.push('\n');
    }
    let big = Scene::parse(&text, scenes_dir().join("cornell-box.toml")).unwrap();
    let small = Scene::parse(&scaled, scenes_dir().join("small.toml")).unwrap_or_else(|e| panic!("{e}"));
    let (a, _) = big.world_triangles();
    let (b, _) = small.world_triangles();
    assert_eq!(a.len(), b.len());
    for (ta, tb) in a.iter().zip(&b) {
        for (pa, pb) in [(ta.v0, tb.v0), (ta.v1, tb.v1), (ta.v2, tb.v2)] {
            assert!((pa * 1e-4 - pb).length() <= 1e-9 + 1e-6 * pb.length(), "{pa} x 1e-4 is not {pb}");
        }
    }
}

/// A mirroring matrix, or a negative scale (also in keyframes), places the mirror image with
/// each triangle's winding flipped, so that its front (the normal of `(v1 - v0) x (v2 - v0)`)
/// is the mirror image of the front the file gave.
#[test]
fn mirrors_keep_each_triangle_front() {
    let scene = |placement: &str| {
        let text = format!(
            "[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n\
             [materials.w]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\
             [[objects]]\nshape = \"box\"\nmaterial = \"w\"\n{placement}"
        );
        Scene::parse(&text, "mirror.toml").unwrap_or_else(|e| panic!("{placement}: {e}"))
    };
    let (plain, _) = scene("translate = [0.25, 0, 0]\n").world_triangles();
    let mirror = |p: Vec3| Vec3::new(-p.x, p.y, p.z);
    for placement in [
        "matrix = [[-1, 0, 0, -0.25], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n",
        "scale = [-1, 1, 1]\ntranslate = [-0.25, 0, 0]\n",
    ] {
        let (mirrored, _) = scene(placement).world_triangles();
        assert_eq!(plain.len(), mirrored.len());
        for (t, m) in plain.iter().zip(&mirrored) {
            let expected = mirror(t.normal()).normalize();
            assert!((m.normal().normalize() - expected).length() < 1e-5, "{placement}: {m:?} against {t:?}");
            // A box is closed: every front still faces out, away from its centre (-0.25, 0, 0).
            let centre = (m.v0 + m.v1 + m.v2) / 3.0 - Vec3::new(-0.25, 0.0, 0.0);
            assert!(m.normal().dot(centre) > 0.0, "{placement}: a face turned inwards");
        }
    }
}

/// Radiance above 2^40 is refused at load, naming the file, the line and the key (and the MTL
/// file and its line): an emitter's radiance, an emission texture's brightest texel times the
/// radiance it multiplies, an MTL `Ke`, a constant sky, a sky map's texels times its `scale`.
/// The film drops every sample above 2^44, so such a scene rendered black with exit code 0.
/// Exactly 2^40 loads.
#[test]
fn radiance_above_two_to_the_forty_is_refused() {
    use arbor::image_io::{Image, write_image};
    let dir = temp_dir("radiance");
    let mut hot = Image::new(4, 2);
    hot.pixels[5] = [1.0, 3e38, 1.0];
    write_image(dir.join("hot.exr"), &hot).unwrap();
    let mut warm = Image::new(4, 2);
    warm.pixels[2] = [2e6, 0.5, 0.5];
    write_image(dir.join("warm.exr"), &warm).unwrap();
    std::fs::write(dir.join("ke.obj"), "mtllib ke.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl glow\nf 1 2 3\n").unwrap();
    std::fs::write(dir.join("ke.mtl"), "newmtl glow\nKd 0.5 0.5 0.5\nKe 1e38 1 1\n").unwrap();
    let head = "[camera]\nposition = [0, 0, 4]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n\n";
    let lamp = |keys: &str| {
        format!(
            "{head}[materials.lamp]\ntype = \"emissive\"\n{keys}\n[[objects]]\nshape = \"quad\"\nmaterial = \"lamp\"\n"
        )
    };
    let sky = |keys: &str| {
        format!(
            "{head}[environment]\n{keys}\n[[objects]]\nmesh = \"ke.obj\"\nmaterial = \"x\"\n[materials.x]\ntype = \"diffuse\"\nalbedo = [1, 1, 1]\n"
        )
    };
    // (scene, line, key, words)
    let cases: Vec<(String, usize, &str, &[&str])> = vec![
        (lamp("radiance = [3e38, 1, 1]\n"), 9, "materials.lamp.radiance", &["2^40"]),
        (
            lamp("radiance = [1, 1, 1]\nemission_texture = \"hot.exr\"\n"),
            10,
            "materials.lamp.emission_texture",
            &["hot.exr", "2^40"],
        ),
        // Each below the limit, their product above it.
        (
            lamp("radiance = [1e7, 1, 1]\nemission_texture = \"warm.exr\"\n"),
            10,
            "materials.lamp.emission_texture",
            &["warm.exr", "2^40"],
        ),
        (format!("{head}[[objects]]\nmesh = \"ke.obj\"\n"), 8, "objects[0].mesh", &["ke.mtl:3", "Ke", "2^40"]),
        (sky("radiance = [3e38, 3e38, 3e38]\n"), 8, "environment.radiance", &["2^40"]),
        (sky("map = \"warm.exr\"\nscale = 1e38\n"), 9, "environment.scale", &["warm.exr", "2^40"]),
        (sky("map = \"hot.exr\"\n"), 8, "environment.map", &["hot.exr", "(1, 1)", "2^40"]),
    ];
    let mut failures = Vec::new();
    for (k, (text, line, key, words)) in cases.iter().enumerate() {
        let path = dir.join(format!("r{k}.toml"));
        std::fs::write(&path, text).unwrap();
        let err = match Scene::load(&path) {
            Ok(_) => {
                failures.push(format!("case {k} ({key}) loaded"));
                continue;
            }
            Err(e) => e.to_string(),
        };
        let prefix = format!("{}:{line}: {key}: ", path.display());
        if !err.starts_with(&prefix) || !words.iter().all(|w| err.contains(w)) {
            failures.push(format!("case {k}: expected `{prefix}` and {words:?}, got `{err}`"));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    // At the limit: loads.
    let limit = 2f32.powi(40);
    std::fs::write(dir.join("at.toml"), lamp(&format!("radiance = [{limit:?}, 1, 1]\n"))).unwrap();
    let scene = Scene::load(dir.join("at.toml")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.materials[0].emission, Some(Vec3::new(limit, 1.0, 1.0)));
}
