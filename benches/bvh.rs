//! BVH benchmarks (issue "BVH core", section 7).
//!
//! - `lbvh_build/N`: LBVH over N random triangles, in triangles/s, from scratch (every build
//!   faults in fresh memory), and `lbvh_build_warm/N` with an [`LbvhBuilder`] building into the
//!   same tree each time, as an animation rebuilding every frame would.
//! - `trace_dragon/{primary,diffuse}/BUILDER`: closest-hit traversal on the Stanford dragon
//!   (`../shared/models/dragon_res2.obj`), in rays/s, for primary rays from a camera that frames
//!   the mesh and diffuse rays bounced off their hits; over LBVH and over a top-down binned-SAH
//!   tree, each after leaf collapse and with one triangle per leaf.
//! - `refit/parallel` against `refit/sequential`: what the unsafe parallel bottom-up pass buys.
//!
//! Run: `cargo bench --bench bvh` (all threads; set `RAYON_NUM_THREADS` to change).

use std::path::Path;

use arbor::bvh::lbvh::LbvhBuilder;
use arbor::bvh::{self, Bvh, CollapseConfig, bench_rays, binned_sah, collapse_leaves, lbvh};
use arbor::geometry::{Aabb, Ray, Triangle, TriangleMesh};
use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
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

fn trace(bvh: &Bvh, tris: &[Triangle], rays: &[Ray]) -> usize {
    rays.par_iter().with_min_len(64).filter(|r| bvh.closest_hit_triangles(tris, r, f32::INFINITY).is_some()).count()
}

fn trace_dragon(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/models/dragon_res2.obj");
    let Ok(mesh) = TriangleMesh::load_obj(&path) else {
        eprintln!("skipping trace_dragon: {} not found", path.display());
        return;
    };
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
    for (kind, rays) in [("primary", &primary), ("diffuse", &diffuse)] {
        let mut g = c.benchmark_group(format!("trace_dragon/{kind}"));
        g.sample_size(10);
        g.throughput(Throughput::Elements(rays.len() as u64));
        for (name, tree) in &trees {
            g.bench_function(*name, |b| b.iter(|| black_box(trace(tree, &tris, rays))));
        }
        g.finish();
    }
}

criterion_group!(benches, lbvh_build, refit, trace_dragon);
criterion_main!(benches);
