//! The GPU LBVH builds the CPU's `lbvh::build_karras` tree (Karras as published), node for node (topology, boxes, primitive order),
//! on random boxes, on inputs with many equal Morton codes, and on the shared dragon; and the
//! tree passes `validate()`. Runs on any adapter, lavapipe included; skips without one, except
//! under `CI=true`.

use crate::common;

use arbor::bvh::{build::lbvh, validate};
use arbor::geometry::{Aabb, Triangle};
use arbor::gpu::lbvh as gpu_lbvh;
use common::gpu_or_skip;

fn same_tree(name: &str, prims: &[Aabb]) {
    let Some(ctx) = gpu_or_skip(name) else { return };
    // Karras' algorithm as published: the CPU's default build also refines runs of equal codes.
    let cpu = lbvh::build_karras(prims);
    let (gpu, times) = gpu_lbvh::build(ctx, prims).unwrap_or_else(|e| panic!("{name}: {e}"));
    eprintln!("{name}: {} primitives on {}: {:?}", prims.len(), ctx.describe(), times);
    validate(&gpu, prims).unwrap_or_else(|e| panic!("{name}: the GPU tree is invalid: {e}"));
    let (cpu_codes, cpu_ids) = lbvh::sorted_morton_codes(prims);
    let (gpu_codes, gpu_ids) = gpu_lbvh::sorted_morton_codes(ctx, prims).unwrap();
    if let Some(k) = (0..prims.len()).find(|&k| cpu_codes[k] != gpu_codes[k] || cpu_ids[k] != gpu_ids[k]) {
        let p = cpu_ids[k] as usize;
        panic!(
            "{name}: key {k} differs: CPU primitive {p} code {:#x}, GPU primitive {} code {:#x}; box {:?}",
            cpu_codes[k], gpu_ids[k], gpu_codes[k], prims[p]
        );
    }
    assert!(gpu.prim_ids == cpu.prim_ids, "{name}: primitive order");
    assert!(gpu.parents == cpu.parents, "{name}: parents");
    for (i, (g, c)) in gpu.nodes.iter().zip(cpu.nodes.iter()).enumerate() {
        assert_eq!(g, c, "{name}: node {i}");
    }
    assert_eq!(gpu.nodes.len(), cpu.nodes.len());
}

#[test]
fn random_boxes_give_the_cpu_tree() {
    let mut rng = common::rng(11);
    for n in [2usize, 3, 17, 1000, 70_001] {
        let tris = common::random_triangles(n, 0.05, &mut rng);
        let prims: Vec<Aabb> = tris.iter().map(Triangle::aabb).collect();
        same_tree(&format!("random {n}"), &prims);
    }
}

/// Many primitives share a Morton code: the index tie-break must match.
#[test]
fn duplicate_codes_give_the_cpu_tree() {
    let mut rng = common::rng(12);
    let mut prims: Vec<Aabb> = Vec::new();
    for k in 0..5000 {
        // 50 distinct centres, each 100 times.
        let c = glam::Vec3::splat((k % 50) as f32);
        prims.push(Aabb::new(c - 0.5, c + 0.5));
    }
    prims.extend(common::random_triangles(100, 0.1, &mut rng).iter().map(Triangle::aabb));
    same_tree("duplicates", &prims);
    // All equal, and a flat (zero-extent) axis.
    same_tree("all equal", &vec![Aabb::new(glam::Vec3::ZERO, glam::Vec3::ONE); 300]);
}

#[test]
fn dragon_gives_the_cpu_tree() {
    let Some(mesh) = common::shared_model("dragon_res2.obj") else { return };
    let prims: Vec<Aabb> = mesh.triangles().iter().map(Triangle::aabb).collect();
    same_tree("dragon", &prims);
}

/// A sphere inside a box of 10^6 (a sky box): the sphere's triangles share a few Morton cells,
/// where Karras' tree keeps them in file order. `render --device gpu` then builds the CPU's
/// LBVH, which splits such runs: the same tree as `render --device cpu`, where Karras' tree
/// has several times the sphere's interior area.
#[test]
fn a_sky_box_gets_the_cpu_lbvh_for_rendering() {
    use arbor::bvh::build::Builder;
    use arbor::bvh::{Bvh, collapse_leaves};
    use arbor::render::geometry::Geometry;
    use arbor::render::{BuildReport, RenderScene};
    use arbor::scene::Scene;
    let Some(ctx) = gpu_or_skip("a sky box") else { return };
    let text = "[camera]\nposition = [0, 0, 4]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n\n\
        [materials.w]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\n\
        [[objects]]\nshape = \"sphere\"\nsubdivisions = 4\nmaterial = \"w\"\n\n\
        [[objects]]\nshape = \"box\"\nmaterial = \"w\"\nscale = 1e6\n";
    let scene = Scene::parse(text, std::env::temp_dir().join("arbor-sky-box.toml")).unwrap();
    let tree = |(rs, _): &(RenderScene, BuildReport)| match &rs.geometry {
        Geometry::Flat(f) => f.mesh.bvh.clone(),
        Geometry::Instanced(_) => panic!("a flat scene was expected"),
    };
    // Internal nodes within the sphere's bounds: their area.
    let inner = |b: &Bvh| -> f64 {
        let inside =
            |n: &&arbor::bvh::BvhNode| n.aabb().max.abs().max_element().max(n.aabb().min.abs().max_element()) < 2.0;
        b.nodes.iter().filter(|n| !n.is_leaf()).filter(inside).map(|n| f64::from(n.aabb().half_area())).sum()
    };
    let cpu = RenderScene::build(&scene, &"lbvh".parse::<Builder>().unwrap(), common::tracing());
    let gpu = arbor::gpu::build_render_scene(ctx, &scene, false).unwrap().unwrap();
    assert!(gpu.1.builder.contains("on the CPU"), "{}", gpu.1.builder);
    assert!(tree(&gpu).nodes[..] == tree(&cpu).nodes[..], "{}: not the CPU's tree", gpu.1.builder);
    let (triangles, _) = scene.world_triangles();
    let prims: Vec<Aabb> = triangles.iter().map(Triangle::aabb).collect();
    let karras = inner(&collapse_leaves(&lbvh::build_karras(&prims), &Default::default()));
    let refined = inner(&tree(&cpu));
    assert!(karras > 2.0 * refined, "Karras' tree: {karras} against {refined}: the test no longer shows the problem");
    let optimized = arbor::gpu::build_render_scene(ctx, &scene, true).unwrap().unwrap();
    assert!(optimized.1.builder.contains("prbvh on the GPU"), "{}", optimized.1.builder);
    validate(&tree(&optimized), &prims).unwrap();
}
