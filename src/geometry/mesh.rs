//! Indexed triangle meshes: loaded from OBJ, or made in code (tessellated sphere, torus).
//!
//! Procedural meshes share every vertex between the triangles that meet there, including at the
//! poles and the wrap-around seams, so they are closed and watertight tests can rely on it.

use std::f32::consts::TAU;
use std::path::{Path, PathBuf};

use glam::{Mat4, Vec3};

use super::{Aabb, Triangle};

/// Positions and triangles indexing them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriangleMesh {
    pub positions: Vec<Vec3>,
    /// Every index is `< positions.len()`.
    pub indices: Vec<[u32; 3]>,
}

#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    #[error("{path}: cannot read OBJ: {source}")]
    Obj { path: PathBuf, source: tobj::LoadError },
}

impl TriangleMesh {
    pub fn triangle_count(&self) -> usize {
        self.indices.len()
    }

    pub fn triangle(&self, i: usize) -> Triangle {
        let [a, b, c] = self.indices[i];
        let p = &self.positions;
        Triangle::new(p[a as usize], p[b as usize], p[c as usize])
    }

    /// The triangles as a flat array, the form traversal reads.
    pub fn triangles(&self) -> Vec<Triangle> {
        (0..self.indices.len()).map(|i| self.triangle(i)).collect()
    }

    pub fn bounds(&self) -> Aabb {
        self.indices.iter().flatten().fold(Aabb::EMPTY, |b, &i| b.grow(self.positions[i as usize]))
    }

    /// The mesh with every position mapped by `world_from_object`.
    pub fn transformed(&self, world_from_object: Mat4) -> Self {
        Self {
            positions: self.positions.iter().map(|&p| world_from_object.transform_point3(p)).collect(),
            indices: self.indices.clone(),
        }
    }

    /// Appends `other`, re-basing its indices.
    pub fn append(&mut self, other: &TriangleMesh) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&other.positions);
        self.indices.extend(other.indices.iter().map(|t| t.map(|i| i + base)));
    }

    /// Loads every object of a Wavefront OBJ file into one mesh, triangulating polygons.
    pub fn load_obj(path: impl AsRef<Path>) -> Result<Self, MeshError> {
        let path = path.as_ref();
        let opts = tobj::LoadOptions { triangulate: true, single_index: true, ..Default::default() };
        let (models, _materials) =
            tobj::load_obj(path, &opts).map_err(|source| MeshError::Obj { path: path.to_owned(), source })?;
        let mut mesh = TriangleMesh::default();
        for m in &models {
            let part = TriangleMesh {
                positions: m.mesh.positions.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])).collect(),
                indices: m.mesh.indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
            };
            mesh.append(&part);
        }
        Ok(mesh)
    }

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
        Self { positions, indices }
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
        Self { positions, indices }
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
    fn sphere_winds_outward() {
        let s = TriangleMesh::uv_sphere(Vec3::ZERO, 1.0, 6, 9);
        for i in 0..s.triangle_count() {
            let t = s.triangle(i);
            let c = (t.v0 + t.v1 + t.v2) / 3.0;
            assert!(t.normal().dot(c) > 0.0, "triangle {i} faces inward");
        }
    }
}
