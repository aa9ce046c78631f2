//! Procedural meshes of any size with a fixed seed, for benchmarks beyond the shared models.
//!
//! - `hairball`: thin triangles along tangled strands inside a sphere (the paper's Hairball
//!   stress case: heavy overlap, no good split), with the same density at every size;
//! - `city`: a grid of boxes of random heights on a ground plane (architecture-like: many
//!   axis-aligned, coplanar faces);
//! - `subdivide`: a copy of a mesh with every triangle split into four until it is large enough.

use glam::Vec3;

use super::TriangleMesh;

/// A small deterministic generator (PCG32), so every run and platform makes the same mesh.
struct Pcg(u64);

impl Pcg {
    fn next_f32(&mut self) -> f32 {
        self.0 = self.0.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        let x = (((self.0 >> 18) ^ self.0) >> 27) as u32;
        let r = x.rotate_right((self.0 >> 59) as u32);
        (r >> 8) as f32 / (1u32 << 24) as f32
    }

    fn in_unit_ball(&mut self) -> Vec3 {
        loop {
            let p = Vec3::new(self.next_f32(), self.next_f32(), self.next_f32()) * 2.0 - 1.0;
            if p.length_squared() <= 1.0 {
                return p;
            }
        }
    }
}

/// `triangles` thin triangles along hair-like strands inside the unit ball. Each strand is a
/// random walk of [`HAIR_SEGMENTS`] steps (the last strand may be shorter) whose direction turns
/// a little at each step and back inward at the ball's edge; each step is one triangle, a
/// hundredth as wide as it is long.
///
/// The step length is `sqrt(HAIR_DENSITY / triangles)`, at most 0.3: the sum of the triangles'
/// squared lengths, which sets how many boxes a ray crosses, is the same at every size. A
/// larger count is the same tangle made of finer hair, so `hairball:10M` costs about as much
/// per ray as `hairball:100k`, and its SAH stays in the range of the real Hairball scene of
/// Meister & Bittner 2018 (Table 1) instead of growing with the count.
pub fn hairball(triangles: usize, seed: u64) -> TriangleMesh {
    let mut rng = Pcg(seed ^ 0x6861_6972);
    let mut mesh = TriangleMesh {
        positions: Vec::with_capacity(3 * triangles),
        indices: Vec::with_capacity(triangles),
        ..Default::default()
    };
    let step = (HAIR_DENSITY / triangles.max(1) as f32).sqrt().min(0.3);
    let (mut p, mut dir) = (Vec3::ZERO, Vec3::X);
    for i in 0..triangles as u32 {
        if i as usize % HAIR_SEGMENTS == 0 {
            p = rng.in_unit_ball() * 0.85;
            dir = rng.in_unit_ball().normalize_or(Vec3::X);
        }
        let mut next = p + dir * step;
        if next.length_squared() > 0.95 * 0.95 {
            dir = (-p.normalize_or(Vec3::X) + rng.in_unit_ball() * 0.5).normalize_or(-Vec3::X);
            next = p + dir * step;
        }
        let side = dir.any_orthonormal_vector() * (step * 0.01);
        mesh.positions.extend([p, next, p + side]);
        mesh.indices.push([3 * i, 3 * i + 1, 3 * i + 2]);
        p = next;
        dir = (dir + rng.in_unit_ball() * 0.4).normalize_or(dir);
    }
    mesh
}

/// Steps per hairball strand.
pub const HAIR_SEGMENTS: usize = 16;

/// The hairball's constant sum of squared step lengths (see [`hairball`]).
pub const HAIR_DENSITY: f32 = 1000.0;

/// A city of boxes (10 triangles each: no bottom face) on a ground quad, at least `triangles`
/// triangles in all, on a square grid.
pub fn city(triangles: usize, seed: u64) -> TriangleMesh {
    let mut rng = Pcg(seed ^ 0x6369_7479);
    let boxes = triangles.div_ceil(10).max(1);
    let side = (boxes as f32).sqrt().ceil() as usize;
    let mut mesh = TriangleMesh::default();
    let size = side as f32;
    mesh.append(&TriangleMesh {
        positions: vec![Vec3::ZERO, Vec3::new(size, 0.0, 0.0), Vec3::new(size, 0.0, size), Vec3::new(0.0, 0.0, size)],
        indices: vec![[0, 2, 1], [0, 3, 2]],
        ..Default::default()
    });
    for k in 0..boxes {
        let (x, z) = ((k % side) as f32, (k / side) as f32);
        let w = 0.3 + 0.6 * rng.next_f32();
        let h = 0.2 + 4.0 * rng.next_f32().powi(3);
        let min = Vec3::new(x + (1.0 - w) * 0.5, 0.0, z + (1.0 - w) * 0.5);
        mesh.append(&open_box(min, min + Vec3::new(w, h, w)));
    }
    mesh
}

/// An axis-aligned box without its bottom face, wound outward.
fn open_box(lo: Vec3, hi: Vec3) -> TriangleMesh {
    let c = |i: u32| {
        Vec3::new(
            if i & 1 != 0 { hi.x } else { lo.x },
            if i & 2 != 0 { hi.y } else { lo.y },
            if i & 4 != 0 { hi.z } else { lo.z },
        )
    };
    let quads: [[u32; 4]; 5] = [[2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5], [0, 2, 3, 1], [4, 5, 7, 6]];
    TriangleMesh {
        positions: (0..8).map(c).collect(),
        indices: quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect(),
        ..Default::default()
    }
}

/// `mesh` with every triangle split into four at its edge midpoints, repeatedly, until it has
/// at least `min_triangles`. Midpoints are not shared between neighbours: the copy is for
/// benchmarks, where only the triangle count and distribution matter.
pub fn subdivide(mesh: &TriangleMesh, min_triangles: usize) -> TriangleMesh {
    let mut tris = mesh.triangles();
    while tris.len() < min_triangles && !tris.is_empty() {
        tris = tris
            .iter()
            .flat_map(|t| {
                let (a, b, c) = (t.v0, t.v1, t.v2);
                let (ab, bc, ca) = ((a + b) * 0.5, (b + c) * 0.5, (c + a) * 0.5);
                [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]
            })
            .map(|[a, b, c]| super::Triangle::new(a, b, c))
            .collect();
    }
    let mut out = TriangleMesh {
        positions: Vec::with_capacity(3 * tris.len()),
        indices: Vec::with_capacity(tris.len()),
        ..Default::default()
    };
    for (i, t) in tris.iter().enumerate() {
        let i = 3 * i as u32;
        out.positions.extend([t.v0, t.v1, t.v2]);
        out.indices.push([i, i + 1, i + 2]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_and_determinism() {
        assert_eq!(hairball(1000, 1).triangle_count(), 1000);
        assert_eq!(hairball(1000, 1), hairball(1000, 1));
        assert_ne!(hairball(1000, 1), hairball(1000, 2));
        let c = city(10_000, 3);
        assert!(c.triangle_count() >= 10_000 && c.triangle_count() < 10_100, "{}", c.triangle_count());
        let base = TriangleMesh::uv_sphere(Vec3::ZERO, 1.0, 4, 6);
        let s = subdivide(&base, 1000);
        assert_eq!(s.triangle_count(), base.triangle_count() * 64);
        let area = |m: &TriangleMesh| m.triangles().iter().map(|t| t.area() as f64).sum::<f64>();
        assert!((area(&s) - area(&base)).abs() < 1e-4 * area(&base));
    }

    /// The hairball is the same tangle at any size: inside the ball, strands joined end to end,
    /// and the sum of squared triangle lengths equal to the density constant.
    #[test]
    fn hairball_density_does_not_grow_with_the_count() {
        for n in [20_000, 200_000, 2_000_000] {
            let h = hairball(n, 5);
            let tris = h.triangles();
            assert_eq!(tris.len(), n);
            assert!(h.positions.iter().all(|p| p.length() <= 0.96), "{n}: a vertex outside the ball");
            let squared: f64 = tris.iter().map(|t| (t.v1 - t.v0).length_squared() as f64).sum();
            assert!((squared / HAIR_DENSITY as f64 - 1.0).abs() < 1e-3, "{n}: sum of squared lengths {squared}");
            // Each step starts where the previous one ended, within a strand.
            let joined =
                tris.windows(2).enumerate().filter(|(i, w)| (i + 1) % HAIR_SEGMENTS != 0 && w[1].v0 == w[0].v1);
            assert_eq!(joined.count(), n - n.div_ceil(HAIR_SEGMENTS));
        }
    }
}
