//! Writing reports: JSON, CSV and plots, each to a temporary file renamed into place.

use anyhow::{Context, Result};
use arbor::atomic_file::{self, AtomicWriteError};
use std::io::Write;
use std::path::Path;

use crate::Args;
use crate::plot::{Series, write_plot};

/// What one builder's process reports to `--memory`.
#[derive(serde::Serialize, serde::Deserialize)]
pub(crate) struct MemoryReport {
    pub name: String,
    pub triangles: usize,
    pub build_ms: f64,
    /// Bytes the built structure keeps to trace: nodes, indices and its copy of the triangles
    /// (Arbor's: the binary tree, the leaf-ordered triangles and the wide form it traces).
    pub kept_bytes: u64,
    /// The process's peak resident memory: the mesh, its triangles and the build.
    pub peak_bytes: u64,
    pub kept_bytes_per_triangle: f64,
    pub peak_bytes_per_triangle: f64,
    /// Of `kept_bytes`, the wide form's: its nodes and triangle packets (0 for obvhs).
    #[serde(default)]
    pub wide_bytes: u64,
    #[serde(default)]
    pub wide_bytes_per_triangle: f64,
}

/// `--memory`'s JSON report.
#[derive(serde::Serialize)]
pub(crate) struct MemoryComparison<'a> {
    pub triangles: usize,
    pub builders: &'a [MemoryReport],
}

/// `--gpu`'s JSON report: a row per build stage and device (`rows`; the `collapse` rows' SAH
/// is the host's wide tree's own), and the builder comparison with its GPU fields (`builders` and the
/// rest of the comparison's report, inline).
#[derive(serde::Serialize)]
pub(crate) struct GpuComparison {
    pub adapter: String,
    pub runs: usize,
    pub rows: Vec<GpuRow>,
    #[serde(flatten)]
    pub comparison: arbor_bench::compare::Report,
}

/// One stage (`lbvh`, `prbvh`) on one device; fields that do not apply are left out.
#[derive(serde::Serialize)]
pub(crate) struct GpuRow {
    pub stage: &'static str,
    pub device: &'static str,
    /// PRBVH on the GPU: `32-bit` or `64-bit` locks.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub locks: Option<&'static str>,
    /// Median milliseconds.
    pub ms: f64,
    /// LBVH on the GPU: the median upload time.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub upload_ms: Option<f64>,
    pub sah: f64,
    /// LBVH on the GPU: whether it built the CPU's tree, node for node.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub same_tree_as_cpu: Option<bool>,
    /// PRBVH on the GPU: iterations run.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub iterations: Option<usize>,
    /// The collapse on the GPU: wide nodes made.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub nodes: Option<usize>,
}

impl GpuRow {
    pub fn new(stage: &'static str, device: &'static str, ms: f64, sah: f64) -> Self {
        Self {
            stage,
            device,
            locks: None,
            ms,
            upload_ms: None,
            sah,
            same_tree_as_cpu: None,
            iterations: None,
            nodes: None,
        }
    }
}

/// `--converge`'s JSON report.
#[derive(serde::Serialize)]
pub(crate) struct ConvergeReport<'a> {
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub max_depth: u32,
    pub threads: usize,
    pub reference: ReferenceInfo,
    pub curves: &'a [arbor_bench::converge::ConvergeCurve],
    pub auto: &'a [arbor_bench::converge::AutoComparison],
    pub auto_not_compared: Vec<NotCompared>,
}

/// Where `--converge`'s reference came from.
#[derive(serde::Serialize)]
#[serde(tag = "source", rename_all = "lowercase")]
pub(crate) enum ReferenceInfo {
    /// `--reference FILE`.
    File { path: String },
    /// Rendered with another seed.
    Rendered { spp: u32, seed: u64, time_s: f64 },
}

/// A device whose `auto` curve could not be compared with the fixed builders, and why.
#[derive(serde::Serialize)]
pub(crate) struct NotCompared {
    pub device: String,
    pub reason: &'static str,
}

/// Writes the report as JSON, the table as CSV and the plot, for each option given.
pub(crate) fn write_outputs(
    args: &Args,
    report: &impl serde::Serialize,
    csv: impl FnOnce(&mut dyn Write) -> Result<()>,
    (title, labels): (String, (&str, &str)),
    series: &[Series],
    log: bool,
) -> Result<()> {
    if let Some(path) = &args.json {
        write_atomic(path, |f| write_json(f, report))?;
    }
    if let Some(path) = &args.csv {
        write_atomic(path, csv)?;
    }
    if let Some(path) = &args.plot {
        write_plot(path, &title, labels, series, log)?;
    }
    Ok(())
}

/// `value` as pretty JSON, ending in a newline as text files do.
pub(crate) fn write_json(f: &mut dyn Write, value: &impl serde::Serialize) -> Result<()> {
    serde_json::to_writer_pretty(&mut *f, value)?;
    writeln!(f)?;
    Ok(())
}

/// Writes `path` atomically (see `arbor::atomic_file`).
pub(crate) fn write_atomic(path: &Path, write: impl FnOnce(&mut dyn Write) -> Result<()>) -> Result<()> {
    atomic_file::write_atomic(path, |f| write(f))
        .map_err(atomic_error)
        .with_context(|| format!("writing {}", path.display()))
}

pub(crate) fn atomic_error(e: AtomicWriteError<anyhow::Error>) -> anyhow::Error {
    match e {
        AtomicWriteError::Io { what, source } => anyhow::Error::new(source).context(what),
        AtomicWriteError::Write(e) => e,
    }
}
