//! Geometry: boxes, rays, triangles, Morton codes and meshes ([`mesh`]; built-in [`shapes`]; the
//! OBJ/MTL reader, [`obj`]; the PLY reader, [`ply`]).

mod aabb;
pub mod mesh;
pub mod morton;
pub mod obj;
pub mod ply;
pub mod procedural;
mod ray;
pub mod shapes;
mod triangle;

pub use aabb::{Aabb, ROBUST_SLAB_SCALE, RayInv, intersect_ray_packed, slab_interval};
pub use mesh::{MeshError, TriangleMesh};
pub use ray::{Ray, offset_ray_origin, spawn_ray};
pub use triangle::{Triangle, TriangleHit, WatertightRay, gamma, mirrors};
