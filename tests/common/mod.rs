//! Helpers shared by the integration tests: seeded random geometry and rays, the shared test
//! meshes, and PLY and glTF files ([`ply`], [`gltf`]).
#![allow(dead_code)]

pub mod analytic;
pub mod gltf;
pub mod ply;
mod tools;

pub use tools::{gpu_or_skip, output_with_stdout_closed};

use std::path::PathBuf;

use arbor::geometry::{Aabb, Ray, Triangle, TriangleMesh};
use glam::Vec3;
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

pub type Rng = Pcg64Mcg;

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

/// A fresh temporary folder, one per call: tests run in parallel and may make the same scene.
pub fn temp_dir(name: &str) -> PathBuf {
    static CALLS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let call = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!("arbor-test-{name}-{}-{call}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Ordinary triangles mixed with every kind of degenerate one, all in the unit cube (some
/// reach a little outside): exactly collinear (axis-aligned) and nearly collinear (diagonal)
/// zero-area triangles, all three vertices equal, two vertices equal, needles 1 long and 1e-6
/// wide, five identical copies of one triangle, and 30 partially overlapping triangles in one
/// axis-aligned plane and 30 in one oblique plane (there rounding leaves them only nearly
/// coplanar).
pub fn degenerate_triangles(seed: u64) -> Vec<Triangle> {
    let mut r = rng(seed);
    let mut t = random_triangles(400, 0.1, &mut r);
    for _ in 0..50 {
        let a = unit_vec3(&mut r);
        let d = r.random_range(0.01..0.3f32);
        let axis = [Vec3::X, Vec3::Y, Vec3::Z][r.random_range(0..3usize)] * d;
        t.push(Triangle::new(a, a + axis, a + 2.0 * axis));
        let diag = (unit_vec3(&mut r) - 0.5) * d;
        t.push(Triangle::new(a, a + diag, a + diag * 0.37));
        t.push(Triangle::new(a, a, a));
        let b = unit_vec3(&mut r);
        t.push(Triangle::new(a, a, b));
        t.push(Triangle::new(b, a, b));
        let u = random_dir(&mut r);
        let v = u.any_orthonormal_vector() * 1e-6;
        t.push(Triangle::new(a - u * 0.5, a + u * 0.5, a + v));
    }
    let base = Triangle::new(Vec3::new(0.2, 0.2, 0.5), Vec3::new(0.8, 0.3, 0.5), Vec3::new(0.4, 0.9, 0.5));
    t.extend(std::iter::repeat_n(base, 5));
    let (o, e1, e2) = (Vec3::new(0.5, 0.1, 0.2), Vec3::new(0.6, 0.3, 0.5).normalize(), Vec3::new(-0.2, 0.9, 0.1));
    let e2 = (e2 - e1 * e1.dot(e2)).normalize();
    for _ in 0..30 {
        let c = Vec3::new(r.random_range(0.3..0.7), r.random_range(0.3..0.7), 0.5);
        let s = r.random_range(0.1..0.3f32);
        t.push(Triangle::new(c, c + Vec3::new(s, 0.0, 0.0), c + Vec3::new(0.0, s, 0.0)));
        let (p, q) = (r.random_range(0.0..0.4f32), r.random_range(0.0..0.4f32));
        let c = o + e1 * p + e2 * q;
        t.push(Triangle::new(c, c + e1 * s, c + e2 * s));
    }
    t
}

/// Rays for [`degenerate_triangles`]: those of `common::rays_at` (a quarter aimed exactly at
/// vertices), plus rays straight down onto the axis-aligned coplanar pile and along the
/// oblique plane's normal onto its pile, where hits tie.
pub fn degenerate_rays(tris: &[Triangle], n: usize, seed: u64) -> Vec<Ray> {
    let mut r = rng(seed);
    let bounds = tris.iter().fold(arbor::geometry::Aabb::EMPTY, |b, t| b.union(t.aabb()));
    let targets: Vec<Vec3> = tris.iter().flat_map(|t| [t.v0, t.v1, t.v2]).collect();
    let mut rays = rays_at(&bounds, &targets, n / 2, &mut r);
    let normal = Vec3::new(0.6, 0.3, 0.5).normalize().cross(Vec3::new(-0.2, 0.9, 0.1)).normalize();
    for k in 0..n - n / 2 {
        let p = Vec3::new(r.random_range(0.2..0.9), r.random_range(0.2..0.9), 2.0);
        if k % 2 == 0 {
            rays.push(Ray::new(p, Vec3::new(0.0, 0.0, -1.0)));
        } else {
            let target = Vec3::new(0.5, 0.1, 0.2) + (unit_vec3(&mut r) - 0.5) * 0.6;
            rays.push(Ray::new(target + normal * 2.0, -normal));
        }
    }
    rays
}

/// Every way the CPU can trace a mesh on this machine: the binary tree, and the 4- and 8-wide
/// trees on each SIMD path the CPU has (the scalar one always), so that each test that compares
/// hits runs under every dispatch path.
pub fn tracings() -> Vec<arbor::bvh::Tracing> {
    use arbor::bvh::{SimdPath, TraceLayout, Tracing};
    let mut all = vec![Tracing { layout: TraceLayout::Binary, simd: SimdPath::Scalar }];
    for simd in SimdPath::available() {
        all.extend([TraceLayout::Wide4, TraceLayout::Wide8].map(|layout| Tracing { layout, simd }));
    }
    all
}

/// The trace form the tests build their trees with: as `ARBOR_SIMD` says (CI renders the golden
/// images once per SIMD path), else the best this CPU has. Read here, at the tests' edge, as
/// `render` reads it at its own.
pub fn tracing() -> arbor::bvh::Tracing {
    arbor::bvh::Tracing::from_env(None).expect("ARBOR_SIMD names a SIMD path this CPU has")
}
