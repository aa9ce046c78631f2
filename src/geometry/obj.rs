//! OBJ and MTL files are parsed by tobj 4, after checks of our own (`read_obj`): tobj panics on
//! some bad input (an MTL colour with fewer than 3 numbers; a `vt` or `vn` index out of range,
//! whose offset overflows), and most of its errors do not say where. Every error here names the
//! file and, where the fault is one line, the line.
//!
//! tobj is handed the files rewritten line for line, so that its line numbers stay the file's:
//! without a leading byte-order mark or comments ([`without_comments`]), and for OBJ files
//! without line and point elements or vertex colours ([`for_tobj`]).

use std::cell::RefCell;
use std::collections::HashSet;
use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::str::SplitWhitespace;

use glam::Vec3;

use super::mesh::{MeshError, TriangleMesh};

/// An OBJ file as tobj reads it, with the materials of the MTL files it names.
pub(crate) struct ObjFile {
    /// One per object and material; every position finite.
    pub models: Vec<tobj::Model>,
    /// The materials of the MTL files that loaded, which `material_id` indexes; every value
    /// Arbor reads is in range ([`check_mtl`]).
    pub materials: Vec<tobj::Material>,
    /// The MTL files named, each relative to the OBJ file's folder.
    pub mtl_files: Vec<PathBuf>,
    /// The first MTL file that could not be read or parsed.
    pub mtl_error: Option<MeshError>,
    /// The first `usemtl` naming a material that no MTL file defines: its line and the name.
    pub unknown_material: Option<(usize, String)>,
}

/// Reads the OBJ file at `path`, triangulated, and with `materials` the MTL files it names
/// (a broken MTL file is no error here: see [`ObjFile::mtl_error`]).
pub(crate) fn read_obj(path: &Path, materials: bool) -> Result<ObjFile, MeshError> {
    // One rewrite of the text alive at a time beside the next (the file read is dropped here).
    let text = without_comments(&lossy_utf8(
        crate::memory::read_file(path).map_err(|error| MeshError::Read { path: path.to_owned(), error })?,
    ));
    let usemtl = check_obj(path, &text)?;
    let text = for_tobj(text);
    let (mtl_files, mtl_error) = (RefCell::new(Vec::new()), RefCell::new(None));
    let load_mtl = |name: &Path| {
        if !materials {
            return Ok(Default::default());
        }
        let mtl = path.parent().map_or_else(|| name.to_owned(), |dir| dir.join(name));
        let loaded = load_mtl(&mtl, &mtl_error);
        mtl_files.borrow_mut().push(mtl);
        loaded
    };
    // Polygons as they are: tobj triangulates by a fan, which is wrong for a concave polygon.
    let opts = tobj::LoadOptions { triangulate: false, single_index: true, ..Default::default() };
    let mut reader = Cursor::new(&text[..]);
    let (mut models, loaded) = match tobj::load_obj_buf(&mut reader, &opts, load_mtl) {
        Ok(r) => r,
        Err(e) => return Err(tobj_error(path, &text, reader.position(), e)),
    };
    for m in &mut models {
        triangulate(&mut m.mesh);
    }
    // An error only when no MTL file loaded, and then `mtl_error` says why.
    let materials = loaded.unwrap_or_default();
    let defined: HashSet<&str> = materials.iter().map(|m| m.name.as_str()).collect();
    let unknown_material = usemtl.into_iter().find(|(_, name)| !defined.contains(name.as_str()));
    let (mtl_files, mtl_error) = (mtl_files.into_inner(), mtl_error.into_inner());
    Ok(ObjFile { models, materials, mtl_files, mtl_error, unknown_material })
}

/// Replaces `mesh`'s polygons (tobj's `face_arities`) by triangles, in place: a convex polygon
/// by a fan from its first vertex (what tobj's own triangulation gives), a concave one by ear
/// clipping in the plane of its Newell normal, so that an L- or U-shaped floor keeps its shape
/// (a fan covered the notch with back-facing triangles). Windings are kept. A polygon of more
/// than [`EAR_CLIPPING_MAX`] vertices, or one whose ears run out (a self-intersecting one),
/// gets a fan for what is left. Ear clipping as in Meisters' two-ears theorem (every simple
/// polygon of four or more vertices has two non-overlapping ears; G. H. Meisters, "Polygons Have
/// Ears", Amer. Math. Monthly 82, 1975). Written here because tobj has only the fan and the one
/// crate that ear-clips (earcutr) adds hole handling and a dependency for this one loop.
fn triangulate(mesh: &mut tobj::Mesh) {
    if mesh.face_arities.is_empty() {
        return;
    }
    let arities = std::mem::take(&mut mesh.face_arities);
    let position = |i: u32| {
        let p = &mesh.positions[3 * i as usize..3 * i as usize + 3];
        glam::DVec3::new(p[0].into(), p[1].into(), p[2].into())
    };
    let mut triangles = Vec::with_capacity(mesh.indices.len() * 3);
    let mut at = 0;
    for &n in &arities {
        let polygon = &mesh.indices[at..at + n as usize];
        at += n as usize;
        triangulate_polygon(polygon, &position, &mut triangles);
    }
    mesh.indices = triangles;
}

/// Polygons above this size are fanned: ear clipping costs up to the cube of the size.
const EAR_CLIPPING_MAX: usize = 1024;

/// Appends the triangles of one polygon (vertex indices in order) to `out` (see [`triangulate`]);
/// PLY faces are triangulated by it too.
pub(crate) fn triangulate_polygon(polygon: &[u32], position: &impl Fn(u32) -> glam::DVec3, out: &mut Vec<u32>) {
    let n = polygon.len();
    let fan = |from: &[u32], out: &mut Vec<u32>| {
        for k in 1..from.len().saturating_sub(1) {
            out.extend([from[0], from[k], from[k + 1]]);
        }
    };
    if n <= 3 || n > EAR_CLIPPING_MAX {
        return fan(polygon, out);
    }
    // Newell's normal, then 2D coordinates in the plane across its largest component, oriented
    // so that the polygon winds counter-clockwise there.
    let p: Vec<glam::DVec3> = polygon.iter().map(|&i| position(i)).collect();
    let normal = (0..n).fold(glam::DVec3::ZERO, |acc, k| {
        let (a, b) = (p[k], p[(k + 1) % n]);
        acc + glam::DVec3::new((a.y - b.y) * (a.z + b.z), (a.z - b.z) * (a.x + b.x), (a.x - b.x) * (a.y + b.y))
    });
    let axis = normal.abs().max_position();
    // Zero (a degenerate polygon) or NaN.
    if normal[axis].abs().partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return fan(polygon, out);
    }
    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
    let sign = normal[axis].signum();
    let q: Vec<glam::DVec2> = p.iter().map(|a| glam::DVec2::new(a[u], a[v] * sign)).collect();
    let cross = |a: usize, b: usize, c: usize| (q[b] - q[a]).perp_dot(q[c] - q[a]);
    if (0..n).all(|k| cross(k, (k + 1) % n, (k + 2) % n) >= 0.0) {
        return fan(polygon, out);
    }
    let mut left: Vec<usize> = (0..n).collect();
    while left.len() > 3 {
        let m = left.len();
        let ear = (0..m).find(|&k| {
            let (a, b, c) = (left[(k + m - 1) % m], left[k], left[(k + 1) % m]);
            let turn = cross(a, b, c);
            // A vertex in the middle of a straight run (a T-junction's) goes as a zero-area
            // triangle, which keeps it joined to its neighbours without changing the shape.
            (turn == 0.0 && (q[b] - q[a]).dot(q[c] - q[b]) > 0.0)
                || turn > 0.0
                    && left.iter().all(|&o| {
                        o == a
                            || o == b
                            || o == c
                            || cross(a, b, o) < 0.0
                            || cross(b, c, o) < 0.0
                            || cross(c, a, o) < 0.0
                    })
        });
        let Some(k) = ear else { break };
        out.extend([polygon[left[(k + m - 1) % m]], polygon[left[k]], polygon[left[(k + 1) % m]]]);
        left.remove(k);
    }
    let rest: Vec<u32> = left.iter().map(|&k| polygon[k]).collect();
    fan(&rest, out);
}

/// The MTL file at `path`, for tobj's OBJ loader, checked first ([`check_mtl`]). The first
/// failure is kept in `error`: tobj keeps only its kind.
fn load_mtl(path: &Path, error: &RefCell<Option<MeshError>>) -> tobj::MTLLoadResult {
    let fail = |e: MeshError| {
        error.borrow_mut().get_or_insert(e);
        tobj::LoadError::GenericFailure
    };
    let file =
        crate::memory::read_file(path).map_err(|error| fail(MeshError::Read { path: path.to_owned(), error }))?;
    let text = without_comments(&lossy_utf8(file));
    check_mtl(path, &text).map_err(fail)?;
    let mut reader = Cursor::new(&text[..]);
    tobj::load_mtl_buf(&mut reader).map_err(|e| fail(tobj_error(path, &text, reader.position(), e)))
}

/// An OBJ or MTL file's bytes as UTF-8, any byte that is not replaced by U+FFFD. Exporters
/// write names and comments in Latin-1 or the system's code page (`g Fläche`, `# Modèle`),
/// and one such byte made tobj refuse the whole file. OBJ and MTL files are converted alike, so
/// a `usemtl` still finds its `newmtl`; only names that differ in such bytes alone would merge.
/// A file of which more than a quarter of the bytes are not UTF-8 is no text file (a binary one
/// given by mistake; Latin-1 prose has a few percent): it is left as it is, for tobj's "not UTF-8
/// text" at its line, and so that the three bytes of each replacement cannot triple the file.
fn lossy_utf8(bytes: Vec<u8>) -> Vec<u8> {
    match String::from_utf8(bytes) {
        Ok(text) => text.into_bytes(),
        Err(e) => {
            let bytes = e.into_bytes();
            let bad: usize = bytes.utf8_chunks().map(|c| c.invalid().len()).sum();
            if bad > bytes.len() / 4 {
                return bytes;
            }
            String::from_utf8_lossy(&bytes).into_owned().into_bytes()
        }
    }
}

/// `text` (an OBJ or MTL file) without a leading UTF-8 byte-order mark, which tobj would read
/// as part of the first line's keyword, and without comments after numbers (`#` to the end of
/// a line whose keyword takes numbers, [`NUMBER_KEYWORDS`]), which tobj skips only as a line's
/// first word: exporters write them after a face or a value. Line for line, so that line
/// numbers stay the file's.
fn without_comments(text: &[u8]) -> Vec<u8> {
    let text = text.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(text);
    let joined = logical_lines(text);
    let text = joined.as_deref().unwrap_or(text);
    let mut out = Vec::with_capacity(text.len());
    for (k, line) in text.split(|&b| b == b'\n').enumerate() {
        if k > 0 {
            out.push(b'\n');
        }
        // Only lines of numbers lose a trailing comment: a name or a path may hold `#`
        // (`newmtl Material #25`, `map_Kd #1.png`), and cutting it would merge two names.
        let numbers = std::str::from_utf8(line)
            .ok()
            .and_then(|l| l.split_whitespace().next())
            .is_some_and(|w| NUMBER_KEYWORDS.contains(&w));
        let kept = if numbers { line.split(|&b| b == b'#').next().unwrap_or_default() } else { line };
        out.extend_from_slice(kept);
    }
    out
}

/// `text` with its physical lines made the logical lines tobj reads, where they differ (`None`
/// where they do not): a lone carriage return (classic Mac OS line ends) ends a line, and a
/// line ending in `\` goes on in the next, as the OBJ format allows (long face lines), unless
/// it is a comment. A continued line is joined with a space in place of the `\` and its line
/// end, and its line ends are written after it, so that every later line keeps its number; an
/// error in a joined line names its first line. tobj does neither: it reads a file of lone CRs
/// as one line, and a `\` as a value.
fn logical_lines(text: &[u8]) -> Option<Vec<u8>> {
    let lone_cr = |i: usize| text[i] == b'\r' && text.get(i + 1) != Some(&b'\n');
    if !text.contains(&b'\\') && !(0..text.len()).any(lone_cr) {
        return None;
    }
    let unified: Vec<u8> = (0..text.len()).map(|i| if lone_cr(i) { b'\n' } else { text[i] }).collect();
    let mut out = Vec::with_capacity(unified.len());
    let mut owed = 0;
    let mut lines = unified.split(|&b| b == b'\n').peekable();
    while let Some(line) = lines.next() {
        let last = lines.peek().is_none();
        // A comment is not continued: `# C:\models\` would swallow the next line.
        let comment = line.trim_ascii_start().starts_with(b"#") && owed == 0;
        match line.trim_ascii_end().strip_suffix(b"\\") {
            Some(head) if !last && !comment => {
                out.extend_from_slice(head);
                out.push(b' ');
                owed += 1;
            }
            _ => {
                out.extend_from_slice(line);
                if !last {
                    out.resize(out.len() + 1 + owed, b'\n');
                }
                owed = 0;
            }
        }
    }
    Some(out)
}

/// The OBJ and MTL keywords whose values are numbers (or indices), after which a `#` starts a
/// comment.
const NUMBER_KEYWORDS: [&str; 17] =
    ["v", "vt", "vn", "vp", "f", "l", "p", "s", "Ka", "Kd", "Ks", "Ke", "Tf", "Ns", "Ni", "d", "Tr"];

/// An OBJ file's `text` (after [`without_comments`] and [`check_obj`]) as tobj is to read it,
/// line for line. Line (`l`) and point (`p`) elements are blanked: tobj makes triangles of them
/// (`l 1 2 3` is a face, `l 1 2` a degenerate one), and Arbor renders faces only. A vertex colour
/// (`v x y z r g b`) is dropped: tobj needs one on every vertex or on none, and Arbor does not
/// use them. Lines that are not UTF-8 (a file [`lossy_utf8`] left as it was) are kept, for
/// tobj's error.
fn for_tobj(text: Vec<u8>) -> Vec<u8> {
    let mut out = Vec::with_capacity(text.len());
    for (k, line) in text.split(|&b| b == b'\n').enumerate() {
        if k > 0 {
            out.push(b'\n');
        }
        // Words are collected only on `v` lines: a face line (most of a mesh) is copied as is.
        let mut words = std::str::from_utf8(line).map(str::split_whitespace).ok();
        match words.as_mut().and_then(Iterator::next) {
            Some("l" | "p") => {}
            Some("v") => match words.map(Iterator::collect::<Vec<_>>).as_deref() {
                Some(&[x, y, z, _, _, _]) => out.extend_from_slice(format!("v {x} {y} {z}").as_bytes()),
                _ => out.extend_from_slice(line),
            },
            _ => out.extend_from_slice(line),
        }
    }
    out
}

/// The lines of `text` up to the first that is not UTF-8, where tobj stops with an error.
fn utf8_lines(text: &[u8]) -> impl Iterator<Item = (usize, &str)> {
    text.split(|&b| b == b'\n').map_while(|l| std::str::from_utf8(l).ok()).enumerate().map(|(k, l)| (k + 1, l))
}

/// What tobj 4 misses or panics on in an OBJ file (after [`without_comments`]), with its line:
/// a face index of 0, past the end of its list, or (relative) before its start; a face of fewer
/// than 3 vertices, or a vertex without a position index; a vertex position that is not finite
/// ([`check_vertex`]). A `vt` or `vn` index out of range is the panic: tobj multiplies it by 2
/// or 3 unchecked, which overflows. Indices are resolved as tobj does: relative ones against
/// the elements so far, absolute ones against the whole file; a `vt` or `vn` reference (or one
/// of 0) is ignored when the file has none of them. Line and point elements (`l`, `p`) are not
/// checked: tobj does not see them ([`for_tobj`]). Lines that tobj rejects itself (a number
/// that does not parse) are left to it. Returns each `usemtl` line's number and name.
fn check_obj(path: &Path, text: &[u8]) -> Result<Vec<(usize, String)>, MeshError> {
    const KINDS: [&str; 3] = ["v", "vt", "vn"];
    let mut total = [0; 3];
    for (_, l) in utf8_lines(text) {
        if let Some(k) = l.split_whitespace().next().and_then(|w| KINDS.iter().position(|&kind| kind == w)) {
            total[k] += 1;
        }
    }
    let mut seen = [0; 3];
    let mut usemtl = Vec::new();
    for (line, l) in utf8_lines(text) {
        let at = |message| MeshError::Invalid { path: path.to_owned(), line, message };
        let mut words = l.split_whitespace();
        match words.next() {
            Some("v") => {
                seen[0] += 1;
                let words: Vec<&str> = words.collect();
                check_vertex(&words).map_err(|m| at(format!("vertex {}: {m}", seen[0])))?;
            }
            Some("vt") => seen[1] += 1,
            Some("vn") => seen[2] += 1,
            Some("f") => check_face(words, seen, total).map_err(at)?,
            Some("usemtl") => usemtl.push((line, l.split_once(' ').unwrap_or_default().1.trim().to_owned())),
            _ => {}
        }
    }
    Ok(usemtl)
}

/// The words of a `v` line after the keyword: a position within f32 and finite, and a colour,
/// if given, of 3 numbers (it is dropped unchecked otherwise: Arbor does not use it). A line
/// tobj rejects itself is left to it.
fn check_vertex(words: &[&str]) -> Result<(), String> {
    let Some(p) = obj_position(words) else { return Ok(()) };
    // The numbers the position is made of: x y z, and w when it is the one number more.
    let used = if words.len() == 4 { 4 } else { 3 };
    if let Some(w) = words[..used].iter().find(|w| overflows(w)) {
        return Err(format!("`{w}` overflows f32"));
    }
    if let [_, _, _, r, g, b] = words {
        if [r, g, b].iter().any(|c| c.parse::<f32>().is_err()) {
            return Err(format!("colour `{r} {g} {b}` is not 3 numbers"));
        }
    }
    if !p.iter().all(|c| c.is_finite()) {
        return Err(format!("position {p:?} is not finite"));
    }
    Ok(())
}

/// Whether `word` is a number past f32's range, which parses as an infinity, rather than an
/// infinity written as one (`inf`, `-Infinity`).
fn overflows(word: &str) -> bool {
    word.parse::<f32>().is_ok_and(f32::is_infinite) && !word.to_ascii_lowercase().contains("inf")
}

/// A `v` line's position as tobj computes it (divided by w when a fourth number is given), from
/// the words after the keyword, or `None` where tobj rejects the line itself.
fn obj_position(words: &[&str]) -> Option<[f32; 3]> {
    let [x, y, z, rest @ ..] = words else { return None };
    let mut p = [0f32; 3];
    for (c, word) in p.iter_mut().zip([x, y, z]) {
        *c = word.parse().ok()?;
    }
    match rest {
        [w] => {
            let w: f32 = w.parse().ok()?;
            (w != 0.0).then(|| p.map(|c| c / w))
        }
        _ => Some(p),
    }
}

/// The indices of an `f` line, checked as [`check_obj`] says; `seen` counts the vertices,
/// texture coordinates and normals before the line, `total` those in the file.
fn check_face(words: SplitWhitespace, seen: [usize; 3], total: [usize; 3]) -> Result<(), String> {
    const NAMES: [(&str, &str); 3] =
        [("vertex", "vertices"), ("texture coordinate", "texture coordinates"), ("normal", "normals")];
    let mut refs = Vec::new();
    let mut vertices = 0;
    for word in words {
        vertices += 1;
        for (slot, part) in word.split('/').enumerate().filter(|(_, p)| !p.is_empty()) {
            // A part that does not parse, or a fourth part: tobj's own error.
            let Ok(x) = part.parse::<isize>() else { return Ok(()) };
            if slot > 2 {
                return Ok(());
            }
            refs.push((slot, x));
        }
        if word.split('/').next().is_none_or(str::is_empty) {
            return Err(format!("`f` vertex `{word}` has no position index"));
        }
    }
    // tobj makes a degenerate triangle of 1 or 2.
    if vertices < 3 {
        let noun = if vertices == 1 { "vertex" } else { "vertices" };
        return Err(format!("`f` has {vertices} {noun}; a face needs at least 3"));
    }
    for (slot, x) in refs {
        let (one, many) = NAMES[slot];
        if slot > 0 && (x == 0 || total[slot] == 0) {
            continue;
        }
        if x == 0 {
            return Err(format!("`f` refers to {one} 0; OBJ indices start at 1"));
        }
        if x > 0 && x.unsigned_abs() > total[slot] {
            return Err(format!("`f` refers to {one} {x}, but the file has {} {many}", total[slot]));
        }
        if x < 0 && x.unsigned_abs() > seen[slot] {
            return Err(format!("`f` refers to {one} {x} (relative), but {} {many} come before it", seen[slot]));
        }
    }
    Ok(())
}

/// What tobj 4 panics on in an MTL file (after [`without_comments`]), with its line: a colour
/// (`Ka`, `Kd`, `Ks`, `Ke`) with fewer than 3 numbers. And the values Arbor reads (see
/// `from_mtl` in `scene/load/materials.rs`) where they would silently break a material: colours, `Ns` and
/// `Ni` not finite, the dissolve `d` outside [0, 1]. Negative colours, `Ns` < 0, `Ni` <= 0 and
/// any `illum` load, with `from_mtl`'s fallbacks. A number that does not parse is left to tobj.
fn check_mtl(path: &Path, text: &[u8]) -> Result<(), MeshError> {
    for (line, l) in utf8_lines(text) {
        let mut words = l.split_whitespace();
        if let Some(key) = words.next() {
            check_mtl_value(key, words).map_err(|message| MeshError::Invalid {
                path: path.to_owned(),
                line,
                message,
            })?;
        }
    }
    Ok(())
}

/// The numbers after `key` on an MTL line, checked as [`check_mtl`] says.
fn check_mtl_value(key: &str, words: SplitWhitespace) -> Result<(), String> {
    // Negative colours, `Ns` < 0 and `Ni` <= 0 are common in downloaded assets (`Ni 0.000000`
    // on opaque materials) and have fallbacks in `from_mtl` (clamped to 0, the default
    // roughness, an index of 1.5): only values that would silently break a material are errors.
    let count = match key {
        "Ka" | "Kd" | "Ks" | "Ke" => 3,
        "Ns" | "Ni" | "d" => 1,
        _ => return Ok(()),
    };
    let words: Vec<&str> = words.take(count).collect();
    if count == 3 && words.len() < 3 {
        return Err(format!("`{key}` needs 3 numbers (r g b), not {}", words.len()));
    }
    // A missing number, or one that does not parse, is tobj's error; Arbor does not read `Ka`.
    let Ok(values) = words.iter().map(|w| w.parse::<f32>()).collect::<Result<Vec<_>, _>>() else { return Ok(()) };
    if values.is_empty() || key == "Ka" {
        return Ok(());
    }
    if let Some(w) = words.iter().find(|w| overflows(w)) {
        return Err(format!("`{key}`: `{w}` overflows f32"));
    }
    let shown = values.iter().map(f32::to_string).collect::<Vec<_>>().join(" ");
    if !values.iter().all(|x| x.is_finite()) {
        return Err(format!("`{key}`: {shown} is not finite"));
    }
    if key == "d" && !(0.0..=1.0).contains(&values[0]) {
        return Err(format!("`d`: {shown} is not in [0, 1]"));
    }
    Ok(())
}

/// tobj's error `e` after it read `read` bytes of `text` (from a `Cursor`): at the line it
/// stopped at, unless tobj found it when an object ended, past the line at fault.
fn tobj_error(path: &Path, text: &[u8], read: u64, e: tobj::LoadError) -> MeshError {
    use tobj::LoadError as E;
    let path = path.to_owned();
    if matches!(
        e,
        E::FaceVertexOutOfBounds
            | E::FaceTexCoordOutOfBounds
            | E::FaceNormalOutOfBounds
            | E::FaceColorOutOfBounds
            | E::InvalidPolygon
    ) {
        return MeshError::Obj { path, error: e };
    }
    let read = &text[..usize::try_from(read).map_or(text.len(), |r| r.min(text.len()))];
    let read = read.strip_suffix(b"\n").unwrap_or(read);
    let start = read.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
    let line = read[..start].iter().filter(|&&b| b == b'\n').count() + 1;
    let message = if e == E::ReadError {
        "not UTF-8 text".to_owned()
    } else {
        let shown: String = String::from_utf8_lossy(&read[start..]).trim().chars().take(60).collect();
        format!("{e}: `{shown}`")
    };
    MeshError::Invalid { path, line, message }
}

impl TriangleMesh {
    /// The positions and triangles of one tobj mesh (loaded with `single_index`, its polygons
    /// triangulated by [`triangulate`]), with its `vn` normals (normalised; a zero or
    /// non-finite one becomes zero: none) and `vt` texture coordinates where every vertex has
    /// them.
    pub(crate) fn from_tobj(m: &tobj::Mesh) -> Self {
        let count = m.positions.len() / 3;
        let normals = if m.normals.len() == 3 * count {
            m.normals.chunks_exact(3).map(|n| Vec3::new(n[0], n[1], n[2]).normalize_or_zero()).collect()
        } else {
            Vec::new()
        };
        let uvs = if m.texcoords.len() == 2 * count {
            m.texcoords.chunks_exact(2).map(|t| glam::Vec2::new(t[0], t[1])).collect()
        } else {
            Vec::new()
        };
        TriangleMesh {
            positions: m.positions.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])).collect(),
            indices: m.indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
            normals,
            uvs,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `vn` and `vt` are kept, one per vertex, each with the position it was given beside
    /// (a position used with two normals becomes two vertices); a mesh part without them gets
    /// zero normals where it is appended to one with them.
    #[test]
    fn normals_and_texture_coordinates_are_kept_per_vertex() {
        let dir = std::env::temp_dir().join(format!("arbor-obj-attributes-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("m.obj");
        let text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 2\nvn 0 1 1\n\
                    f 1/1/1 2/2/1 3/3/2 4/4/2\n";
        std::fs::write(&path, text).unwrap();
        let m = TriangleMesh::load_obj(&path).unwrap();
        assert_eq!(m.triangle_count(), 2);
        assert_eq!((m.normals.len(), m.uvs.len()), (m.positions.len(), m.positions.len()));
        let diagonal = Vec3::new(0.0, 1.0, 1.0).normalize();
        for (k, p) in m.positions.iter().enumerate() {
            let corner = [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y].iter().position(|c| c == p).unwrap();
            assert_eq!(m.uvs[k], glam::Vec2::new(p.x, p.y), "vt follows its position");
            let normal = if corner < 2 { Vec3::Z } else { diagonal };
            assert!((m.normals[k] - normal).length() < 1e-6, "vn normalised and kept: {:?}", m.normals[k]);
        }
        let mut both = m.clone();
        both.append(&TriangleMesh::quad());
        assert_eq!(both.normals.len(), both.positions.len());
        assert!(both.normals[m.positions.len()..].iter().all(|n| *n == Vec3::ZERO));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A U-shaped octagon and a 10-point star (concave) keep their shapes: their triangles
    /// add up to the polygon's area, all wound as the polygon (normal +z), and none covers
    /// the notch; a convex quad is the fan tobj gave, and a straight run's middle vertex is kept.
    #[test]
    fn concave_polygons_keep_their_shape() {
        let dir = std::env::temp_dir().join(format!("arbor-polygons-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let star: String = (0..10)
            .map(|k| {
                let (r, a) = (if k % 2 == 0 { 1.0 } else { 0.4 }, k as f64 * std::f64::consts::PI / 5.0);
                format!("v {} {} 0\n", r * a.cos(), r * a.sin())
            })
            .collect();
        let cases = [
            (
                "v 0 0 0\nv 3 0 0\nv 3 3 0\nv 2 3 0\nv 2 1 0\nv 1 1 0\nv 1 3 0\nv 0 3 0\nf 1 2 3 4 5 6 7 8\n"
                    .to_string(),
                7.0,
            ),
            (star + "f 1 2 3 4 5 6 7 8 9 10\n", 10.0 * 0.5 * 0.4 * (std::f64::consts::PI / 5.0).sin()),
            // An L with a vertex in the middle of its bottom edge.
            ("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 2 1 0\nv 1 1 0\nv 1 2 0\nv 0 2 0\nf 1 2 3 4 5 6 7\n".to_string(), 3.0),
        ];
        for (k, (text, area)) in cases.iter().enumerate() {
            let path = dir.join(format!("p{k}.obj"));
            std::fs::write(&path, text).unwrap();
            let m = TriangleMesh::load_obj(&path).unwrap();
            let tris = m.triangles();
            let sum: f64 = tris.iter().map(|t| f64::from((t.v1 - t.v0).cross(t.v2 - t.v0).z) * 0.5).sum();
            assert!((sum - area).abs() < 1e-5, "polygon {k}: triangles of area {sum}, polygon {area}");
            assert!(
                tris.iter().all(|t| (t.v1 - t.v0).cross(t.v2 - t.v0).z >= 0.0),
                "polygon {k}: a triangle turned over"
            );
            assert!(m.indices.iter().flatten().copied().collect::<HashSet<u32>>().len() == m.positions.len());
        }
        std::fs::write(dir.join("quad.obj"), "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n").unwrap();
        assert_eq!(TriangleMesh::load_obj(dir.join("quad.obj")).unwrap().indices, vec![[0, 1, 2], [0, 2, 3]]);
        std::fs::remove_dir_all(&dir).ok();
    }

    /// Loads `bytes` as an OBJ file of its own.
    fn load_obj_bytes(name: &str, bytes: &[u8]) -> Result<TriangleMesh, MeshError> {
        let dir = std::env::temp_dir().join(format!("arbor-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("m.obj"), bytes).unwrap();
        let result = TriangleMesh::load_obj(dir.join("m.obj"));
        std::fs::remove_dir_all(&dir).ok();
        result
    }

    /// One Latin-1 byte in a comment or a group name (a 3ds Max export's `g Fläche`) made the
    /// whole file "not UTF-8 text"; a binary file, mostly not UTF-8, is still refused as such.
    #[test]
    fn latin1_text_loads_and_binary_is_refused() {
        let latin1 = b"# Mod\xe8le\ng Fl\xe4che\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
        assert_eq!(load_obj_bytes("latin1", latin1).unwrap().triangle_count(), 1);
        let binary: Vec<u8> = (0..4096u32).map(|i| (i.wrapping_mul(2654435761) >> 24) as u8 | 0x80).collect();
        let e = load_obj_bytes("binary", &binary).unwrap_err().to_string();
        assert!(e.contains("not UTF-8 text") && e.contains("m.obj"), "{e}");
    }

    /// Lone carriage returns end lines, and a `\` continues one; line numbers stay the file's.
    #[test]
    fn line_ends_and_continuations() {
        let mac = b"v 0 0 0\rv 1 0 0\rv 0 1 0\rf 1 2 3\r";
        assert_eq!(load_obj_bytes("cr", mac).unwrap().triangle_count(), 1);
        let continued = b"v 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nv 1 1 0\r\nf 1 \\\r\n 2 \\ \n3 4\nf 1 2 9\n";
        let e = load_obj_bytes("continued", continued).unwrap_err().to_string();
        assert!(e.contains("m.obj:8"), "the error after a joined face names its own line: {e}");
        let continued = &continued[..continued.len() - b"f 1 2 9\n".len()];
        assert_eq!(load_obj_bytes("continued", continued).unwrap().triangle_count(), 2);
        assert_eq!(logical_lines(b"a \\\nb\nc\\").unwrap(), b"a  b\n\nc\\");
        assert_eq!(logical_lines(b"# C:\\m\\\nv 0 0 0").unwrap(), b"# C:\\m\\\nv 0 0 0");
        assert!(logical_lines(b"a\r\nb\n").is_none());
    }

    /// tobj's line numbers are the file's only if every rewrite keeps every line.
    #[test]
    fn rewrites_for_tobj_keep_every_line() {
        let file = b"\xEF\xBB\xBFv 0 0 0 # a\r\nl 1 2\nv 1 0 0 1 1 1\np 1\n#\nf 1 2 3#x\n\xff # \xfe";
        let text = without_comments(file);
        assert_eq!(text, b"v 0 0 0 \nl 1 2\nv 1 0 0 1 1 1\np 1\n#\nf 1 2 3\n\xff # \xfe");
        assert_eq!(for_tobj(text), b"v 0 0 0 \n\nv 1 0 0\n\n#\nf 1 2 3\n\xff # \xfe");
        // Names keep their `#`.
        assert_eq!(without_comments(b"newmtl Material #25\nKd 1 0 0 # red"), b"newmtl Material #25\nKd 1 0 0 ");
        // A mark only at the start of the file is one.
        assert_eq!(without_comments(b"v\n\xEF\xBB\xBFv"), b"v\n\xEF\xBB\xBFv");
    }

    #[test]
    fn only_numbers_past_f32_overflow() {
        assert!(overflows("1e39") && overflows("-3.5e38") && overflows("1e400"));
        assert!(!overflows("inf") && !overflows("-Infinity") && !overflows("3.4e38") && !overflows("x"));
    }
}
