//! Closest-hit and any-hit traversal against brute force: the same primitive id, and the same t,
//! u and v to the bit, for every builder, on random and real meshes, through the binary trees
//! and the 4- and 8-wide trees collapsed from them.

use crate::common;

use arbor::bvh::trace::wide::{Bvh4, Bvh8, WideBvh};
use arbor::bvh::{
    Bvh, CollapseConfig, Hit, MeshBvh, brute_force_any, brute_force_closest, build::binned_sah, build::lbvh,
    collapse_leaves,
};
use arbor::geometry::{Ray, Triangle};
use common::*;
use rand::RngExt;
use rayon::prelude::*;

fn trees(tris: &[Triangle]) -> Vec<(&'static str, Bvh)> {
    let prims = aabbs(tris);
    let l = lbvh::build(&prims);
    let b = binned_sah::build(&prims, &Default::default());
    let cfg = CollapseConfig::default();
    vec![
        ("lbvh", l.clone()),
        ("lbvh+collapse", collapse_leaves(&l, &cfg)),
        ("binned-sah", b.clone()),
        ("binned-sah+collapse", collapse_leaves(&b, &cfg)),
    ]
}

fn same_hit(a: Option<Hit>, b: Option<Hit>) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some(a), Some(b)) => {
            a.prim_id == b.prim_id
                && a.t.to_bits() == b.t.to_bits()
                && a.u.to_bits() == b.u.to_bits()
                && a.v.to_bits() == b.v.to_bits()
        }
        _ => false,
    }
}

/// What brute force says for one ray: the closest hit, and with `t_max` at half its distance
/// the closest and any hit.
struct Expected {
    full: Option<Hit>,
    half: Option<Hit>,
    any_half: bool,
}

/// Checks closest hits (unbounded and bounded) and any hits of every tree against brute force;
/// returns how many rays hit.
fn check(name: &str, tris: &[Triangle], rays: &[Ray]) -> usize {
    let expected: Vec<Expected> = rays
        .par_iter()
        .map(|r| {
            let full = brute_force_closest(tris, r, f32::INFINITY);
            let half_t = full.map_or(f32::INFINITY, |h| h.t * 0.5);
            Expected { full, half: brute_force_closest(tris, r, half_t), any_half: brute_force_any(tris, r, half_t) }
        })
        .collect();
    for (tree_name, bvh) in trees(tris) {
        let bad: Vec<usize> = rays
            .par_iter()
            .zip(&expected)
            .enumerate()
            .filter(|(_, (r, e))| {
                let closest = bvh.closest_hit_triangles(tris, r, f32::INFINITY);
                let Some(full) = e.full else {
                    return closest.is_some() || bvh.any_hit_triangles(tris, r, f32::INFINITY);
                };
                let half_t = full.t * 0.5;
                !same_hit(closest, e.full)
                    || !same_hit(bvh.closest_hit_triangles(tris, r, full.t), e.full)
                    || !bvh.any_hit_triangles(tris, r, full.t)
                    || !same_hit(bvh.closest_hit_triangles(tris, r, half_t), e.half)
                    || bvh.any_hit_triangles(tris, r, half_t) != e.any_half
            })
            .map(|(i, _)| i)
            .collect();
        // The same queries through the leaf-ordered triangles, in every form and on every SIMD
        // path this CPU has.
        let prims = aabbs(tris);
        for tracing in tracings() {
            let mesh_bvh = MeshBvh::new(bvh.clone(), tris, tracing);
            mesh_bvh.validate_wide(&prims).unwrap_or_else(|e| panic!("{name}/{tree_name}, {tracing}: {e}"));
            let bad_ordered = rays
                .par_iter()
                .zip(&expected)
                .filter(|(r, e)| {
                    let Some(full) = e.full else {
                        return mesh_bvh.closest_hit(r, f32::INFINITY).is_some() || mesh_bvh.any_hit(r, f32::INFINITY);
                    };
                    let half_t = full.t * 0.5;
                    !same_hit(mesh_bvh.closest_hit(r, f32::INFINITY), e.full)
                        || !same_hit(mesh_bvh.closest_hit(r, full.t), e.full)
                        || !mesh_bvh.any_hit(r, full.t)
                        || !same_hit(mesh_bvh.closest_hit(r, half_t), e.half)
                        || mesh_bvh.any_hit(r, half_t) != e.any_half
                })
                .count();
            assert_eq!(bad_ordered, 0, "{name}/{tree_name}, {tracing}: traversal differs from brute force");
        }
        let (w4, w8) = (Bvh4::from_binary(&bvh), Bvh8::from_binary(&bvh));
        w4.validate(&prims).unwrap_or_else(|e| panic!("{name}/{tree_name}, 4 wide: {e}"));
        w8.validate(&prims).unwrap_or_else(|e| panic!("{name}/{tree_name}, 8 wide: {e}"));
        assert_eq!(wide_mismatches(&w4, tris, rays, &expected), 0, "{name}/{tree_name}: 4-wide traversal differs");
        assert_eq!(wide_mismatches(&w8, tris, rays, &expected), 0, "{name}/{tree_name}: 8-wide traversal differs");
        if let Some(&i) = bad.first() {
            let r = &rays[i];
            panic!(
                "{name}/{tree_name}: {} of {} rays differ from brute force; first: {r:?}: bvh {:?}, brute {:?}",
                bad.len(),
                rays.len(),
                bvh.closest_hit_triangles(tris, r, f32::INFINITY),
                expected[i].full,
            );
        }
    }
    expected.iter().filter(|e| e.full.is_some()).count()
}

/// Rays on which the wide tree's closest hits (unbounded and bounded) or any hits differ from
/// brute force.
fn wide_mismatches<const N: usize>(w: &WideBvh<N>, tris: &[Triangle], rays: &[Ray], expected: &[Expected]) -> usize {
    rays.par_iter()
        .zip(expected)
        .filter(|(r, e)| {
            let Some(full) = e.full else {
                return w.closest_hit_triangles(tris, r, f32::INFINITY).is_some()
                    || w.any_hit_triangles(tris, r, f32::INFINITY);
            };
            let half_t = full.t * 0.5;
            !same_hit(w.closest_hit_triangles(tris, r, f32::INFINITY), e.full)
                || !same_hit(w.closest_hit_triangles(tris, r, full.t), e.full)
                || !w.any_hit_triangles(tris, r, full.t)
                || !same_hit(w.closest_hit_triangles(tris, r, half_t), e.half)
                || w.any_hit_triangles(tris, r, half_t) != e.any_half
        })
        .count()
}

/// `triangles` random triangles (seeded by `seed`) and `rays` rays aimed at their vertices.
fn random_scene(seed: u64, triangles: usize, rays: usize) -> (Vec<Triangle>, Vec<Ray>) {
    let mut r = rng(seed);
    let tris = random_triangles(triangles, 0.05, &mut r);
    let targets: Vec<_> = tris.iter().flat_map(|t| [t.v0, t.v1, t.v2]).collect();
    let bounds = tris.iter().fold(arbor::geometry::Aabb::EMPTY, |b, t| b.union(t.aabb()));
    let rays = rays_at(&bounds, &targets, rays, &mut r);
    (tris, rays)
}

#[test]
fn random_triangles_match_brute_force() {
    let (tris, rays) = random_scene(10, 20_000, 4000);
    let hits = check("random", &tris, &rays);
    assert!(hits > 2000, "the rays should mostly hit: {hits}");
}

/// The same triangles and rays scaled by 2^80 and 2^-80, where f32 edge functions, normals and
/// lengths overflow or underflow: traversal still equals brute force, and the rays hit the same
/// triangles as at unit scale (all but rays within rounding of an edge, which at unit scale
/// are decided in f32 and here in f64). Direction lengths scale too, as for shadow rays.
#[test]
fn extreme_scales_hit_what_unit_scale_hits() {
    let (tris, rays) = random_scene(12, 5000, 2000);
    let ids = |tris: &[Triangle], rays: &[Ray]| -> Vec<Option<u32>> {
        rays.par_iter().map(|ray| brute_force_closest(tris, ray, f32::INFINITY).map(|h| h.prim_id)).collect()
    };
    let unit = ids(&tris, &rays);
    let unit_hits = unit.iter().flatten().count();
    assert!(unit_hits > 1000, "{unit_hits}");
    for s in [2f32.powi(80), 2f32.powi(-80)] {
        let scaled: Vec<Triangle> = tris.iter().map(|t| Triangle::new(t.v0 * s, t.v1 * s, t.v2 * s)).collect();
        let scaled_rays: Vec<Ray> = rays.iter().map(|ray| Ray::new(ray.origin * s, ray.dir * s)).collect();
        let hits = check(&format!("x{s:e}"), &scaled, &scaled_rays);
        let differ = ids(&scaled, &scaled_rays).iter().zip(&unit).filter(|(a, b)| a != b).count();
        assert!(
            hits.abs_diff(unit_hits) <= 2 && differ <= 2,
            "x{s:e}: {hits} hits ({unit_hits} at unit scale), {differ} differ"
        );
    }
}

#[test]
fn duplicates_resolve_to_the_lowest_id() {
    let mut r = rng(11);
    let base = random_triangles(2000, 0.1, &mut r);
    // Every triangle four times: ties everywhere.
    let tris: Vec<Triangle> = base.iter().cycle().take(base.len() * 4).copied().collect();
    let targets: Vec<_> = base.iter().map(|t| (t.v0 + t.v1 + t.v2) / 3.0).collect();
    let bounds = tris.iter().fold(arbor::geometry::Aabb::EMPTY, |b, t| b.union(t.aabb()));
    let rays = rays_at(&bounds, &targets, 4000, &mut r);
    check("duplicates", &tris, &rays);
    for ray in &rays {
        if let Some(h) = brute_force_closest(&tris, ray, f32::INFINITY) {
            assert!((h.prim_id as usize) < base.len(), "a tie went to a later copy");
        }
    }
}

#[test]
fn shared_meshes_match_brute_force() {
    for (name, mesh) in all_shared_models() {
        let tris = mesh.triangles();
        let mut r = rng(12);
        // Brute force costs |tris| per ray: keep the product near 4 * 10^8.
        let n = (400_000_000 / tris.len()).clamp(500, 8000);
        let rays = rays_at(&mesh.bounds(), &mesh.positions, n, &mut r);
        let hits = check(&name, &tris, &rays);
        eprintln!("{name}: {n} rays, {hits} hits, all equal to brute force");
    }
}

#[test]
fn axis_aligned_walls_and_grazing_rays() {
    // Two boxes' worth of axis-aligned quads, some coplanar: the triangles lie in their leaf
    // boxes' faces, where box entry and triangle t are computed by different formulas.
    let mut mesh = arbor::geometry::TriangleMesh::default();
    for k in 0..20 {
        let s = 0.25 * k as f32;
        let quad = |o: glam::Vec3, u: glam::Vec3, v: glam::Vec3| arbor::geometry::TriangleMesh {
            positions: vec![o, o + u, o + u + v, o + v],
            indices: vec![[0, 1, 2], [0, 2, 3]],
            ..Default::default()
        };
        mesh.append(&quad(glam::Vec3::new(s, 0.0, 0.0), glam::Vec3::Y, glam::Vec3::Z));
        mesh.append(&quad(glam::Vec3::new(0.0, s * 0.5, 0.0), glam::Vec3::X * 5.0, glam::Vec3::Z));
        mesh.append(&quad(glam::Vec3::new(0.0, 0.0, 0.0), glam::Vec3::X * 5.0, glam::Vec3::Y * (0.1 * k as f32 + 0.1)));
    }
    let tris = mesh.triangles();
    let mut r = rng(13);
    let mut rays = rays_at(&mesh.bounds(), &mesh.positions, 4000, &mut r);
    // Rays parallel to the walls, starting inside their planes.
    for _ in 0..1000 {
        let o = glam::Vec3::new(0.25 * r.random_range(0..20) as f32, r.random(), r.random());
        rays.push(Ray::new(o, glam::Vec3::new(0.0, r.random_range(-1.0..1.0), r.random_range(-1.0..1.0))));
    }
    check("axis-aligned", &tris, &rays);
}
