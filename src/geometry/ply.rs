//! PLY files, as Greg Turk's "The PLY Polygon File Format" (1994) defines them: a text header
//! (`ply`, `format`, `element` and `property` lines, `comment` and `obj_info` lines, `end_header`)
//! and a body in one of its three encodings, `ascii`, `binary_little_endian` and
//! `binary_big_endian`, version 1.0. Elements come in the header's order, each a record of its
//! properties in their order; a scalar property is one number of its type, a list one count (of
//! its count type) and that many items. The eight types are `char`, `uchar`, `short`, `ushort`,
//! `int`, `uint`, `float` and `double` (1, 1, 2, 2, 4, 4, 4 and 8 bytes), also spelt `int8`,
//! `uint8`, `int16`, `uint16`, `int32`, `uint32`, `float32` and `float64`.
//!
//! What is read: the `vertex` element's `x y z` (any type), its `nx ny nz` where it has all three
//! (normalised; a zero or non-finite one becomes zero: none), and its texture coordinates, the
//! first pair of `u v`, `s t` and `texture_u texture_v` that it has; the `face` element's
//! `vertex_indices` list (or `vertex_index`), of any count and (integer) index type, each polygon
//! triangulated as OBJ polygons are (`obj::triangulate_polygon`: a fan, or ear clipping where it is
//! concave). Every other property and element (colours, `edge`, `material`, ...) is skipped.
//! Errors name the file and, in the header and an ASCII body, the line; in a binary body the byte
//! offset. Past the header they name the element (counted from 0, as PLY indices are) and the
//! property.
//!
//! Where this reader departs from, or goes past, the specification:
//! - An ASCII element is one line, as Turk's own reader (`plyfile.c`) reads it: a line with too
//!   few or too many values is an error at that line, not a silent shift of every value after it.
//!   Blank lines are skipped.
//! - Lines end in LF, CR LF or a lone CR (the specification says carriage return; most writers
//!   write LF). A binary body after an `end_header` ended by a lone CR must not start with a line
//!   feed, which would be read as part of the line end.
//! - An element with no properties holds no data, in either encoding.
//! - Bytes after the last element are ignored.
//! - Counts are checked against the file's size before anything is allocated (each record needs
//!   at least one byte per value in a binary body, two in an ASCII one), so a header that
//!   declares 10^12 vertices is an error, not an allocation failure.
//! - A `face` needs at least 3 vertices; an index must be below the vertex count and not
//!   negative; a position must be finite in f32, and so must texture coordinates.
//! - Triangle strips (`tristrips`) are not read.
//!
//! Written here, not with a crate. ply-rs (0.1.3, 2020) is unmaintained; its maintained fork
//! ply-rs-bw (4.0) needs Rust 1.87, above Arbor's 1.85, hands every value to a setter by property
//! name and each face's indices to a `Vec` of its own, and took more than twice as long as this
//! reader on a binary mesh of 10^6 triangles (96 ms against 43 ms, with its in-place list path,
//! on 2 cores; this reader checks every index besides); its binary errors give neither the byte
//! offset nor the property. The format is small: a header of six keywords and records of eight
//! fixed-size types. `examples/mesh_load_times.rs` times this reader against the OBJ reader and
//! the LBVH build.

use std::ops::Range;
use std::path::Path;

use glam::{DVec3, Vec2, Vec3};

use super::mesh::{MeshError, TriangleMesh};
use super::obj::triangulate_polygon;

/// Reads the PLY file at `path` ([`parse_ply`]).
pub(crate) fn read_ply(path: &Path) -> Result<TriangleMesh, MeshError> {
    let bytes = crate::memory::read_file(path).map_err(|error| MeshError::Read { path: path.to_owned(), error })?;
    parse_ply(path, &bytes)
}

/// The mesh of `bytes`, a whole PLY file; `path` names it in errors. A file without a `face`
/// element is a mesh without triangles.
pub(crate) fn parse_ply(path: &Path, bytes: &[u8]) -> Result<TriangleMesh, MeshError> {
    let fail = |(at, message): (At, String)| match at {
        At::Line(line) => MeshError::Invalid { path: path.to_owned(), line, message },
        At::Byte(offset) => MeshError::InvalidBinary { path: path.to_owned(), offset, message },
    };
    let header = parse_header(bytes).map_err(fail)?;
    let plan = Plan::new(&header, bytes.len()).map_err(fail)?;
    let mut out = Builder::new(&header, &plan).map_err(|(line, error)| MeshError::Memory {
        path: path.to_owned(),
        line,
        error,
    })?;
    let body = &bytes[header.body..];
    match header.encoding {
        Encoding::Ascii => read_body(&mut Ascii::new(body, header.lines), &header, &plan, &mut out),
        Encoding::LittleEndian => read_body(&mut Binary::<false>::new(body, header.body), &header, &plan, &mut out),
        Encoding::BigEndian => read_body(&mut Binary::<true>::new(body, header.body), &header, &plan, &mut out),
    }
    .map_err(fail)?;
    Ok(out.finish())
}

/// Where in the file: a line (of the header, or of an ASCII body), or a byte offset (in a binary
/// body).
#[derive(Clone, Copy, Debug)]
enum At {
    Line(usize),
    Byte(usize),
}

// ---------------------------------------------------------------------------------------------
// The header

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Encoding {
    Ascii,
    LittleEndian,
    BigEndian,
}

/// A PLY scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    Char,
    UChar,
    Short,
    UShort,
    Int,
    UInt,
    Float,
    Double,
}

impl Scalar {
    fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::Char,
            "uchar" | "uint8" => Self::UChar,
            "short" | "int16" => Self::Short,
            "ushort" | "uint16" => Self::UShort,
            "int" | "int32" => Self::Int,
            "uint" | "uint32" => Self::UInt,
            "float" | "float32" => Self::Float,
            "double" | "float64" => Self::Double,
            _ => return None,
        })
    }

    fn name(self) -> &'static str {
        match self {
            Self::Char => "char",
            Self::UChar => "uchar",
            Self::Short => "short",
            Self::UShort => "ushort",
            Self::Int => "int",
            Self::UInt => "uint",
            Self::Float => "float",
            Self::Double => "double",
        }
    }

    /// Bytes in a binary body.
    fn size(self) -> usize {
        match self {
            Self::Char | Self::UChar => 1,
            Self::Short | Self::UShort => 2,
            Self::Int | Self::UInt | Self::Float => 4,
            Self::Double => 8,
        }
    }

    /// The least and greatest value of an integer type; `None` for `float` and `double`.
    fn integer_range(self) -> Option<(i64, i64)> {
        Some(match self {
            Self::Char => (i8::MIN.into(), i8::MAX.into()),
            Self::UChar => (0, u8::MAX.into()),
            Self::Short => (i16::MIN.into(), i16::MAX.into()),
            Self::UShort => (0, u16::MAX.into()),
            Self::Int => (i32::MIN.into(), i32::MAX.into()),
            Self::UInt => (0, u32::MAX.into()),
            Self::Float | Self::Double => return None,
        })
    }
}

#[derive(Clone, Copy, Debug)]
enum Kind {
    Scalar(Scalar),
    /// A count of type `count` (an integer type), then that many `item`s.
    List {
        count: Scalar,
        item: Scalar,
    },
}

#[derive(Debug)]
struct Property {
    name: String,
    kind: Kind,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: u64,
    properties: Vec<Property>,
    /// Its `element` line.
    line: usize,
}

#[derive(Debug)]
struct Header {
    encoding: Encoding,
    elements: Vec<Element>,
    /// The body's first byte: the one after `end_header`'s line end.
    body: usize,
    /// The header's lines, `end_header`'s the last.
    lines: usize,
}

const TYPES: &str = "char, uchar, short, ushort, int, uint, float, double (or int8, uint8, int16, uint16, int32, uint32, float32, float64)";

/// The header of the PLY file `bytes`, checked line by line.
fn parse_header(bytes: &[u8]) -> Result<Header, (At, String)> {
    let mut lines = LineEnds { bytes, pos: 0 };
    let mut line = 0;
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        let Some(text) = lines.next() else {
            return Err((At::Line(line.max(1)), "the header has no `end_header` line".to_owned()));
        };
        line += 1;
        let err = |message: String| (At::Line(line), message);
        if line == 1 {
            if text.trim_ascii() != b"ply" {
                return Err(err("not a PLY file: its first line is not `ply`".to_owned()));
            }
            continue;
        }
        // Comments may hold any bytes (a name in Latin-1); nothing else in a header may.
        let first = text.split(u8::is_ascii_whitespace).find(|w| !w.is_empty());
        if matches!(first, Some(b"comment" | b"obj_info")) {
            continue;
        }
        let Some(text) = std::str::from_utf8(text).ok().filter(|t| !t.chars().any(|c| c.is_control() && c != '\t'))
        else {
            return Err(err("not header text: is `end_header` missing?".to_owned()));
        };
        let words: Vec<&str> = text.split_ascii_whitespace().collect();
        match words[..] {
            [] => {}
            ["end_header"] => break,
            ["format", name, version] => {
                if encoding.is_some() {
                    return Err(err("a second `format` line".to_owned()));
                }
                encoding = Some(match name {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::LittleEndian,
                    "binary_big_endian" => Encoding::BigEndian,
                    _ => {
                        return Err(err(format!(
                            "unknown format `{name}`; known: ascii, binary_little_endian, binary_big_endian"
                        )));
                    }
                });
                if version.parse::<f64>() != Ok(1.0) {
                    return Err(err(format!("format version `{version}`; only 1.0 is known")));
                }
            }
            ["format", ..] => {
                return Err(err("`format` takes an encoding and a version, as `format ascii 1.0`".to_owned()));
            }
            ["element", name, count] => {
                let Ok(count) = count.parse::<u64>() else {
                    return Err(err(format!("element `{name}`: its count `{count}` is not a whole number")));
                };
                if matches!(name, "vertex" | "face") && elements.iter().any(|e| e.name == name) {
                    return Err(err(format!("a second `{name}` element")));
                }
                elements.push(Element { name: name.to_owned(), count, properties: Vec::new(), line });
            }
            ["element", ..] => return Err(err("`element` takes a name and a count, as `element vertex 8`".to_owned())),
            ["property", ..] => {
                let Some(element) = elements.last_mut() else {
                    return Err(err("`property` before any `element`".to_owned()));
                };
                let property = parse_property(&words[1..]).map_err(err)?;
                if element.properties.iter().any(|p| p.name == property.name) {
                    return Err(err(format!("element `{}` has a second property `{}`", element.name, property.name)));
                }
                element.properties.push(property);
            }
            ["end_header", ..] => return Err(err("`end_header` takes nothing after it".to_owned())),
            [keyword, ..] => {
                let keyword: String = keyword.chars().take(40).collect();
                return Err(err(format!("unknown header keyword `{keyword}` (is `end_header` missing?)")));
            }
        }
    }
    let Some(encoding) = encoding else {
        return Err((At::Line(line), "the header has no `format` line".to_owned()));
    };
    Ok(Header { encoding, elements, body: lines.pos, lines: line })
}

/// A `property` line's words after the keyword.
fn parse_property(words: &[&str]) -> Result<Property, String> {
    let scalar = |name: &str| Scalar::from_name(name).ok_or_else(|| format!("unknown type `{name}`; known: {TYPES}"));
    let (kind, name) = match *words {
        ["list", count, item, name] => {
            let count = scalar(count)?;
            if count.integer_range().is_none() {
                return Err(format!("list `{name}`: its count type `{}` is not an integer type", count.name()));
            }
            (Kind::List { count, item: scalar(item)? }, name)
        }
        [ty, name] if ty != "list" => (Kind::Scalar(scalar(ty)?), name),
        _ => {
            return Err("`property` takes a type and a name (`property float x`), or `list`, a count type, an \
                        item type and a name (`property list uchar int vertex_indices`)"
                .to_owned());
        }
    };
    Ok(Property { name: name.to_owned(), kind })
}

/// The lines of a header, each without its line end (LF, CR LF or CR); `pos` is where the next
/// starts.
struct LineEnds<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Iterator for LineEnds<'a> {
    type Item = &'a [u8];

    fn next(&mut self) -> Option<&'a [u8]> {
        let rest = self.bytes.get(self.pos..).filter(|r| !r.is_empty())?;
        let end = rest.iter().position(|&b| b == b'\n' || b == b'\r').unwrap_or(rest.len());
        let ending = match rest.get(end..) {
            Some([b'\r', b'\n', ..]) => 2,
            Some([_, ..]) => 1,
            _ => 0,
        };
        self.pos += end + ending;
        Some(&rest[..end])
    }
}

// ---------------------------------------------------------------------------------------------
// What to read

/// What each element is to the mesh.
enum Role {
    Vertex(VertexSlots),
    /// The property that is the face's list of vertex indices.
    Face {
        list: usize,
    },
    Other,
}

/// Where each property of the `vertex` element goes: slots 0 to 2 are the position, 3 to 5 the
/// normal, 6 and 7 the texture coordinates.
struct VertexSlots {
    slots: Vec<Option<usize>>,
    normals: bool,
    uvs: bool,
}

/// The header checked for what the mesh needs, and against the file's size.
struct Plan {
    roles: Vec<Role>,
    vertices: u64,
}

/// Texture coordinate pairs, in the order they are looked for.
const UV_NAMES: [[&str; 2]; 3] = [["u", "v"], ["s", "t"], ["texture_u", "texture_v"]];

impl Plan {
    fn new(header: &Header, file_len: usize) -> Result<Self, (At, String)> {
        let vertex = header.elements.iter().find(|e| e.name == "vertex");
        let mut roles = Vec::with_capacity(header.elements.len());
        for element in &header.elements {
            let err = |message: String| (At::Line(element.line), message);
            roles.push(match element.name.as_str() {
                "vertex" => Role::Vertex(vertex_slots(element).map_err(err)?),
                "face" => {
                    if vertex.is_none() {
                        return Err(err("a `face` element, but no `vertex` element".to_owned()));
                    }
                    Role::Face { list: face_list(element).map_err(err)? }
                }
                _ => Role::Other,
            });
        }
        check_size(header, file_len)?;
        let vertices = vertex.map_or(0, |v| v.count);
        if let Some(v) = vertex.filter(|v| v.count > u64::from(u32::MAX)) {
            return Err((At::Line(v.line), format!("{} vertices; at most {} are indexable", v.count, u32::MAX)));
        }
        Ok(Plan { roles, vertices })
    }
}

/// The `vertex` element's slots: `x y z` must be scalars; normals and texture coordinates are
/// read where all their properties are.
fn vertex_slots(element: &Element) -> Result<VertexSlots, String> {
    let find = |name: &str| element.properties.iter().position(|p| p.name == name && matches!(p.kind, Kind::Scalar(_)));
    let mut slots = vec![None; element.properties.len()];
    for (slot, name) in ["x", "y", "z"].into_iter().enumerate() {
        let Some(k) = find(name) else {
            let list = element.properties.iter().any(|p| p.name == name);
            return Err(if list {
                format!("`vertex` property `{name}` is a list; a coordinate is one number")
            } else {
                format!("element `vertex` has no property `{name}`")
            });
        };
        slots[k] = Some(slot);
    }
    let normal = ["nx", "ny", "nz"].map(find);
    let normals = normal.iter().all(Option::is_some);
    if normals {
        for (slot, k) in normal.into_iter().flatten().enumerate() {
            slots[k] = Some(3 + slot);
        }
    }
    let uv = UV_NAMES.iter().map(|pair| pair.map(find)).find(|pair| pair.iter().all(Option::is_some));
    if let Some(pair) = uv {
        for (slot, k) in pair.into_iter().flatten().enumerate() {
            slots[k] = Some(6 + slot);
        }
    }
    Ok(VertexSlots { slots, normals, uvs: uv.is_some() })
}

/// The `face` element's list of vertex indices, which must be a list of an integer type.
fn face_list(element: &Element) -> Result<usize, String> {
    let found = ["vertex_indices", "vertex_index"]
        .iter()
        .find_map(|name| element.properties.iter().position(|p| p.name == *name));
    let Some(k) = found else {
        return Err("element `face` has no `vertex_indices` (or `vertex_index`) list".to_owned());
    };
    let p = &element.properties[k];
    match p.kind {
        Kind::List { item, .. } if item.integer_range().is_some() => Ok(k),
        Kind::List { item, .. } => {
            Err(format!("`face` list `{}` holds `{}`; indices are integers", p.name, item.name()))
        }
        Kind::Scalar(_) => Err(format!("`face` property `{}` is not a list", p.name)),
    }
}

/// An error where the elements need more bytes than the body has: each value of a record takes
/// at least one byte in a binary body (a list at least its count) and two in an ASCII one (a
/// digit and a space or line end; the file's last value may go without).
fn check_size(header: &Header, file_len: usize) -> Result<(), (At, String)> {
    let body = (file_len - header.body) as u128;
    let slack = u128::from(header.encoding == Encoding::Ascii);
    let mut left = body;
    for (k, e) in header.elements.iter().enumerate() {
        let each: u128 = e
            .properties
            .iter()
            .map(|p| match (header.encoding, p.kind) {
                (Encoding::Ascii, _) => 2,
                (_, Kind::Scalar(ty) | Kind::List { count: ty, .. }) => ty.size() as u128,
            })
            .sum();
        let need = each * u128::from(e.count);
        if need > left + slack {
            let before = if k > 0 { " and the elements before it" } else { "" };
            let message = format!(
                "{} `{}` elements need at least {need} bytes ({each} each), and {left} are left after the header{before} \
                 (is the file cut short?)",
                e.count, e.name
            );
            return Err((At::Line(e.line), message));
        }
        left = left.saturating_sub(need);
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// The body

/// What went wrong reading a value, before the reader says where.
enum Fault {
    /// The file ended.
    End,
    /// ASCII: the element's line ended.
    LineEnded,
    /// ASCII: a word after the element's last property.
    Extra(String),
    /// A value that is not of its type, or out of range.
    Bad(String),
}

/// An encoding's reader of values, one element record at a time.
trait Body {
    /// Starts a record (ASCII: its line, the next that is not blank).
    fn begin(&mut self) -> Result<(), Fault>;
    /// The next value, of type `ty`: as an f64, which holds every value of every PLY type
    /// exactly, so that a `float` becomes the same f32 again whichever encoding gave it.
    fn value(&mut self, ty: Scalar) -> Result<f64, Fault>;
    /// Skips `n` values of type `ty`.
    fn skip(&mut self, ty: Scalar, n: u64) -> Result<(), Fault>;
    /// Ends a record (ASCII: nothing may be left on its line).
    fn end(&mut self) -> Result<(), Fault>;
    /// Where the next value starts (ASCII: the record's line).
    fn at(&self) -> At;
}

/// A binary body, big-endian where `BIG`.
struct Binary<'a, const BIG: bool> {
    bytes: &'a [u8],
    pos: usize,
    /// The body's offset in the file.
    base: usize,
}

impl<'a, const BIG: bool> Binary<'a, BIG> {
    fn new(bytes: &'a [u8], base: usize) -> Self {
        Binary { bytes, pos: 0, base }
    }
}

impl<const BIG: bool> Body for Binary<'_, BIG> {
    fn begin(&mut self) -> Result<(), Fault> {
        Ok(())
    }

    #[inline]
    fn value(&mut self, ty: Scalar) -> Result<f64, Fault> {
        let Some(b) = self.bytes.get(self.pos..self.pos + ty.size()) else { return Err(Fault::End) };
        self.pos += ty.size();
        macro_rules! read {
            ($t:ty) => {{
                let b = b.try_into().expect("a slice of the type's size");
                f64::from(if BIG { <$t>::from_be_bytes(b) } else { <$t>::from_le_bytes(b) })
            }};
        }
        Ok(match ty {
            Scalar::Char => read!(i8),
            Scalar::UChar => read!(u8),
            Scalar::Short => read!(i16),
            Scalar::UShort => read!(u16),
            Scalar::Int => read!(i32),
            Scalar::UInt => read!(u32),
            Scalar::Float => read!(f32),
            Scalar::Double => read!(f64),
        })
    }

    fn skip(&mut self, ty: Scalar, n: u64) -> Result<(), Fault> {
        let len = u128::from(n) * ty.size() as u128;
        if len > (self.bytes.len() - self.pos) as u128 {
            return Err(Fault::End);
        }
        self.pos += len as usize;
        Ok(())
    }

    fn end(&mut self) -> Result<(), Fault> {
        Ok(())
    }

    fn at(&self) -> At {
        At::Byte(self.base + self.pos)
    }
}

/// An ASCII body: one record a line.
struct Ascii<'a> {
    text: &'a [u8],
    /// The start of the line after the record's.
    next: usize,
    /// The record's line number.
    line: usize,
    /// What is left of the record's line.
    rest: &'a [u8],
}

impl<'a> Ascii<'a> {
    /// The body `text`, after a header of `lines` lines.
    fn new(text: &'a [u8], lines: usize) -> Self {
        Ascii { text, next: 0, line: lines, rest: &[] }
    }

    fn word(&mut self) -> Option<&'a [u8]> {
        let rest = self.rest;
        let start = rest.iter().position(|b| !b.is_ascii_whitespace())?;
        let len = rest[start..].iter().position(u8::is_ascii_whitespace).unwrap_or(rest.len() - start);
        self.rest = &rest[start + len..];
        Some(&rest[start..start + len])
    }
}

impl Body for Ascii<'_> {
    fn begin(&mut self) -> Result<(), Fault> {
        let mut lines = LineEnds { bytes: self.text, pos: self.next };
        loop {
            let line = lines.next().ok_or(Fault::End)?;
            self.line += 1;
            self.next = lines.pos;
            if !line.trim_ascii().is_empty() {
                self.rest = line;
                return Ok(());
            }
        }
    }

    fn value(&mut self, ty: Scalar) -> Result<f64, Fault> {
        let word = self.word().ok_or(Fault::LineEnded)?;
        parse_word(ty, word).map_err(Fault::Bad)
    }

    fn skip(&mut self, ty: Scalar, n: u64) -> Result<(), Fault> {
        for _ in 0..n {
            self.value(ty)?;
        }
        Ok(())
    }

    fn end(&mut self) -> Result<(), Fault> {
        match self.word() {
            Some(w) => Err(Fault::Extra(shown(w))),
            None => Ok(()),
        }
    }

    fn at(&self) -> At {
        At::Line(self.line)
    }
}

/// An ASCII value of type `ty`: an integer type's in its range, a `float` parsed as f32 (so that
/// it rounds as a binary file's writer rounded it) and within its range.
fn parse_word(ty: Scalar, word: &[u8]) -> Result<f64, String> {
    let not_a = || format!("`{}` is not a `{}`", shown(word), ty.name());
    let text = std::str::from_utf8(word).map_err(|_| not_a())?;
    let infinity_written = || text.to_ascii_lowercase().contains("inf");
    match ty.integer_range() {
        Some((lo, hi)) => {
            let x: i64 = text.parse().map_err(|_| not_a())?;
            if !(lo..=hi).contains(&x) {
                return Err(format!("{x} is out of range for `{}`", ty.name()));
            }
            Ok(x as f64)
        }
        None if ty == Scalar::Float => {
            let x: f32 = text.parse().map_err(|_| not_a())?;
            if x.is_infinite() && !infinity_written() {
                return Err(format!("`{text}` overflows `float`"));
            }
            Ok(f64::from(x))
        }
        None => {
            let x: f64 = text.parse().map_err(|_| not_a())?;
            if x.is_infinite() && !infinity_written() {
                return Err(format!("`{text}` overflows `double`"));
            }
            Ok(x)
        }
    }
}

/// A word of the file as an error shows it: lossy UTF-8, at most 40 characters.
fn shown(word: &[u8]) -> String {
    String::from_utf8_lossy(word).chars().take(40).collect()
}

/// An error in one record: where, at which property, and what.
struct RecordError {
    at: At,
    property: Option<usize>,
    what: Result<String, Fault>,
}

impl RecordError {
    fn fault(at: At, property: Option<usize>, fault: Fault) -> Self {
        RecordError { at, property, what: Err(fault) }
    }

    fn message(at: At, property: Option<usize>, message: String) -> Self {
        RecordError { at, property, what: Ok(message) }
    }

    /// The error in record `index` of `element`.
    fn describe(self, element: &Element, index: u64) -> (At, String) {
        let record = format!("{} {index}", element.name);
        let property = self.property.map(|k| element.properties[k].name.as_str());
        let message = match (self.what, property) {
            (Err(Fault::End), None) => format!("the file ends before {record} (of {})", element.count),
            (Err(Fault::End), Some(p)) => format!("the file ends in {record} (of {}), at `{p}`", element.count),
            (Err(Fault::LineEnded), Some(p)) => format!("{record}: its line ends before `{p}`"),
            (Err(Fault::Extra(w)), _) => format!("{record}: `{w}` after its last property"),
            (Err(Fault::Bad(m)) | Ok(m), Some(p)) => format!("{record}, `{p}`: {m}"),
            (Err(Fault::Bad(m)) | Ok(m), None) => format!("{record}: {m}"),
            (Err(Fault::LineEnded), None) => format!("{record}: its line ends early"),
        };
        (self.at, message)
    }
}

/// Reads every element of the body into `out`.
fn read_body<B: Body>(body: &mut B, header: &Header, plan: &Plan, out: &mut Builder) -> Result<(), (At, String)> {
    for (element, role) in header.elements.iter().zip(&plan.roles) {
        if element.properties.is_empty() {
            continue;
        }
        for index in 0..element.count {
            let read = match role {
                Role::Vertex(slots) => read_vertex(body, element, slots, out),
                Role::Face { list } => read_face(body, element, *list, plan.vertices, out),
                Role::Other => read_other(body, element),
            };
            read.map_err(|e| e.describe(element, index))?;
        }
    }
    Ok(())
}

/// Starts a record.
fn begin<B: Body>(body: &mut B) -> Result<(), RecordError> {
    body.begin().map_err(|f| RecordError::fault(body.at(), None, f))
}

/// Ends a record.
fn end<B: Body>(body: &mut B) -> Result<(), RecordError> {
    body.end().map_err(|f| RecordError::fault(body.at(), None, f))
}

/// Reads (or skips) property `k`, a scalar of type `ty`.
#[inline]
fn value<B: Body>(body: &mut B, ty: Scalar, k: usize) -> Result<f64, RecordError> {
    body.value(ty).map_err(|f| RecordError::fault(body.at(), Some(k), f))
}

/// The length of list property `k`, whose count is of (integer) type `ty`.
fn list_len<B: Body>(body: &mut B, ty: Scalar, k: usize) -> Result<u64, RecordError> {
    let at = body.at();
    let n = value(body, ty, k)?;
    if n < 0.0 {
        return Err(RecordError::message(at, Some(k), format!("the list's count {n} is negative")));
    }
    Ok(n as u64)
}

/// Skips property `k` of `kind`.
fn skip<B: Body>(body: &mut B, kind: Kind, k: usize) -> Result<(), RecordError> {
    let (ty, n) = match kind {
        Kind::Scalar(ty) => (ty, 1),
        Kind::List { count, item } => (item, list_len(body, count, k)?),
    };
    body.skip(ty, n).map_err(|f| RecordError::fault(body.at(), Some(k), f))
}

fn read_other<B: Body>(body: &mut B, element: &Element) -> Result<(), RecordError> {
    begin(body)?;
    for (k, p) in element.properties.iter().enumerate() {
        skip(body, p.kind, k)?;
    }
    end(body)
}

fn read_vertex<B: Body>(
    body: &mut B,
    element: &Element,
    slots: &VertexSlots,
    out: &mut Builder,
) -> Result<(), RecordError> {
    begin(body)?;
    let at = body.at();
    let mut v = [0f64; 8];
    for (k, (p, slot)) in element.properties.iter().zip(&slots.slots).enumerate() {
        match (p.kind, slot) {
            (Kind::Scalar(ty), Some(s)) => v[*s] = value(body, ty, k)?,
            (kind, _) => skip(body, kind, k)?,
        }
    }
    end(body)?;
    let exact = DVec3::new(v[0], v[1], v[2]);
    let p = exact.as_vec3();
    if !p.is_finite() {
        let why = if exact.is_finite() { "overflows f32" } else { "is not finite" };
        return Err(RecordError::message(at, None, format!("position {:?} {why}", exact.to_array())));
    }
    out.positions.push(p);
    if slots.normals {
        out.normals.push(DVec3::new(v[3], v[4], v[5]).normalize_or_zero().as_vec3());
    }
    if slots.uvs {
        let uv = Vec2::new(v[6] as f32, v[7] as f32);
        if !uv.is_finite() {
            let message = format!("texture coordinates {:?} are not finite in f32", [v[6], v[7]]);
            return Err(RecordError::message(at, None, message));
        }
        out.uvs.push(uv);
    }
    Ok(())
}

fn read_face<B: Body>(
    body: &mut B,
    element: &Element,
    list: usize,
    vertices: u64,
    out: &mut Builder,
) -> Result<(), RecordError> {
    begin(body)?;
    for (k, p) in element.properties.iter().enumerate() {
        let (Kind::List { count, item }, true) = (p.kind, k == list) else {
            skip(body, p.kind, k)?;
            continue;
        };
        let at = body.at();
        let n = list_len(body, count, k)?;
        if n < 3 {
            let noun = if n == 1 { "vertex" } else { "vertices" };
            return Err(RecordError::message(at, Some(k), format!("{n} {noun}; a face needs at least 3")));
        }
        if n == 3 {
            let mut t = [0; 3];
            for c in &mut t {
                *c = vertex_index(body, item, k, vertices)?;
            }
            out.triangles.push(t);
        } else {
            let start = out.corners.len();
            for _ in 0..n {
                let i = vertex_index(body, item, k, vertices)?;
                out.corners.push(i);
            }
            out.polygons.push(Polygon { before: out.triangles.len(), corners: start..out.corners.len() });
        }
    }
    end(body)
}

/// A vertex index of (integer) type `ty` in list property `k`, checked against the count.
#[inline]
fn vertex_index<B: Body>(body: &mut B, ty: Scalar, k: usize, vertices: u64) -> Result<u32, RecordError> {
    let at = body.at();
    let i = value(body, ty, k)?;
    if i < 0.0 {
        return Err(RecordError::message(at, Some(k), format!("vertex index {i} is negative")));
    }
    if i >= vertices as f64 {
        let message = format!("vertex index {i} is past the last vertex (the file has {vertices})");
        return Err(RecordError::message(at, Some(k), message));
    }
    Ok(i as u32)
}

// ---------------------------------------------------------------------------------------------
// The mesh

/// A face of more than 3 vertices, triangulated once every position is read.
struct Polygon {
    /// How many triangles came before it: its own go there.
    before: usize,
    corners: Range<usize>,
}

/// The mesh as it is read.
struct Builder {
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    uvs: Vec<Vec2>,
    /// The triangle faces, and the triangles of the polygons once [`Builder::finish`] has made
    /// them.
    triangles: Vec<[u32; 3]>,
    polygons: Vec<Polygon>,
    /// The polygons' vertex indices.
    corners: Vec<u32>,
}

impl Builder {
    /// Room for the header's vertices and faces (one triangle each), which [`check_size`] keeps
    /// within the file's size, once they are known to fit in memory (else the line of the
    /// vertex element, and the estimate).
    fn new(header: &Header, plan: &Plan) -> Result<Self, (usize, crate::memory::OutOfMemory)> {
        let (mut vertices, mut faces, mut line) = (0, 0, 1);
        let (mut normals, mut uvs) = (false, false);
        for (e, role) in header.elements.iter().zip(&plan.roles) {
            match role {
                Role::Vertex(s) => (vertices, normals, uvs, line) = (e.count as usize, s.normals, s.uvs, e.line),
                Role::Face { .. } => faces = e.count as usize,
                Role::Other => {}
            }
        }
        let bytes = vertices as f64 * (12.0 + 12.0 * f64::from(u8::from(normals)) + 8.0 * f64::from(u8::from(uvs)))
            + faces as f64 * 12.0;
        let what = format!("{vertices} vertices and {faces} faces");
        crate::memory::check_fits(&what, bytes).map_err(|e| (line, e))?;
        Ok(Builder {
            positions: Vec::with_capacity(vertices),
            normals: Vec::with_capacity(if normals { vertices } else { 0 }),
            uvs: Vec::with_capacity(if uvs { vertices } else { 0 }),
            triangles: Vec::with_capacity(faces),
            polygons: Vec::new(),
            corners: Vec::new(),
        })
    }

    /// The mesh, every polygon triangulated in its place among the faces.
    fn finish(self) -> TriangleMesh {
        let Builder { positions, normals, uvs, triangles, polygons, corners } = self;
        let indices = if polygons.is_empty() {
            triangles
        } else {
            let position = |i: u32| positions[i as usize].as_dvec3();
            let mut indices = Vec::with_capacity(triangles.len() + corners.len());
            let (mut done, mut flat) = (0, Vec::new());
            for p in polygons {
                indices.extend_from_slice(&triangles[done..p.before]);
                done = p.before;
                flat.clear();
                triangulate_polygon(&corners[p.corners], &position, &mut flat);
                indices.extend(flat.chunks_exact(3).map(|t| [t[0], t[1], t[2]]));
            }
            indices.extend_from_slice(&triangles[done..]);
            indices
        };
        TriangleMesh { positions, indices, normals, uvs }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A property for [`encode`]: a scalar of a type, or a list of a count type and an item type,
    /// the types as the header spells them.
    enum P {
        S(&'static str, &'static str),
        L(&'static str, &'static str, &'static str),
    }

    /// An element for [`encode`]: each record its values in order, a list as its count then its
    /// items.
    struct El {
        name: &'static str,
        props: Vec<P>,
        records: Vec<Vec<f64>>,
    }

    /// A PLY file of `elements` in `format` (`ascii`, `binary_little_endian`,
    /// `binary_big_endian`), a list's items as many as its count says or as there are:
    /// `float` written as f32 (in ASCII its shortest form that reads back
    /// to it), `double` as f64, integers as themselves.
    fn encode(elements: &[El], format: &str) -> Vec<u8> {
        let mut out = format!("ply\nformat {format} 1.0\ncomment written by the tests\nobj_info none\n").into_bytes();
        for e in elements {
            out.extend(format!("element {} {}\n", e.name, e.records.len()).bytes());
            for p in &e.props {
                let line = match p {
                    P::S(ty, name) => format!("property {ty} {name}\n"),
                    P::L(count, item, name) => format!("property list {count} {item} {name}\n"),
                };
                out.extend(line.bytes());
            }
        }
        out.extend(b"end_header\n");
        for e in elements {
            for record in &e.records {
                let mut values = record.iter().copied();
                let mut words = Vec::new();
                for p in &e.props {
                    let (count, item) = match p {
                        P::S(ty, _) => (None, *ty),
                        P::L(count, item, _) => (Some(*count), *item),
                    };
                    let n = match count {
                        Some(ty) => {
                            let n = values.next().unwrap();
                            put(&mut out, &mut words, ty, n, format);
                            n.max(0.0) as usize
                        }
                        None => 1,
                    };
                    // A count past the values given (a broken file) writes those there are.
                    for x in values.by_ref().take(n) {
                        put(&mut out, &mut words, item, x, format);
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

    /// Writes `x` as type `ty`: its bytes to `out`, or in ASCII its word to `words`.
    fn put(out: &mut Vec<u8>, words: &mut Vec<String>, ty: &str, x: f64, format: &str) {
        let ty = Scalar::from_name(ty).unwrap();
        if format == "ascii" {
            words.push(match ty {
                Scalar::Float => (x as f32).to_string(),
                Scalar::Double => x.to_string(),
                _ => (x as i64).to_string(),
            });
            return;
        }
        let big = format == "binary_big_endian";
        macro_rules! bytes {
            ($v:expr) => {{
                let v = $v;
                if big { v.to_be_bytes().to_vec() } else { v.to_le_bytes().to_vec() }
            }};
        }
        out.extend(match ty {
            Scalar::Char => bytes!(x as i8),
            Scalar::UChar => bytes!(x as u8),
            Scalar::Short => bytes!(x as i16),
            Scalar::UShort => bytes!(x as u16),
            Scalar::Int => bytes!(x as i32),
            Scalar::UInt => bytes!(x as u32),
            Scalar::Float => bytes!(x as f32),
            Scalar::Double => bytes!(x),
        });
    }

    const FORMATS: [&str; 3] = ["ascii", "binary_little_endian", "binary_big_endian"];

    fn parse(bytes: &[u8]) -> Result<TriangleMesh, String> {
        parse_ply(Path::new("m.ply"), bytes).map_err(|e| e.to_string())
    }

    /// A U-shaped octagon (concave), a quad and two triangles: 12 vertices.
    fn u_quad_triangles() -> (Vec<[f64; 3]>, Vec<Vec<f64>>) {
        let u = [[0.0, 0.0], [3.0, 0.0], [3.0, 3.0], [2.0, 3.0], [2.0, 1.0], [1.0, 1.0], [1.0, 3.0], [0.0, 3.0]];
        let mut positions: Vec<[f64; 3]> = u.iter().map(|p| [p[0], p[1], 0.0]).collect();
        positions.extend([[0.1, -2.5e-3, 1e-7], [3e5, 0.3, -1.0], [0.7, 0.7, 0.7], [-4.0, 1.0 / 3.0, 2.0]]);
        let faces = vec![
            vec![3.0, 8.0, 9.0, 10.0],
            vec![8.0, 0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0],
            vec![4.0, 8.0, 9.0, 10.0, 11.0],
            vec![3.0, 11.0, 10.0, 9.0],
        ];
        (positions, faces)
    }

    /// The same mesh in each encoding, and with other types and other elements around it, loads
    /// to the same `TriangleMesh`, bit for bit: positions, normals (normalised; zero and NaN
    /// ones become zero), texture coordinates, and the faces triangulated in their order.
    #[test]
    fn every_encoding_and_type_loads_the_same_mesh_bit_for_bit() {
        let (positions, faces) = u_quad_triangles();
        let normal = |k: usize| match k {
            0 => [0.0, 0.0, 2.0],
            1 => [0.0, 0.0, 0.0],
            2 => [f64::NAN, 0.0, 1.0],
            _ => [1.0, k as f64, -3.0],
        };
        let uv = |k: usize| [k as f64 * 0.125, 1.0 - k as f64 * 0.0625];
        // Floats, normals, `s t`, colours and a list among the vertex properties; a scalar
        // before the indices and a list after them; an element before and after.
        let floats = vec![
            El {
                name: "edge",
                props: vec![P::S("int", "vertex1"), P::S("int", "vertex2"), P::L("uchar", "float", "weights")],
                records: vec![vec![0.0, 1.0, 2.0, 0.5, 0.25], vec![1.0, 2.0, 0.0]],
            },
            El {
                name: "vertex",
                props: vec![
                    P::S("float", "x"),
                    P::S("uchar", "red"),
                    P::S("float", "y"),
                    P::S("float", "z"),
                    P::S("float", "nx"),
                    P::S("float", "ny"),
                    P::S("float", "nz"),
                    P::L("uchar", "short", "tags"),
                    P::S("float", "s"),
                    P::S("float", "t"),
                ],
                records: (0..positions.len())
                    .map(|k| {
                        let [x, y, z] = positions[k].map(|c| f64::from(c as f32));
                        let tags: &[f64] = if k % 2 == 0 { &[2.0, -7.0, 300.0] } else { &[0.0] };
                        let mut r = vec![x, 200.0, y, z];
                        r.extend(normal(k));
                        r.extend(tags);
                        r.extend(uv(k).map(|c| f64::from(c as f32)));
                        r
                    })
                    .collect(),
            },
            El {
                name: "face",
                props: vec![
                    P::S("int", "flags"),
                    P::L("uchar", "int", "vertex_indices"),
                    P::L("uchar", "float", "texcoord"),
                ],
                records: faces
                    .iter()
                    .map(|f| {
                        let mut r = vec![-1.0];
                        r.extend(f);
                        r.extend([2.0, 0.5, 0.5]);
                        r
                    })
                    .collect(),
            },
            El { name: "material", props: vec![P::S("double", "shininess")], records: vec![vec![0.5]] },
        ];
        // Doubles, `texture_u texture_v`, other index and count types and their aliases.
        let doubles = |count: &'static str, index: &'static str, name: &'static str| {
            vec![
                El {
                    name: "vertex",
                    props: vec![
                        P::S("float64", "z"),
                        P::S("double", "y"),
                        P::S("double", "x"),
                        P::S("double", "texture_u"),
                        P::S("ushort", "confidence"),
                        P::S("double", "texture_v"),
                        P::S("double", "nx"),
                        P::S("double", "ny"),
                        P::S("double", "nz"),
                    ],
                    records: (0..positions.len())
                        .map(|k| {
                            let [x, y, z] = positions[k].map(|c| f64::from(c as f32));
                            let [u, v] = uv(k).map(|c| f64::from(c as f32));
                            let mut r = vec![z, y, x, u, 65535.0, v];
                            r.extend(normal(k).map(|c| f64::from(c as f32)));
                            r
                        })
                        .collect(),
                },
                El { name: "face", props: vec![P::L(count, index, name)], records: faces.clone() },
            ]
        };
        let reference = parse(&encode(&floats, "ascii")).unwrap();
        for format in FORMATS {
            for (what, elements) in [
                ("floats", floats.as_slice()),
                ("doubles", &doubles("ushort", "uint", "vertex_indices")),
                ("aliases", &doubles("int8", "int16", "vertex_index")),
                ("uint counts", &doubles("uint32", "uint8", "vertex_indices")),
            ] {
                let mesh = parse(&encode(elements, format)).unwrap_or_else(|e| panic!("{format} {what}: {e}"));
                let bits = |m: &TriangleMesh| {
                    let v3 = |v: &[Vec3]| v.iter().flat_map(|p| p.to_array().map(f32::to_bits)).collect::<Vec<_>>();
                    let uvs: Vec<u32> = m.uvs.iter().flat_map(|p| p.to_array().map(f32::to_bits)).collect();
                    (v3(&m.positions), v3(&m.normals), uvs, m.indices.clone())
                };
                assert_eq!(bits(&mesh), bits(&reference), "{format} {what}");
            }
        }
        // What the reference holds.
        assert_eq!(reference.positions.len(), 12);
        assert_eq!(reference.positions[9], Vec3::new(3e5, 0.3, -1.0));
        assert_eq!(reference.normals[0], Vec3::Z);
        assert_eq!((reference.normals[1], reference.normals[2]), (Vec3::ZERO, Vec3::ZERO));
        assert!((reference.normals[5] - Vec3::new(1.0, 5.0, -3.0).normalize()).length() < 1e-6);
        assert_eq!(reference.uvs[4], Vec2::new(0.5, 0.75));
        // The triangle first, the octagon's 6, the quad's fan, the last triangle.
        let i = &reference.indices;
        assert_eq!((i.len(), i[0], i[7], i[8], i[9]), (10, [8, 9, 10], [8, 9, 10], [8, 10, 11], [11, 10, 9]));
    }

    /// A concave polygon keeps its shape (its triangles cover its area, all facing +z), as the
    /// OBJ reader's; a quad is a fan from its first vertex.
    #[test]
    fn polygons_are_triangulated_as_obj_polygons_are() {
        let (positions, faces) = u_quad_triangles();
        let ply = format!(
            "ply\nformat ascii 1.0\nelement vertex 12\nproperty double x\nproperty double y\nproperty double z\n\
             element face 1\nproperty list uchar uint vertex_indices\nend_header\n{}\n{}\n",
            positions.iter().map(|p| format!("{} {} {}", p[0], p[1], p[2])).collect::<Vec<_>>().join("\n"),
            faces[1].iter().map(f64::to_string).collect::<Vec<_>>().join(" "),
        );
        let mesh = parse(ply.as_bytes()).unwrap();
        let tris = mesh.triangles();
        assert_eq!(tris.len(), 6);
        let area: f32 = tris.iter().map(|t| (t.v1 - t.v0).cross(t.v2 - t.v0).z * 0.5).sum();
        assert!((area - 7.0).abs() < 1e-5 && tris.iter().all(|t| (t.v1 - t.v0).cross(t.v2 - t.v0).z >= 0.0));
        let quad = ply.replace("8 0 1 2 3 4 5 6 7", "4 8 9 10 11");
        assert_eq!(parse(quad.as_bytes()).unwrap().indices, vec![[8, 9, 10], [8, 10, 11]]);
    }

    const SQUARE: &str = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
                          property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n\
                          0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n";

    /// Each fault of a header or an ASCII body is an error at its line, saying what is wrong.
    #[test]
    fn ascii_errors_name_their_line() {
        assert_eq!(parse(SQUARE.as_bytes()).unwrap().indices, vec![[0, 1, 2], [0, 2, 3]]);
        let cases: &[(&str, &str, &str)] = &[
            ("ply\n", "plx\n", "m.ply:1: not a PLY file: its first line is not `ply`"),
            ("end_header\n", "", "m.ply:9: unknown header keyword `0` (is `end_header` missing?)"),
            ("format ascii 1.0", "format binary_middle_endian 1.0", "m.ply:2: unknown format `binary_middle_endian`"),
            ("format ascii 1.0", "format ascii 2.0", "m.ply:2: format version `2.0`; only 1.0 is known"),
            ("format ascii 1.0\n", "", "m.ply:8: the header has no `format` line"),
            ("property float y", "property real y", "m.ply:5: unknown type `real`; known: char, uchar"),
            ("element vertex 4\n", "property float w\nelement vertex 4\n", "m.ply:3: `property` before any `element`"),
            ("property float x\n", "", "m.ply:3: element `vertex` has no property `x`"),
            ("property float x\n", "property list uchar float x\n", "m.ply:3: `vertex` property `x` is a list"),
            ("property float z\n", "property float z\nproperty int z\n", "m.ply:7: element `vertex` has a second"),
            ("vertex_indices", "vertex_ids", "m.ply:7: element `face` has no `vertex_indices` (or `vertex_index`)"),
            ("list uchar int", "list float int", "m.ply:8: list `vertex_indices`: its count type `float` is not an"),
            ("list uchar int", "list uchar double", "m.ply:7: `face` list `vertex_indices` holds `double`"),
            ("element vertex 4", "element point 4", "m.ply:7: a `face` element, but no `vertex` element"),
            ("element vertex 4", "element vertex -4", "m.ply:3: element `vertex`: its count `-4` is not a whole"),
            ("element face 2\n", "element face 2\nelement vertex 1\n", "m.ply:8: a second `vertex` element"),
            ("element vertex 4", "element vertex 1000000000000", "m.ply:3: 1000000000000 `vertex` elements need at"),
            (
                "element face 2",
                "element face 18446744073709551615",
                "m.ply:7: 18446744073709551615 `face` elements need at least 36893488147419103230 bytes",
            ),
            (
                "3 0 2 3",
                "3 0 2 4",
                "m.ply:15: face 1, `vertex_indices`: vertex index 4 is past the last vertex (the file has 4)",
            ),
            ("3 0 1 2", "3 0 -1 2", "m.ply:14: face 0, `vertex_indices`: vertex index -1 is negative"),
            ("3 0 1 2", "2 0 1", "m.ply:14: face 0, `vertex_indices`: 2 vertices; a face needs at least 3"),
            ("3 0 1 2", "300 0 1 2", "m.ply:14: face 0, `vertex_indices`: 300 is out of range for `uchar`"),
            ("3 0 1 2", "3 0 1 2.5", "m.ply:14: face 0, `vertex_indices`: `2.5` is not a `int`"),
            ("1 0 0", "1 nan 0", "m.ply:11: vertex 1: position [1.0, NaN, 0.0] is not finite"),
            ("1 0 0", "1 -inf 0", "m.ply:11: vertex 1: position [1.0, -inf, 0.0] is not finite"),
            ("1 0 0", "1 1e39 0", "m.ply:11: vertex 1, `y`: `1e39` overflows `float`"),
            ("1 0 0", "1 abc 0", "m.ply:11: vertex 1, `y`: `abc` is not a `float`"),
            ("1 0 0", "1 0 0 5", "m.ply:11: vertex 1: `5` after its last property"),
            ("1 0 0", "1 0", "m.ply:11: vertex 1: its line ends before `z`"),
            ("3 0 2 3\n", "", "m.ply:14: the file ends before face 1 (of 2)"),
            ("3 0 2 3\n", "3 0 2", "m.ply:15: face 1: its line ends before `vertex_indices`"),
        ];
        for (from, to, says) in cases {
            assert!(SQUARE.contains(from), "{from}");
            let err = parse(SQUARE.replacen(from, to, 1).as_bytes()).unwrap_err();
            assert!(err.starts_with(says), "{from} -> {to}:\n  got      {err}\n  expected {says}");
        }
        let err = parse(b"ply\nformat ascii 1.0\nelement vertex 1\n").unwrap_err();
        assert_eq!(err, "m.ply:3: the header has no `end_header` line");
        assert_eq!(parse(b"").unwrap_err(), "m.ply:1: the header has no `end_header` line");
    }

    /// Each fault of a binary body is an error at its byte offset, naming the element and the
    /// property.
    #[test]
    fn binary_errors_name_their_byte_offset() {
        let square = |format: &str, faces: Vec<Vec<f64>>| {
            let positions = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
            let xyz = vec![P::S("float", "x"), P::S("float", "y"), P::S("float", "z")];
            let elements = [
                El { name: "vertex", props: xyz, records: positions.iter().map(|p| p.to_vec()).collect() },
                El { name: "face", props: vec![P::L("char", "int", "vertex_indices")], records: faces },
            ];
            encode(&elements, format)
        };
        let good = vec![vec![3.0, 0.0, 1.0, 2.0], vec![3.0, 0.0, 2.0, 3.0]];
        for format in &FORMATS[1..] {
            let file = square(format, good.clone());
            let body = file.len() - 48 - 2 * 13;
            assert_eq!(parse(&file).unwrap().indices, vec![[0, 1, 2], [0, 2, 3]]);
            let faces = |k: usize, corners: &[f64]| {
                let mut f = good.clone();
                f[k] = corners.to_vec();
                parse(&square(format, f)).unwrap_err()
            };
            let at = |offset: usize, says: &str| format!("m.ply: byte {}: {says}", body + offset);
            let face1 = 48 + 13;
            let out_of_range = "face 1, `vertex_indices`: vertex index 4 is past the last vertex (the file has 4)";
            assert_eq!(faces(1, &[3.0, 0.0, 2.0, 4.0]), at(face1 + 1 + 8, out_of_range));
            let negative = "face 1, `vertex_indices`: vertex index -3 is negative";
            assert_eq!(faces(1, &[3.0, 0.0, -3.0, 1.0]), at(face1 + 1 + 4, negative));
            let count = "face 1, `vertex_indices`: the list's count -1 is negative";
            assert_eq!(faces(1, &[-1.0]), at(face1, count));
            assert_eq!(faces(1, &[0.0]), at(face1, "face 1, `vertex_indices`: 0 vertices; a face needs at least 3"));
            // A list count too large for the file, and the file cut inside a value.
            let ends = "the file ends in face 1 (of 2), at `vertex_indices`";
            assert_eq!(faces(1, &[100.0, 0.0, 1.0, 2.0, 3.0]), at(face1 + 1 + 16, ends));
            assert_eq!(parse(&file[..file.len() - 6]).unwrap_err(), at(face1 + 1 + 4, ends));
            // Records of fixed size are counted before they are read.
            let err = parse(&file[..body + 20]).unwrap_err();
            assert!(
                err.starts_with("m.ply:5: 4 `vertex` elements need at least 48 bytes (12 each), and 20 are"),
                "{err}"
            );
            // Non-finite coordinates.
            let mut inf = file.clone();
            let z = body + 2 * 12 + 8;
            inf[z..z + 4].copy_from_slice(&if *format == "binary_big_endian" {
                f32::INFINITY.to_be_bytes()
            } else {
                f32::INFINITY.to_le_bytes()
            });
            assert_eq!(parse(&inf).unwrap_err(), at(24, "vertex 2: position [1.0, 1.0, inf] is not finite"));
            // Counts the file cannot hold.
            let header = String::from_utf8_lossy(&file[..body]).into_owned();
            let huge = header.replace("element face 2", "element face 1000000000000");
            let mut huge = huge.into_bytes();
            huge.extend(&file[body..]);
            let err = parse(&huge).unwrap_err();
            assert!(
                err.starts_with("m.ply:9: 1000000000000 `face` elements need at least 1000000000000 bytes"),
                "{err}"
            );
        }
        // A double past f32's range.
        let elements = [
            El {
                name: "vertex",
                props: vec![P::S("double", "x"), P::S("double", "y"), P::S("double", "z")],
                records: vec![vec![0.0, 0.0, 0.0], vec![1e300, 0.0, 0.0], vec![0.0, 1.0, 0.0]],
            },
            El { name: "face", props: vec![P::L("uchar", "uint", "vertex_indices")], records: vec![] },
        ];
        let file = encode(&elements, "binary_little_endian");
        let body = file.len() - 72;
        let says = format!("m.ply: byte {}: vertex 1: position [1e300, 0.0, 0.0] overflows f32", body + 24);
        assert_eq!(parse(&file).unwrap_err(), says);
    }

    /// What the specification allows, or real files do, loads: CR LF and CR line ends, comments
    /// anywhere in the header (in Latin-1 too), blank lines in an ASCII body, an element of no
    /// properties of any count, bytes after the last element, faces before the vertices, a file
    /// of no faces.
    #[test]
    fn what_writers_write_loads() {
        let expected = vec![[0, 1, 2], [0, 2, 3]];
        assert_eq!(parse(SQUARE.replace('\n', "\r\n").as_bytes()).unwrap().indices, expected);
        assert_eq!(parse(SQUARE.replace('\n', "\r").as_bytes()).unwrap().indices, expected);
        let commented = SQUARE
            .replace("element face", "comment Fl\u{e4}che\nobj_info x\nelement face")
            .replace("end_header\n", "end_header\n\n")
            .replace("3 0 1 2\n", "\n  3 0 1 2  \n\n")
            .replace("ply\n", "ply\ncomment first\n");
        let mut latin1 = commented.into_bytes();
        let at = latin1.iter().position(|&b| b == 0xc3).unwrap();
        latin1.splice(at..at + 2, [0xe4]);
        assert_eq!(parse(&latin1).unwrap().indices, expected);
        let empty = SQUARE.replace("element face 2", "element nothing 18446744073709551615\nelement face 2");
        assert_eq!(parse(format!("{empty}trailing words\n").as_bytes()).unwrap().indices, expected);
        // Faces before the vertices they index.
        let faces_first = "ply\nformat ascii 1.0\nelement face 2\nproperty list uchar int vertex_indices\n\
                           element vertex 4\nproperty float x\nproperty float y\nproperty float z\nend_header\n\
                           3 0 1 2\n4 0 1 2 3\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n";
        assert_eq!(parse(faces_first.as_bytes()).unwrap().indices, vec![[0, 1, 2], [0, 1, 2], [0, 2, 3]]);
        let points = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
                      end_header\n0 0 0\n1 1 1\n";
        let m = parse(points.as_bytes()).unwrap();
        assert_eq!((m.positions.len(), m.indices.len(), m.normals.len(), m.uvs.len()), (2, 0, 0, 0));
    }

    /// `load_ply` reads the file, and its errors name it.
    #[test]
    fn load_ply_reads_the_file() {
        let dir = std::env::temp_dir().join(format!("arbor-ply-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("square.PLY");
        std::fs::write(&path, SQUARE).unwrap();
        assert_eq!(TriangleMesh::load_ply(&path).unwrap().triangle_count(), 2);
        let err = TriangleMesh::load_ply(dir.join("missing.ply")).unwrap_err().to_string();
        assert!(err.contains("missing.ply: cannot read: "), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
