//! glTF files written by the tests (nothing binary is committed): a document built as JSON, its
//! one buffer written as a base64 `data:` URI, as a `.bin` file beside it, or as a GLB's BIN
//! chunk.

use serde_json::{Value, json};

pub const BYTE: u32 = 5120;
pub const UNSIGNED_BYTE: u32 = 5121;
pub const UNSIGNED_SHORT: u32 = 5123;
pub const UNSIGNED_INT: u32 = 5125;
pub const FLOAT: u32 = 5126;

/// A glTF document under construction: its JSON and the bytes of buffer 0.
#[derive(Clone, Debug)]
pub struct Doc {
    pub json: Value,
    pub bin: Vec<u8>,
}

impl Default for Doc {
    fn default() -> Self {
        Self::new()
    }
}

impl Doc {
    pub fn new() -> Self {
        let json = json!({
            "asset": { "version": "2.0" },
            "buffers": [], "bufferViews": [], "accessors": [], "meshes": [], "nodes": [],
            "scenes": [{ "nodes": [] }], "scene": 0,
        });
        Self { json, bin: Vec::new() }
    }

    /// Appends `v` to the array `key` of the document, returning its index.
    pub fn push(&mut self, key: &str, v: Value) -> usize {
        let root = self.json.as_object_mut().unwrap();
        let list = root.entry(key).or_insert_with(|| json!([])).as_array_mut().unwrap();
        list.push(v);
        list.len() - 1
    }

    /// A buffer view of `bytes` (placed at a multiple of 4), with `stride` if given.
    pub fn view(&mut self, bytes: &[u8], stride: Option<usize>) -> usize {
        while self.bin.len() % 4 != 0 {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        let mut v = json!({ "buffer": 0, "byteOffset": offset, "byteLength": bytes.len() });
        if let Some(s) = stride {
            v["byteStride"] = json!(s);
        }
        self.push("bufferViews", v)
    }

    /// An accessor of `count` elements of type `ty` (`"VEC3"`, ...) and `component` over view
    /// `view`.
    pub fn accessor(&mut self, view: usize, component: u32, count: usize, ty: &str) -> usize {
        self.push("accessors", json!({ "bufferView": view, "componentType": component, "count": count, "type": ty }))
    }

    /// A tightly packed FLOAT accessor of `ty` over `values` (each element `values.len() / count` floats).
    pub fn floats(&mut self, values: &[f32], ty: &str) -> usize {
        let n = match ty {
            "SCALAR" => 1,
            "VEC2" => 2,
            "VEC3" => 3,
            _ => 4,
        };
        let bytes: Vec<u8> = values.iter().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.view(&bytes, None);
        self.accessor(view, FLOAT, values.len() / n, ty)
    }

    /// An index accessor of `component` (UNSIGNED_BYTE, _SHORT or _INT) over `indices`.
    pub fn indices(&mut self, indices: &[u32], component: u32) -> usize {
        let bytes: Vec<u8> = match component {
            UNSIGNED_BYTE => indices.iter().map(|&i| i as u8).collect(),
            UNSIGNED_SHORT => indices.iter().flat_map(|&i| (i as u16).to_le_bytes()).collect(),
            _ => indices.iter().flat_map(|&i| i.to_le_bytes()).collect(),
        };
        let view = self.view(&bytes, None);
        self.accessor(view, component, indices.len(), "SCALAR")
    }

    /// A mesh of one primitive with `attributes` (name, accessor), `indices` and `mode`.
    pub fn mesh(&mut self, attributes: &[(&str, usize)], indices: Option<usize>, mode: Option<u32>) -> usize {
        let mut p = json!({ "attributes": attributes.iter().map(|(k, v)| (k.to_string(), json!(v))).collect::<serde_json::Map<_, _>>() });
        if let Some(i) = indices {
            p["indices"] = json!(i);
        }
        if let Some(m) = mode {
            p["mode"] = json!(m);
        }
        self.push("meshes", json!({ "primitives": [p] }))
    }

    /// A node, listed among the scene's roots when `root`.
    pub fn node(&mut self, node: Value, root: bool) -> usize {
        let n = self.push("nodes", node);
        if root {
            self.json["scenes"][0]["nodes"].as_array_mut().unwrap().push(json!(n));
        }
        n
    }

    fn with_buffer(&self, uri: Option<String>) -> Vec<u8> {
        let mut json = self.json.clone();
        let mut buffer = json!({ "byteLength": self.bin.len() });
        if let Some(uri) = uri {
            buffer["uri"] = json!(uri);
        }
        if !self.bin.is_empty() {
            json["buffers"] = json!([buffer]);
        }
        serde_json::to_vec_pretty(&json).unwrap()
    }

    /// The `.gltf` text with the buffer as a base64 data URI.
    pub fn gltf_embedded(&self) -> Vec<u8> {
        let data = base64(&self.bin);
        self.with_buffer(Some(format!("data:application/octet-stream;base64,{data}")))
    }

    /// The `.gltf` text naming `bin` for the buffer, and the buffer's bytes.
    pub fn gltf_external(&self, bin: &str) -> (Vec<u8>, Vec<u8>) {
        (self.with_buffer(Some(bin.to_owned())), self.bin.clone())
    }

    /// The `.glb` file: header, JSON chunk (padded with spaces), BIN chunk (padded with zeros).
    pub fn glb(&self) -> Vec<u8> {
        let mut json = self.with_buffer(None);
        while json.len() % 4 != 0 {
            json.push(b' ');
        }
        let mut bin = self.bin.clone();
        while bin.len() % 4 != 0 {
            bin.push(0);
        }
        let total = 12 + 8 + json.len() + if bin.is_empty() { 0 } else { 8 + bin.len() };
        let mut out = b"glTF".to_vec();
        out.extend(2u32.to_le_bytes());
        out.extend((total as u32).to_le_bytes());
        out.extend((json.len() as u32).to_le_bytes());
        out.extend(b"JSON");
        out.extend(&json);
        if !bin.is_empty() {
            out.extend((bin.len() as u32).to_le_bytes());
            out.extend(b"BIN\0");
            out.extend(&bin);
        }
        out
    }
}

/// One triangle (0, 0, 0), (1, 0, 0), (0, 1, 0) facing +z, with normals and texture
/// coordinates (0, 0), (1, 0), (0, 1) as glTF writes them, and UNSIGNED_SHORT indices: mesh 0.
pub fn triangle_doc() -> Doc {
    let mut d = Doc::new();
    let p = d.floats(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0], "VEC3");
    let n = d.floats(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0], "VEC3");
    let t = d.floats(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0], "VEC2");
    let i = d.indices(&[0, 1, 2], UNSIGNED_SHORT);
    d.mesh(&[("POSITION", p), ("NORMAL", n), ("TEXCOORD_0", t)], Some(i), None);
    d
}

/// `bytes` in base64 (RFC 4648, standard alphabet, padded), written here rather than with the
/// crate the reader uses, so that the two check each other.
pub fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let b = [chunk[0], chunk.get(1).copied().unwrap_or(0), chunk.get(2).copied().unwrap_or(0)];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(ALPHABET[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}
