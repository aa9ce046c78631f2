//! Fuzzing the scene loader: `Scene::load` on random and mutated input never panics, an error
//! names the file at fault (the scene, or the OBJ/MTL file it names) and, for the scene, the line
//! and key, and a scene that loads is usable (finite numbers, indices in range).
//!
//! Inputs:
//! - random bytes, random text and a soup of TOML tokens as the scene file;
//! - random bytes, random OBJ/MTL lines (numbers with nan, inf, huge and negative values; faces
//!   with valid, zero, out-of-range and relative indices, `vt`/`vn` references, too few
//!   vertices; unknown `usemtl` names, `o`/`g` lines, comments, vertex colours, garbage), and
//!   mostly valid files with a few such lines mixed in, as the OBJ and the MTL of an otherwise
//!   valid scene;
//! - random bytes, random PLY headers (valid and broken lines, huge and overflowing counts,
//!   unknown types) over random bodies, and meshes of random types in each encoding (with
//!   normals, texture coordinates, other properties and elements, NaN, infinite and huge
//!   coordinates, indices negative and out of range, faces of fewer than 3 vertices), their
//!   bytes mutated: truncated, changed, inserted, four bytes set to a huge count, -1, NaN or
//!   infinity, a number of the header or an ASCII body replaced (wrong counts and list counts);
//!   and valid meshes, which must load to the same mesh from each encoding;
//! - random bytes as a `.glb` file (some after a valid GLB header), and a valid glTF document
//!   (a hierarchy sharing a mesh, a strip, a sparse accessor, a textured material, a camera)
//!   mutated as JSON (a value anywhere replaced by null, -1, 0, huge or fractional numbers, a
//!   string, an empty array or object; a key removed) and then as bytes (as PLY files are),
//!   written as `.gltf` with a data URI or as `.glb`, named by an object and by the camera's
//!   `from`;
//! - every `scenes/*.toml`, mutated: lines deleted, duplicated, swapped; numbers replaced (nan,
//!   inf, -1, 0, 1e30, 4294967296, a string, an array); keys and table names replaced; the file
//!   truncated; random bytes inserted;
//! - the keys that size things (resolution, spp, subdivisions, scatter count, `triangles` of
//!   `city`/`hairball`, keyframe times, fps, frames) set within their documented limits, where
//!   the scene must load (sizes capped at 10^5 so that a case stays fast), or past them, where
//!   it must be an error at that key and line.
//!
//! Every case writes its files into its own folder under the system temp dir and removes it.
//! Failures are not persisted (`failure_persistence: None`): each bug found is a named
//! regression test at the end of this file.
//!
//! The default case counts (1000 for each random input, 500 for sizes, 256 for syntax lines and
//! for PLY encodings) keep this file to about 6 s on 2 cores: the CI smoke run. `PROPTEST_CASES`
//! overrides them all; a long run:
//!
//! ```sh
//! PROPTEST_CASES=20000 cargo test --test tests fuzz_loader
//! ```

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::common::gltf::{Doc, UNSIGNED_BYTE, UNSIGNED_SHORT, triangle_doc};

use arbor::scene::{Animation, Scattering, Scene, SceneError};
use glam::Vec3;
use proptest::prelude::*;
use proptest::sample::{Index, select};
use proptest::test_runner::Config;
use serde_json::{Value, json};

/// `cases` unless `PROPTEST_CASES` says otherwise (the `proptest!` macro reads it over this).
fn config(cases: u32) -> Config {
    Config { cases, failure_persistence: None, ..Config::default() }
}

// ---------------------------------------------------------------------------------------------
// Running one case

/// A folder of its own for one case, removed when dropped.
struct CaseDir(PathBuf);

impl CaseDir {
    fn new() -> Self {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("arbor-fuzz-{}-{n}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        CaseDir(dir)
    }

    fn write(&self, name: &str, bytes: &[u8]) -> PathBuf {
        let path = self.0.join(name);
        std::fs::write(&path, bytes).unwrap();
        path
    }
}

impl Drop for CaseDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// What loading gave: a scene, an error, or a panic (its message).
enum Outcome {
    Loaded(Box<Scene>),
    Failed(SceneError),
    Panicked(String),
}

/// Writes `files` (the first is the scene) into a fresh folder and loads the scene.
fn load(files: &[(&str, &[u8])]) -> (Outcome, PathBuf) {
    let dir = CaseDir::new();
    let paths: Vec<PathBuf> = files.iter().map(|(name, bytes)| dir.write(name, bytes)).collect();
    let outcome = match catch_unwind(AssertUnwindSafe(|| Scene::load(&paths[0]))) {
        Ok(Ok(scene)) => Outcome::Loaded(Box::new(scene)),
        Ok(Err(e)) => Outcome::Failed(e),
        Err(payload) => Outcome::Panicked(
            payload
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default(),
        ),
    };
    (outcome, paths[0].clone())
}

/// The parts of `file:line: key: message`, if `error` has that form for `file`.
fn located(error: &str, file: &Path) -> Option<(usize, String, String)> {
    let rest = error.strip_prefix(&format!("{}:", file.display()))?;
    let (line, rest) = rest.split_once(": ")?;
    let (key, message) = rest.split_once(": ")?;
    Some((line.parse().ok()?, key.to_owned(), message.to_owned()))
}

fn lines_of(bytes: &[u8]) -> usize {
    bytes.iter().filter(|&&b| b == b'\n').count() + 1
}

fn show(files: &[(&str, &[u8])]) -> String {
    files.iter().map(|(name, b)| format!("--- {name}\n{}\n", String::from_utf8_lossy(b))).collect()
}

/// The property every case checks: no panic; an error in `file:line: key: message` form with the
/// line inside the scene file, naming every file in `names`; a loaded scene usable. Returns the
/// error's line and key, if it failed.
fn check(files: &[(&str, &[u8])], names: &[&str]) -> Result<Option<(usize, String)>, TestCaseError> {
    let (outcome, path) = load(files);
    match outcome {
        Outcome::Panicked(msg) => Err(TestCaseError::fail(format!("panicked: {msg}\n{}", show(files)))),
        Outcome::Loaded(scene) => {
            usable(&scene).map_err(|why| TestCaseError::fail(format!("loaded but {why}\n{}", show(files))))?;
            Ok(None)
        }
        Outcome::Failed(e) => {
            let text = e.to_string();
            let Some((line, key, message)) = located(&text, &path) else {
                return Err(TestCaseError::fail(format!("not `file:line: key: message`: {text}\n{}", show(files))));
            };
            prop_assert!(
                (1..=lines_of(files[0].1)).contains(&line) && !key.is_empty() && !message.trim().is_empty(),
                "bad line, key or message: {text}\n{}",
                show(files)
            );
            for name in names {
                prop_assert!(text.contains(name), "does not name {name}: {text}\n{}", show(files));
            }
            Ok(Some((line, key)))
        }
    }
}

/// What a loaded scene promises the renderer.
fn usable(s: &Scene) -> Result<(), String> {
    let c = &s.camera;
    let ok = [c.position, c.look_at, c.up].iter().all(|v| v.is_finite())
        && (c.fov_y_degrees > 0.0 && c.fov_y_degrees < 180.0)
        && (c.width > 0 && c.height > 0)
        && (c.aperture.is_finite() && c.aperture >= 0.0)
        && (c.focus_distance.is_finite() && c.focus_distance > 0.0);
    if !ok {
        return Err(format!("camera {c:?}"));
    }
    if !(c.look_at - c.position).is_finite() {
        return Err(format!("camera view direction not finite: {c:?}"));
    }
    let r = &s.render;
    if r.spp == 0 || r.max_depth == 0 || r.time.is_some_and(|t| !(t.is_finite() && t > 0.0)) {
        return Err(format!("render {r:?}"));
    }
    if s.environment.as_ref().is_some_and(|e| !e.radiance.is_finite() || e.radiance.min_element() < 0.0) {
        return Err(format!("environment {:?}", s.environment));
    }
    for m in &s.materials {
        if m.emission.is_some_and(|e| !e.is_finite() || e.min_element() < 0.0) {
            return Err(format!("material {m:?}"));
        }
    }
    for (k, m) in s.meshes.iter().enumerate() {
        if m.mesh.positions.iter().any(|p| !p.is_finite()) {
            return Err(format!("mesh {k} ({}) has a non-finite position", m.source));
        }
        let n = m.mesh.positions.len();
        if m.mesh.indices.iter().flatten().any(|&i| i as usize >= n) {
            return Err(format!("mesh {k} ({}) has an index out of range", m.source));
        }
        if m.material_ids.len() != m.mesh.indices.len() {
            return Err(format!("mesh {k} ({}): {} material ids", m.source, m.material_ids.len()));
        }
        if m.material_ids.iter().any(|&i| i != u32::MAX && i as usize >= s.materials.len()) {
            return Err(format!("mesh {k} ({}) has a material id out of range", m.source));
        }
    }
    for (k, o) in s.objects.iter().enumerate() {
        let Some(m) = s.meshes.get(o.mesh) else { return Err(format!("object {k}: no mesh {}", o.mesh)) };
        match o.material {
            Some(i) if i as usize >= s.materials.len() => return Err(format!("object {k}: material {i}")),
            None if m.material_ids.contains(&u32::MAX) => return Err(format!("object {k}: no material")),
            _ => {}
        }
        if !o.world_from_object.is_finite() {
            return Err(format!("object {k}: world_from_object {}", o.world_from_object));
        }
        match &o.animation {
            None => {}
            Some(_) if s.animation.is_none() => return Err(format!("object {k} moves without [animation]")),
            Some(Animation::Keyframes(keys)) => {
                let ok = !keys.is_empty()
                    && keys.iter().all(|k| {
                        k.time.is_finite() && k.translation.is_finite() && k.rotation.is_finite() && k.scale.is_finite()
                    })
                    && keys.windows(2).all(|w| w[0].time < w[1].time);
                if !ok {
                    return Err(format!("object {k}: keyframes {keys:?}"));
                }
            }
            Some(Animation::Orbit { radius, period, phase }) => {
                let (radius, period, phase) = (*radius, *period, *phase);
                if !(radius.is_finite() && radius >= 0.0 && period.is_finite() && period > 0.0 && phase.is_finite()) {
                    return Err(format!("object {k}: orbit {:?}", o.animation));
                }
            }
        }
    }
    if let Some(a) = &s.animation {
        if !(a.fps.is_finite() && a.fps > 0.0) || a.frames.is_empty() {
            return Err(format!("animation {a:?}"));
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// (1) Random scene files

#[rustfmt::skip]
const TOML_TOKENS: &[&str] = &[
    "[camera]\n", "[render]\n", "[environment]\n", "[animation]\n", "[materials.m]\n", "[[objects]]\n",
    "[objects.scatter]\n", "[[objects.keyframes]]\n",
    "position", "look_at", "up", "fov", "resolution", "aperture", "spp", "max_depth", "time", "radiance", "type",
    "\"diffuse\"", "\"emissive\"", "albedo", "roughness", "shape", "\"box\"", "\"sphere\"", "\"city\"",
    "subdivisions", "triangles", "material", "\"m\"", "mesh", "\"m.obj\"", "scale", "translate", "matrix",
    "count", "min", "max", "fps", "frames", "map", "\"m.exr\"", "rotate",
    " = ", "=", "\n", "[", "]", "[0, 0, 1]", "[16, 16]", "{", "}", ",", ".", "\"", "'", "\"\"\"", "'''", "#",
    "0", "1", "-1", "2.5", "nan", "-inf", "1e400", "9223372036854775808", "true", "1979-05-27T07:32:00Z",
    "\\u0000", "\\", "\u{e9}", "\u{2028}", "\t", "\r\n", "\r", " ",
];

/// TOML-ish tokens: near-valid scenes reach the checks after parsing.
fn toml_soup() -> impl Strategy<Value = String> {
    let tokens = select(TOML_TOKENS);
    prop::collection::vec(tokens, 0..80).prop_map(|t| t.concat())
}

proptest! {
    #![proptest_config(config(1000))]

    #[test]
    fn random_bytes_as_the_scene(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        check(&[("scene.toml", &bytes)], &["scene.toml"])?;
    }

    #[test]
    fn random_text_as_the_scene(text in "(?s).{0,400}") {
        check(&[("scene.toml", text.as_bytes())], &["scene.toml"])?;
    }

    #[test]
    fn toml_soup_as_the_scene(text in toml_soup()) {
        check(&[("scene.toml", text.as_bytes())], &["scene.toml"])?;
    }
}

// ---------------------------------------------------------------------------------------------
// (2) Random OBJ and MTL files

const OBJ_SCENE: &str = "[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]
fov = 40
resolution = [16, 16]

[materials.white]
type = \"diffuse\"
albedo = [0.5, 0.5, 0.5]

[[objects]]
mesh = \"m.obj\"
";

const GOOD_OBJ: &str = "mtllib m.mtl
o thing
v 0 0 0
v 1 0 0
v 0 1 0
v 1 1 0
usemtl red
f 1 2 3
usemtl glass
f 2 4 3
";

const GOOD_MTL: &str = "newmtl red
Kd 0.8 0.1 0.1
newmtl glass
Kd 0 0 0
d 0.2
Ni 1.5
newmtl lamp
Ke 4 4 4
";

/// The scene naming `m.obj`, with or without an object material.
fn obj_scene(material: bool) -> String {
    format!("{OBJ_SCENE}{}", if material { "material = \"white\"\n" } else { "" })
}

/// A number as an OBJ or MTL file might hold one, or not.
fn number() -> impl Strategy<Value = String> {
    prop_oneof![
        4 => (-10.0f32..10.0).prop_map(|x| x.to_string()),
        1 => select(vec![
            "nan", "NaN", "inf", "-inf", "infinity", "1e39", "-1e39", "3.4e38", "1e-45", "0", "-0", "1e30",
            "-1e30", "4294967296", "1..2", "0x10", "+1", "1e", "-", "\u{661}",
        ]).prop_map(str::to_owned),
    ]
}

/// A face index: valid, relative, zero, out of range, overflowing, or not a number.
fn face_index() -> impl Strategy<Value = String> {
    prop_oneof![
        6 => (1i64..12).prop_map(|i| i.to_string()),
        2 => (-12i64..0).prop_map(|i| i.to_string()),
        1 => select(vec![
            "0", "4294967296", "9223372036854775807", "-9223372036854775808", "99999999999999999999",
            "6148914691236517206", "-4611686018427387904", "a", "",
        ]).prop_map(str::to_owned),
    ]
}

/// One vertex of a face: `v`, `v/vt`, `v//vn`, `v/vt/vn`, or one part too many.
fn face_vertex() -> impl Strategy<Value = String> {
    (prop::collection::vec(face_index(), 1..5), any::<bool>()).prop_map(|(parts, skip_vt)| match &parts[..] {
        [v, vn] if skip_vt => format!("{v}//{vn}"),
        _ => parts.join("/"),
    })
}

fn material_name() -> impl Strategy<Value = String> {
    select(vec!["red", "glass", "lamp", "nope", "", "red glass", "\u{e9}"]).prop_map(str::to_owned)
}

/// Lines of OBJ and MTL keywords without their values, and of what tobj reads its own way.
#[rustfmt::skip]
const GARBAGE_LINES: &[&str] = &[
    "s 1", "#", "p 1", "vp 1", "\t", "f", "v", "o", "usemtl", "mtllib", "newmtl", "Kd", "  v 1 2 3",
    "l 1 2 3", "f 1 2 3 # c", "v 1 2 3 # c", "v 1 2 3 0 1 1", "v 1 2 3 a b c", "\u{feff}v 1 2 3", "#x",
];

fn garbage_line() -> impl Strategy<Value = String> {
    prop_oneof!["(?s).{0,20}", select(GARBAGE_LINES).prop_map(str::to_owned)]
}

fn obj_line() -> impl Strategy<Value = String> {
    prop_oneof![
        4 => prop::collection::vec(number(), 3).prop_map(|v| format!("v {}", v.join(" "))),
        1 => prop::collection::vec(number(), 0..8).prop_map(|v| format!("v {}", v.join(" "))),
        1 => prop::collection::vec(number(), 2).prop_map(|v| format!("vt {}", v.join(" "))),
        1 => prop::collection::vec(number(), 3).prop_map(|v| format!("vn {}", v.join(" "))),
        5 => prop::collection::vec(face_vertex(), 0..7).prop_map(|v| format!("f {}", v.join(" "))),
        1 => prop::collection::vec(face_vertex(), 0..4).prop_map(|v| format!("l {}", v.join(" "))),
        1 => material_name().prop_map(|n| format!("usemtl {n}")),
        1 => select(vec!["m.mtl", "other.mtl", "", "../m.mtl", "m.mtl m.mtl", ".", "/dev/null"])
            .prop_map(|n| format!("mtllib {n}")),
        1 => (select(vec!["o", "g", " o", "\u{3000}g"]), "[a-z \u{e9}]{0,6}").prop_map(|(k, n)| format!("{k} {n}")),
        1 => garbage_line(),
    ]
}

fn mtl_line() -> impl Strategy<Value = String> {
    prop_oneof![
        2 => material_name().prop_map(|n| format!("newmtl {n}")),
        4 => (select(vec!["Ka", "Kd", "Ks", "Ke"]), prop::collection::vec(number(), 0..5))
            .prop_map(|(k, v)| format!("{k} {}", v.join(" "))),
        2 => (select(vec!["Ns", "Ni", "d", "Tr"]), prop::collection::vec(number(), 0..2))
            .prop_map(|(k, v)| format!("{k} {}", v.join(" "))),
        1 => select(vec!["-1", "0", "2", "4", "7", "9", "255", "300", "x", ""]).prop_map(|n| format!("illum {n}")),
        1 => select(vec!["map_Kd tex.png", "map_Kd", "map_Bump", "bump", "map_d x"]).prop_map(str::to_owned),
        1 => garbage_line(),
    ]
}

fn lines(line: impl Strategy<Value = String>) -> impl Strategy<Value = Vec<u8>> {
    (prop::collection::vec(line, 0..40), select(vec!["\n", "\r\n"])).prop_map(|(l, end)| l.join(end).into_bytes())
}

/// `lines` with each `(at, line)` of `faults` inserted, so that a fault can come after valid
/// content (a random file mostly fails at its first lines).
fn with_faults(mut lines: Vec<String>, faults: Vec<(Index, String)>, end: &str) -> Vec<u8> {
    for (at, line) in faults {
        lines.insert(at.index(lines.len() + 1), line);
    }
    lines.join(end).into_bytes()
}

/// An index into a list of `n` (1-based, or relative), now and then anything.
fn index_below(n: usize) -> impl Strategy<Value = String> {
    let n = n.max(1) as i64;
    prop_oneof![
        8 => (1..=n).prop_map(|i| i.to_string()),
        3 => (1..=n).prop_map(|i| (-i).to_string()),
        1 => face_index(),
    ]
}

/// A mostly valid OBJ file: vertices, texture coordinates and normals, then faces over them,
/// `usemtl` and `o`/`g` lines, with a few random lines mixed in.
fn mostly_valid_obj() -> impl Strategy<Value = Vec<u8>> {
    (3usize..8, 0usize..4, 0usize..4).prop_flat_map(|(nv, nvt, nvn)| {
        let vertex = (index_below(nv), index_below(nvt), index_below(nvn), 0..4)
            .prop_map(|(v, t, n, form)| match form {
                0 => v,
                1 => format!("{v}/{t}"),
                2 => format!("{v}//{n}"),
                _ => format!("{v}/{t}/{n}"),
            })
            .boxed();
        let face = prop_oneof![
            8 => prop::collection::vec(vertex.clone(), 3..6),
            1 => prop::collection::vec(vertex, 0..3),
        ]
        .prop_map(|v| format!("f {}", v.join(" ")));
        let body = prop_oneof![
            6 => face,
            1 => material_name().prop_map(|n| format!("usemtl {n}")),
            1 => select(vec!["o a", "g b", "o", "g"]).prop_map(str::to_owned),
        ];
        let coords = |n: usize, k: usize| prop::collection::vec((-10.0f32..10.0).prop_map(|x| x.to_string()), n * k);
        (
            coords(nv, 3),
            coords(nvt, 2),
            coords(nvn, 3),
            prop::collection::vec(body, 1..12),
            prop::collection::vec((any::<Index>(), obj_line()), 0..3),
            select(vec!["\n", "\r\n"]),
        )
            .prop_map(move |(v, vt, vn, body, faults, end)| {
                let mut lines = vec!["mtllib m.mtl".to_owned()];
                lines.extend(v.chunks(3).map(|c| format!("v {}", c.join(" "))));
                lines.extend(vt.chunks(2).map(|c| format!("vt {}", c.join(" "))));
                lines.extend(vn.chunks(3).map(|c| format!("vn {}", c.join(" "))));
                lines.extend(body);
                with_faults(lines, faults, end)
            })
    })
}

/// A mostly valid MTL file: the materials `GOOD_OBJ` uses, with a few random lines mixed in.
fn mostly_valid_mtl() -> impl Strategy<Value = Vec<u8>> {
    (prop::collection::vec((any::<Index>(), mtl_line()), 0..3), select(vec!["\n", "\r\n"]))
        .prop_map(|(faults, end)| with_faults(GOOD_MTL.lines().map(str::to_owned).collect(), faults, end))
}

fn obj_bytes() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![1 => prop::collection::vec(any::<u8>(), 0..300), 2 => lines(obj_line()), 4 => mostly_valid_obj()]
}

fn mtl_bytes() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![1 => prop::collection::vec(any::<u8>(), 0..300), 2 => lines(mtl_line()), 4 => mostly_valid_mtl()]
}

proptest! {
    #![proptest_config(config(1000))]

    /// The MTL file is fine, so whatever goes wrong is the OBJ's fault.
    #[test]
    fn random_obj_files(obj in obj_bytes(), material in any::<bool>()) {
        let scene = obj_scene(material);
        check(&[("scene.toml", scene.as_bytes()), ("m.obj", &obj), ("m.mtl", GOOD_MTL.as_bytes())], &["m.obj"])?;
    }

    /// The OBJ file is fine: without an object material a broken MTL file is an error naming
    /// it; with one, the MTL file is not needed and the scene loads.
    #[test]
    fn random_mtl_files(mtl in mtl_bytes(), material in any::<bool>()) {
        let scene = obj_scene(material);
        let files: [(&str, &[u8]); 3] = [("scene.toml", scene.as_bytes()), ("m.obj", GOOD_OBJ.as_bytes()), ("m.mtl", &mtl)];
        let failed = check(&files, &["m.obj", "m.mtl"])?;
        prop_assert!(!material || failed.is_none(), "an object material did not make the MTL file unneeded");
    }

    #[test]
    fn random_obj_and_mtl_files(obj in obj_bytes(), mtl in mtl_bytes(), material in any::<bool>()) {
        let scene = obj_scene(material);
        check(&[("scene.toml", scene.as_bytes()), ("m.obj", &obj), ("m.mtl", &mtl)], &["m.obj"])?;
    }
}

// ---------------------------------------------------------------------------------------------
// (2b) Random PLY files

/// The scene naming `m.ply`, with or without an object material.
fn ply_scene(material: bool) -> String {
    obj_scene(material).replace("m.obj", "m.ply")
}

const PLY_FORMATS: [&str; 3] = ["ascii", "binary_little_endian", "binary_big_endian"];

#[rustfmt::skip]
const PLY_TYPES: &[&str] = &[
    "char", "uchar", "short", "ushort", "int", "uint", "float", "double",
    "int8", "uint8", "int16", "uint16", "int32", "uint32", "float32", "float64",
];

/// One property of a generated PLY element: a scalar of type `ty`, or a list of `ty` items
/// after a count of type `count`.
#[derive(Clone, Debug)]
struct PlyProperty {
    name: &'static str,
    count: Option<&'static str>,
    ty: &'static str,
}

/// A generated PLY element: each record its values in order, a list as its count then its items.
#[derive(Clone, Debug)]
struct PlyElement {
    name: &'static str,
    properties: Vec<PlyProperty>,
    records: Vec<Vec<f64>>,
}

/// `elements` as a PLY file in `format`; a list writes as many items as its count says, or as
/// there are. Values are cast to their type as Rust's `as` casts (saturating, NaN to 0).
fn encode_ply(elements: &[PlyElement], format: &str) -> Vec<u8> {
    let mut out = format!("ply\nformat {format} 1.0\ncomment fuzz\n");
    for e in elements {
        out += &format!("element {} {}\n", e.name, e.records.len());
        for p in &e.properties {
            out += &match p.count {
                Some(count) => format!("property list {count} {} {}\n", p.ty, p.name),
                None => format!("property {} {}\n", p.ty, p.name),
            };
        }
    }
    out += "end_header\n";
    let mut out = out.into_bytes();
    let big = format == "binary_big_endian";
    for e in elements {
        for record in &e.records {
            let mut values = record.iter().copied();
            let mut words: Vec<String> = Vec::new();
            let mut put = |out: &mut Vec<u8>, ty: &str, x: f64| {
                macro_rules! bytes {
                    ($v:expr) => {{
                        let v = $v;
                        if big { v.to_be_bytes().to_vec() } else { v.to_le_bytes().to_vec() }
                    }};
                }
                let (word, bytes) = match ty {
                    "char" | "int8" => ((x as i8).to_string(), bytes!(x as i8)),
                    "uchar" | "uint8" => ((x as u8).to_string(), bytes!(x as u8)),
                    "short" | "int16" => ((x as i16).to_string(), bytes!(x as i16)),
                    "ushort" | "uint16" => ((x as u16).to_string(), bytes!(x as u16)),
                    "int" | "int32" => ((x as i32).to_string(), bytes!(x as i32)),
                    "uint" | "uint32" => ((x as u32).to_string(), bytes!(x as u32)),
                    "float" | "float32" => ((x as f32).to_string(), bytes!(x as f32)),
                    _ => (x.to_string(), bytes!(x)),
                };
                if format == "ascii" {
                    words.push(word);
                } else {
                    out.extend(bytes);
                }
            };
            for p in &e.properties {
                let n = match p.count {
                    Some(count) => {
                        let n = values.next().unwrap_or(0.0);
                        put(&mut out, count, n);
                        n.max(0.0) as usize
                    }
                    None => 1,
                };
                for x in values.by_ref().take(n) {
                    put(&mut out, p.ty, x);
                }
            }
            if format == "ascii" {
                out.extend(words.join(" ").bytes());
                out.push(b'\n');
            }
        }
    }
    out
}

/// A coordinate: mostly an ordinary number, now and then one no mesh should hold.
fn ply_coordinate(finite: bool) -> BoxedStrategy<f64> {
    let ordinary = (-10.0f64..10.0).boxed();
    if finite {
        return ordinary;
    }
    prop_oneof![
        60 => ordinary,
        1 => select(vec![f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e39, -1e300, 3.4e38, -0.0, 1e-45]),
    ]
    .boxed()
}

/// A face's vertex index among `n` vertices: mostly valid, now and then negative, out of range
/// or past its type.
fn ply_index(n: usize, valid: bool) -> BoxedStrategy<f64> {
    let ordinary = (0..n).prop_map(|i| i as f64).boxed();
    if valid {
        return ordinary;
    }
    prop_oneof![
        60 => ordinary,
        1 => select(vec![-1.0, n as f64, 255.0, 256.0, 65535.0, 4294967295.0, -2147483648.0, 1e10]),
    ]
    .boxed()
}

/// A PLY mesh of a few vertices and faces in random types, with normals, texture coordinates,
/// other properties and other elements or not. Where `valid`, every coordinate is finite (and
/// of a float type), every index in range and every face of 3 to 5 vertices; otherwise now and
/// then not.
fn ply_mesh(valid: bool) -> impl Strategy<Value = Vec<PlyElement>> {
    let coord_types: Vec<&'static str> =
        if valid { vec!["float", "double", "float32", "float64"] } else { PLY_TYPES.to_vec() };
    let index_types: Vec<&'static str> = vec!["int", "uint", "short", "ushort", "uchar", "char", "int32", "uint8"];
    let count_types: Vec<&'static str> = vec!["uchar", "ushort", "uint", "char", "int", "uint8", "int32"];
    (3usize..8, select(coord_types), select(index_types), select(count_types), any::<bool>(), 0usize..4, any::<bool>())
        .prop_flat_map(move |(nv, coord, index, count, normals, uv, extra)| {
            // An index type too small for the vertex count, or a count type for the corners,
            // only where the file may be broken.
            let index = if valid && matches!(index, "char" | "uchar" | "uint8") { "int" } else { index };
            let count = if valid { "uchar" } else { count };
            let attributes = 3 * usize::from(normals) + if uv > 0 { 2 } else { 0 };
            let polygon = prop::collection::vec(ply_index(nv, valid), 3..6);
            let face = if valid {
                polygon.boxed()
            } else {
                prop_oneof![20 => polygon, 1 => prop::collection::vec(ply_index(nv, valid), 0..3)].boxed()
            };
            (
                Just((coord, index, count, normals, uv, extra)),
                prop::collection::vec(prop::collection::vec(ply_coordinate(valid), 3 + attributes), nv),
                prop::collection::vec(face, 0..8),
                prop::collection::vec(0u8..=255, nv),
            )
        })
        .prop_map(|((coord, index, count, normals, uv, extra), vertices, faces, colours)| {
            let p = |name, ty| PlyProperty { name, count: None, ty };
            let mut properties = vec![p("x", coord), p("red", "uchar"), p("y", coord), p("z", coord)];
            if normals {
                properties.extend([p("nx", coord), p("ny", coord), p("nz", coord)]);
            }
            let uv_names = [["u", "v"], ["s", "t"], ["texture_u", "texture_v"]];
            if uv > 0 {
                properties.extend(uv_names[uv - 1].map(|n| p(n, coord)));
            }
            let records = vertices
                .iter()
                .zip(colours)
                .map(|(v, c)| {
                    let mut r = vec![v[0], f64::from(c)];
                    r.extend(&v[1..]);
                    r
                })
                .collect();
            let mut elements = vec![PlyElement { name: "vertex", properties, records }];
            let name = if extra { "vertex_index" } else { "vertex_indices" };
            let list = PlyProperty { name, count: Some(count), ty: index };
            let faces = faces
                .into_iter()
                .map(|f| {
                    let mut r = vec![f.len() as f64];
                    r.extend(f);
                    if extra {
                        r.push(7.0);
                    }
                    r
                })
                .collect();
            let mut face_properties = vec![list];
            if extra {
                face_properties.push(p("flags", "int"));
                let edge = PlyProperty { name: "weights", count: Some("uchar"), ty: "float" };
                elements.insert(
                    0,
                    PlyElement {
                        name: "edge",
                        properties: vec![p("vertex1", "int"), edge],
                        records: vec![vec![0.0, 2.0, 0.5, 0.25], vec![1.0, 0.0]],
                    },
                );
            }
            elements.push(PlyElement { name: "face", properties: face_properties, records: faces });
            elements
        })
}

/// One random change to a PLY file's bytes.
#[derive(Clone, Debug)]
enum PlyMutation {
    Truncate(Index),
    SetByte(Index, u8),
    InsertBytes(Index, Vec<u8>),
    /// Four bytes replaced by a value that breaks a count, an index or a coordinate: a count
    /// of 2^32 - 1, an index of -1, NaN, infinity.
    Overwrite(Index, [u8; 4]),
    /// A number of the text (a header's count, an ASCII value) replaced.
    ReplaceNumber(Index, &'static str),
}

fn ply_mutation() -> impl Strategy<Value = PlyMutation> {
    let words = vec![
        "nan",
        "inf",
        "-inf",
        "-1",
        "0",
        "2",
        "255",
        "256",
        "65536",
        "4294967296",
        "1000000000000",
        "18446744073709551615",
        "1e39",
        "x",
        "1.5",
    ];
    let values = vec![
        [0xff; 4],
        [0x7f, 0xc0, 0, 0],
        [0, 0, 0xc0, 0x7f],
        [0x7f, 0x80, 0, 0],
        [0, 0, 0x80, 0x7f],
        [0x80, 0, 0, 0],
        [0, 0, 0, 0x80],
        [0x02, 0, 0, 0],
        [0, 0, 0, 0x02],
        [0xff, 0xff, 0xff, 0x7f],
    ];
    prop_oneof![
        1 => any::<Index>().prop_map(PlyMutation::Truncate),
        1 => (any::<Index>(), any::<u8>()).prop_map(|(i, b)| PlyMutation::SetByte(i, b)),
        1 => (any::<Index>(), prop::collection::vec(any::<u8>(), 1..8)).prop_map(|(i, b)| PlyMutation::InsertBytes(i, b)),
        2 => (any::<Index>(), select(values)).prop_map(|(i, v)| PlyMutation::Overwrite(i, v)),
        2 => (any::<Index>(), select(words)).prop_map(|(i, w)| PlyMutation::ReplaceNumber(i, w)),
    ]
}

impl PlyMutation {
    fn apply(&self, bytes: &mut Vec<u8>) {
        let at = |i: &Index, len: usize| i.index(len + 1);
        match self {
            PlyMutation::Truncate(i) => bytes.truncate(at(i, bytes.len())),
            PlyMutation::SetByte(i, b) if !bytes.is_empty() => {
                let k = i.index(bytes.len());
                bytes[k] = *b;
            }
            PlyMutation::SetByte(..) => {}
            PlyMutation::InsertBytes(i, b) => {
                let k = at(i, bytes.len());
                splice(bytes, k..k, b);
            }
            PlyMutation::Overwrite(i, v) => {
                if bytes.len() >= 4 {
                    let k = i.index(bytes.len() - 3);
                    bytes[k..k + 4].copy_from_slice(v);
                }
            }
            PlyMutation::ReplaceNumber(i, w) => {
                let found = numbers(bytes);
                if !found.is_empty() {
                    splice(bytes, found[i.index(found.len())].clone(), w.as_bytes());
                }
            }
        }
    }
}

/// An `element` line: a name and a count, mostly small, now and then huge, overflowing or not a
/// number.
fn ply_element_line() -> impl Strategy<Value = String> {
    let count = prop_oneof![
        6 => (0u64..6).prop_map(|n| n.to_string()),
        1 => select(vec!["4294967296", "1000000000000", "18446744073709551615", "18446744073709551616", "-1", "x"])
            .prop_map(str::to_owned),
    ];
    (select(vec!["vertex", "face", "edge", "material", ""]), count).prop_map(|(n, c)| format!("element {n} {c}"))
}

/// A `property` line: a scalar or a list, of a name the reader knows or not, and a type or not.
fn ply_property_line() -> impl Strategy<Value = String> {
    let names = vec![
        "x",
        "y",
        "z",
        "nx",
        "ny",
        "nz",
        "u",
        "v",
        "s",
        "t",
        "texture_u",
        "texture_v",
        "red",
        "vertex_indices",
        "vertex_index",
        "flags",
    ];
    let types = || {
        prop_oneof![
            12 => select(PLY_TYPES.to_vec()),
            1 => select(vec!["real", "list", "", "int64"]),
        ]
    };
    prop_oneof![
        2 => (types(), select(names.clone())).prop_map(|(t, n)| format!("property {t} {n}")),
        1 => (types(), types(), select(names)).prop_map(|(c, t, n)| format!("property list {c} {t} {n}")),
    ]
}

/// A PLY header's line, valid and not.
fn ply_header_line() -> impl Strategy<Value = String> {
    prop_oneof![
        3 => select(vec![
            "ply", "format ascii 1.0", "format binary_little_endian 1.0", "format binary_big_endian 1.0",
            "format ascii 2.0", "format utf8 1.0", "format", "comment x", "obj_info y", "end_header", "end_header x",
            "element", "property", "property list", "", " ", "\u{e9}",
        ])
        .prop_map(str::to_owned),
        2 => ply_element_line(),
        3 => ply_property_line(),
    ]
}

/// A header after `ply`: mostly a `format` line, then elements of a few properties each, any of
/// them broken, with random lines mixed in; `end_header` or not; then random bytes or lines of
/// random numbers.
fn random_header_ply() -> impl Strategy<Value = Vec<u8>> {
    let element = (ply_element_line(), prop::collection::vec(ply_property_line(), 0..5));
    let body = prop_oneof![
        prop::collection::vec(any::<u8>(), 0..200),
        prop::collection::vec(prop::collection::vec(number(), 0..6).prop_map(|w| w.join(" ")), 0..12)
            .prop_map(|l| l.join("\n").into_bytes()),
    ];
    let format = prop_oneof![
        6 => select(PLY_FORMATS.to_vec()).prop_map(|f| format!("format {f} 1.0")),
        1 => ply_header_line(),
    ];
    let faults = prop::collection::vec((any::<Index>(), ply_header_line()), 0..3);
    (format, prop::collection::vec(element, 0..4), faults, any::<bool>(), body).prop_map(
        |(format, elements, faults, end, body)| {
            let mut lines = vec![format];
            for (element, properties) in elements {
                lines.push(element);
                lines.extend(properties);
            }
            for (at, line) in faults {
                lines.insert(at.index(lines.len() + 1), line);
            }
            if end {
                lines.push("end_header".to_owned());
            }
            let mut out = format!("ply\n{}\n", lines.join("\n")).into_bytes();
            out.extend(body);
            out
        },
    )
}

fn ply_bytes() -> impl Strategy<Value = Vec<u8>> {
    let mutated = (ply_mesh(false), select(PLY_FORMATS.to_vec()), prop::collection::vec(ply_mutation(), 0..3))
        .prop_map(|(elements, format, mutations)| {
            let mut bytes = encode_ply(&elements, format);
            for m in &mutations {
                m.apply(&mut bytes);
            }
            bytes
        });
    prop_oneof![1 => prop::collection::vec(any::<u8>(), 0..300), 2 => random_header_ply(), 5 => mutated]
}

proptest! {
    #![proptest_config(config(1000))]

    /// Random bytes, random headers, and meshes in every encoding with broken values and bytes:
    /// whatever goes wrong is the PLY file's fault, and the error names it.
    #[test]
    fn random_ply_files(ply in ply_bytes(), material in any::<bool>()) {
        let scene = ply_scene(material);
        check(&[("scene.toml", scene.as_bytes()), ("m.ply", &ply)], &["m.ply"])?;
    }
}

proptest! {
    #![proptest_config(config(256))]

    /// A valid mesh loads, and to the same mesh bit for bit from each encoding.
    #[test]
    fn ply_encodings_load_the_same_mesh(elements in ply_mesh(true)) {
        let dir = CaseDir::new();
        let bits = |m: &arbor::geometry::TriangleMesh| {
            let v3 = |v: &[Vec3]| v.iter().flat_map(|p| p.to_array().map(f32::to_bits)).collect::<Vec<_>>();
            let uvs: Vec<u32> = m.uvs.iter().flat_map(|p| p.to_array().map(f32::to_bits)).collect();
            (v3(&m.positions), v3(&m.normals), uvs, m.indices.clone())
        };
        let mut loaded = Vec::new();
        for format in PLY_FORMATS {
            let path = dir.write(&format!("{format}.ply"), &encode_ply(&elements, format));
            let mesh = arbor::geometry::TriangleMesh::load_ply(&path);
            let mesh = mesh.map_err(|e| TestCaseError::fail(format!("{format}: {e}\n{elements:?}")))?;
            loaded.push(bits(&mesh));
        }
        prop_assert!(loaded[0] == loaded[1] && loaded[1] == loaded[2], "{elements:?}");
    }
}

// ---------------------------------------------------------------------------------------------
// (2c) Random glTF files

/// The scene naming `file`, with or without an object material, its camera from the file or not.
fn gltf_scene(file: &str, material: bool, camera_from_file: bool) -> String {
    let scene = obj_scene(material).replace("m.obj", file);
    if !camera_from_file {
        return scene;
    }
    let (camera, rest) = scene.split_once("\n\n").unwrap();
    let resolution = camera.lines().find(|l| l.starts_with("resolution")).unwrap();
    format!("[camera]\nfrom = \"{file}\"\n{resolution}\n\n{rest}")
}

/// A valid document touching most of the reader: a parent over a TRS node and a matrix node
/// sharing the triangle, a strip over a sparse accessor, a textured material, a camera.
fn gltf_doc() -> Doc {
    let mut d = triangle_doc();
    let p = d.floats(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0], "VEC3");
    let si = d.view(&[1u8], None);
    let sv = d.view(&[2f32, 0.0, 0.0].iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>(), None);
    d.json["accessors"][p]["sparse"] = json!({ "count": 1, "indices": { "bufferView": si, "componentType": UNSIGNED_BYTE }, "values": { "bufferView": sv } });
    let strip = d.indices(&[0, 1, 2, 3], UNSIGNED_SHORT);
    d.mesh(&[("POSITION", p)], Some(strip), Some(5));
    d.json["meshes"][1]["primitives"][0]["material"] = json!(0);
    // A 1 x 1 PNG as a data URI: the texture loads.
    let mut png = Vec::new();
    image::RgbaImage::from_raw(1, 1, vec![200, 100, 50, 255])
        .unwrap()
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageOutputFormat::Png)
        .unwrap();
    d.push("images", json!({ "uri": format!("data:image/png;base64,{}", crate::common::gltf::base64(&png)) }));
    d.push("textures", json!({ "source": 0 }));
    d.push(
        "materials",
        json!({ "pbrMetallicRoughness": { "baseColorFactor": [0.5, 0.5, 0.5, 1], "baseColorTexture": { "index": 0 } },
                "emissiveFactor": [0.1, 0.1, 0.1] }),
    );
    let a =
        d.node(json!({ "mesh": 0, "translation": [0, 1, 0], "rotation": [0, 0, 0.6, 0.8], "scale": [1, 2, 1] }), false);
    let b = d.node(json!({ "mesh": 0, "matrix": [-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 3, 0, 0, 1] }), false);
    d.node(json!({ "children": [a, b], "translation": [0, 0, -2] }), true);
    d.node(json!({ "mesh": 1 }), true);
    d.push("cameras", json!({ "type": "perspective", "perspective": { "yfov": 0.7, "znear": 0.1 } }));
    d.node(json!({ "camera": 0, "translation": [0, 0, 5] }), true);
    d
}

/// Values a JSON mutation puts in place of another.
fn json_values() -> Vec<Value> {
    vec![
        json!(null),
        json!(-1),
        json!(0),
        json!(1),
        json!(3),
        json!(4294967296u64),
        json!(1e12),
        json!(1.5),
        json!(1e38),
        json!("x"),
        json!([]),
        json!({}),
        json!([0, 0]),
    ]
}

/// Every JSON pointer below `v` (`/meshes/0/primitives/0/mode`).
fn pointers(v: &Value, at: &str, out: &mut Vec<String>) {
    match v {
        Value::Object(m) => {
            for (k, child) in m {
                let p = format!("{at}/{k}");
                out.push(p.clone());
                pointers(child, &p, out);
            }
        }
        Value::Array(a) => {
            for (i, child) in a.iter().enumerate() {
                let p = format!("{at}/{i}");
                out.push(p.clone());
                pointers(child, &p, out);
            }
        }
        _ => {}
    }
}

/// Replaces the value at a pointer chosen by `at` by `json_values()[value]`, or removes it
/// (an object's key; an array element is replaced by null instead, keeping indices).
fn mutate_json(v: &mut Value, at: &Index, value: usize, remove: bool) {
    let mut all = Vec::new();
    pointers(v, "", &mut all);
    if all.is_empty() {
        return;
    }
    let p = &all[at.index(all.len())];
    let (parent, key) = p.rsplit_once('/').unwrap();
    let replacement = json_values()[value].clone();
    match v.pointer_mut(parent) {
        Some(Value::Object(m)) if remove => {
            m.remove(key);
        }
        Some(target) => {
            if let Some(slot) = target.pointer_mut(&format!("/{key}")) {
                *slot = if remove { Value::Null } else { replacement };
            }
        }
        None => {}
    }
}

fn random_glb() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        prop::collection::vec(any::<u8>(), 0..300),
        prop::collection::vec(any::<u8>(), 0..300).prop_map(|b| [b"glTF\x02\0\0\0".as_slice(), &b].concat()),
    ]
}

proptest! {
    #![proptest_config(config(500))]

    #[test]
    fn random_bytes_as_a_glb_file(bytes in random_glb(), material in any::<bool>(), camera in any::<bool>()) {
        let scene = gltf_scene("m.glb", material, camera);
        check(&[("scene.toml", scene.as_bytes()), ("m.glb", &bytes)], &["m.glb"])?;
    }

    /// A valid document changed as JSON, then as bytes: whatever goes wrong is the glTF file's
    /// fault, and the error names it; unchanged, it loads.
    #[test]
    fn mutated_gltf_files(
        changes in prop::collection::vec((any::<Index>(), 0..json_values().len(), any::<bool>()), 0..4),
        bytes in prop::collection::vec(ply_mutation(), 0..3),
        glb in any::<bool>(),
        material in any::<bool>(),
        camera in any::<bool>(),
    ) {
        let mut doc = gltf_doc();
        for (at, value, remove) in &changes {
            mutate_json(&mut doc.json, at, *value, *remove);
        }
        let (name, mut data) = if glb { ("m.glb", doc.glb()) } else { ("m.gltf", doc.gltf_embedded()) };
        for m in &bytes {
            m.apply(&mut data);
        }
        let scene = gltf_scene(name, material, camera);
        let failed = check(&[("scene.toml", scene.as_bytes()), (name, &data)], &[name])?;
        prop_assert!(!changes.is_empty() || !bytes.is_empty() || failed.is_none(), "the valid document failed");
    }
}

// ---------------------------------------------------------------------------------------------
// (3) Mutated example scenes

/// Every `scenes/*.toml`, read when the tests run, sorted by name.
fn example_scenes() -> &'static [(String, String)] {
    static SCENES: std::sync::OnceLock<Vec<(String, String)>> = std::sync::OnceLock::new();
    SCENES.get_or_init(|| {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
        let mut scenes: Vec<(String, String)> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "toml"))
            .map(|p| (p.file_name().unwrap().to_string_lossy().into_owned(), std::fs::read_to_string(&p).unwrap()))
            // The scenes are loaded from a temporary folder: their assets by absolute path.
            .map(|(name, text)| (name, text.replace("\"assets/", &format!("\"{}/assets/", dir.display()))))
            .collect();
        scenes.sort();
        assert!(!scenes.is_empty(), "no scenes in {}", dir.display());
        scenes
    })
}

#[rustfmt::skip]
const VALUES: &[&str] = &[
    "nan", "inf", "-inf", "-1", "0", "1", "-0.0", "1e30", "1e-45", "3.4e38", "-3.4e38", "4294967296",
    "18446744073709551615", "65537", "10000001", "100000001", "\"a string\"", "[1, 2]", "[]", "[[1]]", "{}", "true",
];

#[rustfmt::skip]
const KEYS: &[&str] = &[
    "camera", "position", "look_at", "up", "fov", "resolution", "aperture", "focus_distance", "render", "spp",
    "max_depth", "seed", "time", "environment", "radiance", "materials", "type", "albedo", "two_sided", "roughness",
    "eta", "k", "base_color", "ior", "objects", "mesh", "shape", "subdivisions", "triangles", "material", "translate",
    "rotate", "scale", "matrix", "keyframes", "scatter", "animation", "fps", "frames", "count", "min", "max",
    "moving", "radius", "period", "map", "bogus", "a.b", "\"quoted key\"", "position.x",
];

#[rustfmt::skip]
const TABLES: &[&str] = &[
    "[camera]", "[render]", "[environment]", "[animation]", "[materials.white]", "[materials]", "[[objects]]",
    "[objects]", "[objects.scatter]", "[[objects.keyframes]]", "[[materials]]", "[bogus]",
];

/// One random change to a scene file; indices pick among what the file holds.
#[derive(Clone, Debug)]
enum Mutation {
    DeleteLine(Index),
    DuplicateLine(Index),
    SwapLines(Index, Index),
    ReplaceNumber(Index, &'static str),
    ReplaceKey(Index, &'static str),
    ReplaceTable(Index, &'static str),
    Truncate(Index),
    InsertBytes(Index, Vec<u8>),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        1 => any::<Index>().prop_map(Mutation::DeleteLine),
        1 => any::<Index>().prop_map(Mutation::DuplicateLine),
        1 => (any::<Index>(), any::<Index>()).prop_map(|(a, b)| Mutation::SwapLines(a, b)),
        3 => (any::<Index>(), select(VALUES)).prop_map(|(i, v)| Mutation::ReplaceNumber(i, v)),
        2 => (any::<Index>(), select(KEYS)).prop_map(|(i, k)| Mutation::ReplaceKey(i, k)),
        1 => (any::<Index>(), select(TABLES)).prop_map(|(i, t)| Mutation::ReplaceTable(i, t)),
        1 => any::<Index>().prop_map(Mutation::Truncate),
        1 => (any::<Index>(), prop::collection::vec(any::<u8>(), 1..8)).prop_map(|(i, b)| Mutation::InsertBytes(i, b)),
    ]
}

/// Byte ranges of the numbers in `text` (runs like `-1.5e3` not inside a word).
fn numbers(text: &[u8]) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < text.len() {
        let starts = text[i].is_ascii_digit()
            || (matches!(text[i], b'-' | b'+') && text.get(i + 1).is_some_and(u8::is_ascii_digit));
        let after_word = i > 0 && (text[i - 1].is_ascii_alphanumeric() || matches!(text[i - 1], b'_' | b'.'));
        if !starts || after_word {
            i += 1;
            continue;
        }
        let start = i;
        i += 1;
        while i < text.len()
            && (text[i].is_ascii_digit()
                || matches!(text[i], b'.' | b'e' | b'E' | b'_')
                || (matches!(text[i], b'-' | b'+') && matches!(text[i - 1], b'e' | b'E')))
        {
            i += 1;
        }
        out.push(start..i);
    }
    out
}

/// Line `k` of `text` as a byte range, its newline excluded.
fn line_ranges(text: &[u8]) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut start = 0;
    for (i, &b) in text.iter().enumerate() {
        if b == b'\n' {
            out.push(start..i);
            start = i + 1;
        }
    }
    out.push(start..text.len());
    out
}

/// The key of a `key = value` line, as a byte range.
fn key_of(text: &[u8], line: std::ops::Range<usize>) -> Option<std::ops::Range<usize>> {
    let l = &text[line.clone()];
    let start = l.iter().position(|b| !b.is_ascii_whitespace())?;
    let eq = l.iter().position(|&b| b == b'=')?;
    let end = l[..eq].iter().rposition(|b| !b.is_ascii_whitespace())? + 1;
    (start < end && l[start] != b'[' && l[start] != b'#').then(|| line.start + start..line.start + end)
}

fn splice(text: &mut Vec<u8>, range: std::ops::Range<usize>, with: &[u8]) {
    text.splice(range, with.iter().copied());
}

impl Mutation {
    fn apply(&self, text: &mut Vec<u8>) {
        let lines = line_ranges(text);
        let line = |i: &Index| lines[i.index(lines.len())].clone();
        match self {
            Mutation::DeleteLine(i) => {
                let l = line(i);
                let end = (l.end + 1).min(text.len());
                splice(text, l.start..end, b"");
            }
            Mutation::DuplicateLine(i) => {
                let l = line(i);
                let mut copy = text[l.clone()].to_vec();
                copy.push(b'\n');
                splice(text, l.start..l.start, &copy);
            }
            Mutation::SwapLines(a, b) => {
                let (mut a, mut b) = (line(a), line(b));
                if a.start > b.start {
                    std::mem::swap(&mut a, &mut b);
                }
                if a != b {
                    let (la, lb) = (text[a.clone()].to_vec(), text[b.clone()].to_vec());
                    splice(text, b, &la);
                    splice(text, a, &lb);
                }
            }
            Mutation::ReplaceNumber(i, value) => {
                let found = numbers(text);
                if !found.is_empty() {
                    splice(text, found[i.index(found.len())].clone(), value.as_bytes());
                }
            }
            Mutation::ReplaceKey(i, key) => {
                let keys: Vec<_> = lines.iter().filter_map(|l| key_of(text, l.clone())).collect();
                if !keys.is_empty() {
                    splice(text, keys[i.index(keys.len())].clone(), key.as_bytes());
                }
            }
            Mutation::ReplaceTable(i, table) => {
                let headers: Vec<_> = lines.iter().filter(|l| text[(*l).clone()].starts_with(b"[")).cloned().collect();
                if !headers.is_empty() {
                    splice(text, headers[i.index(headers.len())].clone(), table.as_bytes());
                }
            }
            Mutation::Truncate(i) => text.truncate(i.index(text.len() + 1)),
            Mutation::InsertBytes(i, bytes) => {
                let at = i.index(text.len() + 1);
                splice(text, at..at, bytes);
            }
        }
    }
}

proptest! {
    #![proptest_config(config(1000))]

    /// Syntactically valid TOML that fails, fails at a key (not `syntax`), and with a line.
    #[test]
    fn mutated_example_scenes(scene in any::<Index>(), mutations in prop::collection::vec(mutation(), 1..4)) {
        let (name, original) = &example_scenes()[scene.index(example_scenes().len())];
        let mut text = original.clone().into_bytes();
        for m in &mutations {
            m.apply(&mut text);
        }
        let files: [(&str, &[u8]); 1] = [(name, &text)];
        if let Some((_, key)) = check(&files, &[name])? {
            let syntax_ok = std::str::from_utf8(&text).is_ok_and(|t| t.parse::<toml::Table>().is_ok());
            prop_assert!(!syntax_ok || key != "syntax", "valid TOML failed as `syntax`\n{}", show(&files));
        }
    }
}

// ---------------------------------------------------------------------------------------------
// (3b) Syntax errors at a known line

/// Lines of `text` (1-based) that start outside any bracket, where a new line can go.
fn top_level_lines(text: &str) -> Vec<usize> {
    let mut depth = 0i32;
    let mut out = Vec::new();
    for (k, line) in text.lines().enumerate() {
        if depth == 0 {
            out.push(k + 1);
        }
        let code = line.split('#').next().unwrap_or("");
        depth += code.matches('[').count() as i32 - code.matches(']').count() as i32;
    }
    out
}

proptest! {
    #![proptest_config(config(256))]

    /// A line that is not TOML, inserted as line `at`, is an error at that line: `syntax`, or
    /// the line's key where toml finds a bad value only when it is read.
    #[test]
    fn syntax_errors_name_their_line(
        scene in any::<Index>(),
        at in any::<Index>(),
        bad in select(vec![
            "= 1", "key =", "key = 1 2", "key = \"open", "[open", "[[open]",
            "key = 1979-13-45", "key = 1__0", "key = 0x", "key = 'a", "\u{0}", "[a]]", "a.=1", "key = 99999999999999999999",
        ]),
    ) {
        let (name, original) = &example_scenes()[scene.index(example_scenes().len())];
        let starts = top_level_lines(original);
        let line = starts[at.index(starts.len())];
        let mut lines: Vec<&str> = original.lines().collect();
        lines.insert(line - 1, bad);
        let text = lines.join("\n");
        let files: [(&str, &[u8]); 1] = [(name, text.as_bytes())];
        let failed = check(&files, &[name])?;
        let at_line = failed.as_ref().is_some_and(|(l, key)| *l == line && (key == "syntax" || key.rsplit('.').next() == Some("key")));
        prop_assert!(at_line, "expected line {}, got {:?}\n{}", line, failed, show(&files));
    }
}

// ---------------------------------------------------------------------------------------------
// (3c) Keys that size things

/// A value for a key that sizes something, and whether it is past the key's documented limit.
#[derive(Clone, Debug)]
struct SizeCase {
    /// The key as errors name it, after the object index (`camera.resolution`, `triangles`).
    key: &'static str,
    value: String,
    over_limit: bool,
}

fn sized(
    key: &'static str,
    within: impl Strategy<Value = String> + 'static,
    over: Vec<&'static str>,
) -> BoxedStrategy<SizeCase> {
    prop_oneof![
        3 => within.prop_map(move |value| SizeCase { key, value, over_limit: false }),
        2 => select(over).prop_map(move |v| SizeCase { key, value: v.to_owned(), over_limit: true }),
    ]
    .boxed()
}

fn sizing_value() -> impl Strategy<Value = SizeCase> {
    prop_oneof![
        sized(
            "camera.resolution",
            (1u32..=65_536, 1u32..=65_536).prop_map(|(w, h)| format!("[{w}, {h}]")),
            vec!["[0, 16]", "[16, 0]", "[65537, 16]", "[16, 4294967296]", "[-1, 16]", "[16]", "[16, 16, 16]"],
        ),
        sized("render.spp", (1u32..).prop_map(|n| n.to_string()), vec!["0", "-1", "4294967296"]),
        sized(
            "subdivisions",
            (0u32..=5).prop_map(|n| n.to_string()),
            vec!["9", "64", "4294967295", "4294967296", "-1"],
        ),
        sized(
            "scatter.count",
            (1u64..=100_000).prop_map(|n| n.to_string()),
            vec!["0", "10000001", "4294967296", "9223372036854775807", "-1"],
        ),
        sized(
            "triangles",
            (1u64..=100_000).prop_map(|n| n.to_string()),
            vec!["0", "100000001", "4294967296", "9223372036854775807", "-5"],
        ),
        sized("animation.fps", (1e-3f32..1e6).prop_map(|x| x.to_string()), vec!["0", "-1", "nan", "inf", "-inf"]),
        sized(
            "animation.frames",
            (0u32..u32::MAX).prop_flat_map(|a| (Just(a), a + 1..=u32::MAX)).prop_map(|(a, b)| format!("[{a}, {b}]")),
            vec!["[5, 5]", "[5, 1]", "[-1, 5]", "[0, 4294967296]", "[0]"],
        ),
        sized("time", (-1e6f32..1e6).prop_map(|x| x.to_string()), vec!["nan", "inf", "-inf"]),
    ]
}

/// The first `[materials.NAME]` of a scene; `None` for a scene without (one whose glTF file
/// brings its materials).
fn first_material(text: &str) -> Option<&str> {
    let line = text.lines().find(|l| l.starts_with("[materials."))?;
    Some(line.trim_start_matches("[materials.").trim_end_matches(']'))
}

/// `text` with `s` applied: an existing `key = ...` line rewritten, or an object added at the end
/// for the keys of objects. Returns the new text, the value's line, and whether the scene is
/// still valid when the value is within its limit (keyframe times can fall out of order).
fn apply_sized(text: &str, s: &SizeCase, pick: &Index) -> Option<(String, usize, bool)> {
    let material = first_material(text)?;
    let added = |body: String| {
        let head = format!("{}\n[[objects]]\n", text.trim_end());
        let line =
            head.lines().count() + body.lines().position(|l| l.starts_with(s.key.rsplit('.').next().unwrap()))? + 1;
        Some((format!("{head}{body}"), line, true))
    };
    match s.key {
        "subdivisions" => added(format!("shape = \"sphere\"\nmaterial = \"{material}\"\nsubdivisions = {}\n", s.value)),
        "triangles" => added(format!(
            "shape = \"{}\"\nmaterial = \"{material}\"\ntriangles = {}\nseed = {}\n",
            if pick.index(2) == 0 { "city" } else { "hairball" },
            s.value,
            pick.index(1000)
        )),
        "scatter.count" => added(format!(
            "shape = \"box\"\nmaterial = \"{material}\"\n[objects.scatter]\nmin = [0, 0, 0]\nmax = [1, 1, 1]\ncount = {}\n",
            s.value
        )),
        key => {
            let name = key.rsplit('.').next().unwrap();
            let hits: Vec<usize> = text
                .lines()
                .enumerate()
                .filter(|(_, l)| l.split('=').next().is_some_and(|k| k.trim() == name))
                .map(|(k, _)| k)
                .collect();
            let k = *hits.get(pick.index(hits.len().max(1)))?;
            let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
            lines[k] = format!("{name} = {}", s.value);
            Some((lines.join("\n"), k + 1, key != "time"))
        }
    }
}

proptest! {
    #![proptest_config(config(500))]

    /// Within its limit a size loads (the generator stays at 10^5 or below); past it, it is an
    /// error at its key and line, before anything of that size is made.
    #[test]
    fn sizes_past_their_limits_are_errors(scene in any::<Index>(), s in sizing_value(), pick in any::<Index>()) {
        let (name, original) = &example_scenes()[scene.index(example_scenes().len())];
        let Some((text, line, valid)) = apply_sized(original, &s, &pick) else { return Ok(()) };
        let files: [(&str, &[u8]); 1] = [(name, text.as_bytes())];
        let failed = check(&files, &[name])?;
        if s.over_limit {
            let Some((at, key)) = failed else {
                return Err(TestCaseError::fail(format!("{} = {} loaded\n{}", s.key, s.value, show(&files))));
            };
            prop_assert!(at == line && key.contains(s.key), "expected line {line}, key {}, got {at}: {key}", s.key);
        } else if valid {
            prop_assert!(failed.is_none(), "{} = {} failed: {:?}\n{}", s.key, s.value, failed, show(&files));
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Regression tests: one per bug. The properties above found the first five (the OBJ index
// overflow only once mostly valid OBJ files were generated); the next two were found reading
// the loader while writing `usable` and the size limits, the next two reading the errors the
// fuzzer's inputs get; the OBJ/MTL ones at the end, a black-box QA pass.

/// Loads `scene` (with `files` beside it) and returns the error, which must be in
/// `file:line: key: message` form for the scene file, with `line` and `key` as given.
fn error_at(scene: &str, files: &[(&str, &str)], line: usize, key: &str) -> String {
    let mut all: Vec<(&str, &[u8])> = vec![("scene.toml", scene.as_bytes())];
    all.extend(files.iter().map(|(name, text)| (*name, text.as_bytes())));
    let (outcome, path) = load(&all);
    let text = match outcome {
        Outcome::Failed(e) => e.to_string(),
        Outcome::Loaded(_) => panic!("loaded:\n{}", show(&all)),
        Outcome::Panicked(msg) => panic!("panicked: {msg}\n{}", show(&all)),
    };
    let (at, k, _) = located(&text, &path).unwrap_or_else(|| panic!("not `file:line: key: message`: {text}"));
    assert_eq!((at, k.as_str()), (line, key), "{text}");
    text
}

const TRIANGLE: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";

/// tobj 4 unwraps a colour of fewer than 3 numbers (`Kd 0.5`) and panics.
#[test]
fn mtl_colour_with_fewer_than_three_numbers_is_an_error() {
    let obj = format!("mtllib m.mtl\n{TRIANGLE}usemtl red\nf 1 2 3\n");
    for colour in ["Ka", "Kd 0.5", "Ks 1 1", "Ke"] {
        let mtl = format!("newmtl red\n{colour}\n");
        let err = error_at(&obj_scene(false), &[("m.obj", &obj), ("m.mtl", &mtl)], 12, "objects[0].mesh");
        assert!(err.contains("m.mtl:2: `") && err.contains("needs 3 numbers"), "{err}");
        // An object material makes the MTL file unneeded.
        let (outcome, _) =
            load(&[("scene.toml", obj_scene(true).as_bytes()), ("m.obj", obj.as_bytes()), ("m.mtl", mtl.as_bytes())]);
        assert!(matches!(outcome, Outcome::Loaded(_)));
    }
}

/// tobj 4 resolves a `vt` or `vn` index out of range to a huge offset and multiplies it by 2 or
/// 3, which overflows (a panic with overflow checks, as in the test profile).
#[test]
fn obj_texture_or_normal_index_out_of_range_is_an_error() {
    for (face, says) in [
        ("f 1//-3 2//1 3//1", "normal -3 (relative), but 1 normals come before it"),
        ("f 1//6148914691236517206 2//1 3//1", "normal 6148914691236517206, but the file has 1 normals"),
        ("f 1/-2 2/1 3/1", "texture coordinate -2 (relative), but 1 texture coordinates come before it"),
        ("f 1/9223372036854775807 2/1 3/1", "texture coordinate 9223372036854775807, but the file has 1"),
    ] {
        let obj = format!("vn 0 0 1\nvt 0 0\n{TRIANGLE}{face}\n");
        let err = error_at(&obj_scene(true), &[("m.obj", &obj)], 12, "objects[0].mesh");
        assert!(err.contains("m.obj:6: `f` refers to ") && err.contains(says), "{err}");
        let dir = CaseDir::new();
        let err = arbor::geometry::TriangleMesh::load_obj(dir.write("m.obj", obj.as_bytes())).unwrap_err();
        assert!(err.to_string().contains("m.obj:6: `f` refers to "), "{err}");
    }
}

/// The scene was read with `read_to_string`: an error without a line, and not a TOML one.
#[test]
fn scene_that_is_not_utf8_is_an_error_at_its_line() {
    let (outcome, path) = load(&[("scene.toml", b"[camera]\nfov = \"\xff\"\n")]);
    let Outcome::Failed(e) = outcome else { panic!("loaded or panicked") };
    assert_eq!(e.to_string(), format!("{}:2: syntax: not UTF-8 (byte 0xff)", path.display()));
}

/// A broken MTL file was reported as the OBJ's, without the MTL file's name or line; a
/// `usemtl` of a name no MTL file defines said only that an object has no material.
#[test]
fn mtl_errors_name_the_mtl_file_and_line() {
    let obj = format!("mtllib m.mtl\n{TRIANGLE}usemtl red\nf 1 2 3\nusemtl blue\nf 1 2 3\n");
    let err = error_at(&obj_scene(false), &[("m.obj", &obj), ("m.mtl", "newmtl red\nNs x\n")], 12, "objects[0].mesh");
    assert!(
        err.contains("m.obj: cannot load its MTL materials: ") && err.contains("m.mtl:2: material parse error: `Ns x`"),
        "{err}"
    );
    let err = error_at(&obj_scene(false), &[("m.obj", &obj)], 12, "objects[0].mesh");
    assert!(err.contains("m.mtl: cannot read: "), "{err}");
    let err =
        error_at(&obj_scene(false), &[("m.obj", &obj), ("m.mtl", "newmtl red\nKd 1 0 0\n")], 12, "objects[0].mesh");
    assert!(err.contains("m.obj:7: `usemtl blue`: no MTL material `blue` (") && err.contains("m.mtl)"), "{err}");
    // The OBJ's own errors name its line too.
    let err = error_at(&obj_scene(true), &[("m.obj", "v 0 0 0\nv 1 nan 0\n")], 12, "objects[0].mesh");
    assert!(err.contains("m.obj:2: vertex 2: position [1.0, NaN, 0.0] is not finite"), "{err}");
    let err = error_at(&obj_scene(true), &[("m.obj", &format!("{TRIANGLE}v 1 2\n"))], 12, "objects[0].mesh");
    assert!(err.contains("m.obj:4: position parse error: `v 1 2`"), "{err}");
}

/// serde's `[T; N]` reads the first N elements and toml lets the rest pass, so
/// `resolution = [16, 16, 16]` loaded.
#[test]
fn arrays_longer_than_their_key_takes_are_errors() {
    let scene = obj_scene(false).replace("mesh = \"m.obj\"", "shape = \"box\"\nmaterial = \"white\"");
    let cases = [
        ("resolution = [16, 16]", "resolution = [16, 16, 16]", 5, "camera.resolution"),
        ("position = [0, 0, 5]", "position = [0, 0, 5, 1]", 2, "camera.position"),
        ("albedo = [0.5, 0.5, 0.5]", "albedo = [0.5, 0.5, 0.5, 0.5]", 9, "materials.white.albedo"),
        ("material = \"white\"", "material = \"white\"\ntranslate = [1, 2, 3, 4]", 14, "objects[0].translate"),
        ("material = \"white\"", "material = \"white\"\nscale = [1, 2, 3, 4]", 14, "objects[0].scale"),
        (
            "material = \"white\"",
            "material = \"white\"\nmatrix = [[1, 0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]",
            14,
            "objects[0].matrix[0]",
        ),
        (
            "material = \"white\"",
            "material = \"white\"\nmatrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [0, 0, 0, 1]]",
            14,
            "objects[0].matrix",
        ),
    ];
    for (from, to, line, key) in cases {
        let err = error_at(&scene.replace(from, to), &[], line, key);
        assert!(err.contains("invalid length"), "{err}");
    }
    let err = error_at(
        &scene.replace("material = \"white\"", "material = \"white\"\nscale = \"big\""),
        &[],
        14,
        "objects[0].scale",
    );
    assert!(err.ends_with("invalid type: string \"big\", expected a number or an array of 3 numbers"), "{err}");
}

/// A camera 3.4e38 from its target passed (its distance overflows to infinity) or failed as
/// "parallel to the view direction"; a scatter box from -3.4e38 to 3.4e38 placed instances at
/// NaN; a rotated scale of f32::MAX made an infinite placement.
#[test]
fn numbers_whose_arithmetic_overflows_are_errors() {
    let scene = obj_scene(false).replace("mesh = \"m.obj\"", "shape = \"box\"\nmaterial = \"white\"");
    let err = error_at(&scene.replace("[0, 0, 5]", "[0, 0, 3.4e38]"), &[], 3, "camera.look_at");
    assert!(err.contains("too far from camera.position"), "{err}");
    let err = error_at(&scene.replace("fov = 40", "up = [0, 1e30, 0]\nfov = 40"), &[], 4, "camera.up");
    assert!(err.contains("too long"), "{err}");
    let scatter = format!("{scene}[objects.scatter]\ncount = 2\nmin = [-3.4e38, 0, 0]\nmax = [3.4e38, 0, 0]\n");
    let err = error_at(&scatter, &[], 16, "objects[0].scatter.min");
    assert!(err.contains("too large"), "{err}");
    let placed =
        scene.replace("material = \"white\"", "material = \"white\"\nscale = 3.4028235e38\nrotate = [17, 90, 8.5]");
    let err = error_at(&placed, &[], 14, "objects[0].scale");
    assert!(err.contains("overflows"), "{err}");
}

/// Each scatter was limited to 10^7 instances and each procedural shape to 10^8 triangles, but
/// not their sums: a few lines could ask for any amount of memory.
#[test]
fn scene_totals_of_instances_and_procedural_triangles_are_bounded() {
    let scene = obj_scene(false).replace("mesh = \"m.obj\"", "shape = \"box\"\nmaterial = \"white\"");
    let scatter = format!(
        "{scene}\n[[objects]]\nshape = \"box\"\nmaterial = \"white\"\n[objects.scatter]\nmin = [0, 0, 0]\nmax = [1, 1, 1]\ncount = 10000000\n"
    );
    let err = error_at(&scatter, &[], 21, "objects[1].scatter.count");
    assert!(err.ends_with("10000000 instances make 10000001 objects in the scene, more than 10000000"), "{err}");
    let procedural = |n: u64, seed: u64| {
        format!("\n[[objects]]\nshape = \"hairball\"\nmaterial = \"white\"\ntriangles = {n}\nseed = {seed}\n")
    };
    let two = format!("{scene}{}{}", procedural(1, 0), procedural(100_000_000, 1));
    let err = error_at(&two, &[], 24, "objects[2].triangles");
    assert!(err.contains("more than 100000000"), "{err}");
}

/// serde's derive reads a struct from an array too, field by field: `[[camera]]` said
/// "camera[0]: invalid type: map, expected a sequence", and `camera = 5` named the Rust type.
#[test]
fn tables_given_as_something_else_say_a_table_is_expected() {
    let scene = obj_scene(false).replace("mesh = \"m.obj\"", "shape = \"box\"\nmaterial = \"white\"");
    for (from, to, line, key, says) in [
        ("[camera]", "[[camera]]", 1, "camera", "invalid type: sequence, expected a table"),
        ("[materials.white]", "[[materials.white]]", 7, "materials.white", "invalid type: sequence, expected a table"),
    ] {
        let err = error_at(&scene.replace(from, to), &[], line, key);
        assert!(err.ends_with(says), "{err}");
    }
    let no_objects = OBJ_SCENE.split("[[objects]]").next().unwrap();
    for (from, to, key, says) in [
        ("[camera]", "objects = [1]\n[camera]", "objects[0]", "invalid type: integer `1`, expected a table"),
        ("[camera]", "camera = 5\n[render]", "camera", "invalid type: integer `5`, expected a table"),
    ] {
        let err = error_at(&no_objects.replace(from, to), &[], 1, key);
        assert!(err.ends_with(says), "{err}");
    }
}

/// toml hands a datetime to serde as a map: `fov = 1979-05-27` said "invalid type: map".
#[test]
fn a_datetime_is_called_a_datetime() {
    let no_objects = OBJ_SCENE.split("[[objects]]").next().unwrap();
    let fov = no_objects.lines().position(|l| l.starts_with("fov")).expect("the scene sets fov") + 1;
    for (value, says) in [
        ("1979-05-27", "invalid type: datetime, expected f32"),
        ("07:32:00", "invalid type: datetime, expected f32"),
        ("1979-05-27T07:32:00Z", "invalid type: datetime, expected f32"),
        ("{ a = 1 }", "invalid type: map, expected f32"),
    ] {
        let scene =
            no_objects.lines().map(|l| if l.starts_with("fov") { format!("fov = {value}") } else { l.to_string() });
        let err = error_at(&scene.collect::<Vec<_>>().join("\n"), &[], fov, "camera.fov");
        assert!(err.ends_with(says), "{value}: {err}");
    }
}

/// tobj reads a file of no OBJ lines (random bytes, say) as one object of no faces: the error
/// was that object `unnamed_object` has no MTL material.
#[test]
fn obj_without_faces_is_an_error_that_says_so() {
    for obj in ["", "\u{1}garbage\n", "v 0 0 0\n"] {
        let err = error_at(&obj_scene(true), &[("m.obj", obj)], 12, "objects[0].mesh");
        assert!(err.ends_with("m.obj: no faces (`f` lines)"), "{err}");
    }
}

/// Loads `scene` (with `files` beside it), which must load.
fn loaded(scene: &str, files: &[(&str, &str)]) -> Scene {
    let mut all: Vec<(&str, &[u8])> = vec![("scene.toml", scene.as_bytes())];
    all.extend(files.iter().map(|(name, text)| (*name, text.as_bytes())));
    match load(&all).0 {
        Outcome::Loaded(scene) => *scene,
        Outcome::Failed(e) => panic!("{e}\n{}", show(&all)),
        Outcome::Panicked(msg) => panic!("panicked: {msg}\n{}", show(&all)),
    }
}

/// `TriangleMesh::load_obj` of `obj`, the error as text.
fn obj_mesh(obj: &str) -> Result<arbor::geometry::TriangleMesh, String> {
    let dir = CaseDir::new();
    arbor::geometry::TriangleMesh::load_obj(dir.write("m.obj", obj.as_bytes())).map_err(|e| e.to_string())
}

/// The corners of each triangle of `obj`, which must load.
fn corners(obj: &str) -> Vec<[[f32; 3]; 3]> {
    let mesh = obj_mesh(obj).unwrap_or_else(|e| panic!("{e}\n{obj}"));
    mesh.triangles().iter().map(|t| [t.v0.to_array(), t.v1.to_array(), t.v2.to_array()]).collect()
}

/// tobj read a UTF-8 byte-order mark as part of the first line's keyword: a first `v` line was
/// dropped (every index after it shifted by one), a first `newmtl` line too.
#[test]
fn byte_order_mark_is_skipped() {
    let bom = "\u{feff}";
    let obj = format!("{bom}v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 2 3 4\n");
    assert_eq!(corners(&obj), [[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]]]);
    // Line numbers are unchanged.
    let err = obj_mesh(&format!("{bom}v 0 0 0\nv 1 nan 0\n")).unwrap_err();
    assert!(err.ends_with("m.obj:2: vertex 2: position [1.0, NaN, 0.0] is not finite"), "{err}");
    let obj = format!("{bom}mtllib m.mtl\n{TRIANGLE}usemtl red\nf 1 2 3\n");
    let mtl = format!("{bom}newmtl red\nKd 1 0 0\n");
    let scene = loaded(&obj_scene(false), &[("m.obj", &obj), ("m.mtl", &mtl)]);
    assert_eq!(scene.materials.last().unwrap().scattering, Scattering::Diffuse { albedo: Vec3::X });
    let mtl = format!("{bom}newmtl red\nKd 1 0 nan\n");
    let err = error_at(&obj_scene(false), &[("m.obj", &obj), ("m.mtl", &mtl)], 12, "objects[0].mesh");
    assert!(err.contains("m.mtl:2: `Kd`: "), "{err}");
}

/// tobj made triangles of line (`l`) and point (`p`) elements: `l 1 2 3` rendered as a face,
/// `l 1 2` and `f 1 2` added degenerate ones. Arbor renders faces only.
#[test]
fn line_and_point_elements_make_no_triangles_and_short_faces_are_errors() {
    let obj = format!("{TRIANGLE}v 0 0 1\nl 1 2 3\nl 1 4\nl 1 2 3 4 1\np 1\np 1 2 3\nf 1 2 4\n");
    assert_eq!(corners(&obj), [[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]]);
    // Only lines and points: no faces, and the scene says so.
    let err = error_at(&obj_scene(true), &[("m.obj", &format!("{TRIANGLE}l 1 2 3\n"))], 12, "objects[0].mesh");
    assert!(err.ends_with("m.obj: no faces (`f` lines)"), "{err}");
    for (face, n) in [("f", 0), ("f 1", 1), ("f 1 2", 2), ("f 1/1 -1", 2)] {
        let err = obj_mesh(&format!("vt 0 0\n{TRIANGLE}{face}\n")).unwrap_err();
        let noun = if n == 1 { "vertex" } else { "vertices" };
        assert!(err.ends_with(&format!("m.obj:5: `f` has {n} {noun}; a face needs at least 3")), "{err}");
    }
}

/// `f 1 2 3 # comment` was a face parse error (tobj reads `#` as an index) and `v 0 0 0 # c`
/// a position parse error; exporters write such comments.
#[test]
fn trailing_comments_are_ignored() {
    let obj = "# a triangle\nmtllib m.mtl\nv 0 0 0 # origin\nv 1 0 0#x\nv 0 1 0 1 # w\n\
               o tri\nusemtl red\nf 1 2 3 # face\n";
    let mtl = "newmtl red\nKd 1 0 0 # red\nNs 10 #\n";
    assert_eq!(corners(obj), [[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]]);
    let scene = loaded(&obj_scene(false), &[("m.obj", obj), ("m.mtl", mtl)]);
    let material = &scene.materials[scene.meshes[0].material_ids[0] as usize];
    assert_eq!(material.scattering, Scattering::Diffuse { albedo: Vec3::X });
    // Names keep their `#` (3ds Max names materials `Material #25`): two such names stay two.
    let obj = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl Material #26\nf 1 2 3\n";
    let mtl = "newmtl Material #25\nKd 1 0 0\nnewmtl Material #26\nKd 0 1 0\n";
    let scene = loaded(&obj_scene(false), &[("m.obj", obj), ("m.mtl", mtl)]);
    let material = &scene.materials[scene.meshes[0].material_ids[0] as usize];
    assert_eq!(material.scattering, Scattering::Diffuse { albedo: Vec3::Y });
}

/// A vertex colour on some vertices but not all: tobj failed with "face vertex color index out
/// of bounds", without a line. Arbor does not use vertex colours.
#[test]
fn vertex_colours_on_some_vertices_are_ignored() {
    let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0 0 0 1\nf 1 2 3\n";
    assert_eq!(corners(obj), [[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]]);
    let obj = "v 0 0 0 1 1 1\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
    assert_eq!(corners(obj), [[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]]);
    // A colour that is not 3 numbers is still an error at its line.
    let err = obj_mesh("v 0 0 0\nv 1 0 0 a b c\n").unwrap_err();
    assert!(err.ends_with("m.obj:2: vertex 2: colour `a b c` is not 3 numbers"), "{err}");
    let err = obj_mesh("v 0 0 0\nv 1 0 0 1 1\n").unwrap_err();
    assert!(err.contains("m.obj:2: "), "{err}");
}

/// MTL values Arbor reads were not checked: a NaN or infinite `Kd` rendered black, a non-finite
/// `Ke` was dropped, a NaN `Ni` fell back to a default. Values real assets carry and that have a
/// fallback (a negative colour is clamped, `Ni 0` on an opaque material, `Ns` < 0, any `illum`)
/// still load.
#[test]
fn mtl_values_arbor_cannot_use_are_errors_at_their_line_and_key() {
    let obj = format!("mtllib m.mtl\n{TRIANGLE}usemtl red\nf 1 2 3\n");
    for (value, says) in [
        ("Kd 1 0 nan", "`Kd`: 1 0 NaN is not finite"),
        ("Kd 1 0 inf", "`Kd`: 1 0 inf is not finite"),
        ("Kd 1 0 1e39", "`Kd`: `1e39` overflows f32"),
        ("Ke nan 1 1", "`Ke`: NaN 1 1 is not finite"),
        ("Ke inf 1 1", "`Ke`: inf 1 1 is not finite"),
        ("Ks nan 1 1", "`Ks`: NaN 1 1 is not finite"),
        ("Ns inf", "`Ns`: inf is not finite"),
        ("Ni nan", "`Ni`: NaN is not finite"),
        ("d 1.5", "`d`: 1.5 is not in [0, 1]"),
        ("d -0.5", "`d`: -0.5 is not in [0, 1]"),
    ] {
        let mtl = format!("newmtl red\nKd 0.5 0.5 0.5\n{value}\n");
        let err = error_at(&obj_scene(false), &[("m.obj", &obj), ("m.mtl", &mtl)], 12, "objects[0].mesh");
        assert!(err.contains("m.obj: cannot load its MTL materials: ") && err.contains("m.mtl:3: "), "{err}");
        assert!(err.ends_with(says), "{err}");
    }
    // Values at the ends of their ranges load.
    let mtl = "newmtl red\nKd 0 0 0\nKs 0 0 0\nKe 0 0 0\nNs 0\nNi 1e-3\nd 0\nillum 10\n";
    loaded(&obj_scene(false), &[("m.obj", &obj), ("m.mtl", mtl)]);
    let mtl = "newmtl red\nKd -1 0 0\nKe -5 1 1\nNs -5\nNi 0\nillum 11\n";
    loaded(&obj_scene(false), &[("m.obj", &obj), ("m.mtl", mtl)]);
}

/// `v 1e39 0 0` said "position [inf, 0.0, 0.0] is not finite", though no infinity was written.
#[test]
fn vertex_position_past_f32_says_it_overflows() {
    let err = obj_mesh("v 0 0 0\nv 1e39 0 0\n").unwrap_err();
    assert!(err.ends_with("m.obj:2: vertex 2: `1e39` overflows f32"), "{err}");
    let err = obj_mesh("v inf 0 0\n").unwrap_err();
    assert!(err.ends_with("m.obj:1: vertex 1: position [inf, 0.0, 0.0] is not finite"), "{err}");
}

// ---------------------------------------------------------------------------------------------
// Environment maps: EXR and Radiance HDR files, valid, mutated and random

fn map_scene(file: &str) -> String {
    format!(
        "[camera]\nposition = [0, 0, 4]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n\
         [environment]\nmap = \"{file}\"\n"
    )
}

/// `bytes` with `edits` (position, new byte) made, then cut short at `cut`.
fn mutated(mut bytes: Vec<u8>, edits: Vec<(Index, u8)>, cut: Option<Index>) -> Vec<u8> {
    for (at, b) in edits {
        if !bytes.is_empty() {
            let i = at.index(bytes.len());
            bytes[i] = b;
        }
    }
    if let Some(at) = cut.filter(|_| !bytes.is_empty()) {
        bytes.truncate(at.index(bytes.len()));
    }
    bytes
}

/// A small valid map in `format` ("exr" or "hdr"), as bytes.
fn map_bytes(format: &str) -> Vec<u8> {
    let (w, h) = (6u32, 3u32);
    let pixels: Vec<[f32; 3]> = (0..w * h).map(|i| [i as f32, 0.5, 2.0]).collect();
    let dir = CaseDir::new();
    let path = dir.0.join(format!("m.{format}"));
    if format == "exr" {
        arbor::image_io::write_image(&path, &arbor::image_io::Image { width: w, height: h, pixels }).unwrap();
    } else {
        let rgb: Vec<image::Rgb<f32>> = pixels.into_iter().map(image::Rgb).collect();
        let file = std::fs::File::create(&path).unwrap();
        image::codecs::hdr::HdrEncoder::new(file).encode(&rgb, w as usize, h as usize).unwrap();
    }
    std::fs::read(path).unwrap()
}

proptest! {
    #![proptest_config(config(300))]

    /// A map file with bytes changed, cut short or random: it loads, or the error names the
    /// scene's line and key and the map file.
    #[test]
    fn mutated_and_random_maps(
        exr in any::<bool>(),
        edits in prop::collection::vec((any::<Index>(), any::<u8>()), 0..6),
        cut in prop::option::of(any::<Index>()),
        random in prop::option::of(prop::collection::vec(any::<u8>(), 0..300)),
    ) {
        let format = if exr { "exr" } else { "hdr" };
        let bytes = mutated(random.unwrap_or_else(|| map_bytes(format)), edits, cut);
        let name = format!("m.{format}");
        check(&[("scene.toml", map_scene(&name).as_bytes()), (&name, &bytes)], &[&name])?;
    }
}

/// The valid maps themselves load.
#[test]
fn valid_maps_load() {
    for format in ["exr", "hdr"] {
        let name = format!("m.{format}");
        let (scene, bytes) = (map_scene(&name), map_bytes(format));
        let Outcome::Loaded(scene) = load(&[("scene.toml", scene.as_bytes()), (&name, &bytes)]).0 else {
            panic!("{name} does not load");
        };
        let map = scene.environment.unwrap().map.unwrap();
        assert_eq!((map.width, map.height), (6, 3));
    }
}

// ---------------------------------------------------------------------------------------------
// Textures: PNG, JPEG, TGA and BMP files, valid, mutated and random

const TEXTURE_FORMATS: [&str; 4] = ["png", "jpg", "tga", "bmp"];

fn texture_scene(file: &str) -> String {
    format!(
        "[camera]\nposition = [0, 0, 4]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n\
         [materials.m]\ntype = \"diffuse\"\ntexture = \"{file}\"\n\
         [[objects]]\nshape = \"quad\"\nmaterial = \"m\"\n"
    )
}

/// A small valid texture in `format` (an extension of [`TEXTURE_FORMATS`]), as bytes.
fn texture_bytes(format: &str) -> Vec<u8> {
    let image = image::RgbImage::from_fn(5, 3, |x, y| image::Rgb([(40 * x) as u8, (80 * y) as u8, 200]));
    let format = image::ImageFormat::from_extension(format).unwrap();
    let mut bytes = Vec::new();
    image.write_to(&mut std::io::Cursor::new(&mut bytes), format).unwrap();
    bytes
}

proptest! {
    #![proptest_config(config(300))]

    /// A texture file with bytes changed, cut short or random: the scene loads, or the error
    /// names the scene's line and key and the texture file. The image decoders are `image`'s;
    /// this checks that what they refuse reaches the user as an error, and that none panics.
    #[test]
    fn mutated_and_random_textures(
        format in 0..TEXTURE_FORMATS.len(),
        edits in prop::collection::vec((any::<Index>(), any::<u8>()), 0..6),
        cut in prop::option::of(any::<Index>()),
        random in prop::option::of(prop::collection::vec(any::<u8>(), 0..300)),
    ) {
        let format = TEXTURE_FORMATS[format];
        let bytes = mutated(random.unwrap_or_else(|| texture_bytes(format)), edits, cut);
        let name = format!("t.{format}");
        check(&[("scene.toml", texture_scene(&name).as_bytes()), (&name, &bytes)], &[&name])?;
    }
}

/// The valid textures themselves load.
#[test]
fn valid_textures_load() {
    for format in TEXTURE_FORMATS {
        let name = format!("t.{format}");
        let (scene, bytes) = (texture_scene(&name), texture_bytes(format));
        let Outcome::Loaded(scene) = load(&[("scene.toml", scene.as_bytes()), (&name, &bytes)]).0 else {
            panic!("{name} does not load");
        };
        assert_eq!((scene.textures[0].width, scene.textures[0].height), (5, 3), "{name}");
    }
}
