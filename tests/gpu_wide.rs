//! The GPU's compressed 8-wide BVH (`arbor::gpu::wide`, `shaders/bvh_wide8.wgsl`): the SAH
//! collapse's table read back at the cost it computed, every decoded box containing what it
//! holds, and on the GPU (lavapipe in CI) the wide and binary traversals finding the same
//! closest hit, bit for bit, on the same rays, and the CPU's triangle.

use arbor::bvh::build::Builder;
use arbor::bvh::build::prbvh::PrbvhConfig;
use arbor::bvh::wide_sah::{self, WideCosts};
use arbor::bvh::{Bvh, CollapseConfig, INVALID_INDEX, collapse_leaves};
use arbor::geometry::{Aabb, Ray, Triangle};
use arbor::gpu::trace::{GpuForm, GpuScene, QueryHit, QueryRay, trace_rays};
use arbor::gpu::wide::{CompressedBvh, CompressedError};
use glam::Vec3;

use crate::common;

fn tree(triangles: &[Triangle], builder: &str, leaves: bool) -> Bvh {
    let prims = common::aabbs(triangles);
    let b: Builder = builder.parse().unwrap();
    let built = b.build(triangles, &prims, &PrbvhConfig { collapse: None, ..Default::default() }).bvh;
    if leaves { collapse_leaves(&built, &CollapseConfig::default()) } else { built }
}

/// Meshes with trees of one triangle a leaf and leaf-collapsed ones (leaves of up to 8, split
/// by the collapse), a flat mesh (zero extent on an axis), a single triangle, and the bunny.
fn cases() -> Vec<(String, Vec<Triangle>, Bvh)> {
    let mut rng = common::rng(7);
    let soup = common::random_triangles(3000, 0.05, &mut rng);
    let flat: Vec<Triangle> = common::random_triangles(500, 0.1, &mut rng)
        .into_iter()
        .map(|t| {
            Triangle::new(
                t.v0 * Vec3::new(1.0, 1.0, 0.0),
                t.v1 * Vec3::new(1.0, 1.0, 0.0),
                t.v2 * Vec3::new(1.0, 1.0, 0.0),
            )
        })
        .collect();
    let one = vec![Triangle::new(Vec3::ZERO, Vec3::X, Vec3::Y)];
    let mut cases = vec![
        ("soup, leaves of 1".to_owned(), soup.clone(), tree(&soup, "lbvh", false)),
        ("soup, collapsed leaves".to_owned(), soup.clone(), tree(&soup, "lbvh+prbvh", true)),
        ("flat".to_owned(), flat.clone(), tree(&flat, "binned-sah", true)),
        ("one triangle".to_owned(), one.clone(), Bvh::single_leaf(&common::aabbs(&one))),
    ];
    if let Some(bunny) = common::shared_model("bunny.obj") {
        let t = bunny.triangles();
        cases.push(("bunny".to_owned(), t.clone(), tree(&t, "lbvh", true)));
    }
    cases
}

#[test]
fn compressed_trees_hold_what_they_should_at_the_cost_the_table_computed() {
    for (name, triangles, bvh) in cases() {
        let prims = common::aabbs(&triangles);
        let wide = wide_sah::collapse(&bvh, &prims, 8, 3, WideCosts::default());
        let sah = wide.sah(WideCosts::default());
        assert!((sah - wide.cost).abs() <= 1e-4 * wide.cost.max(1.0), "{name}: table {} but tree {sah}", wide.cost);
        assert!(wide.nodes.iter().all(|n| (1..=8).contains(&n.len())), "{name}: a node of 0 or over 8 lanes");
        let mut ids = wide.prim_ids.clone();
        ids.sort_unstable();
        assert_eq!(ids, (0..triangles.len() as u32).collect::<Vec<_>>(), "{name}: primitives lost or repeated");
        let c = CompressedBvh::new(&bvh, &prims);
        c.validate(&prims).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(c.nodes.len(), wide.nodes.len(), "{name}");
        assert_eq!(c.memory_bytes(), 80 * c.nodes.len() + 4 * triangles.len(), "{name}: 80 bytes a node");
        // Tampering is caught: a lane's upper byte lowered below its contents.
        let mut bad = c.clone();
        let slot = (0..8).find(|&s| (bad.nodes[0][6 + s / 4] >> (8 * (s % 4))) & 0xff != 0).unwrap();
        bad.nodes[0][14 + slot / 4] &= !(0xff << (8 * (slot % 4)));
        bad.nodes[0][16 + slot / 4] &= !(0xff << (8 * (slot % 4)));
        bad.nodes[0][18 + slot / 4] &= !(0xff << (8 * (slot % 4)));
        if triangles.len() > 1 {
            assert!(matches!(bad.validate(&prims), Err(CompressedError::Box { .. })), "{name}: a shrunken box passed");
        }
    }
    // The SAH collapse beats what a wide tree of the binary tree's own nodes would cost: the
    // table can always keep the binary nodes, so it is never worse.
    let mut rng = common::rng(3);
    let t = common::random_triangles(2000, 0.05, &mut rng);
    let bvh = tree(&t, "lbvh", false);
    let two = wide_sah::collapse(&bvh, &common::aabbs(&t), 2, 1, WideCosts::default());
    let eight = wide_sah::collapse(&bvh, &common::aabbs(&t), 8, 1, WideCosts::default());
    assert!(eight.cost < two.cost, "8 lanes {} not cheaper than 2 {}", eight.cost, two.cost);
}

/// Rays at the mesh: from outside, from inside, and aimed at vertices.
fn rays(triangles: &[Triangle], n: usize) -> Vec<Ray> {
    let bounds = triangles.iter().fold(Aabb::EMPTY, |b, t| b.union(t.aabb()));
    let targets: Vec<Vec3> = triangles.iter().flat_map(|t| [t.v0, t.v1, t.v2]).collect();
    common::rays_at(&bounds, &targets, n, &mut common::rng(11))
}

#[test]
fn wide8_and_binary_find_the_same_hits_on_the_gpu() {
    let Some(ctx) = common::gpu_or_skip("wide8_and_binary_find_the_same_hits_on_the_gpu") else { return };
    for (name, triangles, bvh) in cases() {
        let rays = rays(&triangles, 4000);
        let queries: Vec<QueryRay> =
            rays.iter().map(|&ray| QueryRay { ray, t_max: f32::MAX, skip: INVALID_INDEX }).collect();
        let binary = GpuScene::for_rays(ctx, &bvh, &triangles, GpuForm::Binary).unwrap();
        let wide = GpuScene::for_rays(ctx, &bvh, &triangles, GpuForm::Wide8).unwrap();
        let (hb, _) = trace_rays(ctx, &binary, &queries, false).unwrap();
        let (hw, _) = trace_rays(ctx, &wide, &queries, false).unwrap();
        let bits = |h: &QueryHit| (h.prim, h.t.to_bits(), h.u.to_bits(), h.v.to_bits());
        let hits = hb.iter().filter(|h| h.prim != INVALID_INDEX).count();
        assert!(hits > rays.len() / 10, "{name}: only {hits} of {} rays hit: a weak test", rays.len());
        let mut differ = 0;
        for (i, (b, w)) in hb.iter().zip(&hw).enumerate() {
            assert_eq!(bits(b), bits(w), "{name}: ray {i} {:?}: binary {b:?}, wide8 {w:?}", rays[i]);
            // The CPU's tree finds the same triangle, but where the GPU's f32 fallback of the
            // triangle test (a ray through a vertex or an edge) rounds `t` otherwise than the
            // CPU's f64 and another triangle at that point wins: then the two are within ulps.
            let cpu = bvh.closest_hit_triangles(&triangles, &rays[i], f32::INFINITY);
            if cpu.map_or(INVALID_INDEX, |h| h.prim_id) != b.prim {
                let c = cpu.unwrap_or_else(|| panic!("{name}: ray {i}: GPU {b:?}, CPU nothing"));
                assert!(
                    b.prim != INVALID_INDEX && (c.t - b.t).abs() <= 4.0 * f32::EPSILON * c.t,
                    "{name}: ray {i}: CPU {c:?}, GPU {b:?}"
                );
                // Only rays aimed exactly at vertices (every fourth: common::rays_at) meet them.
                assert_eq!(i % 4, 3, "{name}: ray {i} is not aimed at a vertex: CPU {c:?}, GPU {b:?}");
                differ += 1;
            }
        }
        assert!(
            differ * 10 <= rays.len(),
            "{name}: {differ} of {} rays hit another triangle than on the CPU",
            rays.len()
        );
        // Any hit, up to just short of and just past the closest hit, skipping it or not.
        let any: Vec<QueryRay> = queries
            .iter()
            .zip(&hb)
            .filter(|(_, h)| h.prim != INVALID_INDEX)
            .flat_map(|(q, h)| {
                [
                    QueryRay { t_max: h.t * 0.999, ..*q },
                    QueryRay { t_max: h.t, ..*q },
                    QueryRay { t_max: h.t, skip: h.prim, ..*q },
                ]
            })
            .collect();
        let (ab, _) = trace_rays(ctx, &binary, &any, true).unwrap();
        let (aw, _) = trace_rays(ctx, &wide, &any, true).unwrap();
        for (i, (b, w)) in ab.iter().zip(&aw).enumerate() {
            assert_eq!(b.prim, w.prim, "{name}: any-hit query {i}: binary {b:?}, wide8 {w:?}");
            if i % 3 == 1 {
                assert_ne!(b.prim, INVALID_INDEX, "{name}: query {i}: the closest hit itself is within t_max");
            }
        }
        // Skipping the closest hit's triangle finds the next one, the same in both forms.
        let skipped: Vec<QueryRay> = queries
            .iter()
            .zip(&hb)
            .filter(|(_, h)| h.prim != INVALID_INDEX)
            .map(|(q, h)| QueryRay { skip: h.prim, ..*q })
            .collect();
        let (sb, _) = trace_rays(ctx, &binary, &skipped, false).unwrap();
        let (sw, _) = trace_rays(ctx, &wide, &skipped, false).unwrap();
        for (i, (b, w)) in sb.iter().zip(&sw).enumerate() {
            assert_eq!(bits(b), bits(w), "{name}: skipping query {i}");
            assert_ne!(b.prim, skipped[i].skip, "{name}: query {i} hit the triangle it skips");
        }
    }
}

/// The two forms render the same image bit for bit: every path finds the same hits (ties to the
/// lowest primitive id in both), so the exact film sums agree, on the showcase and on the
/// textured scene with cut-out masks. `--trace wide4` on the GPU is refused, and under `--device
/// gpu` the report names the form traced.
#[test]
fn both_forms_render_the_same_image_on_the_gpu() {
    use arbor::render::RenderScene;
    use arbor::scene::Scene;
    let Some(ctx) = common::gpu_or_skip("both_forms_render_the_same_image_on_the_gpu") else { return };
    let scenes = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes");
    for name in ["showcase.toml", "textured-sky.toml"] {
        let scene = Scene::load(scenes.join(name)).unwrap();
        let (rs, _) = RenderScene::build(&scene, &"lbvh".parse().unwrap(), common::tracing());
        let image = |form| {
            let gpu = GpuScene::upload(ctx, &rs, form).unwrap();
            let out = arbor::gpu::trace::render(ctx, &gpu, 5, scene.render.max_depth, 4).unwrap();
            (out.film.mean(), out.rays)
        };
        let ((binary, rays_b), (wide, rays_w)) = (image(GpuForm::Binary), image(GpuForm::Wide8));
        assert_eq!(rays_b, rays_w, "{name}: the paths traced differ");
        assert!(binary.pixels == wide.pixels, "{name}: the binary and wide8 images differ");
    }
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_render"))
        .args(["--device", "gpu", "--trace", "wide4", "-o"])
        .arg(std::env::temp_dir().join(format!("arbor-wide4-{}.png", std::process::id())))
        .arg(scenes.join("furnace.toml"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("--trace wide4 is a CPU form"), "{stderr}");
    // The report names the form traced: the GPU's default, or the one asked for.
    let dir = std::env::temp_dir().join(format!("arbor-forms-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for (args, form) in [(vec![], "wide8"), (vec!["--trace", "binary"], "binary")] {
        let report = dir.join("r.json");
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_render"))
            .args(["--device", "gpu", "--spp", "1", "--quiet"])
            .args(&args)
            .arg("--report")
            .arg(&report)
            .arg("-o")
            .arg(dir.join("f.png"))
            .arg(scenes.join("furnace.toml"))
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
        assert_eq!(json["bvh"]["trace"], form, "{args:?}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The collapse on the GPU (`gpu::wide::collapse_on_device`) from the GPU's own LBVH: a valid
/// compressed tree (every decoded box holding its contents, every triangle once), within 2% of
/// the host's collapse of the same tree in nodes, and tracing the same hits as the binary tree,
/// bit for bit; also after the GPU's PRBVH.
#[test]
fn the_gpu_collapse_makes_a_valid_tree_that_finds_the_same_hits() {
    use arbor::gpu::{lbvh, prbvh, wide};
    let Some(ctx) = common::gpu_or_skip("the_gpu_collapse_makes_a_valid_tree_that_finds_the_same_hits") else {
        return;
    };
    let mut inputs = vec![("soup".to_owned(), common::random_triangles(5000, 0.05, &mut common::rng(5)))];
    if let Some(bunny) = common::shared_model("bunny.obj") {
        inputs.push(("bunny".to_owned(), bunny.triangles()));
    }
    for (name, triangles) in inputs {
        let prims = common::aabbs(&triangles);
        for optimise in [false, true] {
            let (gpu, _) = lbvh::build_on_device(ctx, &prims).unwrap();
            if optimise {
                let config = PrbvhConfig { collapse: None, ..Default::default() };
                prbvh::optimize_on_device(ctx, &gpu, &config, prbvh::LockScheme::best_for(ctx)).unwrap();
            }
            let binary = gpu.read(ctx).unwrap();
            let made = wide::collapse_on_device(ctx, &gpu).unwrap();
            let read = made.read(ctx).unwrap();
            read.validate(&prims).unwrap_or_else(|e| panic!("{name}, optimised {optimise}: {e}"));
            let host = CompressedBvh::new(&binary, &prims);
            let (a, b) = (read.nodes.len() as f64, host.nodes.len() as f64);
            assert!((a - b).abs() <= 0.02 * b, "{name}: {a} wide nodes on the GPU, {b} on the host");
            let rays = rays(&triangles, 3000);
            let queries: Vec<QueryRay> =
                rays.iter().map(|&ray| QueryRay { ray, t_max: f32::MAX, skip: INVALID_INDEX }).collect();
            let scene = GpuScene::for_rays_with(ctx, made, &triangles).unwrap();
            let reference = GpuScene::for_rays(ctx, &binary, &triangles, GpuForm::Binary).unwrap();
            let (hw, _) = trace_rays(ctx, &scene, &queries, false).unwrap();
            let (hb, _) = trace_rays(ctx, &reference, &queries, false).unwrap();
            let bits = |h: &QueryHit| (h.prim, h.t.to_bits(), h.u.to_bits(), h.v.to_bits());
            for (i, (w, b)) in hw.iter().zip(&hb).enumerate() {
                assert_eq!(bits(w), bits(b), "{name}: ray {i}: GPU-made wide {w:?}, binary {b:?}");
            }
        }
    }
}
