//! Helpers for tests that run the tools or need a GPU, shared with the benchmark crate's tests
//! (`bench/tests/cli.rs` includes this file by path).

/// Runs `cmd` with its standard output closed before it writes (as `| head` does once it has
/// read enough): the tools must neither panic nor stop their work and files.
pub fn output_with_stdout_closed(cmd: &mut std::process::Command) -> std::process::Output {
    use std::process::Stdio;
    let mut child = cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    drop(child.stdout.take());
    child.wait_with_output().unwrap()
}

/// The shared GPU context, or `None` with the reason printed where there is no adapter; under
/// `CI=true` a missing adapter fails the test instead (CI installs lavapipe).
pub fn gpu_or_skip(test: &str) -> Option<&'static arbor::gpu::GpuContext> {
    match arbor::gpu::GpuContext::shared() {
        Ok(ctx) => Some(ctx),
        Err(e) if std::env::var("CI").is_ok_and(|v| v == "true") => panic!("{test}: no GPU under CI=true: {e}"),
        Err(e) => {
            eprintln!("skipping {test}: {e}");
            None
        }
    }
}

/// A fresh folder for one test's files under the system's temporary folder, named by `prefix`,
/// `name` and this process.
pub fn fresh_temp_dir(prefix: &str, name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("{prefix}-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Writes `mesh` as an OBJ file (positions and faces).
pub fn write_obj(path: &std::path::Path, mesh: &arbor::geometry::TriangleMesh) {
    let mut s = String::new();
    for p in &mesh.positions {
        s += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for t in &mesh.indices {
        s += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    std::fs::write(path, s).unwrap();
}
