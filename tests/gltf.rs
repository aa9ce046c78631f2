//! glTF 2.0 files in scenes: a hand-written document of nodes sharing one mesh (a TRS node, a
//! matrix node and a mirroring node under a translated parent) places the right world
//! triangles, identically from a `.gltf` with a data URI, a `.gltf` with a `.bin` file and a
//! `.glb`; normals and texture coordinates (v flipped) come through; strips, fans and every
//! index type give the documented triangles; interleaved, normalized, sparse and unbacked
//! accessors are read, unknown attributes ignored; materials map as documented, the reader keeping their
//! full description; a camera comes from the file; scatter and keyframes move a file's nodes as
//! one; `extras` may be any JSON value; a buffer's file is read only as far as its `byteLength`;
//! and every kind of bad file is an error that names the scene file, line and key, the glTF
//! file, and the place in it.

use crate::common::gltf::{BYTE, Doc, FLOAT, UNSIGNED_BYTE, UNSIGNED_INT, UNSIGNED_SHORT, triangle_doc};

use std::path::{Path, PathBuf};

use arbor::scene::gltf::{GltfFile, GltfImageSource, WrapMode};
use arbor::scene::{Animation, Scattering, Scene};
use glam::{Vec2, Vec3};
use serde_json::json;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("arbor-gltf-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

const CAMERA: &str = "[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n";

/// Writes `files` into `dir` and the scene `CAMERA` + `objects` as `s.toml`; loads it.
fn load(dir: &Path, files: &[(&str, &[u8])], scene: &str) -> Result<Scene, String> {
    for (name, bytes) in files {
        std::fs::write(dir.join(name), bytes).unwrap();
    }
    std::fs::write(dir.join("s.toml"), scene).unwrap();
    Scene::load(dir.join("s.toml")).map_err(|e| e.to_string())
}

fn object(file: &str) -> String {
    format!("{CAMERA}\n[[objects]]\nmesh = \"{file}\"\n")
}

/// The hierarchy of the first test: a parent translated by (10, 0, 0) over three nodes placing
/// mesh 0 (TRS, matrix, mirror), and a camera node at the root, turned 90° about y.
fn hierarchy() -> Doc {
    let mut d = triangle_doc();
    let s = std::f32::consts::FRAC_1_SQRT_2;
    let trs = d.node(
        json!({ "name": "TRS", "mesh": 0, "translation": [0, 1, 0], "rotation": [0, 0, s, s], "scale": [2, 2, 2] }),
        false,
    );
    let matrix = d.node(
        json!({ "name": "Matrix", "mesh": 0, "matrix": [1, 0, 0, 0, 0, 3, 0, 0, 0, 0, 1, 0, 0, 0, 5, 1] }),
        false,
    );
    let mirror = d.node(json!({ "name": "Mirror", "mesh": 0, "scale": [-1, 1, 1] }), false);
    d.node(json!({ "name": "Parent", "translation": [10, 0, 0], "children": [trs, matrix, mirror] }), true);
    d.push("cameras", json!({ "type": "perspective", "name": "Lens", "perspective": { "yfov": 0.5, "znear": 0.1 } }));
    d.node(json!({ "name": "Camera", "camera": 0, "translation": [0, 0, 10], "rotation": [0, s, 0, s] }), true);
    d
}

fn assert_close(got: Vec3, want: Vec3, what: &str) {
    assert!((got - want).abs().max_element() <= 1e-6, "{what}: {got} vs {want}");
}

#[test]
fn nodes_sharing_a_mesh_place_the_right_world_triangles() {
    let dir = temp_dir("hierarchy");
    let d = hierarchy();
    let scene = load(&dir, &[("m.gltf", &d.gltf_embedded())], &format!("{}translate = [0, 0, -1]\n", object("m.gltf")))
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.meshes.len(), 1, "one glTF mesh, one scene mesh");
    assert_eq!(scene.objects.len(), 3);
    assert!(scene.objects.iter().all(|o| o.mesh == 0), "the three nodes share the mesh");
    let (tris, _) = scene.world_triangles();
    // By hand: the object's translate (0, 0, -1), then the parent's (10, 0, 0), then each node.
    let want = [
        // TRS: scale 2, 90° about z ((x, y) -> (-y, x)), + (0, 1, 0).
        [Vec3::new(10.0, 1.0, -1.0), Vec3::new(10.0, 3.0, -1.0), Vec3::new(8.0, 1.0, -1.0)],
        // Matrix: y × 3, + (0, 0, 5).
        [Vec3::new(10.0, 0.0, 4.0), Vec3::new(11.0, 0.0, 4.0), Vec3::new(10.0, 3.0, 4.0)],
        // Mirror: x -> -x; the winding turns, so the second and third vertices swap.
        [Vec3::new(10.0, 0.0, -1.0), Vec3::new(10.0, 1.0, -1.0), Vec3::new(9.0, 0.0, -1.0)],
    ];
    for (k, (t, w)) in tris.iter().zip(want).enumerate() {
        for (got, want) in [t.v0, t.v1, t.v2].into_iter().zip(w) {
            assert_close(got, want, &format!("object {k}"));
        }
    }
    // The mirror keeps the front where the file put it: +z in the file, still +z.
    assert!(tris[2].normal().z > 0.0 && tris[0].normal().z > 0.0);
    let m = &scene.meshes[0].mesh;
    assert_eq!(m.normals, vec![Vec3::Z; 3]);
    assert_eq!(m.uvs, vec![Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(0.0, 0.0)], "v' = 1 - v");
}

#[test]
fn gltf_with_a_bin_file_and_glb_load_identically() {
    let dir = temp_dir("containers");
    let d = hierarchy();
    let (gltf, bin) = d.gltf_external("my buffer.bin");
    let gltf = String::from_utf8(gltf).unwrap().replace("my buffer.bin", "my%20buffer.bin");
    let files: [(&str, &[u8]); 4] =
        [("e.gltf", &d.gltf_embedded()), ("x.gltf", gltf.as_bytes()), ("my buffer.bin", &bin), ("b.GLB", &d.glb())];
    let mut loaded = Vec::new();
    for name in ["e.gltf", "x.gltf", "b.GLB"] {
        let scene = load(&dir, &files, &object(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let meshes: Vec<_> = scene.meshes.iter().map(|m| (m.mesh.clone(), m.material_ids.clone())).collect();
        loaded.push((meshes, scene.objects.clone()));
    }
    assert!(loaded[0] == loaded[1] && loaded[1] == loaded[2]);
}

#[test]
fn two_objects_naming_one_file_share_its_meshes() {
    let dir = temp_dir("shared");
    let scene_text = format!("{}\n[[objects]]\nmesh = \"./m.glb\"\ntranslate = [0, 5, 0]\n", object("m.glb"));
    let scene = load(&dir, &[("m.glb", &hierarchy().glb())], &scene_text).unwrap();
    assert_eq!((scene.meshes.len(), scene.objects.len()), (1, 6));
    // The file's material (the default one) is added once.
    assert_eq!(scene.materials.len(), 1);
    assert_eq!(scene.materials[0].name, "m/default");
}

#[test]
fn strips_fans_and_index_types_give_the_documented_triangles() {
    let dir = temp_dir("topology");
    let mut d = Doc::new();
    let p = d.floats(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0], "VEC3");
    for component in [UNSIGNED_BYTE, UNSIGNED_SHORT, UNSIGNED_INT] {
        let i = d.indices(&[0, 1, 2, 2, 1, 3], component);
        d.mesh(&[("POSITION", p)], Some(i), None);
    }
    let strip = d.indices(&[0, 1, 2, 3], UNSIGNED_SHORT);
    d.mesh(&[("POSITION", p)], Some(strip), Some(5));
    d.mesh(&[("POSITION", p)], Some(strip), Some(6));
    // No indices: the vertices in order.
    d.mesh(&[("POSITION", p)], None, Some(5));
    // A strip with a repeated vertex (its degenerate triangles dropped).
    let joined = d.indices(&[0, 1, 2, 2, 3, 1], UNSIGNED_INT);
    d.mesh(&[("POSITION", p)], Some(joined), Some(5));
    // Points and lines: no triangles.
    d.mesh(&[("POSITION", p)], None, Some(0));
    d.mesh(&[("POSITION", p)], Some(strip), Some(1));
    for m in 0..d.json["meshes"].as_array().unwrap().len() {
        d.node(json!({ "mesh": m }), true);
    }
    std::fs::write(dir.join("t.gltf"), d.gltf_embedded()).unwrap();
    let file = GltfFile::open(dir.join("t.gltf")).unwrap_or_else(|e| panic!("{e}"));
    let tris = |m: usize| file.mesh(m).unwrap().mesh.indices;
    for m in 0..3 {
        assert_eq!(tris(m), vec![[0, 1, 2], [2, 1, 3]], "index type of mesh {m}");
    }
    // glTF 3.7.2.1: strip triangle i is (i, i + 1 + i % 2, i + 2 - i % 2); fan (i + 1, i + 2, 0).
    assert_eq!(tris(3), vec![[0, 1, 2], [1, 3, 2]]);
    assert_eq!(tris(4), vec![[1, 2, 0], [2, 3, 0]]);
    assert_eq!(tris(5), vec![[0, 1, 2], [1, 3, 2]]);
    assert_eq!(tris(6), vec![[0, 1, 2], [2, 1, 3]], "the degenerate triangles are dropped");
    assert!(tris(7).is_empty() && tris(8).is_empty());
    // Strip windings alternate as the spec says: every triangle faces +z, as the plain ones do.
    for m in [3, 5, 6] {
        let mesh = file.mesh(m).unwrap().mesh;
        assert!(mesh.triangles().iter().all(|t| t.normal().z > 0.0), "mesh {m}");
    }
}

#[test]
fn interleaved_normalized_and_sparse_accessors_are_read() {
    let dir = temp_dir("accessors");
    let mut d = Doc::new();
    // Interleaved: position (12 bytes) then a u16 normalized uv (4 bytes), stride 16.
    let mut bytes = Vec::new();
    for (p, uv) in [([0f32, 0.0, 0.0], [0u16, 65535]), ([1.0, 0.0, 0.0], [65535, 0]), ([0.0, 1.0, 0.0], [0, 0])] {
        bytes.extend(p.iter().flat_map(|x| x.to_le_bytes()));
        bytes.extend(uv.iter().flat_map(|x| x.to_le_bytes()));
    }
    let view = d.view(&bytes, Some(16));
    let p = d.accessor(view, FLOAT, 3, "VEC3");
    let t = d.push(
        "accessors",
        json!({ "bufferView": view, "byteOffset": 12, "componentType": UNSIGNED_SHORT, "normalized": true, "count": 3, "type": "VEC2" }),
    );
    // Sparse: vertex 2 of the positions moved to (0, 2, 0).
    let si = d.view(&[2u8], None);
    let sv = d.view(&[0f32, 2.0, 0.0].iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>(), None);
    let sparse = d.push(
        "accessors",
        json!({ "bufferView": view, "componentType": FLOAT, "count": 3, "type": "VEC3",
                "sparse": { "count": 1, "indices": { "bufferView": si, "componentType": UNSIGNED_BYTE }, "values": { "bufferView": sv } } }),
    );
    // A sparse accessor without a buffer view: zeros, then the replaced elements.
    let zeros = d.push(
        "accessors",
        json!({ "componentType": FLOAT, "count": 3, "type": "VEC3",
                "sparse": { "count": 1, "indices": { "bufferView": si, "componentType": UNSIGNED_BYTE }, "values": { "bufferView": sv } } }),
    );
    // No buffer view and not sparse: zeros (glTF 3.6.2.1), which gltf-json alone would refuse.
    let plain_zeros = d.push("accessors", json!({ "componentType": FLOAT, "count": 3, "type": "VEC3" }));
    // An application's own attribute (`_NAME`) is ignored.
    d.mesh(&[("POSITION", p), ("TEXCOORD_0", t), ("_BATCHID", t)], None, None);
    d.mesh(&[("POSITION", sparse)], None, None);
    d.mesh(&[("POSITION", zeros)], None, None);
    d.mesh(&[("POSITION", plain_zeros)], None, None);
    std::fs::write(dir.join("a.gltf"), d.gltf_embedded()).unwrap();
    let file = GltfFile::open(dir.join("a.gltf")).unwrap_or_else(|e| panic!("{e}"));
    let m = file.mesh(0).unwrap().mesh;
    assert_eq!(m.positions, vec![Vec3::ZERO, Vec3::X, Vec3::Y]);
    assert_eq!(m.uvs, vec![Vec2::new(0.0, 0.0), Vec2::new(1.0, 1.0), Vec2::new(0.0, 1.0)], "u16 / 65535, v' = 1 - v");
    assert_eq!(file.mesh(1).unwrap().mesh.positions, vec![Vec3::ZERO, Vec3::X, Vec3::new(0.0, 2.0, 0.0)]);
    assert_eq!(file.mesh(2).unwrap().mesh.positions, vec![Vec3::ZERO, Vec3::ZERO, Vec3::new(0.0, 2.0, 0.0)]);
    assert_eq!(file.mesh(3).unwrap().mesh.positions, vec![Vec3::ZERO; 3]);
}

#[test]
fn materials_map_as_documented_and_the_reader_keeps_their_description() {
    let dir = temp_dir("materials");
    let mut d = triangle_doc();
    let p = d.json["meshes"][0]["primitives"][0]["attributes"]["POSITION"].clone();
    d.push("images", json!({ "uri": "tex%20a.png" }));
    d.push("samplers", json!({ "wrapS": 33071, "wrapT": 33648, "magFilter": 9728 }));
    d.push("textures", json!({ "source": 0, "sampler": 0 }));
    d.push(
        "materials",
        json!({ "name": "paint", "pbrMetallicRoughness": { "baseColorFactor": [0.2, 0.4, 0.6, 1], "metallicFactor": 0.2,
                  "baseColorTexture": { "index": 0, "texCoord": 1 } },
                "emissiveFactor": [1, 0.5, 0], "doubleSided": true,
                "extensions": { "KHR_materials_emissive_strength": { "emissiveStrength": 4 } },
                "normalTexture": { "index": 0, "scale": 0.7 }, "alphaMode": "MASK", "alphaCutoff": 0.3 }),
    );
    d.push(
        "materials",
        json!({ "pbrMetallicRoughness": { "baseColorFactor": [0.9, 0.8, 0.3, 1], "metallicFactor": 0.9, "roughnessFactor": 0.5 } }),
    );
    d.json["meshes"][0]["primitives"][0]["material"] = json!(0);
    let one = d.json["meshes"][0]["primitives"][0].clone();
    let mut metal = one.clone();
    metal["material"] = json!(1);
    let mut default = json!({ "attributes": { "POSITION": p } });
    default["mode"] = json!(4);
    d.json["meshes"][0]["primitives"] = json!([one, metal, default]);
    d.node(json!({ "mesh": 0 }), true);
    // The image the normal texture reads (the base colour texture reads set 1, which is left out).
    let mut png = Vec::new();
    image::RgbaImage::from_raw(1, 1, vec![128, 128, 255, 255])
        .unwrap()
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageOutputFormat::Png)
        .unwrap();
    let files: [(&str, &[u8]); 2] = [("lamp.glb", &d.glb()), ("tex a.png", &png)];
    let scene = load(&dir, &files, &object("lamp.glb")).unwrap_or_else(|e| panic!("{e}"));
    let names: Vec<&str> = scene.materials.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(names, ["lamp/paint", "lamp/1", "lamp/default"]);
    let t = &scene.materials[0].textures;
    assert!(t.base_color.is_none() && t.normal.is_some() && t.normal_scale == 0.7, "{t:?}");
    let ids = &scene.meshes[0].material_ids;
    assert_eq!(ids, &[0, 1, 2]);
    let paint = &scene.materials[0];
    assert_eq!(
        paint.scattering,
        Scattering::Coated { base_color: Vec3::new(0.2, 0.4, 0.6), metallic: 0.2, alpha: 1.0, ior: 1.5 },
        "the coated metallic-roughness material of the factors; roughnessFactor defaults to 1"
    );
    assert_eq!(paint.emission, Some(Vec3::new(4.0, 2.0, 0.0)), "emissiveFactor × emissiveStrength");
    assert!(paint.two_sided, "doubleSided emits from both sides");
    assert_eq!(
        scene.materials[1].scattering,
        Scattering::Coated { base_color: Vec3::new(0.9, 0.8, 0.3), metallic: 0.9, alpha: 0.25, ior: 1.5 },
        "GGX α = roughnessFactor²"
    );
    assert_eq!(
        scene.materials[2].scattering,
        Scattering::Coated { base_color: Vec3::ONE, metallic: 1.0, alpha: 1.0, ior: 1.5 },
        "the spec's default material"
    );
    assert_eq!((scene.materials[1].emission, scene.materials[1].two_sided), (None, false));
    // The reader keeps each material's full description.
    let file = GltfFile::open(dir.join("lamp.glb")).unwrap();
    assert_eq!(file.materials.len(), 2);
    let g = &file.materials[0];
    let base = g.base_color_texture.as_ref().unwrap();
    assert_eq!(
        (base.tex_coord, base.sampler.wrap_s, base.sampler.wrap_t),
        (1, WrapMode::ClampToEdge, WrapMode::MirroredRepeat)
    );
    match &base.source {
        GltfImageSource::File { path, .. } => assert_eq!(path, &dir.join("tex a.png")),
        other => panic!("{other:?}"),
    }
    let (normal, scale) = g.normal_texture.as_ref().unwrap();
    assert_eq!((normal.texture, *scale), (0, 0.7));
    assert_eq!((g.alpha_mode, g.alpha_cutoff), (arbor::scene::gltf::AlphaMode::Mask, 0.3));
    // An object's own material overrides the file's, as for OBJ.
    let with = format!(
        "{CAMERA}\n[materials.w]\ntype = \"diffuse\"\nalbedo = [1, 1, 1]\n\n[[objects]]\nmesh = \"lamp.glb\"\nmaterial = \"w\"\n"
    );
    let scene = load(&dir, &[], &with).unwrap();
    assert_eq!(scene.objects[0].material, Some(0));
}

#[test]
fn a_camera_comes_from_the_file() {
    let dir = temp_dir("camera");
    std::fs::write(dir.join("m.gltf"), hierarchy().gltf_embedded()).unwrap();
    let text = |camera: &str| format!("[camera]\n{camera}resolution = [32, 16]\n\n[[objects]]\nmesh = \"m.gltf\"\n");
    for camera in
        ["from = \"m.gltf\"\n", "from = \"m.gltf\"\nname = \"Camera\"\n", "from = \"m.gltf\"\nname = \"Lens\"\n"]
    {
        std::fs::write(dir.join("s.toml"), text(camera)).unwrap();
        let c = Scene::load(dir.join("s.toml")).unwrap_or_else(|e| panic!("{e}")).camera;
        assert_close(c.position, Vec3::new(0.0, 0.0, 10.0), "position");
        // 90° about y turns the node's -z to -x.
        assert_close((c.look_at - c.position).normalize(), Vec3::NEG_X, "view direction");
        assert_close(c.up, Vec3::Y, "up");
        assert!((c.fov_y_degrees - 0.5f32.to_degrees()).abs() < 1e-4, "{}", c.fov_y_degrees);
        assert_eq!((c.width, c.height, c.aperture), (32, 16, 0.0));
        assert!(c.focus_distance > 0.0);
    }
    // A thin lens needs its distance in focus, which the file does not give.
    std::fs::write(dir.join("s.toml"), text("from = \"m.gltf\"\naperture = 0.1\nfocus_distance = 7\n")).unwrap();
    let c = Scene::load(dir.join("s.toml")).unwrap().camera;
    assert_eq!((c.aperture, c.focus_distance), (0.1, 7.0));
}

#[test]
fn scatter_and_keyframes_move_a_files_nodes_as_one() {
    let dir = temp_dir("scatter");
    let scene_text = format!("{}[objects.scatter]\ncount = 2\nmin = [-5, 0, -5]\nmax = [5, 0, 5]\n", object("m.glb"));
    let scene = load(&dir, &[("m.glb", &hierarchy().glb())], &scene_text).unwrap();
    assert_eq!(scene.objects.len(), 6);
    let file = GltfFile::open(dir.join("m.glb")).unwrap();
    for instance in scene.objects.chunks(3) {
        // One placement per instance: instance × node world, the same for the three nodes.
        let placement = instance[0].world_from_object * file.instances[0].world_from_object.inverse();
        for (o, node) in instance.iter().zip(&file.instances) {
            let want = placement * node.world_from_object;
            assert!(o.world_from_object.abs_diff_eq(want, 1e-4), "{} vs {want}", o.world_from_object);
        }
    }
    let keyed = format!(
        "{CAMERA}\n[animation]\nfps = 24\nframes = [0, 24]\n\n[[objects]]\nmesh = \"m.glb\"\n[[objects.keyframes]]\ntime = 0\n[[objects.keyframes]]\ntime = 1\ntranslate = [0, 2, 0]\n"
    );
    let scene = load(&dir, &[], &keyed).unwrap();
    assert_eq!(scene.objects.len(), 3);
    assert!(scene.objects.iter().all(|o| matches!(&o.animation, Some(Animation::Keyframes(k)) if k.len() == 2)));
}

// ---------------------------------------------------------------------------------------------
// Errors: each names the scene file, line and key, then the glTF file and the place in it.

/// Loads `OBJECT` (line 8 of the scene, key `objects[0].mesh`) naming `file` written from
/// `bytes`, and returns the error after `s.toml:8: objects[0].mesh: <dir>/<file>: `.
fn mesh_error(name: &str, file: &str, files: &[(&str, &[u8])]) -> String {
    let dir = temp_dir(name);
    let err = load(&dir, files, &object(file)).map(|_| ()).unwrap_err();
    let prefix = format!("{}:8: objects[0].mesh: {}: ", dir.join("s.toml").display(), dir.join(file).display());
    err.strip_prefix(&prefix).unwrap_or_else(|| panic!("{name}: not `{prefix}...`: {err}")).to_owned()
}

fn assert_says(name: &str, rest: &str, place: &str, words: &str) {
    assert!(rest.starts_with(place) && rest.contains(words), "{name}: want `{place}...{words}`, got: {rest}");
}

/// `triangle_doc` with one node, with `change` applied to its JSON.
fn doc_with(change: impl FnOnce(&mut Doc)) -> Doc {
    let mut d = triangle_doc();
    d.node(json!({ "mesh": 0 }), true);
    change(&mut d);
    d
}

#[test]
fn missing_and_unreadable_files_are_errors() {
    let dir = temp_dir("missing");
    let err = load(&dir, &[], &object("nope.glb")).unwrap_err();
    assert!(err.contains("s.toml:8: objects[0].mesh:") && err.contains("nope.glb: cannot read"), "{err}");
    let (gltf, _) = doc_with(|_| {}).gltf_external("gone.bin");
    let rest = mesh_error("missing-bin", "m.gltf", &[("m.gltf", &gltf)]);
    assert_says("missing .bin", &rest, "buffers[0].uri: ", "gone.bin: cannot read");
    let (gltf, bin) = doc_with(|_| {}).gltf_external("short.bin");
    let rest = mesh_error("short-bin", "m.gltf", &[("m.gltf", &gltf), ("short.bin", &bin[..10])]);
    assert_says("short .bin", &rest, "buffers[0]: ", "holds only 10 bytes");
    let bad64 = String::from_utf8(doc_with(|_| {}).gltf_embedded()).unwrap().replace(";base64,", ";base64,@@");
    let rest = mesh_error("base64", "m.gltf", &[("m.gltf", bad64.as_bytes())]);
    assert_says("bad base64", &rest, "buffers[0].uri: ", "base64");
}

#[test]
fn broken_glb_containers_are_errors_at_their_byte() {
    let glb = doc_with(|_| {}).glb();
    let rest = mesh_error("truncated", "m.glb", &[("m.glb", &glb[..glb.len() - 5])]);
    assert_says("truncated", &rest, "byte 8: ", "truncated");
    let mut magic = glb.clone();
    magic[3] = b'X';
    let rest = mesh_error("magic", "m.glb", &[("m.glb", &magic)]);
    assert_says("bad magic", &rest, "byte 0: ", "not a GLB file");
    let mut version = glb.clone();
    version[4] = 1;
    let rest = mesh_error("version", "m.glb", &[("m.glb", &version)]);
    assert_says("version 1", &rest, "byte 4: ", "version 1");
    let mut chunk = glb.clone();
    chunk[12..16].copy_from_slice(&(glb.len() as u32).to_le_bytes());
    let rest = mesh_error("chunk", "m.glb", &[("m.glb", &chunk)]);
    assert_says("chunk past the end", &rest, "byte 12: ", "runs past the end");
}

#[test]
fn json_syntax_errors_name_line_and_column() {
    let text = String::from_utf8(doc_with(|_| {}).gltf_embedded()).unwrap();
    let broken = text.replacen("\"asset\":", "\"asset\": :", 1);
    let line = text[..text.find("\"asset\"").unwrap()].matches('\n').count() + 1;
    let rest = mesh_error("syntax", "m.gltf", &[("m.gltf", broken.as_bytes())]);
    assert_says("syntax", &rest, &format!("line {line}, column "), "expected value");
}

#[test]
fn accessors_past_their_data_are_errors_and_allocate_nothing() {
    let short = doc_with(|d| d.json["accessors"][0]["count"] = json!(4));
    let rest = mesh_error("past", "m.gltf", &[("m.gltf", &short.gltf_embedded())]);
    assert_says(
        "past the view",
        &rest,
        "meshes[0].primitives[0].attributes.POSITION: accessor 0: ",
        "reads past the end of bufferViews[0]",
    );
    // 10^12 elements: refused from the view's size, before anything is allocated.
    let huge = doc_with(|d| d.json["accessors"][3]["count"] = json!(1_000_000_000_000u64));
    let rest = mesh_error("huge", "m.glb", &[("m.glb", &huge.glb())]);
    assert_says("huge count", &rest, "meshes[0].primitives[0].indices: accessor 3: ", "1000000000000 elements");
    let unbacked = doc_with(|d| {
        d.json["accessors"][0].as_object_mut().unwrap().remove("bufferView");
        d.json["accessors"][0]["count"] = json!(1u64 << 40);
    });
    let rest = mesh_error("unbacked", "m.glb", &[("m.glb", &unbacked.glb())]);
    assert_says(
        "huge count, no view",
        &rest,
        "meshes[0].primitives[0].attributes.POSITION: accessor 0: ",
        "no bufferView",
    );
    let view = doc_with(|d| d.json["bufferViews"][0]["byteLength"] = json!(1000));
    let rest = mesh_error("view", "m.glb", &[("m.glb", &view.glb())]);
    assert_says("view past the buffer", &rest, "bufferViews[0]: ", "past the end of buffer 0");
}

#[test]
fn bad_indices_and_attributes_are_errors_naming_the_accessor() {
    let mut d = doc_with(|_| {});
    let i = d.indices(&[0, 1, 7], UNSIGNED_INT);
    d.json["meshes"][0]["primitives"][0]["indices"] = json!(i);
    let rest = mesh_error("index", "m.gltf", &[("m.gltf", &d.gltf_embedded())]);
    assert_says(
        "index out of range",
        &rest,
        &format!("meshes[0].primitives[0].indices: accessor {i}: "),
        "is 7, but POSITION has 3 vertices",
    );
    let shorts = doc_with(|d| d.json["accessors"][0]["componentType"] = json!(UNSIGNED_SHORT));
    let rest = mesh_error("component", "m.gltf", &[("m.gltf", &shorts.gltf_embedded())]);
    assert_says(
        "POSITION of shorts",
        &rest,
        "meshes[0].primitives[0].attributes.POSITION: accessor 0: ",
        "UNSIGNED_SHORT",
    );
    let bytes = doc_with(|d| d.json["accessors"][2]["componentType"] = json!(BYTE));
    let rest = mesh_error("uv-type", "m.gltf", &[("m.gltf", &bytes.gltf_embedded())]);
    assert_says(
        "TEXCOORD_0 of signed bytes",
        &rest,
        "meshes[0].primitives[0].attributes.TEXCOORD_0: accessor 2: ",
        "BYTE",
    );
    let vec2 = doc_with(|d| d.json["accessors"][0]["type"] = json!("VEC2"));
    let rest = mesh_error("dims", "m.gltf", &[("m.gltf", &vec2.gltf_embedded())]);
    assert_says("POSITION of VEC2", &rest, "meshes[0].primitives[0].attributes.POSITION: accessor 0: ", "2 components");
    let none = doc_with(|d| {
        d.json["meshes"][0]["primitives"][0]["attributes"].as_object_mut().unwrap().remove("POSITION");
    });
    let rest = mesh_error("no-position", "m.gltf", &[("m.gltf", &none.gltf_embedded())]);
    assert_says("no POSITION", &rest, "meshes[0].primitives[0].attributes.POSITION: ", "missing");
    let nowhere = doc_with(|d| d.json["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = json!(99));
    let rest = mesh_error("no-accessor", "m.gltf", &[("m.gltf", &nowhere.gltf_embedded())]);
    assert_says(
        "POSITION accessor 99",
        &rest,
        "meshes[0].primitives[0].attributes.POSITION: ",
        "accessor 99 does not exist",
    );
    let odd = doc_with(|d| d.json["accessors"][3]["count"] = json!(2));
    let rest = mesh_error("odd", "m.gltf", &[("m.gltf", &odd.gltf_embedded())]);
    assert_says("2 indices", &rest, "meshes[0].primitives[0]: ", "not a multiple of 3");
    let mut nan = doc_with(|_| {});
    nan.bin[4..8].copy_from_slice(&f32::NAN.to_le_bytes());
    let rest = mesh_error("nan", "m.glb", &[("m.glb", &nan.glb())]);
    assert_says("NaN position", &rest, "meshes[0].primitives[0].attributes.POSITION: accessor 0: ", "element 0");
    let mut sparse = doc_with(|_| {});
    let si = sparse.view(&[2u8, 1], None);
    let sv = sparse.view(&[0u8; 24], None);
    sparse.json["accessors"][0]["sparse"] = json!({ "count": 2, "indices": { "bufferView": si, "componentType": UNSIGNED_BYTE }, "values": { "bufferView": sv } });
    let rest = mesh_error("sparse", "m.gltf", &[("m.gltf", &sparse.gltf_embedded())]);
    assert_says(
        "sparse order",
        &rest,
        "meshes[0].primitives[0].attributes.POSITION: accessor 0 sparse indices: ",
        "strictly increase",
    );
    let required = doc_with(|d| d.json["extensionsRequired"] = json!(["KHR_draco_mesh_compression"]));
    let rest = mesh_error("extension", "m.gltf", &[("m.gltf", &required.gltf_embedded())]);
    assert_says("required extension", &rest, "extensionsRequired[0]", "extension that Arbor does not read");
}

#[test]
fn bad_hierarchies_are_errors_naming_the_node() {
    let cycle = doc_with(|d| {
        let a = d.node(json!({ "name": "A", "children": [] }), true);
        let b = d.node(json!({ "name": "B", "children": [a] }), false);
        d.json["nodes"][a]["children"] = json!([b]);
    });
    let rest = mesh_error("cycle", "m.gltf", &[("m.gltf", &cycle.gltf_embedded())]);
    assert_says("cycle", &rest, "nodes[1] (\"A\"): ", "reached a second time");
    let singular = doc_with(|d| d.json["nodes"][0]["scale"] = json!([1, 0, 1]));
    let rest = mesh_error("singular", "m.gltf", &[("m.gltf", &singular.gltf_embedded())]);
    assert_says("singular", &rest, "nodes[0]: ", "singular");
    let nan = doc_with(|d| d.json["nodes"][0]["matrix"] = json!([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0.5]));
    let rest = mesh_error("projective", "m.gltf", &[("m.gltf", &nan.gltf_embedded())]);
    assert_says("projective", &rest, "nodes[0].matrix: ", "affine");
    let lines = doc_with(|d| d.json["meshes"][0]["primitives"][0]["mode"] = json!(1));
    let rest = mesh_error("lines", "m.gltf", &[("m.gltf", &lines.gltf_embedded())]);
    assert!(rest.contains("no triangles"), "{rest}");
    let material = doc_with(|d| {
        d.push("materials", json!({ "pbrMetallicRoughness": { "roughnessFactor": 2 } }));
    });
    let rest = mesh_error("material", "m.gltf", &[("m.gltf", &material.gltf_embedded())]);
    assert_says("roughness 2", &rest, "materials[0].pbrMetallicRoughness.roughnessFactor: ", "not in [0, 1]");
}

#[test]
fn camera_errors_name_the_key_and_the_camera() {
    let dir = temp_dir("camera-errors");
    let mut d = doc_with(|_| {});
    d.push(
        "cameras",
        json!({ "type": "orthographic", "orthographic": { "xmag": 1, "ymag": 1, "znear": 0.1, "zfar": 10 } }),
    );
    d.node(json!({ "name": "Top", "camera": 0 }), true);
    std::fs::write(dir.join("m.gltf"), d.gltf_embedded()).unwrap();
    std::fs::write(dir.join("plain.gltf"), doc_with(|_| {}).gltf_embedded()).unwrap();
    let error = |camera: &str| {
        let text = format!("[camera]\n{camera}\nresolution = [8, 8]\n\n[[objects]]\nmesh = \"m.gltf\"\n");
        std::fs::write(dir.join("s.toml"), text).unwrap();
        Scene::load(dir.join("s.toml")).map(|_| ()).unwrap_err().to_string()
    };
    let s = dir.join("s.toml").display().to_string();
    let m = dir.join("m.gltf").display().to_string();
    let cases = [
        (
            "from = \"m.gltf\"\nname = \"Side\"",
            format!("{s}:3: camera.name: {m}: no camera node or camera is named `Side`"),
            "nodes[1] (\"Top\")",
        ),
        (
            "from = \"m.gltf\"",
            format!("{s}:2: camera.from: {m}: nodes[1] (\"Top\"): cameras[0] is orthographic"),
            "perspective cameras only",
        ),
        (
            "from = \"plain.gltf\"",
            format!("{s}:2: camera.from: {}: its scene has no node with a camera", dir.join("plain.gltf").display()),
            "",
        ),
        ("from = \"gone.glb\"", format!("{s}:2: camera.from: {}: cannot read", dir.join("gone.glb").display()), ""),
        ("from = \"m.gltf\"\nfov = 40", format!("{s}:3: camera.fov: is not given with `camera.from`"), ""),
        (
            "position = [0, 0, 1]\nlook_at = [0, 0, 0]\nfov = 40\nname = \"Top\"",
            format!("{s}:5: camera.name: names a camera of a glTF file"),
            "",
        ),
        ("position = [0, 0, 1]\nfov = 40", format!("{s}:1: camera: missing field `look_at`"), ""),
    ];
    for (camera, start, words) in cases {
        let err = error(camera);
        assert!(err.starts_with(&start) && err.contains(words), "{camera}: want `{start}...{words}`, got: {err}");
    }
    let mut lens = hierarchy();
    lens.json["cameras"][0]["type"] = json!("orthographic");
    std::fs::write(dir.join("m.gltf"), lens.gltf_embedded()).unwrap();
    let err = error("from = \"m.gltf\"");
    assert!(err.contains("cameras[0]: its type is `orthographic`, but it has no `orthographic` object"), "{err}");
    std::fs::write(dir.join("m.gltf"), hierarchy().gltf_embedded()).unwrap();
    let err = error("from = \"m.gltf\"\naperture = 0.1");
    assert!(err.starts_with(&format!("{s}:3: camera.focus_distance: a thin lens")), "{err}");
}

/// `extras` may be any JSON value (glTF 2.0, 3.2 and the schema's `extras`): an array at the
/// root, a string on a node, a number on a mesh, `null` on the asset. Each was refused as "not a
/// struct".
#[test]
fn extras_may_be_any_json_value() {
    let d = doc_with(|d| {
        d.json["extras"] = json!([1, "two", { "three": 3 }]);
        d.json["asset"]["extras"] = json!(null);
        d.json["nodes"][0]["extras"] = json!("a note");
        d.json["meshes"][0]["extras"] = json!(4.5);
        d.json["scenes"][0]["extras"] = json!(true);
    });
    let dir = temp_dir("extras");
    let scene = load(&dir, &[("m.gltf", &d.gltf_embedded())], &object("m.gltf")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.world_triangle_count(), 1);
}

/// Emission above 2^40 (the factor times `KHR_materials_emissive_strength`, or times the
/// emissive texture's brightest texel) is refused, naming the material: the film drops every
/// sample above 2^44, so such a lamp rendered black.
#[test]
fn emission_above_two_to_the_forty_is_an_error_naming_the_material() {
    let strong = doc_with(|d| {
        d.push(
            "materials",
            json!({ "emissiveFactor": [1, 0.5, 0], "extensions": { "KHR_materials_emissive_strength": { "emissiveStrength": 1e38 } } }),
        );
        d.json["meshes"][0]["primitives"][0]["material"] = json!(0);
    });
    let rest = mesh_error("strength", "m.gltf", &[("m.gltf", &strong.gltf_embedded())]);
    assert_says("emissive strength", &rest, "materials[0]", "2^40");
    let textured = doc_with(|d| {
        d.push("images", json!({ "uri": "hot.exr" }));
        d.push("textures", json!({ "source": 0 }));
        d.push("materials", json!({ "emissiveFactor": [1, 1, 1], "emissiveTexture": { "index": 0 } }));
        d.json["meshes"][0]["primitives"][0]["material"] = json!(0);
    });
    let mut hot = arbor::image_io::Image::new(2, 2);
    hot.pixels[3] = [3e38, 1.0, 1.0];
    let dir = temp_dir("hot-texture");
    arbor::image_io::write_image(dir.join("hot.exr"), &hot).unwrap();
    let err = load(&dir, &[("m.gltf", &textured.gltf_embedded())], &object("m.gltf")).map(|_| ()).unwrap_err();
    let at =
        format!("{}:8: objects[0].mesh: {}: materials[0]", dir.join("s.toml").display(), dir.join("m.gltf").display());
    assert!(err.starts_with(&at) && err.contains("hot.exr") && err.contains("2^40"), "{err}");
}

/// A buffer's file is read only as far as its `byteLength`: a file far longer (here a sparse
/// file of 64 GB) is not read whole, as one was before failing at a quarter of the memory.
#[test]
fn a_buffer_file_longer_than_its_byte_length_is_read_only_that_far() {
    let dir = temp_dir("long-bin");
    let (gltf, bin) = doc_with(|_| {}).gltf_external("long.bin");
    let long = std::fs::File::create(dir.join("long.bin")).unwrap();
    std::io::Write::write_all(&mut &long, &bin).unwrap();
    long.set_len(64 << 30).unwrap();
    let started = std::time::Instant::now();
    let scene = load(&dir, &[("m.gltf", &gltf)], &object("m.gltf")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.world_triangle_count(), 1);
    assert!(started.elapsed().as_secs_f64() < 5.0, "took {:?}", started.elapsed());
    std::fs::remove_file(dir.join("long.bin")).unwrap();
}
