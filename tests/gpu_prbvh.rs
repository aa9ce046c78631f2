//! PRBVH on the GPU: with either lock scheme the tree read back passes `validate()`, its SAH
//! is within 2% of the CPU optimiser's on the same input (the same LBVH, μ and ε), and the
//! optimisation lowers the SAH. Skips without an adapter, except under `CI=true`.

use crate::common;

use arbor::bvh::build::prbvh::{self, PrbvhConfig};
use arbor::bvh::{build::lbvh, sah_cost, validate};
use arbor::geometry::{Aabb, Triangle};
use arbor::gpu::prbvh::{self as gpu_prbvh, LockScheme};
use common::gpu_or_skip;
use rand::RngExt;

fn compare(name: &str, prims: &[Aabb]) {
    let Some(ctx) = gpu_or_skip(name) else { return };
    let config = PrbvhConfig { collapse: None, ..Default::default() };
    let input = lbvh::build(prims);
    let mut cpu = input.clone();
    let cpu_stats = prbvh::optimize(&mut cpu, &config);
    let mut schemes = vec![LockScheme::Portable32];
    if LockScheme::best_for(ctx) == LockScheme::Atomic64 {
        schemes.push(LockScheme::Atomic64);
    } else {
        eprintln!("{name}: the adapter has no 64-bit atomics; only the portable locks are tested");
    }
    for scheme in schemes {
        let (gpu, stats) = gpu_prbvh::optimize(ctx, &input, &config, scheme).unwrap_or_else(|e| panic!("{name}: {e}"));
        validate(&gpu, prims).unwrap_or_else(|e| panic!("{name} {scheme:?}: invalid tree: {e}"));
        let (s_in, s_cpu, s_gpu) = (sah_cost(&input), sah_cost(&cpu), sah_cost(&gpu));
        eprintln!(
            "{name} {scheme:?}: SAH {s_in:.2} -> CPU {s_cpu:.2} ({} iterations), GPU {s_gpu:.2} ({} iterations, {:.1} ms, reported {:.2})",
            cpu_stats.iterations.len(),
            stats.iterations.len(),
            stats.optimize_time.as_secs_f64() * 1e3,
            stats.final_sah,
        );
        assert!(s_gpu < s_in, "{name} {scheme:?}: the GPU optimiser did not lower the SAH");
        assert!((s_gpu - s_cpu).abs() <= 0.02 * s_cpu, "{name} {scheme:?}: GPU SAH {s_gpu} vs CPU {s_cpu}");
        assert!((stats.final_sah - s_gpu).abs() <= 1e-3 * s_gpu, "{name}: the SAH the GPU reported is its tree's");
    }
}

#[test]
fn random_triangles_match_the_cpu_optimiser() {
    let mut rng = common::rng(21);
    let tris = common::random_triangles(20_000, 0.05, &mut rng);
    compare("random 20k", &tris.iter().map(Triangle::aabb).collect::<Vec<_>>());
}

#[test]
fn bunny_matches_the_cpu_optimiser() {
    let Some(mesh) = common::shared_model("bunny.obj") else { return };
    compare("bunny", &mesh.triangles().iter().map(Triangle::aabb).collect::<Vec<_>>());
}

/// At scales where f32 areas overflow (2^66) or underflow (2^-66), the GPU search rescales by a
/// power of two as the CPU's does, so it still lowers the SAH and stays within 2% of the CPU.
/// Without that, every decrease at 2^66 is NaN and nothing moves.
#[test]
fn random_triangles_at_extreme_scales() {
    let mut rng = common::rng(22);
    let tris = common::random_triangles(5_000, 0.05, &mut rng);
    for scale in [2f32.powi(66), 2f32.powi(-66)] {
        let prims: Vec<Aabb> = tris.iter().map(Triangle::aabb).map(|b| b.scaled(scale)).collect();
        compare(&format!("random 5k x{scale:e}"), &prims);
    }
}

/// The device's search is the CPU's node by node, its bound on visits included
/// (`SEARCH_MAX_VISITS`, the CPU's `MAX_VISITS`). On a pile of triangles in one square no box
/// prunes another, so many searches stop at the bound; a device search with another bound, or
/// none, finds other outputs there. Near-ties may go either way (the device may fuse
/// arithmetic), so a few nodes may differ, by a decrease within a part in 10^4.
#[test]
fn search_matches_the_cpu_node_by_node_on_a_pile() {
    let name = "pile of 4000 triangles";
    let Some(ctx) = gpu_or_skip(name) else { return };
    let mut rng = common::rng(23);
    let prims: Vec<Aabb> = (0..4000)
        .map(|_| {
            let mut corner = || glam::Vec3::new(rng.random(), rng.random(), 0.0);
            Triangle::new(corner(), corner(), corner()).aabb()
        })
        .collect();
    let bvh = lbvh::build(&prims);
    let gpu = gpu_prbvh::search_on_device(ctx, &bvh).unwrap_or_else(|e| panic!("{name}: {e}"));
    let (mut other_output, mut worst) = (0, 0.0f32);
    for (input, &(gpu_out, gpu_d)) in gpu.iter().enumerate().skip(2) {
        let (out, d) = prbvh::find_best_output(&bvh, input as u32);
        if gpu_out != out {
            other_output += 1;
            worst = worst.max((gpu_d - d).abs() / d.max(gpu_d));
        }
    }
    eprintln!(
        "{name}: {other_output} of {} searches found another output (largest difference {worst:e})",
        bvh.nodes.len() - 2
    );
    assert!(worst <= 1e-4, "{name}: a device search found a decrease {worst:e} away from the CPU's");
    assert!(other_output * 1000 <= bvh.nodes.len(), "{name}: {other_output} searches found another output");
}

/// Where every box is a point, the SAH is the nodes' weights alone, on the device as on the CPU
/// (the device divided by the root's zero area: NaN).
#[test]
fn a_point_sized_scene_has_the_cpus_sah() {
    let name = "five triangles at one point";
    let Some(ctx) = gpu_or_skip(name) else { return };
    let prims = vec![Aabb::from_point(glam::Vec3::ONE); 5];
    let input = lbvh::build(&prims);
    let config = PrbvhConfig { collapse: None, ..Default::default() };
    let (gpu, stats) =
        gpu_prbvh::optimize(ctx, &input, &config, LockScheme::Portable32).unwrap_or_else(|e| panic!("{name}: {e}"));
    validate(&gpu, &prims).unwrap_or_else(|e| panic!("{name}: invalid tree: {e}"));
    assert_eq!(sah_cost(&input), 3.0 * 4.0 + 2.0 * 5.0);
    assert_eq!(stats.initial_sah, sah_cost(&input), "{name}");
    assert_eq!(stats.final_sah, sah_cost(&gpu), "{name}");
}
