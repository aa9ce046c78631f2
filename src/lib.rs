//! Arbor: a path tracer built around its bounding volume hierarchy.
//!
//! Build a BVH over triangles and trace a ray through it:
//!
//! ```
//! use arbor::bvh::Tracing;
//! use arbor::bvh::build::Builder;
//! use arbor::geometry::{Ray, Triangle};
//! use arbor::glam::Vec3;
//!
//! let triangles = vec![
//!     Triangle::new(Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, -1.0, 0.0), Vec3::new(0.0, 1.0, 0.0)),
//!     Triangle::new(Vec3::new(-1.0, -1.0, 2.0), Vec3::new(1.0, -1.0, 2.0), Vec3::new(0.0, 1.0, 2.0)),
//! ];
//! // LBVH (Karras 2012), optimised by parallel reinsertion (Meister & Bittner 2018), then the
//! // leaf collapse; the triangles are stored in leaf order.
//! let builder: Builder = "lbvh+prbvh".parse()?;
//! let bvh = builder.build_mesh(&triangles, Tracing::best());
//! let ray = Ray::new(Vec3::new(0.0, 0.0, -1.0), Vec3::Z);
//! let hit = bvh.closest_hit(&ray, f32::INFINITY).expect("the ray meets the first triangle");
//! assert_eq!((hit.prim_id, hit.t), (0, 1.0));
//! assert!(bvh.any_hit(&ray, f32::INFINITY));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! Render a scene file to an image, on the CPU ([`device::Device::Gpu`] renders on a GPU):
//!
//! ```no_run
//! use arbor::bvh::Tracing;
//! use arbor::device::{BuilderChoice, Device, Renderer};
//! use arbor::render::first_frame_time;
//! use arbor::scene::Scene;
//!
//! let scene = Scene::load("scenes/cornell-box.toml")?;
//! let settings = arbor::scene::RenderSettings { spp: 16, ..scene.render };
//! let time = first_frame_time(&scene);
//! // The trace form: the best this CPU has, or as `ARBOR_SIMD` says.
//! let tracing = Tracing::from_env(None)?;
//! let mut renderer = Renderer::new(Device::Cpu, &scene, &BuilderChoice::Auto, tracing, &settings, 1, time)?;
//! let frame = renderer.render(&settings, &|_| {})?;
//! arbor::image_io::write_image("cornell.png", &frame.film.mean())?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! `examples/` holds both as programs. The modules, bottom to top (none imports one of its own
//! layer or above: `docs/design/architecture.md`, checked by `tests/architecture.rs`):
//!
//! - [`memory`]: peak resident memory and the memory check; [`atomic_file`]: every file
//!   output, written atomically; [`image_io`]: EXR and PNG.
//! - [`geometry`]: boxes, rays, the watertight triangle test, Morton codes, meshes, built-in
//!   shapes and the OBJ/MTL and PLY readers. [`texture`]: decoded images, their cache and wrap
//!   modes, and the environment map's texels and sampling tables.
//! - [`bvh`]: the tree layout shared with the GPU, SAH cost and leaf collapse, validation;
//!   [`bvh::build`] (LBVH, binned SAH, PLOC, parallel and sequential reinsertion),
//!   [`bvh::trace`] (binary and wide traversal, SIMD kernels, the trace form) and
//!   [`bvh::dynamic`] (the dynamic and two-level BVHs).
//! - [`scene`]: the TOML scene format, its loader, the glTF reader (feature `gltf`), and
//!   animation.
//! - [`render`]: camera, film, materials (BSDFs), sampling, lights, scene assembly, `--builder
//!   auto`, passes and regions, and the path tracer.
//! - [`gpu`] (feature `gpu`): the wgpu backend: context, shared layouts, GPU LBVH, PRBVH and
//!   path tracing.
//! - [`device`]: one entry point that renders a frame on the CPU or the GPU.
//! - [`distributed`]: split renders: planning a job's region and outputs, resuming and
//!   skipping them, partial films and their exact merge.
//!
//! Features, all on by default: `gpu` (the wgpu backend), `gltf` (the glTF 2.0 reader,
//! `scene::gltf`, and glTF files in scenes) and `cli` (the `render` binary's dependencies);
//! `default-features = false` gives the library alone, whose scenes then refuse glTF files with
//! an error that names the feature.

pub mod atomic_file;
pub mod bvh;
pub mod device;
pub mod distributed;
pub mod geometry;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod image_io;
pub mod memory;
pub mod render;
pub mod scene;
pub mod texture;

/// The vector maths crate of Arbor's public types (`Vec3` in [`geometry::Triangle`], ...).
pub use glam;
