//! The ray sets trace speed is measured with, as in Meister & Bittner 2018, Table 1: primary rays
//! from a camera that frames the mesh, and diffuse rays bounced once off the primary hits.
//!
//! Deterministic (a hash of the ray index, not a thread-dependent RNG), so every builder and
//! every run traces the same rays.

use glam::Vec3;
use rayon::prelude::*;

use super::{Bvh, hit_point_and_normal};
use crate::geometry::{Aabb, Ray, Triangle, spawn_ray};

/// Pinhole camera rays through pixel centres, `width * height` of them, looking at the centre
/// of `bounds` from the front (+z), a little right and above, with the field of view narrowed until the
/// projected corners of `bounds` just fill the frame (2% margin).
pub fn primary_rays(bounds: &Aabb, width: u32, height: u32) -> Vec<Ray> {
    let center = bounds.center();
    let radius = (bounds.extent().length() * 0.5).max(f32::MIN_POSITIVE);
    let back = Vec3::new(0.1, 0.2, 1.0).normalize();
    // Far enough back that the bounding sphere is in front of the camera.
    let eye = center + back * radius * 2.5;
    let forward = (center - eye).normalize();
    let right = forward.cross(Vec3::Y).normalize();
    let up = right.cross(forward);
    let aspect = width as f32 / height as f32;
    let mut half_h = f32::MIN_POSITIVE;
    for k in 0..8 {
        let corner = Vec3::select(glam::BVec3::new(k & 1 != 0, k & 2 != 0, k & 4 != 0), bounds.max, bounds.min);
        let d = corner - eye;
        let depth = d.dot(forward);
        half_h = half_h.max((d.dot(up) / depth).abs()).max((d.dot(right) / depth).abs() / aspect);
    }
    half_h *= 1.02;
    let half_w = half_h * aspect;
    (0..width * height)
        .map(|i| {
            let (x, y) = (i % width, i / width);
            let sx = ((x as f32 + 0.5) / width as f32 * 2.0 - 1.0) * half_w;
            let sy = (1.0 - (y as f32 + 0.5) / height as f32 * 2.0) * half_h;
            Ray::new(eye, (forward + right * sx + up * sy).normalize())
        })
        .collect()
}

/// One cosine-distributed bounce off each primary hit, on the side the primary ray came from,
/// spawned with the robust offset. Primary rays that miss give no diffuse ray.
pub fn diffuse_rays(bvh: &Bvh, triangles: &[Triangle], primary: &[Ray]) -> Vec<Ray> {
    primary
        .par_iter()
        .enumerate()
        .filter_map(|(i, ray)| {
            let hit = bvh.closest_hit_triangles(triangles, ray, f32::INFINITY)?;
            let (p, n) = hit_point_and_normal(triangles, &hit);
            let n = if n.dot(ray.dir) > 0.0 { -n } else { n };
            let (u1, u2) = hash2(i as u32);
            Some(spawn_ray(p, n, cosine_direction(n, u1, u2)))
        })
        .collect()
}

/// A point light for shadow rays: above, right and in front of `bounds`, three bounding radii
/// from its centre.
pub fn light_position(bounds: &Aabb) -> Vec3 {
    bounds.center() + Vec3::new(0.3, 1.0, 0.6).normalize() * bounds.extent().length() * 1.5
}

/// One shadow ray from each primary hit towards `light`, spawned with the robust offset; the
/// light sits at `t = 1`, so trace with `t_max = 1`.
pub fn shadow_rays(bvh: &Bvh, triangles: &[Triangle], primary: &[Ray], light: Vec3) -> Vec<Ray> {
    primary
        .par_iter()
        .filter_map(|ray| {
            let hit = bvh.closest_hit_triangles(triangles, ray, f32::INFINITY)?;
            let (p, n) = hit_point_and_normal(triangles, &hit);
            let from = spawn_ray(p, n, light - p).origin;
            Some(Ray::new(from, light - from))
        })
        .collect()
}

/// A direction around unit `n` with density cos θ / π.
fn cosine_direction(n: Vec3, u1: f32, u2: f32) -> Vec3 {
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    let (t, b) = n.any_orthonormal_pair();
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - u1).max(0.0).sqrt()).normalize()
}

/// Two uniform numbers in [0, 1) from an index (PCG output permutation of an LCG step).
fn hash2(i: u32) -> (f32, f32) {
    let pcg = |v: u32| {
        let state = v.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
        let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
        (word >> 22) ^ word
    };
    let a = pcg(i);
    let b = pcg(a);
    ((a >> 8) as f32 / (1u32 << 24) as f32, (b >> 8) as f32 / (1u32 << 24) as f32)
}
