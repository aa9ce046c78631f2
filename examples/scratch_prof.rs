use arbor::bvh::{Bvh, lbvh};
use arbor::geometry::{Aabb, Triangle};
use glam::Vec3;
use std::time::Instant;
fn main() {
    let n: usize = std::env::args().nth(1).map_or(100_000, |s| s.parse().unwrap());
    let mut s = 1u64;
    let mut next = move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (s >> 40) as f32 / (1u64 << 24) as f32
    };
    let prims: Vec<Aabb> = (0..n)
        .map(|_| {
            let c = Vec3::new(next(), next(), next());
            Triangle::new(c, c + 0.01 * Vec3::X, c + 0.01 * Vec3::Y).aabb()
        })
        .collect();
    let mut b = lbvh::LbvhBuilder::default();
    let mut out = Bvh::default();
    let t = Instant::now();
    let iters = 20_000_000 / n;
    for _ in 0..iters {
        b.build_into(&prims, &mut out);
    }
    println!("{n}: {:.2} M tris/s warm", (n * iters) as f64 / t.elapsed().as_secs_f64() / 1e6);
}
