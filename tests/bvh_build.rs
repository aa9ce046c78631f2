//! Every builder's output passes validate() on edge cases, on large random input, on degenerate
//! triangles (where its closest hits also agree with brute force) and on the shared meshes;
//! validate() itself rejects broken trees.

use crate::common;

use arbor::bvh::build::prbvh::PrbvhConfig;
use arbor::bvh::build::{BaseBuilder, Builder};
use arbor::bvh::{
    self, Bvh, BvhNode, CollapseConfig, INVALID_INDEX, MeshBvh, ValidationError, brute_force_closest,
    build::binned_sah, build::lbvh, build::ploc, collapse_leaves, refit_sequential, sah_cost, validate,
};
use arbor::geometry::{Aabb, Triangle};
use bytemuck::Zeroable;
use common::*;
use glam::Vec3;
use rayon::prelude::*;

/// Builds with every builder, with and without leaf collapse, validates each, and returns the
/// LBVH.
fn build_all_and_validate(prims: &[Aabb]) -> Bvh {
    let lbvh = lbvh::build(prims);
    let binned = binned_sah::build(prims, &Default::default());
    let ploc = ploc::build(prims, &Default::default());
    let ploc1 = ploc::build(prims, &ploc::PlocConfig { radius: 1 });
    for (name, tree) in [("lbvh", &lbvh), ("binned-sah", &binned), ("ploc", &ploc), ("ploc-1", &ploc1)] {
        let stats = validate(tree, prims).unwrap_or_else(|e| panic!("{name}: {e}"));
        if !prims.is_empty() {
            assert_eq!(stats.leaf_count, prims.len(), "{name}: one primitive per leaf");
            assert_eq!(stats.node_count, 2 * prims.len() - 1, "{name}");
        }
        let collapsed = collapse_leaves(tree, &CollapseConfig::default());
        let cstats = validate(&collapsed, prims).unwrap_or_else(|e| panic!("{name} collapsed: {e}"));
        assert!(cstats.max_leaf_size <= CollapseConfig::default().max_leaf_size.max(1));
        let (before, after) = (sah_cost(tree), sah_cost(&collapsed));
        assert!(after <= before * (1.0 + 1e-9), "{name}: collapse raised SAH {before} -> {after}");
    }
    lbvh
}

#[test]
fn empty_input_gives_an_empty_tree() {
    let bvh = build_all_and_validate(&[]);
    assert!(bvh.is_empty() && bvh.prim_ids.is_empty());
    assert_eq!(validate(&bvh, &[]).unwrap().depth, 0);
    assert_eq!(sah_cost(&bvh), 0.0);
}

#[test]
fn one_and_two_primitives() {
    let tris = random_triangles(2, 0.1, &mut rng(1));
    let one = build_all_and_validate(&aabbs(&tris[..1]));
    assert_eq!(validate(&one, &aabbs(&tris[..1])).unwrap().depth, 1);
    let two = build_all_and_validate(&aabbs(&tris));
    assert_eq!(validate(&two, &aabbs(&tris)).unwrap().depth, 2);
}

#[test]
fn identical_centroids() {
    // Boxes of different sizes around one point: every Morton code ties. Extents are multiples
    // of 1/64 so that every box centre is exactly `c`.
    let mut r = rng(2);
    let c = Vec3::new(0.5, -2.0, 7.0);
    let prims: Vec<Aabb> = (0..1000)
        .map(|_| {
            let e = (unit_vec3(&mut r) * 64.0).floor() / 64.0;
            Aabb::new(c - e, c + e)
        })
        .collect();
    assert!(prims.iter().all(|b| b.center() == c));
    let bvh = build_all_and_validate(&prims);
    // The index tie-break splits equal keys evenly: depth is log2(1000) rounded up, plus 1.
    assert_eq!(validate(&bvh, &prims).unwrap().depth, 11);
}

#[test]
fn zero_area_triangles() {
    let mut r = rng(3);
    let mut tris = Vec::new();
    for _ in 0..500 {
        let (a, b) = (unit_vec3(&mut r), unit_vec3(&mut r));
        tris.push(Triangle::new(a, b, a.lerp(b, 0.25))); // collinear
        tris.push(Triangle::new(a, a, a)); // a point
        tris.push(Triangle::new(a, a, b)); // repeated vertex
    }
    build_all_and_validate(&aabbs(&tris));
}

#[test]
fn duplicate_triangles() {
    let base = random_triangles(300, 0.05, &mut rng(4));
    let tris: Vec<Triangle> = base.iter().cycle().take(base.len() * 4).copied().collect();
    build_all_and_validate(&aabbs(&tris));
}

#[test]
fn a_million_random_triangles() {
    let tris = random_triangles(1_000_000, 0.01, &mut rng(5));
    let prims = aabbs(&tris);
    let bvh = lbvh::build(&prims);
    let stats = validate(&bvh, &prims).unwrap();
    assert_eq!(stats.leaf_count, 1_000_000);
    assert!(stats.depth < 64, "LBVH of uniform points should be shallow, got depth {}", stats.depth);
    eprintln!("10^6 random triangles: LBVH depth {}, SAH {:.2}", stats.depth, sah_cost(&bvh));
    let collapsed = collapse_leaves(&bvh, &CollapseConfig::default());
    validate(&collapsed, &prims).unwrap();
}

/// Also prints each mesh's SAH (cT = 3, cI = 2) per builder, leaf-1 and after collapse:
/// `cargo test --test tests every_shared_mesh -- --nocapture`.
#[test]
fn every_shared_mesh() {
    for (name, mesh) in all_shared_models() {
        let prims = aabbs(&mesh.triangles());
        build_all_and_validate(&prims);
        for (builder, tree) in [
            ("lbvh", lbvh::build(&prims)),
            ("binned-sah", binned_sah::build(&prims, &Default::default())),
            ("ploc", ploc::build(&prims, &Default::default())),
        ] {
            let stats = validate(&tree, &prims).unwrap();
            let collapsed = collapse_leaves(&tree, &CollapseConfig::default());
            eprintln!(
                "{name}: {} triangles, {builder}: depth {}, SAH leaf-1 {:.2}, after collapse {:.2}",
                prims.len(),
                stats.depth,
                sah_cost(&tree),
                sah_cost(&collapsed)
            );
        }
    }
}

#[test]
fn lbvh_does_not_depend_on_thread_count() {
    let prims = aabbs(&random_triangles(200_000, 0.02, &mut rng(6)));
    let build_with = |threads| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| lbvh::build(&prims))
    };
    let one = build_with(1);
    assert_eq!(one, build_with(2));
    assert_eq!(one, build_with(5));
}

#[test]
fn ploc_does_not_depend_on_thread_count() {
    let prims = aabbs(&random_triangles(50_000, 0.02, &mut rng(16)));
    let build_with = |threads| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| ploc::build(&prims, &Default::default()))
    };
    let one = build_with(1);
    assert_eq!(one, build_with(2));
    assert_eq!(one, build_with(3));
}

#[test]
fn parallel_refit_equals_sequential_refit() {
    let prims = aabbs(&random_triangles(100_000, 0.02, &mut rng(7)));
    let mut a = lbvh::build(&prims);
    // Move every primitive, then refit both ways.
    let moved: Vec<Aabb> = prims.iter().map(|b| Aabb::new(b.min * 2.0, b.max * 2.0 + 0.01)).collect();
    let mut b = a.clone();
    bvh::refit(&mut a, &moved);
    refit_sequential(&mut b, &moved);
    assert_eq!(a, b);
    validate(&a, &moved).unwrap();
}

/// A valid three-node tree to break in each of the ways validate() must notice.
fn small_tree() -> (Bvh, Vec<Aabb>) {
    let prims = vec![Aabb::new(Vec3::ZERO, Vec3::ONE), Aabb::new(Vec3::splat(2.0), Vec3::splat(3.0))];
    let bvh = Bvh {
        nodes: vec![
            BvhNode::internal(prims[0].union(prims[1]), 2),
            BvhNode::zeroed(),
            BvhNode::leaf(prims[0], 0, 1),
            BvhNode::leaf(prims[1], 1, 1),
        ]
        .into(),
        parents: vec![INVALID_INDEX, INVALID_INDEX, 0, 0],
        prim_ids: vec![0, 1],
    };
    (bvh, prims)
}

#[test]
fn validate_rejects_broken_trees() {
    let (good, prims) = small_tree();
    assert!(validate(&good, &prims).is_ok());

    let mut t = good.clone();
    t.parents[3] = 2;
    assert!(matches!(validate(&t, &prims), Err(ValidationError::ParentMismatch { child: 3, .. })));

    let mut t = good.clone();
    t.nodes[0].aabb_max.x += 1.0; // encloses, but not tightly
    assert!(matches!(validate(&t, &prims), Err(ValidationError::BoxNotTight { node: 0, .. })));

    let mut t = good.clone();
    t.nodes[2].aabb_min.y += 0.5; // no longer encloses its primitive (nor is the root's union)
    assert!(matches!(validate(&t, &prims), Err(ValidationError::BoxNotTight { .. })));

    let mut t = good.clone();
    t.prim_ids = vec![0, 0];
    t.nodes[3].set_aabb(prims[0]);
    t.nodes[0].set_aabb(prims[0]);
    assert!(matches!(validate(&t, &prims), Err(ValidationError::PrimCount { prim: 0, count: 2 })));

    // A cycle: node 3 becomes internal with children 2 and 3 (itself).
    let mut t = good.clone();
    t.nodes[3] = BvhNode::internal(t.nodes[3].aabb(), 2);
    t.parents = vec![INVALID_INDEX, INVALID_INDEX, 3, 3];
    assert!(validate(&t, &prims).is_err());

    let mut t = good.clone();
    t.nodes[1].prim_count = 1;
    assert!(matches!(validate(&t, &prims), Err(ValidationError::BadPadding)));

    // Children must be a pair at an even index.
    let mut t = good.clone();
    t.nodes[0].first = 1;
    assert!(matches!(validate(&t, &prims), Err(ValidationError::ChildOutOfRange { node: 0, child: 1 })));

    let mut t = good.clone();
    t.parents[0] = 0;
    assert!(matches!(validate(&t, &prims), Err(ValidationError::RootHasParent(0))));

    let mut t = good.clone();
    t.nodes.push(BvhNode::leaf(prims[0], 0, 1));
    t.parents.push(0);
    assert!(matches!(validate(&t, &prims), Err(ValidationError::Unreachable(1))));
}

#[test]
fn a_reused_builder_equals_fresh_builds() {
    // Large, then small, then large again: stale scratch or output state would show.
    let mut builder = lbvh::LbvhBuilder::default();
    let mut out = Bvh::default();
    for (n, seed) in [(50_000, 8), (3, 9), (1, 10), (20_000, 11), (0, 12), (50_000, 13)] {
        let prims = aabbs(&random_triangles(n, 0.02, &mut rng(seed)));
        builder.build_into(&prims, &mut out);
        assert_eq!(out, lbvh::build(&prims), "n = {n}");
        validate(&out, &prims).unwrap();
    }
}

#[test]
fn every_named_builder_gives_a_valid_tree() {
    use arbor::bvh::build::Builder;
    let mut r = rng(14);
    let inputs =
        [random_triangles(1, 0.1, &mut r), random_triangles(2, 0.1, &mut r), random_triangles(5000, 0.05, &mut r)];
    for tris in &inputs {
        let prims = aabbs(tris);
        for name in Builder::names() {
            let builder: Builder = name.parse().unwrap();
            let built = builder.build(tris, &prims, &Default::default());
            let stats = validate(&built.bvh, &prims).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(stats.leaf_count, tris.len(), "{name}: one primitive per leaf");
        }
    }
}

/// For every builder name: the tree over [`degenerate_triangles`] passes `validate`, and so
/// does its leaf collapse; the collapsed tree, traced as a `MeshBvh`, finds the same closest hit
/// as brute force over all triangles on 20000 rays (the same triangle, or t within 1e-6
/// relative; both miss alike). An external (obvhs) builder that panics is reported and skipped.
#[test]
fn degenerate_triangles_for_every_builder() {
    let tris = degenerate_triangles(11);
    let aabbs = aabbs(&tris);
    let rays = degenerate_rays(&tris, 20_000, 12);
    let expected: Vec<_> = rays.par_iter().map(|r| brute_force_closest(&tris, r, f32::INFINITY)).collect();
    let hits = expected.iter().filter(|h| h.is_some()).count();
    eprintln!("degenerate: {} triangles, {hits} of {} rays hit", tris.len(), rays.len());
    assert!(hits > rays.len() / 3, "the rays must hit the triangles often");
    let mut failures = Vec::new();
    for name in Builder::names() {
        let b: Builder = name.parse().unwrap();
        let config = PrbvhConfig { collapse: None, ..Default::default() };
        let built = std::panic::catch_unwind(|| b.build(&tris, &aabbs, &config).bvh);
        let bvh = match built {
            Ok(bvh) => bvh,
            Err(_) if matches!(b.base, BaseBuilder::External(_)) => {
                eprintln!("REPORT: external builder {name} panics on degenerate triangles; skipped");
                continue;
            }
            Err(_) => {
                failures.push(format!("{name}: the build panics"));
                continue;
            }
        };
        if let Err(e) = validate(&bvh, &aabbs) {
            failures.push(format!("{name}: invalid tree: {e}"));
            continue;
        }
        let collapsed = collapse_leaves(&bvh, &CollapseConfig::default());
        if let Err(e) = validate(&collapsed, &aabbs) {
            failures.push(format!("{name}: invalid tree after leaf collapse: {e}"));
            continue;
        }
        let mesh = MeshBvh::new(collapsed, &tris, common::tracing());
        let mismatches: Vec<String> = rays
            .par_iter()
            .zip(&expected)
            .filter_map(|(ray, want)| {
                let got = mesh.closest_hit(ray, f32::INFINITY);
                let same = match (got, want) {
                    (None, None) => true,
                    (Some(g), Some(w)) => g.prim_id == w.prim_id || (g.t - w.t).abs() <= 1e-6 * w.t,
                    _ => false,
                };
                (!same).then(|| format!("{ray:?}: {got:?}, brute force {want:?}"))
            })
            .collect();
        if let Some(first) = mismatches.first() {
            failures.push(format!("{name}: {} rays disagree with brute force, e.g. {first}", mismatches.len()));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
