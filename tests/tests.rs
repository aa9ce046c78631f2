//! Arbor's integration tests: one binary, a module per area (`cargo test --test tests AREA`
//! runs one). `docs/testing.md` says what each proves and with which tolerance.
//!
//! GPU tests skip with a printed reason where no adapter exists, except under `CI=true`, where a
//! missing adapter fails them.

mod common;

// The layers of docs/design/architecture.md.
mod architecture;

// Geometry and the BVH.
mod bvh_build;
mod dynamic_bvh;
mod prbvh;
mod traversal;
mod watertight;

// Scenes: the loader and animation.
mod animation;
mod fuzz_loader;
#[cfg(feature = "gltf")]
mod gltf;
mod scene_load;

// Rendering: exact answers, the independent reference, golden images, numerical stress.
mod environment;
mod golden;
mod render_accuracy;
mod stability;
mod textures;

// The `render` command line, and renders split into jobs and merged.
mod distributed;
mod reliability;
mod render_cli;

// The GPU backend.
#[cfg(feature = "gpu")]
mod gpu_layout;
#[cfg(feature = "gpu")]
mod gpu_lbvh;
#[cfg(feature = "gpu")]
mod gpu_prbvh;
#[cfg(feature = "gpu")]
mod gpu_render;
mod gpu_wide;
