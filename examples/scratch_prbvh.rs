use arbor::bvh::{lbvh, prbvh};
use arbor::geometry::{Triangle, TriangleMesh};
fn main() {
    let mesh = TriangleMesh::load_obj("../shared/models/dragon_res2.obj").unwrap();
    let prims: Vec<_> = mesh.triangles().iter().map(Triangle::aabb).collect();
    for eps in [0.1, 0.0] {
        let mut b = lbvh::build(&prims);
        let cfg = prbvh::PrbvhConfig { mu: 9, epsilon: eps, max_iterations: 300, collapse: None, ..Default::default() };
        let s = prbvh::optimize(&mut b, &cfg);
        println!(
            "eps {eps}: {:.2} -> {:.2}, {} iters, {:.0} ms",
            s.initial_sah,
            s.final_sah,
            s.iterations.len(),
            s.optimize_time.as_secs_f64() * 1e3
        );
        for (k, i) in s.iterations.iter().enumerate().filter(|(k, _)| k % 5 == 0 || *k < 12) {
            println!(
                "  {k}: mu {} searched {} cand {} reins {} sah {:.2} t {:.0}ms",
                i.mu,
                i.searched,
                i.candidates,
                i.reinsertions,
                i.sah,
                i.elapsed.as_secs_f64() * 1e3
            );
        }
    }
}
