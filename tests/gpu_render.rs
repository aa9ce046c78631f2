//! The GPU path tracer (`src/gpu/trace.rs`) against exact answers and against the CPU
//! integrator, and `render --device gpu` as a user runs it. Runs on any adapter, lavapipe
//! included; skips without one, except under `CI=true`.
//!
//! The exact cases are those of `tests/render_accuracy.rs`; the comparisons with the CPU use
//! 8x8-pixel blocks: the difference of block means over the combined standard error must stay
//! below a Bonferroni threshold for a family-wise false-alarm rate of 10⁻³ per image.

use crate::common;

use std::path::PathBuf;
use std::process::Command;

use arbor::bvh::build::Builder;
use arbor::geometry::Triangle;
use arbor::gpu::GpuContext;
use arbor::gpu::trace::{self, Features, GpuForm, GpuScene};
use arbor::render::RenderScene;
use arbor::render::film::Film;
use arbor::render::pass::{Pass, Progress};
use arbor::render::region::Region;
use arbor::scene::Scene;
use common::analytic::{self, region};
use common::{gpu_or_skip, z_for_two_sided_p};
use glam::Vec3;

fn scene_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes").join(name)
}

fn lbvh() -> Builder {
    "lbvh".parse().unwrap()
}

/// Renders `scene` on the GPU; asserts that no sample was non-finite.
fn render_gpu(ctx: &GpuContext, scene: &RenderScene, seed: u64, spp: u32, max_depth: u32) -> Film {
    let gpu = GpuScene::upload(ctx, scene, GpuForm::default()).unwrap_or_else(|e| panic!("{e}"));
    let out = trace::render(ctx, &gpu, seed, max_depth, spp).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(out.samples, spp);
    assert_eq!(out.film.non_finite_count(), 0, "non-finite samples on the GPU");
    assert_eq!(out.film.sample_count(), u64::from(spp) * u64::from(scene.width * scene.height));
    out.film
}

fn render_cpu(scene: &RenderScene, seed: u64, spp: u32, max_depth: u32) -> Film {
    let mut film = Film::new(scene.width, scene.height);
    scene.render(&mut film, seed, max_depth, 0..spp, &|_| {});
    assert_eq!(film.non_finite_count(), 0, "non-finite samples on the CPU");
    film
}

/// A convex sphere of albedo 0.8 under environment radiance 1 reads exactly 0.8 (f32 on the GPU:
/// to 1e-5), and the background exactly 1; also scaled by 10^±12, where f32 squares of edge
/// lengths overflow and underflow, and by 10^±16 and 10^±18, where the triangle test's products
/// do (the GPU then reruns it on coordinates rescaled by powers of two).
#[test]
fn furnace_sphere_is_exactly_its_albedo_on_the_gpu() {
    let Some(ctx) = gpu_or_skip("furnace_sphere_is_exactly_its_albedo_on_the_gpu") else { return };
    let unit = Scene::load(scene_path("furnace.toml")).unwrap();
    for s in [1.0f32, 1e12, 1e-12, 1e16, 1e-16, 1e18, 1e-18] {
        analytic::check_furnace("gpu", &unit, s, 1e-5, |scene| {
            let (rs, _) = RenderScene::build(scene, &lbvh(), common::tracing());
            render_gpu(ctx, &rs, scene.render.seed, 16, scene.render.max_depth)
        });
    }
}

/// A camera inside a closed emitting shell sees a geometric series (`analytic::check_closed_shell`).
#[test]
fn closed_shell_sums_the_geometric_series_on_the_gpu() {
    let Some(ctx) = gpu_or_skip("closed_shell_sums_the_geometric_series_on_the_gpu") else { return };
    for s in [1.0, 1e12, 1e-12, 1e16, 1e-16] {
        analytic::check_closed_shell("gpu", s, |scene, depth| {
            let (rs, _) = RenderScene::build(scene, &lbvh(), common::tracing());
            render_gpu(ctx, &rs, 0, 64, depth)
        });
    }
}

/// A diffuse floor under a square light, direct light only: each 8x8 block matches `albedo/π · E`
/// from the closed form within 3 standard errors, at unit scale and scaled by 2^±40 and 2^±53,
/// where the image must also be the unit-scale one, to 10^-5 (as in render_accuracy.rs; the
/// GPU's rescaled fallback is exact there, and measured 0 on lavapipe and an H100).
#[test]
fn irradiance_under_a_square_light_matches_the_closed_form_on_the_gpu() {
    let Some(ctx) = gpu_or_skip("irradiance_under_a_square_light_matches_the_closed_form_on_the_gpu") else {
        return;
    };
    let scene =
        Scene::parse(&analytic::irradiance_scene_text(), std::env::temp_dir().join("arbor-gpu-irradiance.toml"))
            .unwrap();
    let render = |s: f32| {
        let (rs, _) = RenderScene::build(&analytic::scaled_scene(&scene, s), &lbvh(), common::tracing());
        render_gpu(ctx, &rs, 0, 256, 2)
    };
    let unit = render(1.0);
    let (blocks, worst) = analytic::check_irradiance(&scene, &unit);
    eprintln!("GPU irradiance: {blocks} blocks, worst z {worst:.2}");
    for s in analytic::EXTREME_SCALES {
        let film = render(s);
        let (blocks, worst) = analytic::check_irradiance(&scene, &film);
        eprintln!("GPU irradiance at scale {s:e}: {blocks} blocks, worst z {worst:.2}");
        analytic::check_same_image(&format!("gpu irradiance at scale {s:e}"), &unit.mean(), &film.mean(), 1e-5);
    }
}

/// A floor lit by square lights 10^20 above it (`analytic::check_distant_lights`).
#[test]
fn a_light_at_1e20_lights_as_its_solid_angle_says_on_the_gpu() {
    let Some(ctx) = gpu_or_skip("a_light_at_1e20_lights_as_its_solid_angle_says_on_the_gpu") else { return };
    analytic::check_distant_lights("gpu", |scene| {
        let (rs, _) = RenderScene::build(scene, &lbvh(), common::tracing());
        render_gpu(ctx, &rs, 0, 256, 2)
    });
}

/// 8x8 blocks of `a` against `b`: the worst |z| over blocks and channels and the Bonferroni
/// threshold for a family-wise rate of 10⁻³. Pixel channels with standard error 0 in both must
/// agree within 1e-5 relative and stay out of the z-test.
fn block_z(a: &Film, b: &Film) -> (f64, f64) {
    let (w, h) = (a.width(), a.height());
    let (bx_count, by_count) = (w.div_ceil(8), h.div_ceil(8));
    let mut sums = vec![[(0.0f64, 0.0f64); 3]; (bx_count * by_count) as usize];
    let (ma, sa, mb, sb) = (a.mean(), a.stderr(), b.mean(), b.stderr());
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let block = &mut sums[((y / 8) * bx_count + x / 8) as usize];
            for (c, s) in block.iter_mut().enumerate() {
                let (va, vb) = (f64::from(ma.pixels[i][c]), f64::from(mb.pixels[i][c]));
                let (ea, eb) = (f64::from(sa.pixels[i][c]), f64::from(sb.pixels[i][c]));
                if ea == 0.0 && eb == 0.0 {
                    assert!((va - vb).abs() <= 1e-5 * va.abs().max(vb.abs()), "exact pixel ({x}, {y}): {va} vs {vb}");
                    continue;
                }
                s.0 += va - vb;
                s.1 += ea * ea + eb * eb;
            }
        }
    }
    let worst = sums.iter().flatten().map(|&(d, v)| if v > 0.0 { d.abs() / v.sqrt() } else { 0.0 }).fold(0.0, f64::max);
    (worst, z_for_two_sided_p(1e-3 / (3.0 * sums.len() as f64)))
}

/// GPU and CPU renders of the same scene (different random streams) agree block by block.
fn gpu_matches_cpu(name: &str, mut scene: Scene, spp: u32, clamp: Option<f32>) {
    let Some(ctx) = gpu_or_skip(name) else { return };
    let (w, h) = (scene.camera.width, scene.camera.height);
    let longest = w.max(h);
    scene.camera.width = (w * 64).div_ceil(longest);
    scene.camera.height = (h * 64).div_ceil(longest);
    let (mut rs, _) = RenderScene::build(&scene, &lbvh(), common::tracing());
    rs.sample_clamp = clamp;
    let depth = scene.render.max_depth;
    let gpu = render_gpu(ctx, &rs, 1, spp, depth);
    let cpu = render_cpu(&rs, 2, spp, depth);
    let (worst, threshold) = block_z(&gpu, &cpu);
    let (g, c) = (region(&gpu.mean(), &gpu.stderr(), |_, _| true), region(&cpu.mean(), &cpu.stderr(), |_, _| true));
    eprintln!("{name}: worst block |z| {worst:.2} (limit {threshold:.2}); image means GPU {} CPU {}", g.0, c.0);
    assert!(worst <= threshold, "{name}: GPU and CPU differ: worst block |z| {worst:.2} > {threshold:.2}");
}

#[test]
fn gpu_matches_cpu_on_the_showcase() {
    gpu_matches_cpu("showcase", Scene::load(scene_path("showcase.toml")).unwrap(), 64, None);
}

/// The coated metallic-roughness material in the white furnace: a smooth coat over a white
/// base, a rough half metal, and a rough metal.
#[test]
fn gpu_matches_cpu_on_coated_furnace_spheres() {
    for (metallic, roughness) in [(0.0, 0.0), (0.5, 0.5), (1.0, 0.3)] {
        let scene = crate::render_accuracy::coated_furnace(metallic, roughness);
        gpu_matches_cpu(&format!("coated furnace, metallic {metallic}, roughness {roughness}"), scene, 64, None);
    }
}

#[test]
fn gpu_matches_cpu_on_the_cornell_box() {
    gpu_matches_cpu("cornell-box", Scene::load(scene_path("cornell-box.toml")).unwrap(), 64, None);
}

/// The thin lens and the firefly clamp, on the GPU as on the CPU.
#[test]
fn gpu_matches_cpu_with_a_thin_lens_and_a_clamp() {
    let mut scene = Scene::load(scene_path("cornell-box.toml")).unwrap();
    scene.camera.aperture = 0.08;
    scene.camera.focus_distance = 3.0;
    gpu_matches_cpu("cornell-box, thin lens, clamp 2", scene, 32, Some(2.0));
}

/// Two levels on the GPU: `textured-sky` made animated (so it renders with a tree per mesh
/// under a top-level tree of objects), with a mirrored copy of its lattice, renders as the CPU
/// renders it (cut-out masks, a normal map, textures, the sky map and a conductor, through
/// instance transforms), in both tree forms, at its first frame and after the top level was
/// updated to its second frame and uploaded again.
#[test]
fn gpu_matches_cpu_in_two_levels() {
    let Some(ctx) = gpu_or_skip("gpu_matches_cpu_in_two_levels") else { return };
    let assets = scene_path("assets");
    let text = std::fs::read_to_string(scene_path("textured-sky.toml"))
        .unwrap()
        .replace("\"assets/", &format!("\"{}/", assets.display()))
        + "\n[animation]\nfps = 24\nframes = [0, 2]\n\
           [[objects]]\nshape = \"quad\"\nmaterial = \"lattice\"\nscale = [-0.8, 0.8, 0.8]\n\
           [[objects.keyframes]]\ntime = 0\ntranslate = [-0.9, 0.8, 0.4]\n\
           [[objects.keyframes]]\ntime = 1\ntranslate = [-0.5, 0.8, 0.4]\n";
    let dir = std::env::temp_dir().join(format!("arbor-gpu-two-level-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("scene.toml"), text).unwrap();
    let mut scene = Scene::load(dir.join("scene.toml")).unwrap_or_else(|e| panic!("{e}"));
    assert!(arbor::render::geometry::wants_instancing(&scene));
    scene.camera.width = 64;
    scene.camera.height = 40;
    let (mut rs, _) = RenderScene::build(&scene, &lbvh(), arbor::bvh::Tracing::gpu());
    assert!(matches!(rs.geometry, arbor::render::geometry::Geometry::Instanced(_)));
    let (spp, depth) = (64, 4);
    for form in [GpuForm::Wide8, GpuForm::Binary] {
        let mut gpu = GpuScene::upload(ctx, &rs, form).unwrap_or_else(|e| panic!("{e}"));
        assert!(gpu.features.instances && gpu.features.cutouts, "{:?}", gpu.features);
        for frame in 0..2 {
            if frame == 1 {
                let update = arbor::bvh::dynamic::instances::TopLevelUpdate::Dynamic(Default::default());
                rs.set_time(&scene, scene.frame_time(1), &update);
                gpu.update_instances(ctx, &rs).unwrap();
            }
            let out = trace::render(ctx, &gpu, 1, depth, spp).unwrap();
            assert_eq!(out.film.non_finite_count(), 0);
            let cpu = render_cpu(&rs, 2, spp, depth);
            let (worst, threshold) = block_z(&out.film, &cpu);
            let name = format!("two levels, {}, frame {frame}", form.name());
            eprintln!("{name}: worst block |z| {worst:.2} (limit {threshold:.2})");
            assert!(worst <= threshold, "{name}: GPU and CPU differ: worst block |z| {worst:.2} > {threshold:.2}");
        }
        // Back to frame 0 for the other form.
        let update = arbor::bvh::dynamic::instances::TopLevelUpdate::Dynamic(Default::default());
        rs.set_time(&scene, scene.frame_time(0), &update);
    }
}

/// The memory of a two-level scene on the GPU follows its instances: 300 instances of one
/// 81,920-triangle mesh take the mesh's bytes once plus a fixed number of bytes an instance
/// (its transforms and indices, 128 bytes, and the room kept for the top-level tree: two binary
/// nodes of 32 bytes, or one wide node of 80), not 300 copies of its triangles; and they render.
#[test]
fn instances_cost_their_transforms_on_the_gpu() {
    let Some(ctx) = gpu_or_skip("instances_cost_their_transforms_on_the_gpu") else { return };
    let mut text = String::from(
        "[camera]\nposition = [0, 30, 60]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [32, 24]\n\
         [environment]\nradiance = [1, 1, 1]\n[materials.m]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\
         [animation]\nfps = 24\nframes = [0, 2]\n",
    );
    text += "[[objects]]\nshape = \"sphere\"\nsubdivisions = 6\nmaterial = \"m\"\n\
             [objects.scatter]\ncount = 300\nseed = 4\nmin = [-30, 1, -20]\nmax = [30, 1, 20]\n\
             moving = 0.2\nradius = 1.0\nperiod = 2.0\n";
    let dir = std::env::temp_dir().join(format!("arbor-gpu-instances-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("scene.toml"), text).unwrap();
    let scene = Scene::load(dir.join("scene.toml")).unwrap_or_else(|e| panic!("{e}"));
    let (rs, _) = RenderScene::build(&scene, &lbvh(), arbor::bvh::Tracing::gpu());
    let arbor::render::geometry::Geometry::Instanced(g) = &rs.geometry else { panic!("not two levels") };
    let per_mesh: Vec<usize> = g.mesh_triangles().iter().map(Vec::len).collect();
    let (instances, world) = (g.two_level.instances().len(), rs.geometry.world_triangle_count());
    assert_eq!(instances, 300);
    for form in [GpuForm::Wide8, GpuForm::Binary] {
        let gpu = GpuScene::upload(ctx, &rs, form).unwrap();
        let mesh_triangles: usize = per_mesh.iter().sum();
        // The trees and triangle order hold each mesh's triangles once.
        assert!(gpu.tree_bytes < 200 * mesh_triangles, "{}: {} tree bytes", form.name(), gpu.tree_bytes);
        assert!(gpu.tree_bytes * 100 < 200 * world, "{}: the trees follow the world's triangles", form.name());
        eprintln!(
            "{}: {instances} instances of {mesh_triangles} triangles ({world} in the world): trees {} bytes, \
             instances {} bytes",
            form.name(),
            gpu.tree_bytes,
            gpu.instance_bytes()
        );
        let tlas = if form == GpuForm::Binary { 2 * 32 } else { 80 };
        assert!(gpu.instance_bytes() <= instances * (128 + tlas), "{} bytes", gpu.instance_bytes());
        let out = trace::render(ctx, &gpu, 1, 2, 1).unwrap();
        let lit = out.film.mean().pixels.iter().filter(|p| p[0] < 0.99).count();
        assert!(lit > 0, "{}: no sphere seen", form.name());
        // The mesh is large enough to be built on the GPU (its LBVH and PRBVH, read back): the
        // same surfaces, so the same image but for rare ties and rounding at box edges.
        let (on_gpu, report) = arbor::gpu::build_instanced_for(ctx, &scene, true, &lbvh()).unwrap();
        assert!(report.builder.contains("1 of 1 meshes built on the GPU"), "{}", report.builder);
        let gpu_built = GpuScene::upload(ctx, &on_gpu, form).unwrap();
        let again = trace::render(ctx, &gpu_built, 1, 2, 1).unwrap();
        let (a, b) = (out.film.mean().pixels, again.film.mean().pixels);
        let differ = a.iter().zip(&b).filter(|(x, y)| x != y).count();
        assert!(differ * 100 <= a.len(), "{}: {differ} of {} pixels differ", form.name(), a.len());
    }
}

/// Each scene gets the variant it needs, and the all-features variant renders it the same.
#[test]
fn specialized_and_general_variants_agree() {
    let Some(ctx) = gpu_or_skip("specialized_and_general_variants_agree") else { return };
    let mut scene = Scene::load(scene_path("furnace.toml")).unwrap();
    scene.camera.width = 32;
    scene.camera.height = 32;
    let (rs, _) = RenderScene::build(&scene, &lbvh(), common::tracing());
    assert_eq!(
        Features::of(&rs),
        Features {
            dielectric: false,
            conductor: false,
            coated: false,
            environment: true,
            lights: false,
            thin_lens: false,
            shading_normals: false,
            env_map: false,
            textures: false,
            cutouts: false,
            instances: false
        }
    );
    let mut gpu = GpuScene::upload(ctx, &rs, GpuForm::default()).unwrap();
    let specialized = trace::render(ctx, &gpu, 3, 8, 8).unwrap();
    gpu.features = Features::ALL;
    let general = trace::render(ctx, &gpu, 3, 8, 8).unwrap();
    // The same random streams and the same arithmetic: the same image.
    assert_eq!(specialized.film.mean().pixels, general.film.mean().pixels);
    assert_eq!(specialized.rays, general.rays);
}

/// The GPU's `auto` decides on the GPU's own timings: a render too short to time keeps the
/// GPU's LBVH; a long one gets the GPU's PRBVH (a lower SAH); one bounded by a 1 ms time limit
/// does not, however many samples it asks for.
#[test]
fn gpu_auto_runs_the_gpus_prbvh_where_it_repays() {
    assert!(trace::gpu_prbvh_repays(1.0, 1e-3) && !trace::gpu_prbvh_repays(0.1, 1e-2));
    let Some(ctx) = gpu_or_skip("gpu_auto_runs_the_gpus_prbvh_where_it_repays") else { return };
    let mut scene = Scene::load(scene_path("cornell-box.toml")).unwrap();
    scene.camera.width = 24;
    scene.camera.height = 16;
    let job = |spp, time| arbor::scene::RenderSettings { spp, max_depth: 4, seed: 1, time, clamp: None };
    let (_, short, timed) = trace::build_auto(ctx, &scene, &job(1, None), 1, GpuForm::default());
    assert!(
        short.builder.starts_with("auto: lbvh on the GPU") && short.builder.contains("too short"),
        "{}",
        short.builder
    );
    assert!(timed.is_none());
    let (_, long, timed) = trace::build_auto(ctx, &scene, &job(1 << 24, None), 1, GpuForm::default());
    assert!(long.builder.starts_with("auto: lbvh+prbvh on the GPU"), "{}", long.builder);
    assert!(long.sah < short.sah, "PRBVH's SAH {} against the LBVH's {}", long.sah, short.sah);
    assert_eq!(timed.map(|t| t.samples()), Some(trace::MEASURE_SPP));
    let (_, limited, _) = trace::build_auto(ctx, &scene, &job(1 << 24, Some(1e-3)), 1, GpuForm::default());
    assert!(limited.builder.contains("would not repay"), "{}", limited.builder);
    assert_eq!(limited.sah, short.sah);
}

/// `auto` on the GPU times the render's own first samples and hands them over: a render that
/// carries them on gives the film of one render from scratch, bit for bit; samples of another
/// render (another seed, clamp or depth) are dropped, not mixed in.
#[test]
fn auto_hands_its_timed_samples_to_the_render() {
    let Some(ctx) = gpu_or_skip("auto_hands_its_timed_samples_to_the_render") else { return };
    let mut scene = Scene::load(scene_path("cornell-box.toml")).unwrap();
    scene.camera.width = 24;
    scene.camera.height = 16;
    let (seed, max_depth, spp) = (5, 6, 16 * trace::MEASURE_SPP);
    let job = arbor::scene::RenderSettings { spp, max_depth, seed, time: None, clamp: Some(4.0) };
    let (rs, _, timed) = trace::build_auto(ctx, &scene, &job, 1, GpuForm::default());
    let timed = timed.expect("a render of 16 x MEASURE_SPP samples is timed");
    assert_eq!(timed.samples(), trace::MEASURE_SPP);
    let mut gpu = GpuScene::upload(ctx, &rs, GpuForm::default()).unwrap();
    gpu.set_clamp(Some(4.0));
    let reported = std::sync::Mutex::new(Vec::new());
    let whole = Region { rect: arbor::render::region::Rect::full(24, 16), samples: 0..spp };
    // Progress in rows × samples: a row's samples reached, times the 16 rows.
    let progress = |p: Progress| reported.lock().unwrap().push(p.done / 16);
    let pass = Pass::new(&job, whole.clone()).carrying(Some(timed)).with_progress(&progress);
    let carried = trace::render_from(ctx, &gpu, pass).unwrap();
    let reported = reported.into_inner().unwrap();
    assert_eq!(carried.carried.0, trace::MEASURE_SPP);
    assert_eq!(reported.first(), Some(&u64::from(trace::MEASURE_SPP + trace::PASS_SPP)), "passes: {reported:?}");
    let fresh = trace::render(ctx, &gpu, seed, max_depth, spp).unwrap();
    assert_eq!(fresh.carried, (0, 0.0));
    assert_eq!((carried.samples, carried.rays), (fresh.samples, fresh.rays));
    assert_eq!(carried.film.mean().pixels, fresh.film.mean().pixels);
    assert_eq!(carried.film.stderr().pixels, fresh.film.stderr().pixels);
    // Timed under another seed, clamp or path depth: not this render's samples.
    for (other_seed, clamp, other_depth) in [(6, Some(4.0), max_depth), (seed, None, max_depth), (seed, Some(4.0), 5)] {
        let other_job = arbor::scene::RenderSettings { seed: other_seed, max_depth: other_depth, clamp, ..job };
        let (_, _, other) = trace::build_auto(ctx, &scene, &other_job, 1, GpuForm::default());
        let out = trace::render_from(ctx, &gpu, Pass::new(&job, whole.clone()).carrying(other)).unwrap();
        assert_eq!(out.carried.0, 0, "seed {other_seed}, clamp {clamp:?}, depth {other_depth}");
        assert_eq!(out.film.mean().pixels, fresh.film.mean().pixels);
    }
}

/// A tree deeper than the traversal stack is refused before upload, with a clear error, in
/// either form: a 100-deep binary tree, and a 1000-deep one, whose wide form is still over
/// 33 nodes deep.
#[test]
fn a_tree_deeper_than_the_stack_is_refused() {
    let Some(ctx) = gpu_or_skip("a_tree_deeper_than_the_stack_is_refused") else { return };
    let scene = Scene::load(scene_path("furnace.toml")).unwrap();
    let (mut rs, _) = RenderScene::build(&scene, &lbvh(), common::tracing());
    for (n, form, says) in
        [(100u32, GpuForm::Binary, "binary BVH is 100 nodes deep"), (1000, GpuForm::Wide8, "wide8 BVH is")]
    {
        // A caterpillar: internal node k has leaf k on the left and the next internal node on
        // the right, n levels deep.
        let tris: Vec<Triangle> = (0..n)
            .map(|i| Triangle::new(Vec3::new(i as f32, 0.0, 0.0), Vec3::new(i as f32, 1.0, 0.0), Vec3::Z))
            .collect();
        let aabb = tris.iter().fold(arbor::geometry::Aabb::EMPTY, |b, t| b.union(t.aabb()));
        let mut nodes = vec![arbor::bvh::BvhNode::internal(aabb, 2), bytemuck::Zeroable::zeroed()];
        let mut parents = vec![arbor::bvh::INVALID_INDEX; 2];
        for k in 0..n - 1 {
            let pair = 2 + 2 * k;
            nodes.push(arbor::bvh::BvhNode::leaf(tris[k as usize].aabb(), k, 1));
            nodes.push(if k == n - 2 {
                arbor::bvh::BvhNode::leaf(tris[k as usize + 1].aabb(), k + 1, 1)
            } else {
                arbor::bvh::BvhNode::internal(aabb, pair + 2)
            });
            parents.extend([if k == 0 { 0 } else { pair - 1 }; 2]);
        }
        let bvh = arbor::bvh::Bvh { nodes: nodes.into(), parents, prim_ids: (0..n).collect() };
        let mesh = arbor::bvh::MeshBvh::new(bvh, &tris, common::tracing());
        rs.geometry = arbor::render::geometry::Geometry::Flat(arbor::render::geometry::Flat {
            mesh,
            triangles: tris,
            material_of: vec![0; n as usize],
            normals: Vec::new(),
            uvs: Vec::new(),
            cutouts: None,
        });
        let error = GpuScene::upload(ctx, &rs, form).err().expect("a deep tree must be refused").to_string();
        assert!(error.contains(says) && error.contains("traversal stack"), "{error}");
    }
}

fn ctx_is_software() -> bool {
    GpuContext::shared().is_ok_and(GpuContext::is_software)
}

/// `render --device gpu` names the adapter, renders, and prints the usual summary; sequences of
/// an animated scene render frame by frame.
#[test]
fn render_cli_on_the_gpu() {
    if gpu_or_skip("render_cli_on_the_gpu").is_none() {
        return;
    }
    let dir = std::env::temp_dir().join(format!("arbor-gpu-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let run = |args: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_render")).args(args).output().unwrap();
        let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
        assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
        stdout
    };
    let out = dir.join("f.exr");
    let furnace = scene_path("furnace.toml");
    let stdout = run(&[furnace.to_str().unwrap(), "-o", out.to_str().unwrap(), "--device", "gpu", "--spp", "6"]);
    for word in ["GPU:", "triangles", "SAH", "render", "Mrays/s", "6 spp"] {
        assert!(stdout.contains(word), "summary lacks `{word}`: {stdout}");
    }
    let image = arbor::image_io::read_exr(&out).unwrap();
    assert_eq!((image.width, image.height), (128, 128));
    assert_eq!(image.pixels[0], [1.0; 3], "furnace background");
    let frames = dir.join("c_%02d.png");
    let stdout = run(&[
        scene_path("cornell-animated.toml").to_str().unwrap(),
        "-o",
        frames.to_str().unwrap(),
        "--device",
        "gpu",
        "--frames",
        "3..5",
        "--spp",
        "1",
        "--max-depth",
        "3",
    ]);
    assert!(dir.join("c_03.png").exists() && dir.join("c_04.png").exists(), "{stdout}");
    assert_eq!(stdout.matches(" spp").count(), 2, "{stdout}");
    // Without --builder, an animated scene renders in two levels (each mesh's tree built once),
    // and every frame after the first reports its top level's update as the BVH update.
    assert!(stdout.contains("BVH (two levels: "), "{stdout}");
    assert_eq!(stdout.matches("BVH update").count(), 1, "{stdout}");
    // `auto` takes a hardware GPU, or says in one line that it renders on the CPU.
    let stdout = run(&[furnace.to_str().unwrap(), "-o", out.to_str().unwrap(), "--device", "auto", "--spp", "1"]);
    let on_cpu = stdout.contains("no hardware GPU") && stdout.contains("rendering on the CPU");
    assert!(on_cpu != stdout.contains("GPU: "), "{stdout}");
    assert_eq!(on_cpu, ctx_is_software(), "{stdout}");
    // A time budget stops after the pass (4 samples per pixel) that crosses it.
    let stdout = run(&[
        furnace.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--device",
        "gpu",
        "--spp",
        "100000",
        "--time",
        "0.3",
        "--seed",
        "7",
        "--clamp",
        "5",
    ]);
    let spp: u32 =
        stdout.split(", ").find_map(|f| f.strip_suffix(" spp\n").or(f.strip_suffix(" spp"))).unwrap().parse().unwrap();
    assert!((4..100_000).contains(&spp) && spp % 4 == 0, "{stdout}");
}

/// CPU seconds this process has used (user + system, from `/proc/self/stat`; Linux only, else
/// 0): on lavapipe the GPU's work is this process's threads, and CPU time is steadier than wall
/// time on a shared machine.
fn process_cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else { return 0.0 };
    // Fields after the command name (which is in parentheses): utime and stime are 12 and 13.
    let rest = &stat[stat.rfind(')').map_or(0, |i| i + 2)..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |k: usize| fields.get(k).and_then(|f| f.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

/// What specialization saves: each scene rendered by its own variant and by the all-features
/// variant, alternately, three times each; compilation is left out. Prints the best wall time
/// and CPU time of each and their ratios; asserts nothing about speed (timings are for people,
/// not for tests). `cargo test --release --test tests specialization_speedup -- --ignored --nocapture`
#[test]
#[ignore]
fn specialization_speedup() {
    let Some(ctx) = gpu_or_skip("specialization_speedup") else { return };
    for (name, spp) in [("furnace.toml", 64), ("cornell-box.toml", 16), ("showcase.toml", 16)] {
        let scene = Scene::load(scene_path(name)).unwrap();
        let (rs, _) = RenderScene::build(&scene, &lbvh(), common::tracing());
        let mut gpu = GpuScene::upload(ctx, &rs, GpuForm::default()).unwrap();
        let specialized = Features::of(&rs);
        let (mut wall, mut cpu, mut rays) = ([f64::INFINITY; 2], [f64::INFINITY; 2], [0u64; 2]);
        for features in [specialized, Features::ALL] {
            gpu.features = features;
            trace::compile(ctx, &gpu).unwrap();
        }
        for _ in 0..3 {
            for (k, features) in [specialized, Features::ALL].into_iter().enumerate() {
                gpu.features = features;
                let (t, c) = (std::time::Instant::now(), process_cpu_seconds());
                let out = trace::render(ctx, &gpu, 0, scene.render.max_depth, spp).unwrap();
                wall[k] = wall[k].min(t.elapsed().as_secs_f64());
                cpu[k] = cpu[k].min(process_cpu_seconds() - c);
                rays[k] = out.rays;
            }
        }
        assert_eq!(rays[0], rays[1], "{name}: the variants traced different paths");
        eprintln!(
            "{name} ({}x{}, {spp} spp, {:.1} Mrays), {} vs all features: wall {:.2} s vs {:.2} s \
             (all / specialized {:.2}), CPU {:.2} s vs {:.2} s (ratio {:.2})",
            rs.width,
            rs.height,
            rays[0] as f64 / 1e6,
            specialized.key(),
            wall[0],
            wall[1],
            wall[1] / wall[0],
            cpu[0],
            cpu[1],
            cpu[1] / cpu[0]
        );
    }
}
