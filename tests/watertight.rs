//! Robustness without scene-scale epsilons.
//!
//! - Leaks: rays from inside closed meshes, aimed exactly at their vertices and at points on
//!   their shared edges, must all hit (a closed surface cannot be left without crossing it).
//!   At least 10^6 rays per placement of the meshes: as built, translated to 10^5 from the
//!   origin, and scaled by 10^-3 and 10^4.
//! - Self-intersection: rays spawned from hit points with the ray-origin offset
//!   (`geometry::spawn_ray`) never hit their own triangle, and rays leaving a convex mesh never hit
//!   it again, also where they leave within 10^-5 of an edge, almost tangent to the surface.

use crate::common;

use arbor::bvh::{
    Bvh, CollapseConfig, Hit, INVALID_INDEX, MeshBvh, TraceLayout, Tracing, build::lbvh, collapse_leaves,
    hit_point_and_normal,
};
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
    let bvh = MeshBvh::new(tree(&tris), &tris, tracing);
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

/// The 32 × 64 UV sphere placed by `m`: its triangles, their tree, that tree in every traced
/// form on every SIMD path, and the sphere's centre.
fn placed_sphere(m: Mat4) -> (Vec<Triangle>, Bvh, Vec<MeshBvh>, Vec3) {
    let tris = TriangleMesh::uv_sphere(Vec3::ZERO, 1.0, 32, 64).transformed(m).triangles();
    let bvh = tree(&tris);
    let traced = tracings().into_iter().map(|t| MeshBvh::new(bvh.clone(), &tris, t)).collect();
    (tris, bvh, traced, m.transform_point3(Vec3::ZERO))
}

/// Rays spawned off a convex sphere: outward ones never hit it again, inward ones never hit the
/// triangle they start on, in every traced form on every SIMD path.
#[test]
fn spawned_rays_do_not_self_intersect() {
    for (placement, m) in placements() {
        let (tris, bvh, traced, center) = placed_sphere(m);
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

/// Rays spawned off a convex sphere as the renderer spawns them (offset, skipping the triangle
/// they leave), half of them within 10^-5 of an edge (where the offset clears the spawn
/// triangle's plane but not its neighbour's) and within 10^-2 radians of tangent, the rest
/// anywhere on the triangle in cosine-distributed directions. Outward ones never hit the sphere
/// again; inward ones hit it from inside, never a face from its front. In every traced form on
/// every SIMD path, closest and any hit. The same rays without the offset do go wrong (counted,
/// so the test can fail).
#[test]
fn spawns_off_a_convex_mesh_leave_or_hit_it_from_inside() {
    let mut unoffset = 0;
    for (placement, m) in placements() {
        let (tris, _, traced, center) = placed_sphere(m);
        let outward = |k: u32| {
            let t = &tris[k as usize];
            let n = t.unit_normal();
            if n.dot(t.v0 - center) < 0.0 { -n } else { n }
        };
        // (spawn triangle, ray, the ray from the unoffset point, leaves outwards)
        let rays: Vec<(u32, Ray, Ray, bool)> = (0..200_000u64)
            .into_par_iter()
            .flat_map_iter(|i| {
                let mut r = rng(1000 + i);
                let prim = r.random_range(0..tris.len() as u32);
                // Barycentrics (u, v) of v1, v2: along one edge, `inside` of the triangle's
                // extent away from it.
                let grazing = i % 2 == 0;
                let along: f32 = r.random_range(0.02..0.98);
                let inside: f32 =
                    if grazing { 10f32.powf(r.random_range(-12.0..-5.0)) } else { r.random_range(0.0..0.5) };
                let (u, v) = match r.random_range(0..3) {
                    0 => (along * (1.0 - inside), inside),                         // near edge v0-v1
                    1 => (inside, along * (1.0 - inside)),                         // near edge v0-v2
                    _ => (along * (1.0 - inside), (1.0 - along) * (1.0 - inside)), // near edge v1-v2
                };
                let (p, err, _) = hit_point_and_normal(&tris, &Hit { t: 1.0, prim_id: prim, u, v });
                let n = outward(prim);
                let (t1, t2) = n.any_orthonormal_pair();
                let phi: f32 = r.random_range(0.0..std::f32::consts::TAU);
                let tangent = t1 * phi.cos() + t2 * phi.sin();
                // Tangent to within `lift` radians; cosine-distributed when not grazing.
                let lift = if grazing {
                    10f32.powf(r.random_range(-8.0..-2.0))
                } else {
                    let cos = r.random_range(0.0f32..1.0).sqrt();
                    cos / (1.0 - cos * cos).sqrt()
                };
                // Rounding can tip the flattest directions across the plane: those are dropped.
                [true, false].into_iter().filter_map(move |out| {
                    let dir = (tangent + n * if out { lift } else { -lift }).normalize();
                    (dir.dot(n) != 0.0 && (dir.dot(n) > 0.0) == out)
                        .then(|| (prim, spawn_ray(p, err, n, dir), Ray::new(p, dir), out))
                })
            })
            .collect();
        assert!(rays.len() > 370_000, "{placement}: only {} rays", rays.len());
        let wrong = |t: &MeshBvh, ray: &Ray, skip: u32, out: bool| {
            let closest = t.closest_hit_skipping(ray, f32::INFINITY, skip);
            let any = t.any_hit_skipping(ray, f32::INFINITY, skip);
            if out {
                closest.is_some() || any
            } else {
                !any || closest.is_none_or(|h| ray.dir.dot(outward(h.prim_id)) <= 0.0)
            }
        };
        for t in &traced {
            let n = rays.par_iter().filter(|&&(prim, ref ray, _, out)| wrong(t, ray, prim, out)).count();
            assert_eq!(n, 0, "{placement}, {}: {n} of {} rays hit the sphere wrongly", t.tracing(), rays.len());
        }
        unoffset += rays.par_iter().filter(|&(_, _, ray, out)| wrong(&traced[0], ray, INVALID_INDEX, *out)).count();
    }
    assert!(unoffset > 1000, "only {unoffset} wrong hits without the offset: the test cannot fail");
}

/// Without the offset, the same rays do hit their own surface: `spawned_rays_do_not_self_intersect`
/// can fail.
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
