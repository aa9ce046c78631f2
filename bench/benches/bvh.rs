//! BVH benchmarks.
//!
//! - `lbvh_build/N`: LBVH over N random triangles, in triangles/s, from scratch (every build
//!   faults in fresh memory), and `lbvh_build_warm/N` with an [`LbvhBuilder`] building into the
//!   same tree each time, as an animation rebuilding every frame would.
//! - `trace_dragon/{primary,diffuse}/BUILDER`: closest-hit traversal on the Stanford dragon
//!   (`../shared/models/dragon_res2.obj`), in rays/s, for primary rays from a camera that frames
//!   the mesh and diffuse rays bounced off their hits; over LBVH and over a top-down binned-SAH
//!   tree, each after leaf collapse and with one triangle per leaf; `*-ordered` reads the
//!   collapsed trees' triangles stored in leaf order ([`MeshBvh`], binary tree), and
//!   `lbvh-wide4-PATH` / `lbvh-wide8-PATH` the wide forms `render` traces, on every SIMD path the
//!   CPU has (`scalar`, `sse4`, `avx2`, `neon`).
//! - `kernels/PATH/{boxes-8,boxes-4,triangle-packet}`: the SIMD kernels alone on each path: one
//!   wide node's box test and one packet of four triangles, per ray; `wide_collapse/dragon`: the
//!   collapse into the wide forms (`wide4`, `wide8`) beside the LBVH build it comes from.
//! - `refit/parallel` against `refit/sequential`: what the unsafe parallel bottom-up pass buys.
//! - `prbvh_vs_obvhs/dragon`: parallel reinsertion with its default settings on the dragon's
//!   LBVH (`arbor-prbvh`, the optimisation alone, on a fresh copy of the tree each time; and
//!   `arbor-lbvh+prbvh`, build and optimisation), against obvhs's slowest preset
//!   (`very_slow_build`, PLOC and reinsertion, one primitive per leaf, no pre-splits, as
//!   `bvh-bench` runs it), the baseline for the optimisation time.
//! - Baselines measured in the same run, on the same input: `build_vs_obvhs/{dragon,1000000}`
//!   (our LBVH against the obvhs crate's PLOC with search radius 1 and one primitive per leaf,
//!   its `fastest_build` preset), and `trace_dragon/*/obvhs-very-fast` (obvhs's traversal of
//!   its `very_fast_build` tree, leaves up to 8, on the same rays).
//!
//! Run: `cargo bench -p arbor-bench --bench bvh` (all threads; set `RAYON_NUM_THREADS` to change).

use std::path::Path;

use arbor::bvh::build::lbvh::LbvhBuilder;
use arbor::bvh::build::prbvh::{self, PrbvhConfig};
use arbor::bvh::{
    self, Bvh, CollapseConfig, MeshBvh, SimdPath, TraceLayout, Tracing, build::binned_sah, build::lbvh, collapse_leaves,
};
use arbor::geometry::{Aabb, Ray, Triangle, TriangleMesh};
use arbor_bench::rays as bench_rays;
use criterion::{BatchSize, BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use glam::Vec3;
use rayon::prelude::*;
use std::hint::black_box;

/// Random triangles in the unit cube (a fixed LCG, so every run builds the same input).
fn random_triangles(n: usize) -> Vec<Triangle> {
    let mut state = 0x853c_49e6_748f_ea9bu64;
    let mut next = move || {
        state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    (0..n)
        .map(|_| {
            let c = Vec3::new(next(), next(), next());
            let mut v = || c + (Vec3::new(next(), next(), next()) - 0.5) * 0.01;
            Triangle::new(v(), v(), v())
        })
        .collect()
}

fn lbvh_build(c: &mut Criterion) {
    let mut g = c.benchmark_group("lbvh_build");
    g.sample_size(10);
    for n in [100_000usize, 1_000_000] {
        let prims: Vec<Aabb> = random_triangles(n).iter().map(Triangle::aabb).collect();
        g.throughput(Throughput::Elements(n as u64));
        g.bench_with_input(BenchmarkId::from_parameter(n), &prims, |b, prims| b.iter(|| lbvh::build(prims)));
    }
    g.finish();
    let mut g = c.benchmark_group("lbvh_build_warm");
    g.sample_size(10);
    for n in [100_000usize, 1_000_000] {
        let prims: Vec<Aabb> = random_triangles(n).iter().map(Triangle::aabb).collect();
        let (mut builder, mut out) = (LbvhBuilder::default(), Bvh::default());
        g.throughput(Throughput::Elements(n as u64));
        g.bench_with_input(BenchmarkId::from_parameter(n), &prims, |b, prims| {
            b.iter(|| builder.build_into(prims, &mut out))
        });
    }
    g.finish();
}

fn refit(c: &mut Criterion) {
    let prims: Vec<Aabb> = random_triangles(1_000_000).iter().map(Triangle::aabb).collect();
    let mut tree = lbvh::build(&prims);
    let mut g = c.benchmark_group("refit");
    g.sample_size(10);
    g.throughput(Throughput::Elements(prims.len() as u64));
    g.bench_function("parallel", |b| b.iter(|| bvh::refit(&mut tree, &prims)));
    g.bench_function("sequential", |b| b.iter(|| bvh::refit_sequential(&mut tree, &prims)));
    g.finish();
}

fn obvhs_build(tris: &[obvhs::triangle::Triangle], params: obvhs::BvhBuildParams) -> obvhs::bvh2::Bvh2 {
    let mut core_time = std::time::Duration::ZERO;
    obvhs::bvh2::builder::build_bvh2_from_tris(tris, params, &mut core_time)
}

fn dragon() -> Option<TriangleMesh> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/models/dragon_res2.obj");
    let mesh = TriangleMesh::load_obj(&path).ok();
    if mesh.is_none() {
        eprintln!("skipping the dragon benchmarks: {} not found", path.display());
    }
    mesh
}

fn build_vs_obvhs(c: &mut Criterion) {
    let mut inputs = vec![("1000000".to_string(), random_triangles(1_000_000))];
    if let Some(mesh) = dragon() {
        inputs.insert(0, ("dragon".to_string(), mesh.triangles()));
    }
    for (name, tris) in inputs {
        let prims: Vec<Aabb> = tris.iter().map(Triangle::aabb).collect();
        let theirs = arbor_bench::peers::to_obvhs_triangles(&tris);
        let mut g = c.benchmark_group(format!("build_vs_obvhs/{name}"));
        g.sample_size(10);
        g.throughput(Throughput::Elements(tris.len() as u64));
        // Both from triangles, both computing the boxes, both allocating their output.
        g.bench_function("arbor-lbvh", |b| {
            b.iter(|| lbvh::build(&tris.iter().map(Triangle::aabb).collect::<Vec<_>>()))
        });
        let (mut builder, mut out) = (LbvhBuilder::default(), Bvh::default());
        g.bench_function("arbor-lbvh-warm", |b| b.iter(|| builder.build_into(&prims, &mut out)));
        g.bench_function("obvhs-ploc1", |b| b.iter(|| obvhs_build(&theirs, obvhs::BvhBuildParams::fastest_build())));
        g.finish();
    }
}

fn prbvh_vs_obvhs(c: &mut Criterion) {
    let Some(mesh) = dragon() else { return };
    let tris = mesh.triangles();
    let prims: Vec<Aabb> = tris.iter().map(Triangle::aabb).collect();
    let theirs = arbor_bench::peers::to_obvhs_triangles(&tris);
    let config = PrbvhConfig { collapse: None, ..Default::default() };
    let leaf1 = lbvh::build(&prims);
    let mut g = c.benchmark_group("prbvh_vs_obvhs/dragon");
    g.sample_size(10);
    g.throughput(Throughput::Elements(tris.len() as u64));
    g.bench_function("arbor-prbvh", |b| {
        b.iter_batched_ref(|| leaf1.clone(), |tree| prbvh::optimize(tree, &config), BatchSize::LargeInput)
    });
    g.bench_function("arbor-lbvh+prbvh", |b| {
        b.iter(|| {
            let mut tree = lbvh::build(&prims);
            prbvh::optimize(&mut tree, &config);
            tree
        })
    });
    let params = arbor_bench::peers::peer_params("very-slow");
    g.bench_function("obvhs-very-slow", |b| b.iter(|| obvhs_build(&theirs, params)));
    g.finish();
}

fn trace(bvh: &Bvh, tris: &[Triangle], rays: &[Ray]) -> usize {
    rays.par_iter().with_min_len(64).filter(|r| bvh.closest_hit_triangles(tris, r, f32::INFINITY).is_some()).count()
}

fn trace_ordered(mesh: &MeshBvh, rays: &[Ray]) -> usize {
    rays.par_iter().with_min_len(64).filter(|r| mesh.closest_hit(r, f32::INFINITY).is_some()).count()
}

fn trace_obvhs(bvh: &obvhs::bvh2::Bvh2, tris: &[obvhs::triangle::Triangle], rays: &[obvhs::ray::Ray]) -> usize {
    rays.par_iter()
        .with_min_len(64)
        .filter(|r| {
            let mut hit = obvhs::ray::RayHit::none();
            bvh.ray_traverse(**r, &mut hit, |ray, id| tris[bvh.primitive_indices[id] as usize].intersect(ray))
        })
        .count()
}

fn trace_dragon(c: &mut Criterion) {
    let Some(mesh) = dragon() else { return };
    let tris = mesh.triangles();
    let prims: Vec<Aabb> = tris.iter().map(Triangle::aabb).collect();
    let cfg = CollapseConfig::default();
    let lbvh1 = lbvh::build(&prims);
    let binned1 = binned_sah::build(&prims, &Default::default());
    let trees = [
        ("lbvh", collapse_leaves(&lbvh1, &cfg)),
        ("binned-sah", collapse_leaves(&binned1, &cfg)),
        ("lbvh-leaf1", lbvh1),
        ("binned-sah-leaf1", binned1),
    ];
    let primary = bench_rays::primary_rays(&mesh.bounds(), 512, 512);
    // Bounced off the binned tree's hits; every tree then traces the same rays.
    let diffuse = bench_rays::diffuse_rays(&trees[1].1, &tris, &primary);
    // The leaf-ordered binary tree, and the wide forms on every SIMD path this CPU has.
    let mut ordered = vec![(
        "lbvh-ordered".to_string(),
        MeshBvh::new(trees[0].1.clone(), &tris, Tracing { layout: TraceLayout::Binary, simd: SimdPath::Scalar }),
    )];
    for simd in SimdPath::available() {
        for layout in [TraceLayout::Wide4, TraceLayout::Wide8] {
            let name = format!("lbvh-{}-{}", layout.name(), simd.name());
            ordered.push((name, MeshBvh::new(trees[0].1.clone(), &tris, Tracing { layout, simd })));
        }
    }
    let theirs = arbor_bench::peers::to_obvhs_triangles(&tris);
    let theirs_bvh = obvhs_build(&theirs, obvhs::BvhBuildParams::very_fast_build());
    for (kind, rays) in [("primary", &primary), ("diffuse", &diffuse)] {
        let mut g = c.benchmark_group(format!("trace_dragon/{kind}"));
        g.sample_size(10);
        g.throughput(Throughput::Elements(rays.len() as u64));
        for (name, tree) in &trees {
            g.bench_function(*name, |b| b.iter(|| black_box(trace(tree, &tris, rays))));
        }
        for (name, mesh) in &ordered {
            g.bench_function(name.as_str(), |b| b.iter(|| black_box(trace_ordered(mesh, rays))));
        }
        let their_rays: Vec<obvhs::ray::Ray> =
            rays.iter().map(|r| obvhs::ray::Ray::new(r.origin.into(), r.dir.into(), 0.0, f32::INFINITY)).collect();
        g.bench_function("obvhs-very-fast", |b| b.iter(|| black_box(trace_obvhs(&theirs_bvh, &theirs, &their_rays))));
        g.finish();
    }
}

/// The SIMD kernels alone, per path: one 8-wide and one 4-wide node's box test and one packet
/// of four triangles against 4096 prepared rays (the dragon's nodes and packets, its primary
/// rays), and the wide collapse.
fn kernels(c: &mut Criterion) {
    use arbor::bvh::trace::simd::{BoxRay, PacketRay, test_boxes, test_triangles};
    use arbor::bvh::trace::wide_mesh::WideMesh;
    use arbor::geometry::WatertightRay;
    let Some(mesh) = dragon() else { return };
    let tris = mesh.triangles();
    let prims: Vec<Aabb> = tris.iter().map(Triangle::aabb).collect();
    let bvh = collapse_leaves(&lbvh::build(&prims), &CollapseConfig::default());
    let ordered: Vec<Triangle> = bvh.prim_ids.iter().map(|&p| tris[p as usize]).collect();
    let w8 = WideMesh::<8>::from_binary(&bvh, &ordered, SimdPath::Scalar);
    let w4 = WideMesh::<4>::from_binary(&bvh, &ordered, SimdPath::Scalar);
    let rays = bench_rays::primary_rays(&mesh.bounds(), 64, 64);
    let box_rays: Vec<BoxRay> = rays.iter().map(|r| BoxRay::new(r.inv())).collect();
    let packet_rays: Vec<PacketRay> = rays.iter().map(|r| PacketRay::new(WatertightRay::new(r))).collect();
    let packets = &w8.packets()[..64];
    for simd in SimdPath::available() {
        let mut g = c.benchmark_group(format!("kernels/{}", simd.name()));
        g.throughput(Throughput::Elements(rays.len() as u64));
        g.bench_function("boxes-8", |b| {
            let mut dist = [0.0; 8];
            b.iter(|| {
                box_rays.iter().map(|r| test_boxes(simd, &w8.nodes()[0], r, f32::INFINITY, &mut dist)).sum::<u32>()
            })
        });
        g.bench_function("boxes-4", |b| {
            let mut dist = [0.0; 4];
            b.iter(|| {
                box_rays.iter().map(|r| test_boxes(simd, &w4.nodes()[0], r, f32::INFINITY, &mut dist)).sum::<u32>()
            })
        });
        g.bench_function("triangle-packet", |b| {
            b.iter(|| {
                packet_rays
                    .iter()
                    .zip(packets.iter().cycle())
                    .map(|(r, p)| test_triangles(simd, p, r, f32::INFINITY).check)
                    .sum::<u32>()
            })
        });
        g.finish();
    }
    let mut g = c.benchmark_group("wide_collapse/dragon");
    g.sample_size(10);
    g.bench_function("lbvh-build", |b| b.iter(|| lbvh::build(&prims)));
    g.bench_function("wide8", |b| b.iter(|| WideMesh::<8>::from_binary(&bvh, &ordered, SimdPath::Avx2)));
    g.bench_function("wide4", |b| b.iter(|| WideMesh::<4>::from_binary(&bvh, &ordered, SimdPath::Sse4)));
    g.finish();
}

criterion_group!(benches, lbvh_build, build_vs_obvhs, refit, prbvh_vs_obvhs, trace_dragon, kernels);
criterion_main!(benches);
