//! PLY files written by the tests (nothing binary is committed).

use arbor::geometry::TriangleMesh;

/// `mesh` as a PLY file in `format` (`ascii`, `binary_little_endian` or `binary_big_endian`):
/// `float` positions, normals (`nx ny nz`) and texture coordinates (`s t`) where the mesh has
/// them, and its triangles as `list uchar int vertex_indices`.
pub fn ply_bytes(mesh: &TriangleMesh, format: &str) -> Vec<u8> {
    let (normals, uvs) = (!mesh.normals.is_empty(), !mesh.uvs.is_empty());
    let mut out = format!("ply\nformat {format} 1.0\nelement vertex {}\n", mesh.positions.len());
    for (name, given) in [("x", true), ("y", true), ("z", true), ("nx", normals), ("ny", normals), ("nz", normals)]
        .into_iter()
        .chain([("s", uvs), ("t", uvs)])
    {
        if given {
            out += &format!("property float {name}\n");
        }
    }
    out += &format!("element face {}\nproperty list uchar int vertex_indices\nend_header\n", mesh.indices.len());
    let mut out = out.into_bytes();
    let big = format == "binary_big_endian";
    let values = |out: &mut Vec<u8>, words: &[f32]| {
        if format == "ascii" {
            let line: Vec<String> = words.iter().map(f32::to_string).collect();
            out.extend(line.join(" ").bytes());
            out.push(b'\n');
        } else {
            for w in words {
                out.extend(if big { w.to_be_bytes() } else { w.to_le_bytes() });
            }
        }
    };
    for (k, p) in mesh.positions.iter().enumerate() {
        let mut v = p.to_array().to_vec();
        if normals {
            v.extend(mesh.normals[k].to_array());
        }
        if uvs {
            v.extend(mesh.uvs[k].to_array());
        }
        values(&mut out, &v);
    }
    for t in &mesh.indices {
        if format == "ascii" {
            out.extend(format!("3 {} {} {}\n", t[0], t[1], t[2]).bytes());
        } else {
            out.push(3);
            for i in t {
                out.extend(if big { i.to_be_bytes() } else { i.to_le_bytes() });
            }
        }
    }
    out
}
