//! The ray sets trace speed is measured with, as in Meister & Bittner 2018, Table 1: primary rays
//! from a camera that frames the mesh, and diffuse rays bounced once off the primary hits.
//!
//! Deterministic (one random stream per ray index, not a thread-dependent RNG), so every builder
//! and every run traces the same rays.

use glam::Vec3;
use rayon::prelude::*;

use arbor::bvh::{Bvh, hit_point_and_normal};
use arbor::geometry::{Aabb, Ray, Triangle, spawn_ray};
use arbor::render::rng::Rng;
use arbor::render::sampling::{Frame, cosine_hemisphere};

/// Pinhole camera rays through pixel centres, `width * height` of them, looking at the centre
/// of `bounds` from the front (+z), a little right and above, with the field of view narrowed until the
/// projected corners of `bounds` just fill the frame (2% margin).
pub fn primary_rays(bounds: &Aabb, width: u32, height: u32) -> Vec<Ray> {
    let center = bounds.center();
    let radius = (extent_length(bounds) * 0.5).max(f32::MIN_POSITIVE);
    let back = Vec3::new(0.1, 0.2, 1.0).normalize();
    // Far enough back that the bounding sphere is in front of the camera.
    let eye = center + back * radius * 2.5;
    // `-back`, and not `(center - eye).normalize()`, whose squared length overflows for scenes
    // beyond about 10^19.
    let forward = -back;
    let right = forward.cross(Vec3::Y).normalize();
    let up = right.cross(forward);
    let aspect = width as f32 / height as f32;
    let mut half_h = f32::MIN_POSITIVE;
    for k in 0..8 {
        let corner = bounds.corner(k);
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
    diffuse_rays_with(primary, |ray| {
        let hit = bvh.closest_hit_triangles(triangles, ray, f32::INFINITY)?;
        Some(hit_point_and_normal(triangles, &hit))
    })
}

/// [`diffuse_rays`] for any geometry: `hit(ray)` gives the closest hit's point, its rounding
/// error bound and the unit geometric normal.
pub fn diffuse_rays_with(primary: &[Ray], hit: impl Fn(&Ray) -> Option<(Vec3, Vec3, Vec3)> + Sync) -> Vec<Ray> {
    primary
        .par_iter()
        .enumerate()
        .filter_map(|(i, ray)| {
            let (p, err, n) = hit(ray)?;
            let n = if n.dot(ray.dir) > 0.0 { -n } else { n };
            let u = Rng::for_sample(0, i as u64, 0).next_vec2();
            Some(spawn_ray(p, err, n, Frame::from_normal(n).to_world(cosine_hemisphere(u)).normalize()))
        })
        .collect()
}

/// A point light for shadow rays: above, right and in front of `bounds`, three bounding radii
/// from its centre.
pub fn light_position(bounds: &Aabb) -> Vec3 {
    bounds.center() + Vec3::new(0.3, 1.0, 0.6).normalize() * extent_length(bounds) * 1.5
}

/// One shadow ray from each primary hit towards `light`, spawned with the robust offset; the
/// light sits at `t = 1`, so trace with `t_max = 1`.
pub fn shadow_rays(bvh: &Bvh, triangles: &[Triangle], primary: &[Ray], light: Vec3) -> Vec<Ray> {
    primary
        .par_iter()
        .filter_map(|ray| {
            let hit = bvh.closest_hit_triangles(triangles, ray, f32::INFINITY)?;
            let (p, err, n) = hit_point_and_normal(triangles, &hit);
            let from = spawn_ray(p, err, n, light - p).origin;
            Some(Ray::new(from, light - from))
        })
        .collect()
}

/// The length of the box's diagonal, computed on the extent scaled by a power of two, so that
/// it neither overflows (beyond about 10^19) nor underflows (below about 10^-19).
fn extent_length(bounds: &Aabb) -> f32 {
    let scale = bounds.area_scale();
    (bounds.extent() * scale).length() / scale
}
