//! The layers of `docs/design/architecture.md`, checked: which of the library's top-level modules
//! each module's code names (`use crate::…`, `use crate::{…}` groups, paths in code), outside
//! comments and `#[cfg(test)]` items. A module may name only modules of a lower layer; modules of
//! one layer know nothing of each other. So no circle can form between folders.
//!
//! The check reads the source as text, as the greps the document lists do, but knows Rust's
//! comments and brace groups, so `use crate::{render::texture}` counts and a doc link does not.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The library's top-level modules by layer, bottom first (`docs/design/architecture.md`).
const LAYERS: &[&[&str]] = &[
    &["memory", "atomic_file"],
    &["image_io"],
    &["geometry", "texture"],
    &["bvh", "scene"],
    &["render"],
    &["gpu"],
    &["device"],
    &["distributed"],
];

fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|l| l.contains(&module))
}

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// Every `.rs` file under `dir`.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// `text` without comments (line, block and doc comments) and string literals' contents.
fn code_only(text: &str) -> String {
    let (b, mut out, mut i) = (text.as_bytes(), String::with_capacity(text.len()), 0);
    while i < b.len() {
        if b[i..].starts_with(b"//") {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i..].starts_with(b"/*") {
            let end = text[i + 2..].find("*/").map_or(b.len(), |k| i + 2 + k + 2);
            i = end;
        } else if b[i..].starts_with(b"'\"'") {
            // The character '"', not the start of a string.
            out.push_str("'\"'");
            i += 3;
        } else if b[i] == b'"' {
            out.push('"');
            i += 1;
            while i < b.len() && b[i] != b'"' {
                i += if b[i] == b'\\' { 2 } else { 1 };
            }
            out.push('"');
            i += 1;
        } else {
            let c = text[i..].chars().next().unwrap();
            out.push(c);
            i += c.len_utf8();
        }
    }
    out
}

/// `code` without the items marked `#[cfg(test)]` (a `mod tests { … }`, a test helper).
fn without_test_items(code: &str) -> String {
    let mut out = String::with_capacity(code.len());
    let mut rest = code;
    while let Some(k) = rest.find("#[cfg(test)]") {
        out.push_str(&rest[..k]);
        let after = &rest[k..];
        // The item ends at its closing brace, or at a `;` before any brace (`mod x;`, `use …;`).
        let (semi, open) = (after.find(';'), after.find('{'));
        let end = match (semi, open) {
            (Some(s), Some(o)) if s < o => s + 1,
            (_, Some(o)) => {
                let mut depth = 0;
                let mut end = after.len();
                for (j, c) in after[o..].char_indices() {
                    match c {
                        '{' => depth += 1,
                        '}' => {
                            depth -= 1;
                            if depth == 0 {
                                end = o + j + 1;
                                break;
                            }
                        }
                        _ => {}
                    }
                }
                end
            }
            (Some(s), None) => s + 1,
            (None, None) => after.len(),
        };
        rest = &after[end..];
    }
    out.push_str(rest);
    out
}

/// The top-level modules `code` names through `crate::`: `crate::render::…`, and each item of a
/// `crate::{…}` group.
fn named_modules(code: &str) -> BTreeSet<String> {
    let mut found = BTreeSet::new();
    for (k, _) in code.match_indices("crate::") {
        // Not `arbor_crate::` or the like.
        if code[..k].chars().next_back().is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue;
        }
        let after = &code[k + "crate::".len()..];
        if let Some(group) = after.strip_prefix('{') {
            // Items at depth 1: split by commas outside nested braces.
            let mut depth = 0;
            let mut item = String::new();
            for c in group.chars() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => break,
                    '}' => depth -= 1,
                    ',' if depth == 0 => {
                        found.extend(first_ident(&item));
                        item.clear();
                        continue;
                    }
                    _ => {}
                }
                item.push(c);
            }
            found.extend(first_ident(&item));
        } else {
            found.extend(first_ident(after));
        }
    }
    found
}

fn first_ident(s: &str) -> Option<String> {
    let s = s.trim_start();
    let name: String = s.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
    (!name.is_empty()).then_some(name)
}

/// The top-level module a file under `src/` belongs to (`None` for `lib.rs` and the binaries).
fn module_of(file: &Path) -> Option<String> {
    let rel = file.strip_prefix(src()).unwrap();
    let first = rel.components().next()?.as_os_str().to_str()?.to_owned();
    if first == "bin" || first == "lib.rs" {
        return None;
    }
    Some(first.trim_end_matches(".rs").to_owned())
}

/// For every library module, the other top-level modules its code names.
fn imports() -> BTreeMap<String, BTreeMap<String, Vec<PathBuf>>> {
    let mut files = Vec::new();
    rust_files(&src(), &mut files);
    let mut graph: BTreeMap<String, BTreeMap<String, Vec<PathBuf>>> = BTreeMap::new();
    for file in files {
        let Some(module) = module_of(&file) else { continue };
        let code = without_test_items(&code_only(&std::fs::read_to_string(&file).unwrap()));
        let entry = graph.entry(module.clone()).or_default();
        for named in named_modules(&code) {
            if named != module && layer_of(&named).is_some() {
                entry.entry(named).or_default().push(file.clone());
            }
        }
    }
    graph
}

/// The rules of the architecture document: every module is placed in a layer, and names only
/// modules of the layers below its own.
#[test]
fn modules_import_only_the_layers_below_them() {
    let graph = imports();
    let mut wrong = Vec::new();
    for (module, named) in &graph {
        let Some(own) = layer_of(module) else {
            wrong.push(format!("src/{module}: not placed in a layer (add it to LAYERS and the architecture document)"));
            continue;
        };
        for (other, files) in named {
            if layer_of(other).is_some_and(|l| l >= own) {
                let files: Vec<String> = files.iter().map(|f| f.display().to_string()).collect();
                wrong.push(format!("{module} names {other}, a layer at or above its own, in {}", files.join(", ")));
            }
        }
    }
    assert!(wrong.is_empty(), "layering broken:\n{}", wrong.join("\n"));
    // The rules the issue that made the layers spelled out, named: none of these may come back.
    for (module, forbidden) in [
        ("scene", "render"),
        ("geometry", "render"),
        ("geometry", "scene"),
        ("bvh", "render"),
        ("bvh", "scene"),
        ("texture", "render"),
        ("texture", "scene"),
        ("texture", "bvh"),
        ("render", "gpu"),
        ("render", "device"),
        ("gpu", "device"),
        ("device", "distributed"),
    ] {
        assert!(!graph.get(module).is_some_and(|n| n.contains_key(forbidden)), "{module} names {forbidden}");
    }
}

/// The checker itself: it finds names in `use` lines, groups and paths, and skips comments,
/// strings and test items, so the test above can fail.
#[test]
fn the_layer_check_sees_groups_and_skips_comments_and_tests() {
    let code = code_only(
        "use crate::{geometry::Aabb, render::{film::Film, pass}};\n\
         /// [`crate::gpu`] in a doc link\n\
         // crate::device in a comment\n\
         let s = \"crate::distributed\";\n\
         fn f() { crate::memory::check(); }\n\
         #[cfg(test)]\nmod tests { use crate::scene::Scene; }\n\
         #[cfg(test)]\nuse crate::bvh::Bvh;\n",
    );
    let named = named_modules(&without_test_items(&code));
    let expected: BTreeSet<String> = ["geometry", "render", "memory"].map(String::from).into();
    assert_eq!(named, expected);
}

/// The trace form is passed down, not kept in the library: no static in `src/bvh` (where the
/// form is defined and used) holds state, and nothing in the library reads `ARBOR_SIMD` but the
/// function the tools call at their edge.
#[test]
fn no_static_decides_the_trace_form() {
    let mut files = Vec::new();
    rust_files(&src().join("bvh"), &mut files);
    for file in &files {
        let code = without_test_items(&code_only(&std::fs::read_to_string(file).unwrap()));
        // A `static` item, not a `'static` lifetime.
        let statics = code.match_indices("static ").filter(|(k, _)| !code[..*k].ends_with('\'')).count();
        // The builder registry (`register_external`) is the one static in the tree: a table of
        // names, not a choice of how to trace.
        let allowed = usize::from(file.ends_with("build/mod.rs"));
        assert_eq!(statics, allowed, "{}: a static item", file.display());
        for bad in ["OnceLock", "LazyLock", "thread_local!"] {
            assert!(!code.contains(bad), "{}: `{bad}`", file.display());
        }
    }
    let mut all = Vec::new();
    rust_files(&src(), &mut all);
    let readers: Vec<_> = all
        .iter()
        .filter(|f| module_of(f).is_some())
        .filter(|f| std::fs::read_to_string(f).unwrap().contains("env::var(\"ARBOR_SIMD\")"))
        .collect();
    assert_eq!(readers, [&src().join("bvh/trace/simd/mod.rs")], "ARBOR_SIMD is read in one place");
}
