//! The GPU backend on wgpu: compute shaders in WGSL (`shaders/`), headless.
//!
//! - [`context`]: adapter choice (discrete, integrated, then software only when allowed),
//!   features and limits, the pipeline cache, buffers within the adapter's limits;
//! - [`layout`]: the structs and constants shared with WGSL, and the prelude generated from them;
//! - [`lbvh`]: the LBVH build, the same tree as the CPU's;
//! - [`prbvh`]: parallel reinsertion, the paper's six kernels per iteration;
//! - [`trace`]: path tracing, the CPU's integrator in one kernel per scene variant.
//!
//! On machines without a GPU, wgpu runs on Mesa's lavapipe (Vulkan on the CPU).

pub mod context;
pub mod layout;
pub mod lbvh;
pub mod prbvh;
pub mod trace;

pub use context::{AdapterPolicy, GpuContext, GpuError};
