//! Every struct shared by Rust and WGSL has the same size and member offsets on both sides, and
//! every shader parses and validates with naga (the version wgpu uses). No GPU needed.

use std::mem::offset_of;

use arbor::gpu::layout::{
    BvhNode, GpuAabb, GpuLight, GpuMaterial, GpuPixel, GpuTriangle, LbvhParams, PrbvhParams, TraceParams, prelude,
    with_prelude,
};
use arbor::gpu::trace::{Features, SHADER_FILES, shader_source};

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
        "PrbvhParams",
        size_of::<PrbvhParams>(),
        &[
            ("node_count", offset_of!(PrbvhParams, node_count)),
            ("mu", offset_of!(PrbvhParams, mu)),
            ("phase", offset_of!(PrbvhParams, phase)),
            ("partial_count", offset_of!(PrbvhParams, partial_count)),
            ("cost_traversal", offset_of!(PrbvhParams, cost_traversal)),
            ("cost_intersection", offset_of!(PrbvhParams, cost_intersection)),
            ("area_scale", offset_of!(PrbvhParams, area_scale)),
            ("pad1", offset_of!(PrbvhParams, pad1)),
        ],
    );
    check(
        &module,
        "KeyValue",
        size_of::<lampshade::KeyValue>(),
        &[("key", offset_of!(lampshade::KeyValue, key)), ("value", offset_of!(lampshade::KeyValue, value))],
    );
    trace_structs_match_rust(&module);
}

/// The path tracer's structs (src/gpu/trace.rs).
fn trace_structs_match_rust(module: &naga::Module) {
    check(
        module,
        "GpuTriangle",
        size_of::<GpuTriangle>(),
        &[
            ("v0", offset_of!(GpuTriangle, v0)),
            ("material", offset_of!(GpuTriangle, material)),
            ("v1", offset_of!(GpuTriangle, v1)),
            ("light_pdf", offset_of!(GpuTriangle, light_pdf)),
            ("v2", offset_of!(GpuTriangle, v2)),
            ("pad", offset_of!(GpuTriangle, pad)),
        ],
    );
    check(
        module,
        "GpuMaterial",
        size_of::<GpuMaterial>(),
        &[
            ("albedo", offset_of!(GpuMaterial, albedo)),
            ("kind", offset_of!(GpuMaterial, kind)),
            ("k", offset_of!(GpuMaterial, k)),
            ("alpha", offset_of!(GpuMaterial, alpha)),
            ("emission", offset_of!(GpuMaterial, emission)),
            ("ior", offset_of!(GpuMaterial, ior)),
            ("flags", offset_of!(GpuMaterial, flags)),
            ("pad0", offset_of!(GpuMaterial, pad0)),
            ("pad1", offset_of!(GpuMaterial, pad1)),
            ("pad2", offset_of!(GpuMaterial, pad2)),
        ],
    );
    check(
        module,
        "GpuLight",
        size_of::<GpuLight>(),
        &[
            ("v0", offset_of!(GpuLight, v0)),
            ("cdf", offset_of!(GpuLight, cdf)),
            ("v1", offset_of!(GpuLight, v1)),
            ("pdf_area", offset_of!(GpuLight, pdf_area)),
            ("v2", offset_of!(GpuLight, v2)),
            ("two_sided", offset_of!(GpuLight, two_sided)),
            ("normal", offset_of!(GpuLight, normal)),
            ("pad0", offset_of!(GpuLight, pad0)),
            ("radiance", offset_of!(GpuLight, radiance)),
            ("pad1", offset_of!(GpuLight, pad1)),
        ],
    );
    check(
        module,
        "GpuPixel",
        size_of::<GpuPixel>(),
        &[
            ("shift", offset_of!(GpuPixel, shift)),
            ("count", offset_of!(GpuPixel, count)),
            ("sum", offset_of!(GpuPixel, sum)),
            ("non_finite", offset_of!(GpuPixel, non_finite)),
            ("sum_sq", offset_of!(GpuPixel, sum_sq)),
            ("rays", offset_of!(GpuPixel, rays)),
        ],
    );
    check(
        module,
        "TraceParams",
        size_of::<TraceParams>(),
        &[
            ("cam_origin", offset_of!(TraceParams, cam_origin)),
            ("width", offset_of!(TraceParams, width)),
            ("cam_forward", offset_of!(TraceParams, cam_forward)),
            ("height", offset_of!(TraceParams, height)),
            ("cam_right", offset_of!(TraceParams, cam_right)),
            ("tan_x", offset_of!(TraceParams, tan_x)),
            ("cam_up", offset_of!(TraceParams, cam_up)),
            ("tan_y", offset_of!(TraceParams, tan_y)),
            ("environment", offset_of!(TraceParams, environment)),
            ("lens_radius", offset_of!(TraceParams, lens_radius)),
            ("focus_distance", offset_of!(TraceParams, focus_distance)),
            ("clamp", offset_of!(TraceParams, clamp)),
            ("seed_lo", offset_of!(TraceParams, seed_lo)),
            ("seed_hi", offset_of!(TraceParams, seed_hi)),
            ("sample_start", offset_of!(TraceParams, sample_start)),
            ("sample_count", offset_of!(TraceParams, sample_count)),
            ("max_depth", offset_of!(TraceParams, max_depth)),
            ("light_count", offset_of!(TraceParams, light_count)),
        ],
    );
}

/// The generated constants carry Rust's values.
#[test]
fn constants_come_from_rust() {
    let p = prelude();
    assert!(p.contains(&format!("const WORKGROUP_SIZE: u32 = {}u;", arbor::gpu::layout::WORKGROUP_SIZE)));
    assert!(p.contains(&format!("const INVALID_INDEX: u32 = {}u;", arbor::bvh::INVALID_INDEX)));
    assert!(p.contains(&format!("const RR_DEPTH: u32 = {}u;", arbor::render::integrator::RR_DEPTH)));
    assert!(p.contains(&format!("const SMOOTH_ALPHA: f32 = {:?};", arbor::render::bsdf::SMOOTH_ALPHA)));
    assert!(p.contains(&format!("const TRACE_STACK_SIZE: u32 = {}u;", arbor::gpu::layout::TRACE_STACK_SIZE)));
}

fn validate(name: &str, source: &str) {
    let module =
        naga::front::wgsl::parse_str(source).unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(source)));
    naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::all())
        .validate(&module)
        .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(source)));
}

/// Each shader file, with the prelude, parses and passes naga's validation.
#[test]
fn every_shader_validates() {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("shaders");
    let mut count = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        // `_name.wgsl` files are fragments, appended to another file by their users.
        if path.extension().is_none_or(|e| e != "wgsl") || name == "prelude.wgsl" || name.starts_with('_') {
            continue;
        }
        count += 1;
        // The path tracer's files are parts of one module, and the LBVH and PRBVH files take
        // `_refit.wgsl` appended: validated as assembled below.
        if SHADER_FILES.contains(&name.as_str()) || name == "lbvh.wgsl" || name == "prbvh.wgsl" {
            continue;
        }
        validate(&name, &with_prelude(&std::fs::read_to_string(&path).unwrap()));
    }
    assert!(count > SHADER_FILES.len(), "no shaders in {}", dir.display());
    // Every variant of the path tracer (src/gpu/trace.rs): the files concatenated after the
    // prelude and the variant's constants.
    for features in Features::every() {
        validate(&features.key(), &shader_source(features));
    }
    validate("lbvh", &arbor::gpu::lbvh::source());
    validate("prbvh", &arbor::gpu::prbvh::source(false));
    validate("prbvh with 64-bit locks", &arbor::gpu::prbvh::source(true));
}
