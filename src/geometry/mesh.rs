//! Indexed triangle meshes: loaded from OBJ ([`super::obj`]) or PLY ([`super::ply`]), or made in
//! code ([`super::shapes`]).

use std::path::{Path, PathBuf};

use glam::{Mat4, Vec2, Vec3};

use super::obj::read_obj;
use super::ply::read_ply;
use super::{Aabb, Triangle};

/// Positions and triangles indexing them, with the per-vertex attributes a file gave.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriangleMesh {
    pub positions: Vec<Vec3>,
    /// Every index is `< positions.len()`.
    pub indices: Vec<[u32; 3]>,
    /// Shading normals, one per position (unit length), or empty where the file gave none. A
    /// zero vector marks a vertex without one (a file that gave normals for part of a mesh).
    pub normals: Vec<Vec3>,
    /// Texture coordinates, one per position, as the file gave them (OBJ's `vt`: v up from the
    /// image's bottom), or empty.
    pub uvs: Vec<Vec2>,
}

/// Why an OBJ file (or an MTL file it names), or a PLY file, cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The I/O error is part of the message, not a `source`, so that a report of the whole
    /// error chain (`{:#}`) says it once.
    #[error("{path}: cannot read: {error}")]
    Read { path: PathBuf, error: std::io::Error },
    /// A line that is not valid OBJ, MTL or PLY (its header, or an ASCII body), or not usable.
    #[error("{path}:{line}: {message}")]
    Invalid { path: PathBuf, line: usize, message: String },
    /// A value in a binary PLY body that is not usable, or where the file ends early: its byte
    /// offset from the start of the file.
    #[error("{path}: byte {offset}: {message}")]
    InvalidBinary { path: PathBuf, offset: usize, message: String },
    /// What tobj finds only when an object ends, past the line at fault.
    #[error("{path}: cannot read OBJ: {error}")]
    Obj { path: PathBuf, error: tobj::LoadError },
    /// What the file declares at `line` would not fit in memory: a render that may fit
    /// elsewhere, not a bad file.
    #[error("{path}:{line}: {error}")]
    Memory { path: PathBuf, line: usize, error: crate::memory::OutOfMemory },
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

    /// The mesh with every position mapped by `world_from_object`, and every normal by its
    /// inverse transpose.
    pub fn transformed(&self, world_from_object: Mat4) -> Self {
        let normal_matrix = glam::Mat3::from_mat4(world_from_object).inverse().transpose();
        Self {
            positions: self.positions.iter().map(|&p| world_from_object.transform_point3(p)).collect(),
            indices: self.indices.clone(),
            normals: self.normals.iter().map(|&n| (normal_matrix * n).normalize_or_zero()).collect(),
            uvs: self.uvs.clone(),
        }
    }

    /// Appends `other`, re-basing its indices. Where only one of the two has normals (or
    /// texture coordinates), the other's vertices get zero ones: no shading normal there.
    pub fn append(&mut self, other: &TriangleMesh) {
        let (before, added) = (self.positions.len(), other.positions.len());
        let base = before as u32;
        self.positions.extend_from_slice(&other.positions);
        self.indices.extend(other.indices.iter().map(|t| t.map(|i| i + base)));
        if !self.normals.is_empty() || !other.normals.is_empty() {
            self.normals.resize(before, Vec3::ZERO);
            self.normals.extend_from_slice(&other.normals);
            self.normals.resize(before + added, Vec3::ZERO);
        }
        if !self.uvs.is_empty() || !other.uvs.is_empty() {
            self.uvs.resize(before, Vec2::ZERO);
            self.uvs.extend_from_slice(&other.uvs);
            self.uvs.resize(before + added, Vec2::ZERO);
        }
    }

    /// Loads every object of a Wavefront OBJ file into one mesh, triangulating polygons. Its MTL
    /// files are not read.
    pub fn load_obj(path: impl AsRef<Path>) -> Result<Self, MeshError> {
        let obj = read_obj(path.as_ref(), false)?;
        let mut mesh = TriangleMesh::default();
        for m in &obj.models {
            mesh.append(&TriangleMesh::from_tobj(&m.mesh));
        }
        Ok(mesh)
    }

    /// Loads a PLY file (ASCII or binary): its vertices, with their normals and texture
    /// coordinates where it has them, and its faces, triangulated. See [`super::ply`].
    pub fn load_ply(path: impl AsRef<Path>) -> Result<Self, MeshError> {
        read_ply(path.as_ref())
    }
}
