//! Helpers shared by the integration tests: seeded random geometry and rays, and the shared test
//! meshes.
#![allow(dead_code)]

pub mod analytic;

use std::path::PathBuf;

use arbor::geometry::{Aabb, Ray, Triangle, TriangleMesh};
use glam::Vec3;
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

pub type Rng = Pcg64Mcg;

/// Runs `cmd` with its standard output closed before it writes (as `| head` does once it has
/// read enough): the tools must neither panic nor stop their work and files.
pub fn output_with_stdout_closed(cmd: &mut std::process::Command) -> std::process::Output {
    use std::process::Stdio;
    let mut child = cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    drop(child.stdout.take());
    child.wait_with_output().unwrap()
}

pub fn rng(seed: u64) -> Rng {
    Pcg64Mcg::seed_from_u64(seed)
}

pub fn unit_vec3(rng: &mut Rng) -> Vec3 {
    Vec3::new(rng.random(), rng.random(), rng.random())
}

/// A uniformly random direction.
pub fn random_dir(rng: &mut Rng) -> Vec3 {
    let z: f32 = rng.random_range(-1.0..1.0);
    let phi: f32 = rng.random_range(0.0..std::f32::consts::TAU);
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// `n` triangles with vertices near random points of the unit cube, edges up to `size` long.
pub fn random_triangles(n: usize, size: f32, rng: &mut Rng) -> Vec<Triangle> {
    (0..n)
        .map(|_| {
            let c = unit_vec3(rng);
            let mut v = || c + (unit_vec3(rng) - 0.5) * size;
            Triangle::new(v(), v(), v())
        })
        .collect()
}

pub fn aabbs(triangles: &[Triangle]) -> Vec<Aabb> {
    triangles.iter().map(Triangle::aabb).collect()
}

/// Rays aimed at `bounds`: half from a sphere around it towards random points inside it, a
/// quarter from inside it in random directions, a quarter aimed exactly at random `targets`.
pub fn rays_at(bounds: &Aabb, targets: &[Vec3], n: usize, rng: &mut Rng) -> Vec<Ray> {
    let center = bounds.center();
    let radius = bounds.extent().length().max(1e-6);
    let inside = |rng: &mut Rng| bounds.min + unit_vec3(rng) * bounds.extent();
    (0..n)
        .map(|i| match i % 4 {
            0 | 1 => {
                let o = center + random_dir(rng) * radius * 1.5;
                Ray::new(o, inside(rng) - o)
            }
            2 => Ray::new(inside(rng), random_dir(rng)),
            _ => {
                let o = center + random_dir(rng) * radius * 1.5;
                let t = targets[rng.random_range(0..targets.len())];
                Ray::new(o, t - o)
            }
        })
        .collect()
}

pub fn models_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/models")
}

/// Loads a mesh from `../shared/models`. Where the folder is missing the test is skipped with a
/// printed reason, except under `CI=true`, where that is a failure.
pub fn shared_model(name: &str) -> Option<TriangleMesh> {
    let path = shared_model_path(name)?;
    Some(TriangleMesh::load_obj(&path).unwrap_or_else(|e| panic!("{e}")))
}

/// The path of a mesh in `../shared/models`, or `None` (a skip, or a failure under `CI=true`) as
/// for [`shared_model`]: for tests that load it through a scene.
pub fn shared_model_path(name: &str) -> Option<PathBuf> {
    let path = models_dir().join(name);
    if !path.exists() {
        let ci = std::env::var("CI").is_ok_and(|v| v == "true");
        assert!(!ci, "{} is missing; CI must have ../shared/models", path.display());
        eprintln!("skipping: {} not found (the shared test meshes live beside the repository)", path.display());
        return None;
    }
    Some(path)
}

/// Every `.obj` in `../shared/models`, by file name.
pub fn all_shared_models() -> Vec<(String, TriangleMesh)> {
    let Ok(dir) = std::fs::read_dir(models_dir()) else {
        shared_model("bunny.obj");
        return vec![];
    };
    let mut names: Vec<String> =
        dir.filter_map(|e| e.ok()?.file_name().into_string().ok()).filter(|n| n.ends_with(".obj")).collect();
    names.sort();
    names.into_iter().filter_map(|n| shared_model(&n).map(|m| (n, m))).collect()
}

/// The shared GPU context, or `None` with the reason printed where there is no adapter; under
/// `CI=true` a missing adapter fails the test instead (CI installs lavapipe).
pub fn gpu_or_skip(test: &str) -> Option<&'static arbor::gpu::GpuContext> {
    match arbor::gpu::GpuContext::shared() {
        Ok(ctx) => Some(ctx),
        Err(e) if std::env::var("CI").is_ok_and(|v| v == "true") => panic!("{test}: no GPU under CI=true: {e}"),
        Err(e) => {
            eprintln!("skipping {test}: {e}");
            None
        }
    }
}

/// The two-sided normal p-value of `z`.
pub fn two_sided_p(z: f64) -> f64 {
    erfc(z.abs() / std::f64::consts::SQRT_2)
}

/// The |z| whose two-sided p-value is `p`, by bisection (p falls monotonically with |z|).
pub fn z_for_two_sided_p(p: f64) -> f64 {
    let (mut lo, mut hi) = (0.0f64, 40.0f64);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if two_sided_p(mid) > p { lo = mid } else { hi = mid }
    }
    0.5 * (lo + hi)
}

/// Complementary error function, relative error below 1.2e-7 everywhere (Press et al.,
/// Numerical Recipes, 2nd ed., §6.2, `erfcc`: a Chebyshev fit).
pub fn erfc(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.5 * x.abs());
    let poly = [
        -1.265_512_23,
        1.000_023_68,
        0.374_091_96,
        0.096_784_18,
        -0.186_288_06,
        0.278_868_07,
        -1.135_203_98,
        1.488_515_87,
        -0.822_152_23,
        0.170_872_77,
    ]
    .iter()
    .rev()
    .fold(0.0, |acc, c| c + t * acc);
    let r = t * (-x * x + poly).exp();
    if x >= 0.0 { r } else { 2.0 - r }
}
