//! Every struct shared by Rust and WGSL has the same size and member offsets on both sides, and
//! every shader parses and validates with naga (the version wgpu uses). No GPU needed.

use std::mem::offset_of;

use arbor::gpu::layout::{BvhNode, GpuAabb, LbvhParams, prelude, with_prelude};

/// Size and `(member, offset)` list of the WGSL struct `name` in `module`.
fn wgsl_struct(module: &naga::Module, name: &str) -> (u32, Vec<(String, u32)>) {
    let ty = module
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("no struct {name} in the WGSL prelude"))
        .1;
    match &ty.inner {
        naga::TypeInner::Struct { members, span } => {
            (*span, members.iter().map(|m| (m.name.clone().unwrap_or_default(), m.offset)).collect())
        }
        other => panic!("{name} is not a struct: {other:?}"),
    }
}

fn check(module: &naga::Module, name: &str, size: usize, offsets: &[(&str, usize)]) {
    let (span, members) = wgsl_struct(module, name);
    assert_eq!(span as usize, size, "{name}: WGSL size {span}, Rust size {size}");
    let ours: Vec<(String, u32)> = offsets.iter().map(|&(n, o)| (n.to_owned(), o as u32)).collect();
    assert_eq!(members, ours, "{name}: member names and offsets differ between WGSL and Rust");
}

#[test]
fn shared_structs_match_rust() {
    // The prelude alone has no entry points; naga parses it as a module all the same.
    let module =
        naga::front::wgsl::parse_str(&prelude()).unwrap_or_else(|e| panic!("{}", e.emit_to_string(&prelude())));
    check(
        &module,
        "BvhNode",
        size_of::<BvhNode>(),
        &[
            ("aabb_min", offset_of!(BvhNode, aabb_min)),
            ("first", offset_of!(BvhNode, first)),
            ("aabb_max", offset_of!(BvhNode, aabb_max)),
            ("prim_count", offset_of!(BvhNode, prim_count)),
        ],
    );
    check(
        &module,
        "GpuAabb",
        size_of::<GpuAabb>(),
        &[
            ("min", offset_of!(GpuAabb, min)),
            ("pad0", offset_of!(GpuAabb, pad0)),
            ("max", offset_of!(GpuAabb, max)),
            ("pad1", offset_of!(GpuAabb, pad1)),
        ],
    );
    check(
        &module,
        "LbvhParams",
        size_of::<LbvhParams>(),
        &[
            ("origin", offset_of!(LbvhParams, origin)),
            ("prim_count", offset_of!(LbvhParams, prim_count)),
            ("scale", offset_of!(LbvhParams, scale)),
            ("pad", offset_of!(LbvhParams, pad)),
        ],
    );
    check(
        &module,
        "KeyValue",
        size_of::<lampshade::KeyValue>(),
        &[("key", offset_of!(lampshade::KeyValue, key)), ("value", offset_of!(lampshade::KeyValue, value))],
    );
}

/// The generated constants carry Rust's values.
#[test]
fn constants_come_from_rust() {
    let p = prelude();
    assert!(p.contains(&format!("const WORKGROUP_SIZE: u32 = {}u;", arbor::gpu::layout::WORKGROUP_SIZE)));
    assert!(p.contains(&format!("const INVALID_INDEX: u32 = {}u;", arbor::bvh::INVALID_INDEX)));
}

/// Each shader file, with the prelude, parses and passes naga's validation.
#[test]
fn every_shader_validates() {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("shaders");
    let mut count = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        if path.extension().is_none_or(|e| e != "wgsl") || name == "prelude.wgsl" {
            continue;
        }
        let source = with_prelude(&std::fs::read_to_string(&path).unwrap());
        let module =
            naga::front::wgsl::parse_str(&source).unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(&source)));
        naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::all())
            .validate(&module)
            .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(&source)));
        count += 1;
    }
    assert!(count >= 1, "no shaders in {}", dir.display());
}
