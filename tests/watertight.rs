//! Robustness without scene-scale epsilons.
//!
//! - Leaks: rays from inside closed meshes, aimed exactly at their vertices and at points on
//!   their shared edges, must all hit (a closed surface cannot be left without crossing it).
//!   At least 10^6 rays per placement of the meshes: as built, translated to 10^5 from the
//!   origin, and scaled by 10^-3 and 10^4.
//! - Self-intersection: rays spawned from hit points with the ray-origin offset
//!   (`geometry::spawn_ray`) never hit their own triangle, and rays leaving a convex mesh never hit
//!   it again.

use crate::common;

use arbor::bvh::{Bvh, CollapseConfig, MeshBvh, TraceLayout, Tracing, collapse_leaves, hit_point_and_normal, lbvh};
use arbor::geometry::{Ray, Triangle, TriangleMesh, spawn_ray};
use common::*;
use glam::{Mat4, Vec3};
use rand::RngExt;
use rayon::prelude::*;

/// A closed mesh and a way to draw points strictly inside it.
struct Closed {
    name: &'static str,
    mesh: TriangleMesh,
    interior: fn(&mut Rng) -> Vec3,
}

fn closed_meshes() -> Vec<Closed> {
    vec![
        // Poles where 128 triangles meet in one vertex, and long thin triangles near them.
        Closed {
            name: "uv-sphere",
            mesh: TriangleMesh::uv_sphere(Vec3::ZERO, 1.0, 64, 128),
            interior: |r| random_dir(r) * r.random_range(0.0..0.8f32),
        },
        // Not convex, not star-shaped: rays from inside the tube cross the hole.
        Closed {
            name: "torus",
            mesh: TriangleMesh::torus(Vec3::ZERO, 2.0, 0.6, 96, 48),
            interior: |r| {
                let phi: f32 = r.random_range(0.0..std::f32::consts::TAU);
                Vec3::new(phi.cos(), 0.0, phi.sin()) * 2.0 + random_dir(r) * r.random_range(0.0..0.4f32)
            },
        },
    ]
}

fn placements() -> Vec<(&'static str, Mat4)> {
    vec![
        ("as built", Mat4::IDENTITY),
        ("translated 1e5", Mat4::from_translation(Vec3::new(1e5, -1e5, 1e5))),
        ("scaled 1e-3", Mat4::from_scale(Vec3::splat(1e-3))),
        ("scaled 1e4", Mat4::from_scale(Vec3::splat(1e4))),
    ]
}

fn tree(tris: &[Triangle]) -> Bvh {
    // Collapsed, so leaves of several triangles are exercised too.
    collapse_leaves(&lbvh::build(&aabbs(tris)), &CollapseConfig::default())
}

/// Fires `n` rays from interior points at vertices and edge points; returns the misses.
fn count_leaks(c: &Closed, world_from_object: Mat4, n: usize, seed: u64, tracing: Tracing) -> usize {
    let mesh = c.mesh.transformed(world_from_object);
    let tris = mesh.triangles();
    let bvh = MeshBvh::with_tracing(tree(&tris), &tris, tracing);
    let edges: Vec<(Vec3, Vec3)> = mesh
        .indices
        .iter()
        .flat_map(|t| (0..3).map(move |k| (t[k], t[(k + 1) % 3])))
        .map(|(a, b)| (mesh.positions[a as usize], mesh.positions[b as usize]))
        .collect();
    (0..n)
        .into_par_iter()
        .chunks(4096)
        .map(|chunk| {
            let mut r = rng(seed ^ chunk[0] as u64);
            chunk
                .iter()
                .filter(|&&i| {
                    let origin = world_from_object.transform_point3((c.interior)(&mut r));
                    let target = if i % 2 == 0 {
                        mesh.positions[r.random_range(0..mesh.positions.len())]
                    } else {
                        let (a, b) = edges[r.random_range(0..edges.len())];
                        a.lerp(b, r.random())
                    };
                    let ray = Ray::new(origin, target - origin);
                    bvh.closest_hit(&ray, f32::INFINITY).is_none()
                })
                .count()
        })
        .sum()
}

/// 2^20 rays per placement through the binary tree, and 2^17 through each wide form on each
/// SIMD path this CPU has.
#[test]
fn no_leaks_through_edges_and_vertices() {
    const RAYS: usize = 1 << 20;
    let mut report = Vec::new();
    for (placement, m) in placements() {
        let mut leaks = 0;
        for tracing in tracings() {
            let rays = if tracing.layout == TraceLayout::Binary { RAYS } else { RAYS / 8 };
            for (k, c) in closed_meshes().iter().enumerate() {
                let l = count_leaks(c, m, rays / 2, 0x5eed + k as u64, tracing);
                report.push(format!("{} {placement}, {tracing}: {l} leaks in {} rays", c.name, rays / 2));
                leaks += l;
            }
        }
        assert_eq!(leaks, 0, "{report:#?}");
    }
    eprintln!("{report:#?}");
}

/// The leak test must be able to fail: a mesh with one triangle removed leaks.
#[test]
fn leak_test_detects_a_hole() {
    let mut c = closed_meshes().remove(0);
    c.mesh.indices.remove(0); // a hole at the north pole
    // Aim every ray at the pole vertex: those that pass through the hole leak.
    let tris = c.mesh.triangles();
    let bvh = tree(&tris);
    let mut r = rng(1);
    let leaks = (0..10_000)
        .filter(|_| {
            let o = (c.interior)(&mut r);
            let target = c.mesh.positions[0].lerp(c.mesh.positions[1], 0.01).lerp(c.mesh.positions[2], 0.01);
            bvh.closest_hit_triangles(&tris, &Ray::new(o, target - o), f32::INFINITY).is_none()
        })
        .count();
    assert!(leaks > 0, "a mesh with a hole must leak");
}

/// Rays spawned off a convex sphere: outward ones never hit it again, inward ones never hit the
/// triangle they start on, in every traced form on every SIMD path.
#[test]
fn spawned_rays_do_not_self_intersect() {
    let sphere = TriangleMesh::uv_sphere(Vec3::ZERO, 1.0, 32, 64);
    for (placement, m) in placements() {
        let mesh = sphere.transformed(m);
        let tris = mesh.triangles();
        let bvh = tree(&tris);
        let traced: Vec<MeshBvh> =
            tracings().into_iter().map(|t| MeshBvh::with_tracing(bvh.clone(), &tris, t)).collect();
        let center = m.transform_point3(Vec3::ZERO);
        let radius = m.transform_vector3(Vec3::X).length();
        let mut r = rng(2);
        let (mut outward_hits, mut self_hits, mut spawned) = (0, 0, 0);
        for _ in 0..100_000 {
            let o = center + random_dir(&mut r) * radius * 3.0;
            let target = center + random_dir(&mut r) * radius * 0.5;
            let Some(hit) = bvh.closest_hit_triangles(&tris, &Ray::new(o, target - o), f32::INFINITY) else { continue };
            let (p, err, n) = hit_point_and_normal(&tris, &hit);
            let n = if n.dot(p - center) < 0.0 { -n } else { n }; // outward
            let mut dir = random_dir(&mut r);
            if dir.dot(n) < 0.0 {
                dir = -dir;
            }
            spawned += 1;
            let (out, inward) = (spawn_ray(p, err, n, dir), spawn_ray(p, err, n, -dir));
            if bvh.closest_hit_triangles(&tris, &out, f32::INFINITY).is_some()
                || traced.iter().any(|t| t.closest_hit(&out, f32::INFINITY).is_some())
            {
                outward_hits += 1;
            }
            let mut inward_hits = traced.iter().map(|t| t.closest_hit(&inward, f32::INFINITY));
            if let Some(h) = bvh.closest_hit_triangles(&tris, &inward, f32::INFINITY) {
                self_hits += (h.prim_id == hit.prim_id || inward_hits.any(|t| t != Some(h))) as u32;
            }
        }
        assert!(spawned > 90_000, "{placement}: only {spawned} primary hits");
        assert_eq!((outward_hits, self_hits), (0, 0), "{placement}: outward re-hits, self-hits");
    }
}

/// Without the offset, the same rays do hit their own surface: the test above can fail.
#[test]
fn unoffset_rays_do_self_intersect() {
    let mesh = TriangleMesh::uv_sphere(Vec3::ZERO, 1.0, 32, 64).transformed(Mat4::from_scale(Vec3::splat(1e4)));
    let tris = mesh.triangles();
    let bvh = tree(&tris);
    let mut r = rng(3);
    let mut self_hits = 0;
    for _ in 0..20_000 {
        let o = random_dir(&mut r) * 3e4;
        let Some(hit) = bvh.closest_hit_triangles(&tris, &Ray::new(o, -o + random_dir(&mut r) * 5e3), f32::INFINITY)
        else {
            continue;
        };
        let (p, _, n) = hit_point_and_normal(&tris, &hit);
        let n = if n.dot(p) < 0.0 { -n } else { n };
        let dir = (n + random_dir(&mut r) * 0.9).normalize();
        self_hits += bvh.closest_hit_triangles(&tris, &Ray::new(p, dir), f32::INFINITY).is_some() as u32;
    }
    assert!(self_hits > 100, "expected self-intersections without offsetting, got {self_hits}");
}
