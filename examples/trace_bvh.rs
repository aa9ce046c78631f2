//! Builds a BVH over triangles and traces rays through it: Arbor's BVH as a library.
//!
//! `cargo run --release --example trace_bvh`

use arbor::bvh::build::Builder;
use arbor::bvh::{Tracing, brute_force_closest, sah_cost};
use arbor::geometry::{Ray, Triangle, procedural};
use arbor::glam::Vec3;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // A procedural city of about 100,000 triangles (any `Vec<Triangle>` will do).
    let triangles: Vec<Triangle> = procedural::city(100_000, 1).triangles();
    // LBVH (Karras 2012), optimised by parallel reinsertion (Meister & Bittner 2018), then the
    // leaf collapse; `Builder::names()` lists the others.
    let builder: Builder = "lbvh+prbvh".parse()?;
    let start = std::time::Instant::now();
    // Traced through the best form this CPU has (8-wide on AVX2), or on the path ARBOR_SIMD names.
    let bvh = builder.build_mesh(&triangles, Tracing::from_env(None)?);
    println!(
        "{} triangles, {builder} in {:.1} ms, SAH {:.2}",
        triangles.len(),
        start.elapsed().as_secs_f64() * 1e3,
        sah_cost(&bvh.bvh)
    );

    // Rays from above the city, looking down, on a 32 x 32 grid over its footprint.
    let bounds = triangles.iter().fold(arbor::geometry::Aabb::EMPTY, |b, t| b.union(t.aabb()));
    let (lo, hi) = (bounds.min, bounds.max);
    let mut hits = 0;
    for i in 0..32 * 32 {
        let (u, v) = ((i % 32) as f32 / 31.0, (i / 32) as f32 / 31.0);
        let origin = Vec3::new(lo.x + u * (hi.x - lo.x), hi.y + 1.0, lo.z + v * (hi.z - lo.z));
        let ray = Ray::new(origin, Vec3::NEG_Y);
        let hit = bvh.closest_hit(&ray, f32::INFINITY);
        // Traversal is exact: the same nearest distance as testing every triangle.
        let expected = brute_force_closest(&bvh.triangles, &ray, f32::INFINITY);
        assert_eq!(hit.map(|h| h.t), expected.map(|h| h.t));
        hits += usize::from(hit.is_some());
    }
    println!("{hits} of {} rays hit the city, as brute force finds", 32 * 32);
    Ok(())
}
