//! Every struct shared by Rust and WGSL has the same size and member offsets on both sides, and
//! every shader parses and validates with naga (the version wgpu uses). No GPU needed.

use arbor::gpu::layout::{Member, SHARED_STRUCTS, StructLayout, prelude, with_prelude};
use arbor::gpu::trace::{Features, GpuForm, SHADER_FILES, shader_source};

/// Size and `(member, offset)` list of the WGSL struct `name` in `module`.
fn wgsl_struct(module: &naga::Module, name: &str) -> Option<(u32, Vec<(String, u32)>)> {
    let ty = &module.types.iter().find(|(_, t)| t.name.as_deref() == Some(name))?.1;
    match &ty.inner {
        naga::TypeInner::Struct { members, span } => {
            Some((*span, members.iter().map(|m| (m.name.clone().unwrap_or_default(), m.offset)).collect()))
        }
        _ => None,
    }
}

/// Whether `layout`, as Rust lays it out, is what WGSL makes of its declaration in `module`:
/// the members cover the Rust struct end to end (a field missing from the list leaves a gap or
/// a short struct), and WGSL puts every member at Rust's offset with Rust's size.
fn check(module: &naga::Module, layout: &StructLayout) -> Result<(), String> {
    let name = layout.name;
    let mut end = 0;
    for m in &layout.members {
        if m.offset != end {
            return Err(format!("{name}: member {} at {} where the one before ended at {end}", m.name, m.offset));
        }
        end = m.offset + m.size;
    }
    if end != layout.size {
        return Err(format!("{name}: members end at {end}, the Rust struct at {}", layout.size));
    }
    let (span, members) = wgsl_struct(module, name).ok_or_else(|| format!("no struct {name} in the WGSL prelude"))?;
    if span as usize != layout.size {
        return Err(format!("{name}: WGSL size {span}, Rust size {}", layout.size));
    }
    let ours: Vec<(String, u32)> = layout.members.iter().map(|m| (m.name.to_owned(), m.offset as u32)).collect();
    if members != ours {
        return Err(format!("{name}: WGSL members {members:?}, Rust members {ours:?}"));
    }
    Ok(())
}

fn parse(source: &str) -> naga::Module {
    naga::front::wgsl::parse_str(source).unwrap_or_else(|e| panic!("{}", e.emit_to_string(source)))
}

#[test]
fn shared_structs_match_rust() {
    // The prelude alone has no entry points; naga parses it as a module all the same.
    let module = parse(&prelude());
    for layout in SHARED_STRUCTS {
        check(&module, &layout()).unwrap_or_else(|e| panic!("{e}"));
    }
    // lampshade's sort item, declared by hand in shaders/prelude.wgsl.
    let (span, _) = wgsl_struct(&module, "KeyValue").expect("KeyValue in the prelude");
    assert_eq!(span as usize, size_of::<lampshade::KeyValue>());
}

/// The check fails where Rust and WGSL part: a field left out of a layout's member list (as a
/// field added to `BvhNode` alone would be), and a `vec3` that WGSL aligns past Rust's offset.
#[test]
fn the_layout_check_sees_a_missing_field_and_a_misaligned_member() {
    let shared: Vec<StructLayout> = SHARED_STRUCTS.iter().map(|l| l()).collect();
    let mut node = shared.iter().find(|l| l.name == "BvhNode").unwrap().clone();
    node.members.pop();
    let module = parse(&node.wgsl());
    let e = check(&module, &node).unwrap_err();
    assert!(e.contains("members end at 28, the Rust struct at 32"), "{e}");

    let vec3 = |name, offset| Member { name, wgsl_type: "vec3<f32>", offset, size: 12 };
    let packed = StructLayout { name: "Packed", size: 24, members: vec![vec3("a", 0), vec3("b", 12)] };
    let e = check(&parse(&packed.wgsl()), &packed).unwrap_err();
    assert!(e.contains("WGSL size 32, Rust size 24"), "{e}");
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
    // Every variant of the path tracer (src/gpu/trace.rs) in both tree forms: the files
    // concatenated after the prelude and the variant's constants.
    for features in Features::every() {
        for form in [GpuForm::Binary, GpuForm::Wide8] {
            validate(&format!("{}[{}]", features.key(), form.name()), &shader_source(features, form));
        }
    }
    validate("lbvh", &arbor::gpu::lbvh::source());
    validate("prbvh", &arbor::gpu::prbvh::source(false));
    validate("prbvh with 64-bit locks", &arbor::gpu::prbvh::source(true));
}
