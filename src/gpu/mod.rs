//! The GPU backend on wgpu: compute shaders in WGSL (`shaders/`), headless.
//!
//! - [`context`]: adapter choice (discrete, integrated, then software only when allowed),
//!   features and limits, the pipeline cache, buffers within the adapter's limits;
//! - [`layout`]: the structs and constants shared with WGSL, and the prelude generated from them;
//! - [`lbvh`]: the LBVH build, the same tree as the CPU's `lbvh::build_karras`;
//! - [`prbvh`]: parallel reinsertion, the paper's six kernels per iteration;
//! - [`texture`]: textures packed for the shaders;
//! - [`wide`]: the compressed 8-wide tree, made on the host or on the device;
//! - [`trace`]: path tracing, the CPU's integrator in one kernel per scene variant.
//!
//! On machines without a GPU, wgpu runs on Mesa's lavapipe (Vulkan on the CPU).

pub mod context;
pub mod layout;
pub mod lbvh;
pub mod prbvh;
pub mod texture;
pub mod trace;
pub mod wide;

pub use context::{AdapterPolicy, GpuContext, GpuError};

use crate::bvh::Tracing;
use crate::render::{BuildReport, RenderScene};
use crate::scene::Scene;

/// A flat scene built with its BVH made on the GPU: the LBVH, then, when `optimize`, parallel
/// reinsertion with the best locks the adapter has, read back once; the leaf collapse and the
/// rest as for a CPU build ([`RenderScene::assemble`]). What `render --device gpu` does for the
/// builders `lbvh` and `lbvh+prbvh`. A scene with many equal Morton codes gets the CPU's LBVH
/// instead (see the body). `None` for scenes the GPU build does not take (fewer than
/// two triangles).
pub fn build_render_scene(
    ctx: &GpuContext,
    scene: &Scene,
    optimize: bool,
) -> Result<Option<(RenderScene, BuildReport)>, GpuError> {
    Ok(build_render_scene_for(ctx, scene, optimize, trace::GpuForm::Binary)?.map(|(rs, report, _)| (rs, report)))
}

/// [`build_render_scene`] for tracing in `form`: for the wide form, the GPU also collapses its
/// tree into the compressed wide one ([`wide::collapse_on_device`], counted in the build's
/// time), which is returned for the upload ([`trace::GpuScene::upload_with`]). A tree the GPU
/// did not build itself (the CPU's LBVH, below) is collapsed on the host at upload instead.
pub fn build_render_scene_for(
    ctx: &GpuContext,
    scene: &Scene,
    optimize: bool,
    form: trace::GpuForm,
) -> Result<Option<(RenderScene, BuildReport, Option<wide::DeviceWide>)>, GpuError> {
    let start = std::time::Instant::now();
    let compiled_before = ctx.compile_time();
    let (triangles, material_of) = scene.world_triangles();
    if triangles.len() < 2 {
        return Ok(None);
    }
    let prims: Vec<crate::geometry::Aabb> = triangles.iter().map(crate::geometry::Triangle::aabb).collect();
    let (tree, mut label) = device_tree(ctx, &prims, optimize)?;
    let mut device_wide = None;
    let tree = match tree {
        DeviceTree::Host(tree) => tree,
        DeviceTree::OnDevice(gpu) => {
            if form == trace::GpuForm::Wide8 {
                // Where its working buffers do not fit the adapter's bindings, the host collapses
                // the tree at upload instead.
                match wide::collapse_on_device(ctx, &gpu) {
                    Ok(w) => {
                        label += &format!(", collapsed to 8-wide on the GPU in {:.1} ms", w.seconds * 1e3);
                        device_wide = Some(w);
                    }
                    Err(e @ GpuError::BufferTooLarge { .. }) => label += &format!(", collapsed on the host ({e})"),
                    Err(e) => return Err(e),
                }
            }
            gpu.read(ctx)?
        }
    };
    // Pipeline compilation, paid once per process, is reported apart from the build.
    let compiled = ctx.compile_time().saturating_sub(compiled_before);
    if compiled >= std::time::Duration::from_millis(1) {
        label += &format!("; {:.2} s compiling its kernels, not counted", compiled.as_secs_f64());
    }
    let (rs, report) =
        RenderScene::assemble(scene, (triangles, material_of, 0.0), &tree, start + compiled, label, Tracing::gpu());
    Ok(Some((rs, report, device_wide)))
}

/// A tree [`device_tree`] made: left on the device, or the CPU's LBVH (optimised on the GPU and
/// read back).
enum DeviceTree {
    OnDevice(lbvh::GpuBvh),
    Host(crate::bvh::Bvh),
}

/// The GPU's LBVH over `prims`, then, when `optimize`, parallel reinsertion with the best locks
/// the adapter has, with a label saying what was done. The GPU builds Karras' LBVH, which leaves
/// runs of equal Morton codes in file order: a model far from another object (inside a sky box
/// of 10^6) lies in a few cells, and its tree would be a list. Where such runs hold more than
/// 1/64 of the primitives (far more than ordinary meshes have, so they keep the GPU build;
/// docs/benchmarks.md, "A model in a sky box"), the CPU's LBVH, which splits them, is built
/// instead and optimised on the GPU all the same.
fn device_tree(
    ctx: &GpuContext,
    prims: &[crate::geometry::Aabb],
    optimize: bool,
) -> Result<(DeviceTree, String), GpuError> {
    let (gpu, _) = lbvh::build_on_device(ctx, prims)?;
    let scheme = prbvh::LockScheme::best_for(ctx);
    let config = crate::bvh::build::prbvh::PrbvhConfig { collapse: None, ..Default::default() };
    if let Some(scrambled) = equal_code_runs(ctx, &gpu, prims)? {
        drop(gpu);
        let cpu = crate::bvh::build::lbvh::build(prims);
        let why = format!("{scrambled} triangles in runs of equal Morton codes");
        if !optimize {
            return Ok((DeviceTree::Host(cpu), format!("lbvh on the CPU ({why})")));
        }
        let (tree, stats) = prbvh::optimize(ctx, &cpu, &config, scheme)?;
        let label = format!(
            "lbvh on the CPU ({why}), prbvh on the GPU, {} iterations, {scheme:?} locks",
            stats.iterations.len()
        );
        return Ok((DeviceTree::Host(tree), label));
    }
    let mut label = "lbvh on the GPU".to_owned();
    if optimize {
        let stats = prbvh::optimize_on_device(ctx, &gpu, &config, scheme)?;
        label = format!("lbvh+prbvh on the GPU, {} iterations, {scheme:?} locks", stats.iterations.len());
    }
    Ok((DeviceTree::OnDevice(gpu), label))
}

/// The primitives in runs of equal Morton codes in the GPU's LBVH `gpu` over `prims`, where
/// they are more than 1/64 of them (see [`device_tree`]); `None` where the GPU's tree serves.
fn equal_code_runs(
    ctx: &GpuContext,
    gpu: &lbvh::GpuBvh,
    prims: &[crate::geometry::Aabb],
) -> Result<Option<usize>, GpuError> {
    let (codes, ids) = gpu.read_codes(ctx)?;
    let scrambled = crate::bvh::build::lbvh::refinable_primitives(prims, &codes, &ids);
    Ok((scrambled > prims.len() / 64).then_some(scrambled))
}

/// Meshes of at least this many triangles get their trees built on the GPU in a two-level
/// scene ([`build_instanced_for`]); smaller ones on the CPU, where a mesh of a few thousand
/// triangles builds in about a millisecond and a GPU build costs a round of dispatches and
/// read-backs as long.
pub const GPU_MESH_TRIANGLES: usize = 1 << 14;

/// A two-level scene (see [`RenderScene::build`]) whose meshes of at least
/// [`GPU_MESH_TRIANGLES`] triangles are built on the GPU ([`device_tree`]: the LBVH, then PRBVH
/// when `optimize`), read back and leaf-collapsed, the others by `cpu` on the CPU; the top level
/// over the objects as the CPU makes it. Built once: the frames move the top level only.
pub fn build_instanced_for(
    ctx: &GpuContext,
    scene: &Scene,
    optimize: bool,
    cpu: &crate::bvh::build::Builder,
) -> Result<(RenderScene, BuildReport), GpuError> {
    use crate::bvh::{CollapseConfig, MeshBvh, collapse_leaves};
    let start = std::time::Instant::now();
    let compiled_before = ctx.compile_time();
    let mut on_gpu = 0;
    let mut labels = Vec::new();
    let mut meshes = Vec::with_capacity(scene.meshes.len());
    for m in &scene.meshes {
        let triangles = m.mesh.triangles();
        if triangles.len() < GPU_MESH_TRIANGLES {
            meshes.push(cpu.build_mesh(&triangles, Tracing::gpu()));
            continue;
        }
        let prims: Vec<crate::geometry::Aabb> = triangles.iter().map(crate::geometry::Triangle::aabb).collect();
        let (tree, label) = device_tree(ctx, &prims, optimize)?;
        let tree = match tree {
            DeviceTree::Host(tree) => tree,
            DeviceTree::OnDevice(gpu) => gpu.read(ctx)?,
        };
        meshes.push(MeshBvh::new(collapse_leaves(&tree, &CollapseConfig::default()), &triangles, Tracing::gpu()));
        on_gpu += 1;
        if !labels.contains(&label) {
            labels.push(label);
        }
    }
    let compiled = ctx.compile_time().saturating_sub(compiled_before);
    let mut label = format!(
        "two levels: {on_gpu} of {} meshes built on the GPU ({}), the rest {cpu} on the CPU",
        scene.meshes.len(),
        if labels.is_empty() { "none large enough".to_owned() } else { labels.join("; ") }
    );
    if compiled >= std::time::Duration::from_millis(1) {
        label += &format!("; {:.2} s compiling kernels, not counted", compiled.as_secs_f64());
    }
    Ok(RenderScene::assemble_instanced(scene, meshes, start + compiled, label, Tracing::gpu()))
}

/// Turns off Mesa's Vulkan device-select layer where `XDG_RUNTIME_DIR` is unset (as in CI): the
/// layer then prints "XDG_RUNTIME_DIR is invalid" on stderr for every instance, even for a
/// `--quiet` render that only probes for a GPU. It only reorders adapters, which [`GpuContext`]
/// sorts itself.
///
/// # Safety
/// Sets an environment variable: call it first thing in `main`, before any other thread exists.
pub unsafe fn quiet_device_select_layer() {
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() && std::env::var_os("NODEVICE_SELECT").is_none() {
        // SAFETY: the caller's promise (no other thread reads the environment).
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
}
