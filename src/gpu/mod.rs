//! The GPU backend on wgpu: compute shaders in WGSL (`shaders/`), headless.
//!
//! - [`context`]: adapter choice (discrete, integrated, then software only when allowed),
//!   features and limits, the pipeline cache, buffers within the adapter's limits;
//! - [`layout`]: the structs and constants shared with WGSL, and the prelude generated from them;
//! - [`lbvh`]: the LBVH build, the same tree as the CPU's.
//!
//! On machines without a GPU, wgpu runs on Mesa's lavapipe (Vulkan on the CPU).

pub mod context;
pub mod layout;
pub mod lbvh;

pub use context::{AdapterPolicy, GpuContext, GpuError};
