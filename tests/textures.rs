//! Image textures: a base colour texture seen where it should be on both devices, cut-out masks
//! that let camera and shadow rays through on both devices (flat and instanced on the CPU), and
//! bad texture files.

use std::path::{Path, PathBuf};

use arbor::device::{BuilderChoice, Device, Renderer};
use arbor::render::film::Film;
use arbor::scene::{RenderSettings, Scene};
use arbor::texture::{Texture, Wrap};
use glam::Vec2;

use crate::render_accuracy::devices;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("arbor-textures-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn render(device: Device, scene: &Scene, spp: u32, max_depth: u32) -> Film {
    let settings = RenderSettings { spp, max_depth, seed: 2, time: None, clamp: None };
    let choice = BuilderChoice::Fixed("lbvh".parse().unwrap());
    let mut r = Renderer::new(device, scene, &choice, crate::common::tracing(), &settings, 1, 0.0).unwrap();
    let film = r.render(&settings, &|_| {}).unwrap().film;
    assert_eq!(film.non_finite_count(), 0);
    film
}

/// An RGBA PNG of `width` x `height` from `f(x, y)`, row 0 at the top.
fn write_png(path: &Path, width: u32, height: u32, f: impl Fn(u32, u32) -> [u8; 4]) {
    let bytes: Vec<u8> = (0..height).flat_map(|y| (0..width).map(move |x| (x, y))).flat_map(|(x, y)| f(x, y)).collect();
    image::RgbaImage::from_raw(width, height, bytes).unwrap().save(path).unwrap();
}

/// A unit quad from (-1, -1) to (1, 1) in the z = 0 plane, facing +z, with texture coordinates
/// (0, 0) at its bottom left and (1, 1) at its top right, and material `m` from `m.mtl`.
const QUAD_OBJ: &str = "mtllib m.mtl\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n\
                        vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl m\nf 1/1 2/2 3/3 4/4\n";

/// A diffuse quad whose albedo is a 4 x 4 texture of distinct colours, facing the camera head
/// on under a white furnace (radiance 1, no lights): each sample is exactly the albedo at its
/// texture coordinates, so each pixel's mean is the texture at the pixel centre, up to the
/// bilinear slope across the pixel (clamped at the edges, where a repeating texture would blend
/// its top and bottom rows steeply). This checks the orientation (v up, row 0 at the top), the
/// sRGB decoding, the filtering and `-clamp on`, on both devices; and the same texture
/// multiplying the coated material's base colour.
#[test]
fn a_base_colour_texture_is_seen_where_it_is() {
    let dir = temp_dir("base-colour");
    write_png(&dir.join("colours.png"), 4, 4, |x, y| [(40 + 60 * x) as u8, (30 + 70 * y) as u8, 200, 255]);
    std::fs::write(dir.join("quad.obj"), QUAD_OBJ).unwrap();
    let text = "[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [32, 32]\n\
                [environment]\nradiance = [1, 1, 1]\n[[objects]]\nmesh = \"quad.obj\"\n";
    std::fs::write(dir.join("scene.toml"), text).unwrap();
    let texture = Texture::load(&dir.join("colours.png")).unwrap();
    // The camera's half-height at the quad: tan(20°) · 3.
    let half = (20f32.to_radians()).tan() * 3.0;
    // Diffuse, and the coated material as a smooth white metal (the PBR extension's `Pm 1`,
    // `Pr 0`), whose reflectance within 25° of normal incidence is its base colour to 1e-5.
    for (kind, mtl) in [("diffuse", "Kd 1 1 1\n"), ("coated metal", "Kd 1 1 1\nKs 1 1 1\nPm 1\nPr 0\n")] {
        std::fs::write(dir.join("m.mtl"), format!("newmtl m\n{mtl}map_Kd -clamp on colours.png\n")).unwrap();
        let scene = Scene::load(dir.join("scene.toml")).unwrap();
        assert_eq!(scene.textures.len(), 1);
        assert_eq!(scene.texture_bytes(), 4 * 4 * 4, "one 4x4 texture of 8-bit RGBA");
        for device in devices("a_base_colour_texture_is_seen_where_it_is") {
            let mean = render(device, &scene, 16, 2).mean();
            let mut on_quad = 0;
            for (i, p) in mean.pixels.iter().enumerate() {
                let (px, py) = ((i % 32) as f32 + 0.5, (i / 32) as f32 + 0.5);
                let (x, y) = ((px / 16.0 - 1.0) * half, (1.0 - py / 16.0) * half);
                if x.abs() > 0.95 || y.abs() > 0.95 {
                    if x.abs() > 1.05 || y.abs() > 1.05 {
                        assert!((p[0] - 1.0).abs() < 1e-5, "{kind} {} pixel {i}: background {p:?}", device.name());
                    }
                    continue;
                }
                on_quad += 1;
                let want = texture.sample(Vec2::new((x + 1.0) / 2.0, (y + 1.0) / 2.0), Wrap::Clamp, true);
                for c in 0..3 {
                    assert!(
                        (p[c] - want[c]).abs() < 0.02,
                        "{kind} {} pixel {i} channel {c}: {} against the texture's {}",
                        device.name(),
                        p[c],
                        want[c]
                    );
                }
            }
            assert!(on_quad > 300, "{on_quad} pixels on the quad");
        }
    }
}

/// A quad whose mask (`map_d`) cuts out its left half. Seen head on under the furnace, the cut
/// half shows the background exactly and the rest the albedo (camera rays: closest hit). Held
/// over a floor under a lamp, it shadows the floor under its right half only (shadow rays: any
/// hit). On both devices, and on the CPU through the instanced path too (an animated scene).
#[test]
fn cut_out_texels_let_camera_and_shadow_rays_through() {
    let dir = temp_dir("cut-out");
    write_png(&dir.join("mask.png"), 8, 2, |x, _| [255, 255, 255, if x < 4 { 0 } else { 255 }]);
    std::fs::write(dir.join("quad.obj"), QUAD_OBJ).unwrap();
    std::fs::write(dir.join("m.mtl"), "newmtl m\nKd 0.5 0.5 0.5\nmap_d mask.png\n").unwrap();
    let seen = "[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\nfov = 30\nresolution = [24, 24]\n\
                [environment]\nradiance = [1, 1, 1]\n[[objects]]\nmesh = \"quad.obj\"\n";
    std::fs::write(dir.join("seen.toml"), seen).unwrap();
    let scene = Scene::load(dir.join("seen.toml")).unwrap();
    for device in devices("cut_out_texels_let_camera_and_shadow_rays_through") {
        let mean = render(device, &scene, 8, 2).mean();
        for y in 2..22 {
            let (left, right) = (mean.pixels[y * 24 + 6][0], mean.pixels[y * 24 + 17][0]);
            assert!((left - 1.0).abs() < 1e-5, "{}: row {y}: the cut-out half shows {left}", device.name());
            assert!((right - 0.5).abs() < 1e-5, "{}: row {y}: the opaque half shows {right}", device.name());
        }
    }
    // The quad laid flat at y = 1 over a floor, a lamp above it; the camera looks at the floor
    // from below the quad.
    let shadow = |animated: bool| {
        let keys = if animated {
            "[[objects.keyframes]]\ntime = 0\ntranslate = [0, 1, 0]\nrotate = [-90, 0, 0]\n\
             [[objects.keyframes]]\ntime = 1\ntranslate = [0, 1, 0]\nrotate = [-90, 0, 0]\n[animation]\nfps = 1\nframes = [0, 1]\n"
        } else {
            "translate = [0, 1, 0]\nrotate = [-90, 0, 0]\n"
        };
        format!(
            "[camera]\nposition = [0, 0.6, 3]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [32, 24]\n\
             [materials.floor]\ntype = \"diffuse\"\nalbedo = [0.8, 0.8, 0.8]\n\
             [materials.lamp]\ntype = \"emissive\"\nradiance = [20, 20, 20]\n\
             [[objects]]\nshape = \"quad\"\nmaterial = \"floor\"\nrotate = [-90, 0, 0]\nscale = 3\n\
             [[objects]]\nshape = \"quad\"\nmaterial = \"lamp\"\ntranslate = [0, 2, 0]\nrotate = [90, 0, 0]\nscale = 0.3\n\
             [[objects]]\nmesh = \"quad.obj\"\n{keys}"
        )
    };
    let floor = |mean: &arbor::image_io::Image| {
        // The floor just left and right of the centre, below the horizon of the view.
        let side = |x0: usize| {
            let mut s = 0.0;
            for y in 16..22 {
                for x in x0..x0 + 4 {
                    s += mean.pixels[y * 32 + x][0];
                }
            }
            s / 24.0
        };
        (side(9), side(19))
    };
    std::fs::write(dir.join("shadow.toml"), shadow(false)).unwrap();
    std::fs::write(dir.join("animated.toml"), shadow(true)).unwrap();
    let mut cases: Vec<(Device, &str)> =
        devices("cut_out_texels_let_camera_and_shadow_rays_through").into_iter().map(|d| (d, "shadow.toml")).collect();
    cases.push((Device::Cpu, "animated.toml"));
    for (device, file) in cases {
        let scene = Scene::load(dir.join(file)).unwrap();
        let (lit, shaded) = floor(&render(device, &scene, 64, 2).mean());
        assert!(
            lit > 4.0 * shaded && lit > 0.1,
            "{} {file}: the floor under the cut-out half is {lit}, under the opaque half {shaded}",
            device.name()
        );
    }
}

fn load_err(dir: &Path, scene: &str) -> String {
    std::fs::write(dir.join("scene.toml"), scene).unwrap();
    match Scene::load(dir.join("scene.toml")) {
        Ok(_) => panic!("loaded:\n{scene}"),
        Err(e) => e.to_string(),
    }
}

/// A texture that is missing, not an image, cut short or of an unsupported kind: an error naming
/// the scene's line and key, the MTL file with its line and statement, and the texture; no
/// panic.
#[test]
fn bad_textures_name_where_they_are_used() {
    let dir = temp_dir("errors");
    std::fs::write(dir.join("quad.obj"), QUAD_OBJ).unwrap();
    write_png(&dir.join("ok.png"), 4, 4, |_, _| [1, 2, 3, 4]);
    let png = std::fs::read(dir.join("ok.png")).unwrap();
    std::fs::write(dir.join("cut.png"), &png[..png.len() / 2]).unwrap();
    std::fs::write(dir.join("text.png"), "not an image").unwrap();
    std::fs::write(dir.join("t.gif"), "GIF89a").unwrap();
    let scene = "[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n\
                 [[objects]]\nmesh = \"quad.obj\"\n";
    let cases: &[(&str, &[&str])] = &[
        ("newmtl m\nKd 1 1 1\nmap_Kd missing.png\n", &["m.mtl:3: `map_Kd`", "missing.png", "cannot read"]),
        ("newmtl m\n\nmap_d -clamp on cut.png\n", &["m.mtl:3: `map_d`", "cut.png"]),
        ("newmtl m\nmap_Kd text.png\n", &["m.mtl:2: `map_Kd`", "text.png"]),
        ("newmtl m\nmap_Kd t.gif\n", &["m.mtl:2: `map_Kd`", "t.gif", "not a supported image"]),
        ("newmtl m\nmap_Kd -bm 1 -o 0 0\n", &["m.mtl:2: `map_Kd`", "names no file"]),
        ("newmtl m\nKe 1 1 1\nmap_Ke missing.png\n", &["m.mtl:3: `map_Ke`", "missing.png"]),
        ("newmtl m\nPr 0.5\nmap_Pr text.png\n", &["m.mtl:3: `map_Pr`", "text.png"]),
        ("newmtl m\nmap_Pm cut.png\n", &["m.mtl:2: `map_Pm`", "cut.png"]),
    ];
    let scene_path = dir.join("scene.toml").display().to_string();
    for (mtl, words) in cases {
        std::fs::write(dir.join("m.mtl"), mtl).unwrap();
        let e = load_err(&dir, scene);
        assert!(e.starts_with(&format!("{scene_path}:7: objects[0].mesh: ")), "{mtl}: {e}");
        for w in *words {
            assert!(e.contains(w), "{mtl}: want `{w}` in: {e}");
        }
    }
    // Options before the name are read past; a name with spaces is kept whole.
    std::fs::copy(dir.join("ok.png"), dir.join("a b.png")).unwrap();
    std::fs::write(dir.join("m.mtl"), "newmtl m\nmap_Kd -s 2 2 1 -clamp on a b.png\n").unwrap();
    std::fs::write(dir.join("scene.toml"), scene).unwrap();
    let loaded = Scene::load(dir.join("scene.toml")).unwrap();
    let r = loaded.materials.last().unwrap().textures.base_color.unwrap();
    assert_eq!((r.wrap, r.srgb, loaded.textures.len()), (Wrap::Clamp, true, 1));
    // A TOML material's texture.
    let toml_material = |t: &str| {
        format!(
            "[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n\
             [materials.m]\ntype = \"diffuse\"\ntexture = \"{t}\"\n[[objects]]\nshape = \"quad\"\nmaterial = \"m\"\n"
        )
    };
    let e = load_err(&dir, &toml_material("missing.png"));
    assert!(e.starts_with(&format!("{scene_path}:8: materials.m.texture: ")) && e.contains("missing.png"), "{e}");
    let e = load_err(&dir, &toml_material(""));
    assert!(e.contains("materials.m.texture: is empty"), "{e}");
    // The emission, roughness and metallic textures, and where each is no key.
    let e = load_err(
        &dir,
        &toml_material("ok.png")
            .replace("type = \"diffuse\"", "type = \"emissive\"\nemission_texture = \"missing.png\""),
    );
    assert!(
        e.starts_with(&format!("{scene_path}:8: materials.m.emission_texture: ")) && e.contains("missing.png"),
        "{e}"
    );
    let e = load_err(
        &dir,
        &toml_material("ok.png").replace("type = \"diffuse\"", "type = \"diffuse\"\nroughness_texture = \"ok.png\""),
    );
    assert!(e.contains("materials.m.roughness_texture: not a key of the `diffuse` material type"), "{e}");
    let e = load_err(
        &dir,
        &toml_material("ok.png")
            .replace("type = \"diffuse\"", "type = \"metallic-roughness\"\nmetallic_texture = \"cut.png\""),
    );
    assert!(e.contains("materials.m.metallic_texture: ") && e.contains("cut.png"), "{e}");
    std::fs::write(dir.join("scene.toml"), toml_material("ok.png")).unwrap();
    let loaded = Scene::load(dir.join("scene.toml")).unwrap();
    assert!(loaded.materials[0].textures.base_color.is_some());
}

/// A glTF quad whose base colour texture's alpha cuts out its left half (`alphaMode` MASK): from
/// a PNG file beside a `.gltf`, and embedded in a `.glb`'s buffer. Both load the texture (one
/// each, and with the mask), and render the cut half as the background and the rest as the
/// base colour times the texture, on both devices. The material is a smooth metal (the default
/// metallicFactor 1, roughnessFactor 0), whose reflectance near normal incidence is its base
/// colour within 1e-5 (Schlick's `(1 - cos θ)⁵` is below 1e-7 over the quad, and the clamped
/// GGX lobe masks less), so that the answer stays exact under the coated material.
#[test]
#[cfg(feature = "gltf")]
fn gltf_base_colour_textures_and_masks() {
    use crate::common::gltf::{Doc, UNSIGNED_SHORT};
    use serde_json::json;
    let dir = temp_dir("gltf");
    write_png(&dir.join("mask.png"), 8, 2, |x, _| [255, 255, 255, if x < 4 { 0 } else { 255 }]);
    let png = std::fs::read(dir.join("mask.png")).unwrap();
    let quad = |embedded: bool| {
        let mut d = Doc::new();
        let p = d.floats(&[-1.0, -1.0, 0.0, 1.0, -1.0, 0.0, 1.0, 1.0, 0.0, -1.0, 1.0, 0.0], "VEC3");
        // glTF's texture coordinates start at the image's top left.
        let t = d.floats(&[0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0], "VEC2");
        let i = d.indices(&[0, 1, 2, 0, 2, 3], UNSIGNED_SHORT);
        d.mesh(&[("POSITION", p), ("TEXCOORD_0", t)], Some(i), None);
        d.json["meshes"][0]["primitives"][0]["material"] = json!(0);
        d.node(json!({ "mesh": 0 }), true);
        let image = if embedded {
            let view = d.view(&png, None);
            json!({ "bufferView": view, "mimeType": "image/png" })
        } else {
            json!({ "uri": "mask.png" })
        };
        d.push("images", image);
        d.push("samplers", json!({ "wrapS": 33071, "wrapT": 33071 }));
        d.push("textures", json!({ "source": 0, "sampler": 0 }));
        d.push(
            "materials",
            json!({
                "pbrMetallicRoughness": { "baseColorFactor": [0.5, 0.5, 0.5, 1], "roughnessFactor": 0,
                                          "baseColorTexture": { "index": 0 } },
                "alphaMode": "MASK",
            }),
        );
        d
    };
    std::fs::write(dir.join("quad.gltf"), quad(false).gltf_embedded()).unwrap();
    std::fs::write(dir.join("quad.glb"), quad(true).glb()).unwrap();
    for file in ["quad.gltf", "quad.glb"] {
        let text = format!(
            "[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\nfov = 30\nresolution = [24, 24]\n\
             [environment]\nradiance = [1, 1, 1]\n[[objects]]\nmesh = \"{file}\"\n"
        );
        std::fs::write(dir.join("scene.toml"), text).unwrap();
        let scene = Scene::load(dir.join("scene.toml")).unwrap();
        let m = scene.materials.last().unwrap();
        assert_eq!(scene.textures.len(), 1, "{file}");
        assert!(m.textures.base_color.is_some_and(|r| r.srgb && r.wrap == Wrap::Clamp), "{file}: {:?}", m.textures);
        assert!(m.textures.alpha.is_some() && m.textures.alpha_cutoff == 0.5, "{file}: {:?}", m.textures);
        for device in devices("gltf_base_colour_textures_and_masks") {
            let mean = render(device, &scene, 8, 2).mean();
            for y in 2..22 {
                let (left, right) = (mean.pixels[y * 24 + 6][0], mean.pixels[y * 24 + 17][0]);
                assert!((left - 1.0).abs() < 1e-5, "{} {file}: row {y}: the cut-out half shows {left}", device.name());
                assert!((right - 0.5).abs() < 1e-5, "{} {file}: row {y}: the opaque half shows {right}", device.name());
            }
        }
    }
}

/// A normal map turns the shading as vertex normals turned the same way do: a lit floor whose
/// map (MTL `norm`, one texel tilting the normal 30° toward +x in tangent space) renders as the
/// same floor with that normal given at its vertices, quadrant by quadrant, and unlike the
/// floor with neither. On both devices.
#[test]
fn a_normal_map_shades_as_the_vertex_normals_it_encodes() {
    use crate::environment::{assert_agree, quadrant_means};
    let dir = temp_dir("normal-map");
    // Tangent-space (sin 30°, 0, cos 30°), as bytes; the vertex normal is decoded from them.
    let texel = [191u8, 128, 238, 255];
    write_png(&dir.join("tilt.png"), 1, 1, |_, _| texel);
    let m = |c: u8| 2.0 * f32::from(c) / 255.0 - 1.0;
    let n = glam::Vec3::new(m(texel[0]), m(texel[2]), -m(texel[1])).normalize();
    // A floor in the xz plane facing +y: u runs along +x, v along -z.
    let scene = |normals: bool, mtl: &str| {
        let vn = if normals { format!("vn {} {} {}\n", n.x, n.y, n.z) } else { String::new() };
        let f = if normals { "f 1/1/1 2/2/1 3/3/1 4/4/1" } else { "f 1/1 2/2 3/3 4/4" };
        let name = format!("floor-{normals}-{mtl}");
        let obj = format!(
            "mtllib {mtl}\nv -2 0 2\nv 2 0 2\nv 2 0 -2\nv -2 0 -2\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n{vn}usemtl m\n{f}\n"
        );
        std::fs::write(dir.join(format!("{name}.obj")), obj).unwrap();
        let text = format!(
            "[camera]\nposition = [0, 4, 0.01]\nlook_at = [0, 0, 0]\nfov = 50\nresolution = [24, 24]\n\
             [materials.lamp]\ntype = \"emissive\"\nradiance = [30, 30, 30]\n\
             [[objects]]\nmesh = \"{name}.obj\"\n\
             [[objects]]\nshape = \"quad\"\nmaterial = \"lamp\"\ntranslate = [3, 1.5, 0]\nrotate = [90, 0, 0]\nscale = 0.3\n"
        );
        std::fs::write(dir.join(format!("{name}.toml")), text).unwrap();
        Scene::load(dir.join(format!("{name}.toml"))).unwrap()
    };
    std::fs::write(dir.join("m.mtl"), "newmtl m\nKd 0.8 0.8 0.8\nnorm tilt.png\n").unwrap();
    std::fs::write(dir.join("n.mtl"), "newmtl m\nKd 0.8 0.8 0.8\n").unwrap();
    let mapped = scene(false, "m.mtl");
    assert!(mapped.materials.last().unwrap().textures.normal.is_some());
    let normals = scene(true, "n.mtl");
    let flat = scene(false, "n.mtl");
    for device in devices("a_normal_map_shades_as_the_vertex_normals_it_encodes") {
        let a = render(device, &mapped, 256, 2);
        let b = render(device, &normals, 256, 2);
        assert_agree(&format!("{}: normal map against vertex normals", device.name()), &a, &b, 4.5);
        // Tilted toward the lamp at +x, the floor is brighter than flat.
        let (tilted, level) = (quadrant_means(&a), quadrant_means(&render(device, &flat, 256, 2)));
        let sum = |q: &[([f64; 3], [f64; 3])]| q.iter().map(|(m, _)| m[0]).sum::<f64>();
        assert!(sum(&tilted) > 1.15 * sum(&level), "{}: {} tilted, {} flat", device.name(), sum(&tilted), sum(&level));
    }
    // `bump` and `map_Bump` name the normal map too.
    for statement in ["bump", "map_Bump"] {
        std::fs::write(dir.join("m.mtl"), format!("newmtl m\nKd 0.8 0.8 0.8\n{statement} tilt.png\n")).unwrap();
        let s = scene(false, "m.mtl");
        assert!(s.materials.last().unwrap().textures.normal.is_some(), "{statement}");
    }
}

/// An emission texture lights the scene as it looks. A lamp facing down onto a floor emits
/// radiance 4 times a ramp texture (linear, EXR) rising along +x, then the same lamp with the
/// ramp reversed: light transport is linear in the emission, and the two ramps add up to 1, so
/// the two renders add up to the lamp with no texture, quadrant by quadrant (z < 4.5), direct
/// and indirect light alike. The ramp alone lights the floor under its bright end more than
/// under its dark end. A lamp that sampled its points without the texture's value, or chose
/// them by the untextured power, would fail the sum. On both devices; the lamp is one quad of
/// two triangles, so the texture varies within each triangle.
#[test]
fn an_emission_texture_lights_as_it_looks() {
    use crate::environment::{assert_quadrants_agree, quadrant_means, quadrant_sums};
    use arbor::image_io::{Image, write_image};
    let dir = temp_dir("emission");
    let ramp = |rising: bool| Image {
        width: 8,
        height: 1,
        pixels: (0..8)
            .map(|x| {
                let t = (x as f32 + 0.5) / 8.0;
                let t = if rising { t } else { 1.0 - t };
                [t, t * 0.5 + 0.25, 1.0 - t * 0.5]
            })
            .collect(),
    };
    let (up, down) = (ramp(true), ramp(false));
    // The second channel sums to 1 and the third to 1.5 as well: the lamp with no texture emits
    // 4 × (1, 1, 1.5).
    for (a, b) in up.pixels.iter().zip(&down.pixels) {
        assert!((a[0] + b[0] - 1.0).abs() < 1e-6 && (a[1] + b[1] - 1.0).abs() < 1e-6, "{a:?} {b:?}");
        assert!((a[2] + b[2] - 1.5).abs() < 1e-6, "{a:?} {b:?}");
    }
    write_image(dir.join("up.exr"), &up).unwrap();
    write_image(dir.join("down.exr"), &down).unwrap();
    std::fs::write(dir.join("floor.obj"), "v -2 0 2\nv 2 0 2\nv 2 0 -2\nv -2 0 -2\nf 1 2 3 4\n").unwrap();
    // Facing -y, u along +x.
    std::fs::write(
        dir.join("lamp.obj"),
        "v -1 1 -0.5\nv 1 1 -0.5\nv 1 1 0.5\nv -1 1 0.5\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n",
    )
    .unwrap();
    let scene = |name: &str, lamp: &str| {
        let text = format!(
            "[camera]\nposition = [0, 0.9, 3]\nlook_at = [0, 0, 0]\nfov = 60\nresolution = [24, 24]\n\
             [materials.floor]\ntype = \"diffuse\"\nalbedo = [0.8, 0.8, 0.8]\n\
             [materials.lamp]\ntype = \"emissive\"\n{lamp}\n\
             [[objects]]\nmesh = \"floor.obj\"\nmaterial = \"floor\"\n\
             [[objects]]\nmesh = \"lamp.obj\"\nmaterial = \"lamp\"\n"
        );
        std::fs::write(dir.join(name), text).unwrap();
        Scene::load(dir.join(name)).unwrap_or_else(|e| panic!("{e}"))
    };
    let up = scene("up.toml", "radiance = [4, 4, 4]\nemission_texture = \"up.exr\"");
    let down = scene("down.toml", "radiance = [4, 4, 4]\nemission_texture = \"down.exr\"");
    let plain = scene("plain.toml", "radiance = [4, 4, 6]");
    assert!(up.materials[1].textures.emission.is_some());
    for device in devices("an_emission_texture_lights_as_it_looks") {
        let name = device.name();
        let (a, b) = (quadrant_means(&render(device, &up, 64, 3)), quadrant_means(&render(device, &down, 64, 3)));
        let sum = quadrant_sums(&a, &b);
        let whole = quadrant_means(&render(device, &plain, 64, 3));
        assert_quadrants_agree(&format!("{name}: rising + falling ramps against no texture"), sum, whole, 4.5);
        // Quadrants 0 and 2 are the left (-x) half of the image, where the rising ramp is dark.
        let (left, right) = (a[0].0[0] + a[2].0[0], a[1].0[0] + a[3].0[0]);
        assert!(right > 1.5 * left, "{name}: the rising ramp lights +x with {right}, -x with {left}");
    }
}

/// The coated material's roughness and metallic textures multiply its factors, each read from
/// its channel: glTF's `metallicRoughnessTexture` green (roughness) and blue (metallic), MTL
/// `map_Pr` and `map_Pm` and TOML `roughness_texture` and `metallic_texture` red. And a floor
/// whose roughness and metallic vary across it renders alike on both devices.
#[test]
#[cfg(feature = "gltf")]
fn roughness_and_metallic_textures_read_their_channels() {
    use arbor::render::RenderMaterial;
    use arbor::render::bsdf::Bsdf;
    let dir = temp_dir("roughness");
    write_png(&dir.join("rm.png"), 1, 1, |_, _| [40, 200, 60, 255]);
    write_png(
        &dir.join("checker.png"),
        4,
        4,
        |x, y| if (x + y) % 2 == 0 { [255, 230, 20, 255] } else { [30, 60, 255, 255] },
    );
    let c = |v: u8| f32::from(v) / 255.0;
    let coated = |scene: &Scene, i: usize| match RenderMaterial::from_scene(&scene.materials[i])
        .bsdf_at(&scene.textures, || Vec2::new(0.3, 0.6))
    {
        Some(Bsdf::Coated { metallic, alpha, .. }) => (metallic, alpha),
        other => panic!("{other:?}"),
    };
    let close = |(m, a): (f32, f32), (wm, wa): (f32, f32), what: &str| {
        assert!((m - wm).abs() < 1e-5 && (a - wa).abs() < 1e-5, "{what}: metallic {m}, α {a}; want {wm}, {wa}");
    };
    // TOML: the textures alone (the factors default to 1), and with factors.
    std::fs::write(dir.join("quad.obj"), QUAD_OBJ.replace("mtllib m.mtl\n", "").replace("usemtl m\n", "")).unwrap();
    let toml = |extra: &str| {
        let text = format!(
            "[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n\
             [materials.m]\ntype = \"metallic-roughness\"\nbase_color = [1, 1, 1]\n{extra}\n\
             [[objects]]\nmesh = \"quad.obj\"\nmaterial = \"m\"\n"
        );
        std::fs::write(dir.join("s.toml"), text).unwrap();
        Scene::load(dir.join("s.toml")).unwrap_or_else(|e| panic!("{e}"))
    };
    let s = toml("roughness_texture = \"rm.png\"\nmetallic_texture = \"rm.png\"");
    close(coated(&s, 0), (c(40), c(40) * c(40)), "TOML, textures alone");
    let s = toml("roughness_texture = \"rm.png\"\nroughness = 0.5\nmetallic = 0.5\nmetallic_texture = \"rm.png\"");
    close(coated(&s, 0), (0.5 * c(40), (0.5 * c(40)).powi(2)), "TOML, with factors");
    // MTL.
    std::fs::write(dir.join("quad.obj"), QUAD_OBJ).unwrap();
    std::fs::write(dir.join("m.mtl"), "newmtl m\nKd 1 1 1\nPr 0.5\nmap_Pr rm.png\nmap_Pm rm.png\n").unwrap();
    std::fs::write(dir.join("s.toml"), "[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n[[objects]]\nmesh = \"quad.obj\"\n").unwrap();
    let s = Scene::load(dir.join("s.toml")).unwrap_or_else(|e| panic!("{e}"));
    close(coated(&s, 0), (c(40), (0.5 * c(40)).powi(2)), "MTL map_Pr and map_Pm (Pm defaults to 1 beside its map)");
    // glTF: one texture, green and blue.
    let mut d = crate::common::gltf::triangle_doc();
    d.push("images", json_value(r#"{ "uri": "rm.png" }"#));
    d.push("textures", json_value(r#"{ "source": 0 }"#));
    d.push(
        "materials",
        json_value(r#"{ "pbrMetallicRoughness": { "metallicFactor": 0.5, "roughnessFactor": 0.8, "metallicRoughnessTexture": { "index": 0 } } }"#),
    );
    d.json["meshes"][0]["primitives"][0]["material"] = json_value("0");
    d.node(json_value(r#"{ "mesh": 0 }"#), true);
    std::fs::write(dir.join("t.glb"), d.glb()).unwrap();
    std::fs::write(dir.join("g.toml"), "[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n[[objects]]\nmesh = \"t.glb\"\n").unwrap();
    let s = Scene::load(dir.join("g.toml")).unwrap_or_else(|e| panic!("{e}"));
    close(coated(&s, 0), (0.5 * c(60), (0.8 * c(200)).powi(2)), "glTF metallicRoughnessTexture");
    // A lit floor (the glTF triangle, laid down) with a checker of roughness and metallic, on
    // both devices: the checker's red differs from its green and blue.
    d.json["images"][0]["uri"] = json_value(r#""checker.png""#);
    d.json["materials"][0]["pbrMetallicRoughness"] =
        json_value(r#"{ "baseColorFactor": [0.9, 0.6, 0.3, 1], "metallicRoughnessTexture": { "index": 0 } }"#);
    std::fs::write(dir.join("lit.glb"), d.glb()).unwrap();
    let text = "[camera]\nposition = [0, 2.5, 2.5]\nlook_at = [0, 0, 0]\nfov = 50\nresolution = [24, 24]\n\
                [materials.lamp]\ntype = \"emissive\"\nradiance = [20, 20, 20]\n\
                [[objects]]\nmesh = \"lit.glb\"\nrotate = [-90, 0, 0]\nscale = 3\ntranslate = [-1, 0, 1]\n\
                [[objects]]\nshape = \"quad\"\nmaterial = \"lamp\"\ntranslate = [0, 1.5, -2]\nrotate = [45, 0, 0]\nscale = 0.5\n";
    std::fs::write(dir.join("lit.toml"), text).unwrap();
    let lit = Scene::load(dir.join("lit.toml")).unwrap_or_else(|e| panic!("{e}"));
    let devices = devices("roughness_and_metallic_textures_read_their_channels");
    if devices.len() > 1 {
        let cpu = render(devices[0], &lit, 128, 3);
        let gpu = render(devices[1], &lit, 128, 3);
        crate::environment::assert_agree("roughness and metallic textures, GPU against CPU", &gpu, &cpu, 4.5);
    }
}

#[cfg(feature = "gltf")]
fn json_value(text: &str) -> serde_json::Value {
    serde_json::from_str(text).unwrap()
}
