//! Times loading a mesh of 10^6 triangles from a binary PLY file, a GLB (binary glTF) file and an
//! OBJ file, against the LBVH build over its triangles: the median of a few runs of each. The
//! files are written to the system's temporary folder and removed at the end.
//!
//! `cargo run --release -p arbor-bench --example mesh_load_times [-- RUNS]` (default 5 runs)

use std::io::Write as _;
use std::time::Instant;

use arbor::bvh::build::Builder;
use arbor::geometry::TriangleMesh;
use arbor::glam::Vec3;
use arbor::scene::gltf::GltfFile;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let runs: usize = std::env::args().nth(1).map_or(Ok(5), |r| r.parse())?;
    // The form the LBVH's tree is traced in, as `bvh-bench` chooses it: ARBOR_SIMD, or the best.
    let tracing = arbor::bvh::Tracing::from_env(None)?;
    // 2 · 1000 · 500 = 10^6 triangles over about 5 · 10^5 vertices, as a scanned mesh has.
    let mesh = TriangleMesh::uv_sphere(Vec3::ZERO, 1.0, 501, 1000);
    let dir = std::env::temp_dir().join(format!("arbor-load-times-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let (ply, ply_attributes, obj) = (dir.join("m.ply"), dir.join("m-attributes.ply"), dir.join("m.obj"));
    let (glb, glb_attributes) = (dir.join("m.glb"), dir.join("m-attributes.glb"));
    write_ply(&ply, &mesh, false)?;
    write_ply(&ply_attributes, &mesh, true)?;
    write_glb(&glb, &mesh, false)?;
    write_glb(&glb_attributes, &mesh, true)?;
    write_obj(&obj, &mesh)?;
    let size = |p: &std::path::Path| std::fs::metadata(p).map(|m| m.len() as f64 / 1e6);
    println!(
        "{} triangles, {} vertices; PLY {:.1} MB (with normals and uvs {:.1} MB), GLB {:.1} MB ({:.1} MB), OBJ {:.1} MB; {runs} runs, median",
        mesh.triangle_count(),
        mesh.positions.len(),
        size(&ply)?,
        size(&ply_attributes)?,
        size(&glb)?,
        size(&glb_attributes)?,
        size(&obj)?
    );
    // What a scene naming the file does: read it, then decode its one mesh.
    let load_glb = |p: &std::path::Path| GltfFile::open(p).and_then(|f| f.mesh(0)).map(|m| m.mesh);

    let loaded = TriangleMesh::load_ply(&ply)?;
    assert!(loaded.positions == mesh.positions && loaded.indices == mesh.indices, "the PLY file reads back");
    assert_eq!(TriangleMesh::load_obj(&obj)?.triangle_count(), mesh.triangle_count());
    let from_glb = load_glb(&glb)?;
    assert!(from_glb.positions == mesh.positions && from_glb.indices == mesh.indices, "the GLB file reads back");
    assert_eq!(load_glb(&glb_attributes)?.uvs.len(), mesh.positions.len());
    let triangles = loaded.triangles();
    let lbvh: Builder = "lbvh".parse()?;
    let limit = arbor::memory::text_file_limit();
    report("read the PLY file's bytes", runs, || arbor::memory::read_at_most(&ply, limit).map(drop))?;
    report("load binary PLY", runs, || TriangleMesh::load_ply(&ply).map(drop))?;
    report("load binary PLY, normals and uvs", runs, || TriangleMesh::load_ply(&ply_attributes).map(drop))?;
    report("load GLB", runs, || load_glb(&glb).map(drop))?;
    report("load GLB, normals and uvs", runs, || load_glb(&glb_attributes).map(drop))?;
    report("load OBJ", runs, || TriangleMesh::load_obj(&obj).map(drop))?;
    report("LBVH build", runs, || {
        std::hint::black_box(lbvh.build_mesh(&triangles, tracing));
        Ok::<_, std::convert::Infallible>(())
    })?;
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}

/// Runs `f` `runs` times and prints the median time.
fn report<E: std::error::Error + 'static>(
    what: &str,
    runs: usize,
    mut f: impl FnMut() -> Result<(), E>,
) -> Result<(), Box<dyn std::error::Error>> {
    let mut ms = Vec::with_capacity(runs);
    for _ in 0..runs {
        let start = Instant::now();
        f()?;
        ms.push(start.elapsed().as_secs_f64() * 1e3);
    }
    ms.sort_by(f64::total_cmp);
    let all: Vec<String> = ms.iter().map(|t| format!("{t:.1}")).collect();
    println!("{what:>34}: {:8.1} ms   (runs: {})", ms[ms.len() / 2], all.join(", "));
    Ok(())
}

/// `mesh` as a binary little-endian PLY file: `float` positions (and, with `attributes`, unit
/// normals and texture coordinates), faces as `list uchar int`.
fn write_ply(path: &std::path::Path, mesh: &TriangleMesh, attributes: bool) -> std::io::Result<()> {
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    let extra = if attributes {
        "property float nx\nproperty float ny\nproperty float nz\nproperty float s\nproperty float t\n"
    } else {
        ""
    };
    write!(
        out,
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\n\
         property float z\n{extra}element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.positions.len(),
        mesh.indices.len()
    )?;
    for p in &mesh.positions {
        let mut values = p.to_array().to_vec();
        if attributes {
            values.extend(p.normalize_or_zero().to_array());
            values.extend([p.x.atan2(p.z), p.y]);
        }
        for v in values {
            out.write_all(&v.to_le_bytes())?;
        }
    }
    for t in &mesh.indices {
        out.write_all(&[3])?;
        for i in t {
            out.write_all(&i.to_le_bytes())?;
        }
    }
    out.flush()
}

/// `mesh` as an OBJ file (f32 `Display` reads back to the same value).
fn write_obj(path: &std::path::Path, mesh: &TriangleMesh) -> std::io::Result<()> {
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    for p in &mesh.positions {
        writeln!(out, "v {} {} {}", p.x, p.y, p.z)?;
    }
    for t in &mesh.indices {
        writeln!(out, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
    }
    out.flush()
}

/// `mesh` as a GLB file: one buffer in the BIN chunk, FLOAT positions (and, with `attributes`,
/// unit normals and texture coordinates, each in its own view) and UNSIGNED_INT indices, one
/// node placing the mesh.
fn write_glb(path: &std::path::Path, mesh: &TriangleMesh, attributes: bool) -> std::io::Result<()> {
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut view = |bin: &mut Vec<u8>, bytes: Vec<u8>| {
        views.push(format!(r#"{{"buffer":0,"byteOffset":{},"byteLength":{}}}"#, bin.len(), bytes.len()));
        bin.extend(bytes);
        views.len() - 1
    };
    let floats = |v: &mut dyn Iterator<Item = f32>| v.flat_map(f32::to_le_bytes).collect::<Vec<u8>>();
    let p = view(&mut bin, floats(&mut mesh.positions.iter().flat_map(|p| p.to_array())));
    let i = view(&mut bin, mesh.indices.iter().flatten().flat_map(|i| i.to_le_bytes()).collect());
    let (n, v) = (mesh.positions.len(), mesh.indices.len() * 3);
    let (lo, hi) = (mesh.bounds().min, mesh.bounds().max);
    let mut accessors = vec![
        format!(
            r#"{{"bufferView":{p},"componentType":5126,"count":{n},"type":"VEC3","min":[{},{},{}],"max":[{},{},{}]}}"#,
            lo.x, lo.y, lo.z, hi.x, hi.y, hi.z
        ),
        format!(r#"{{"bufferView":{i},"componentType":5125,"count":{v},"type":"SCALAR"}}"#),
    ];
    let mut attribute_list = r#""POSITION":0"#.to_owned();
    if attributes {
        let normals = view(&mut bin, floats(&mut mesh.positions.iter().flat_map(|p| p.normalize_or_zero().to_array())));
        let uvs = view(&mut bin, floats(&mut mesh.positions.iter().flat_map(|p| [p.x.atan2(p.z), p.y])));
        accessors.push(format!(r#"{{"bufferView":{normals},"componentType":5126,"count":{n},"type":"VEC3"}}"#));
        accessors.push(format!(r#"{{"bufferView":{uvs},"componentType":5126,"count":{n},"type":"VEC2"}}"#));
        attribute_list += r#","NORMAL":2,"TEXCOORD_0":3"#;
    }
    let mut json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],"meshes":[{{"primitives":[{{"attributes":{{{attribute_list}}},"indices":1}}]}}],"buffers":[{{"byteLength":{}}}],"bufferViews":[{}],"accessors":[{}]}}"#,
        bin.len(),
        views.join(","),
        accessors.join(",")
    )
    .into_bytes();
    while json.len() % 4 != 0 {
        json.push(b' ');
    }
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    out.write_all(b"glTF")?;
    out.write_all(&2u32.to_le_bytes())?;
    out.write_all(&((12 + 8 + json.len() + 8 + bin.len()) as u32).to_le_bytes())?;
    out.write_all(&(json.len() as u32).to_le_bytes())?;
    out.write_all(b"JSON")?;
    out.write_all(&json)?;
    out.write_all(&(bin.len() as u32).to_le_bytes())?;
    out.write_all(b"BIN\0")?;
    out.write_all(&bin)?;
    out.flush()
}
