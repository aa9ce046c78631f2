//! Built-in shapes: tessellated sphere, quad, cube, icosphere, torus.
//!
//! They share every vertex between the triangles that meet there, including at the poles and
//! the wrap-around seams, so they are closed and watertight tests can rely on it.

use std::f32::consts::TAU;

use glam::{Vec2, Vec3};

use super::TriangleMesh;

impl TriangleMesh {
    /// A UV sphere of `stacks` latitude bands and `slices` longitude segments (each at least 3),
    /// with single pole vertices shared by a fan of triangles, wound outward.
    pub fn uv_sphere(center: Vec3, radius: f32, stacks: u32, slices: u32) -> Self {
        assert!(stacks >= 2 && slices >= 3, "uv_sphere needs stacks >= 2 and slices >= 3");
        let mut positions = vec![center + Vec3::Y * radius];
        for i in 1..stacks {
            let theta = std::f32::consts::PI * i as f32 / stacks as f32;
            for j in 0..slices {
                let phi = TAU * j as f32 / slices as f32;
                let d = Vec3::new(theta.sin() * phi.cos(), theta.cos(), -theta.sin() * phi.sin());
                positions.push(center + d * radius);
            }
        }
        positions.push(center - Vec3::Y * radius);
        let south = positions.len() as u32 - 1;
        let ring = |i: u32, j: u32| 1 + (i - 1) * slices + (j % slices);
        let mut indices = Vec::new();
        for j in 0..slices {
            indices.push([0, ring(1, j), ring(1, j + 1)]);
            indices.push([south, ring(stacks - 1, j + 1), ring(stacks - 1, j)]);
        }
        for i in 1..stacks - 1 {
            for j in 0..slices {
                let (a, b, c, d) = (ring(i, j), ring(i, j + 1), ring(i + 1, j), ring(i + 1, j + 1));
                indices.push([a, c, d]);
                indices.push([a, d, b]);
            }
        }
        Self { positions, indices, ..Default::default() }
    }

    /// The built-in quad: the square [-1, 1]² in the xy plane, facing +z, with texture
    /// coordinates from (0, 0) at its bottom left to (1, 1) at its top right.
    pub fn quad() -> Self {
        Self {
            positions: vec![
                Vec3::new(-1.0, -1.0, 0.0),
                Vec3::new(1.0, -1.0, 0.0),
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::new(-1.0, 1.0, 0.0),
            ],
            indices: vec![[0, 1, 2], [0, 2, 3]],
            // The whole texture once over the quad, upright when the quad faces the viewer.
            uvs: vec![Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(1.0, 1.0), Vec2::new(0.0, 1.0)],
            ..Default::default()
        }
    }

    /// The built-in box: the cube [-1, 1]³, 12 triangles over 8 shared corners, wound outward.
    pub fn cube() -> Self {
        let corner = |i: u32| {
            Vec3::new(
                if i & 1 != 0 { 1.0 } else { -1.0 },
                if i & 2 != 0 { 1.0 } else { -1.0 },
                if i & 4 != 0 { 1.0 } else { -1.0 },
            )
        };
        // Each face's corners counter-clockwise seen from outside.
        let faces: [[u32; 4]; 6] = [[0, 4, 6, 2], [1, 3, 7, 5], [0, 1, 5, 4], [2, 6, 7, 3], [0, 2, 3, 1], [4, 5, 7, 6]];
        Self {
            positions: (0..8).map(corner).collect(),
            indices: faces.iter().flat_map(|f| [[f[0], f[1], f[2]], [f[0], f[2], f[3]]]).collect(),
            ..Default::default()
        }
    }

    /// The built-in sphere: an icosahedron of radius 1 whose triangles are split in four
    /// `level` times (20 · 4^level triangles), new vertices pushed out to the sphere. Edge
    /// midpoints are shared between neighbours, so it stays closed.
    pub fn icosphere(level: u32) -> Self {
        let t = (1.0 + 5f32.sqrt()) / 2.0;
        let mut positions: Vec<Vec3> = [
            [-1.0, t, 0.0],
            [1.0, t, 0.0],
            [-1.0, -t, 0.0],
            [1.0, -t, 0.0],
            [0.0, -1.0, t],
            [0.0, 1.0, t],
            [0.0, -1.0, -t],
            [0.0, 1.0, -t],
            [t, 0.0, -1.0],
            [t, 0.0, 1.0],
            [-t, 0.0, -1.0],
            [-t, 0.0, 1.0],
        ]
        .iter()
        .map(|&p| Vec3::from(p).normalize())
        .collect();
        let mut indices: Vec<[u32; 3]> = vec![
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ];
        for _ in 0..level {
            let mut midpoints = std::collections::HashMap::new();
            let mut mid = |a: u32, b: u32, positions: &mut Vec<Vec3>| -> u32 {
                *midpoints.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    positions.push(((positions[a as usize] + positions[b as usize]) * 0.5).normalize());
                    positions.len() as u32 - 1
                })
            };
            indices = indices
                .iter()
                .flat_map(|&[a, b, c]| {
                    let (ab, bc, ca) =
                        (mid(a, b, &mut positions), mid(b, c, &mut positions), mid(c, a, &mut positions));
                    [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
                })
                .collect();
        }
        Self { positions, indices, ..Default::default() }
    }

    /// A torus around the y axis: the tube of radius `minor` follows a circle of radius `major`,
    /// with `major_segments` x `minor_segments` quads split in two.
    pub fn torus(center: Vec3, major: f32, minor: f32, major_segments: u32, minor_segments: u32) -> Self {
        assert!(major_segments >= 3 && minor_segments >= 3, "torus needs at least 3 segments");
        let mut positions = Vec::new();
        for i in 0..major_segments {
            let phi = TAU * i as f32 / major_segments as f32;
            let radial = Vec3::new(phi.cos(), 0.0, phi.sin());
            for j in 0..minor_segments {
                let theta = TAU * j as f32 / minor_segments as f32;
                positions.push(center + radial * (major + minor * theta.cos()) + Vec3::Y * minor * theta.sin());
            }
        }
        let at = |i: u32, j: u32| (i % major_segments) * minor_segments + (j % minor_segments);
        let mut indices = Vec::new();
        for i in 0..major_segments {
            for j in 0..minor_segments {
                let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
                indices.push([a, b, d]);
                indices.push([a, d, c]);
            }
        }
        Self { positions, indices, ..Default::default() }
    }
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use super::*;

    /// Closed and manifold: every undirected edge is used by exactly two triangles, once in each
    /// direction.
    fn assert_closed(m: &TriangleMesh) {
        let mut edges: HashMap<(u32, u32), i32> = HashMap::new();
        for t in &m.indices {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *edges.entry((a.min(b), a.max(b))).or_default() += if a < b { 1 } else { -1 };
            }
        }
        assert!(edges.values().all(|&c| c == 0), "mesh is not closed and consistently wound");
        let mut uses: HashMap<(u32, u32), u32> = HashMap::new();
        for t in &m.indices {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *uses.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        assert!(uses.values().all(|&c| c == 2));
    }

    #[test]
    fn procedural_meshes_are_closed() {
        let s = TriangleMesh::uv_sphere(Vec3::ZERO, 1.0, 8, 12);
        assert_eq!(s.triangle_count(), 2 * 12 * 7);
        assert_closed(&s);
        let t = TriangleMesh::torus(Vec3::ZERO, 2.0, 0.5, 16, 8);
        assert_eq!(t.triangle_count(), 2 * 16 * 8);
        assert_closed(&t);
    }

    #[test]
    fn built_in_shapes_are_closed_and_outward() {
        for (name, m, count) in [
            ("cube", TriangleMesh::cube(), 12),
            ("icosphere 0", TriangleMesh::icosphere(0), 20),
            ("icosphere 3", TriangleMesh::icosphere(3), 1280),
        ] {
            assert_eq!(m.triangle_count(), count, "{name}");
            assert_closed(&m);
            for i in 0..m.triangle_count() {
                let t = m.triangle(i);
                assert!(t.normal().dot((t.v0 + t.v1 + t.v2) / 3.0) > 0.0, "{name}: triangle {i} faces inward");
            }
        }
        let q = TriangleMesh::quad();
        assert!(q.triangles().iter().all(|t| t.normal().z > 0.0));
        assert!((q.triangles().iter().map(|t| t.area()).sum::<f32>() - 4.0).abs() < 1e-6);
    }

    #[test]
    fn sphere_winds_outward() {
        let s = TriangleMesh::uv_sphere(Vec3::ZERO, 1.0, 6, 9);
        for i in 0..s.triangle_count() {
            let t = s.triangle(i);
            let c = (t.v0 + t.v1 + t.v2) / 3.0;
            assert!(t.normal().dot(c) > 0.0, "triangle {i} faces inward");
        }
    }
}
