//! The process's memory as the kernel counts it, for reports (peak memory per triangle).
//!
//! Read from `/proc/self/status` (Linux): `VmHWM`, the peak resident set, and `VmRSS`, the
//! current one. Elsewhere both are `None` and reports leave the figures out. Resident memory
//! counts pages touched, not bytes allocated: memory freed to the allocator but not returned to
//! the kernel still counts, which is what a machine running out of memory sees.

/// The peak resident set of this process so far, bytes.
pub fn peak_rss_bytes() -> Option<u64> {
    status_kib("VmHWM:").map(|k| k * 1024)
}

/// The current resident set of this process, bytes.
pub fn rss_bytes() -> Option<u64> {
    status_kib("VmRSS:").map(|k| k * 1024)
}

/// Memory the system can give this process now without swapping, bytes; `None` where unknown:
/// the machine's `MemAvailable` (`/proc/meminfo`, Linux), or less where the process's control
/// group has a memory limit ([`cgroup_available_bytes`]). Under Slurm or Kubernetes the job's
/// cgroup limit, not the machine, is what ends a job that asks too much.
pub fn available_bytes() -> Option<u64> {
    let machine = std::fs::read_to_string("/proc/meminfo").ok().and_then(|info| kib_field(&info, "MemAvailable:"));
    let machine = machine.map(|k| k * 1024);
    let cgroup =
        std::fs::read_to_string("/proc/self/cgroup").ok().and_then(|c| cgroup_available_bytes(Path::new("/"), &c));
    match (machine, cgroup) {
        (Some(m), Some(c)) => Some(m.min(c)),
        (m, c) => m.or(c),
    }
}

/// What the memory limits of the control groups in `cgroups` (the text of `/proc/self/cgroup`)
/// leave unused, bytes, under the file system root `root`: the least of limit minus usage over
/// the process's group and every group above it (v2 `memory.max` and `memory.current`; v1
/// `memory.limit_in_bytes` and `memory.usage_in_bytes`). `None` where no group has a limit.
///
/// A container often sees its own group as the root of the mount while `/proc/self/cgroup`
/// names the host's path: the path is then tried with its leading parts dropped, and at last
/// the mount's root.
pub fn cgroup_available_bytes(root: &Path, cgroups: &str) -> Option<u64> {
    let mut least: Option<u64> = None;
    for line in cgroups.lines() {
        let mut parts = line.splitn(3, ':');
        let (Some(id), Some(controllers), Some(path)) = (parts.next(), parts.next(), parts.next()) else { continue };
        let (mount, limit_file, usage_file) = if id == "0" && controllers.is_empty() {
            (root.join("sys/fs/cgroup"), "memory.max", "memory.current")
        } else if controllers.split(',').any(|c| c == "memory") {
            (root.join("sys/fs/cgroup/memory"), "memory.limit_in_bytes", "memory.usage_in_bytes")
        } else {
            continue;
        };
        let parts: Vec<&str> = path.split('/').filter(|p| !p.is_empty()).collect();
        let Some(found) = (0..=parts.len()).map(|skip| parts[skip..].join("/")).find(|p| mount.join(p).is_dir()) else {
            continue;
        };
        let mut dir = mount.join(found);
        loop {
            let read = |name: &str| std::fs::read_to_string(dir.join(name)).ok();
            // v2 says `max` for no limit; v1 a number near 2^63.
            let limit = read(limit_file).and_then(|t| t.trim().parse::<u64>().ok()).filter(|&l| l < 1 << 60);
            if let Some(limit) = limit {
                let used = read(usage_file).and_then(|t| t.trim().parse::<u64>().ok()).unwrap_or(0);
                let left = limit.saturating_sub(used);
                least = Some(least.map_or(left, |l| l.min(left)));
            }
            if dir == mount || !dir.pop() {
                break;
            }
        }
    }
    least
}

/// An error where `bytes`, what `what` needs, is more than the memory available
/// ([`available_bytes`]): a clear message up front instead of an abort when the allocation
/// fails. Nothing is checked where the available memory is unknown.
pub fn check_fits(what: &str, bytes: f64) -> Result<(), OutOfMemory> {
    match available_bytes() {
        Some(available) if bytes > available as f64 => Err(OutOfMemory { what: what.to_owned(), bytes, available }),
        _ => Ok(()),
    }
}

/// What [`check_fits`] refuses.
#[derive(Debug, thiserror::Error)]
#[error("{what} needs about {:.1} GB of memory, and {:.1} GB is available", bytes / 1e9, *available as f64 / 1e9)]
pub struct OutOfMemory {
    /// What needs the memory, as the user knows it (a file, a line, a key).
    pub what: String,
    pub bytes: f64,
    pub available: u64,
}

/// Peak bytes per triangle of a flat scene rendered on the CPU, its BVH built and collapsed and
/// the wide form it traces derived: the peak measured on a large city with several builders
/// (docs/benchmarks.md, "Memory"), with room to spare.
pub const RENDER_BYTES_PER_TRIANGLE: f64 = 480.0;

/// [`RENDER_BYTES_PER_TRIANGLE`] where only the binary tree is kept: a GPU render, or a CPU
/// render that traces the binary tree (measured before the wide form existed).
pub const RENDER_BYTES_PER_TRIANGLE_BINARY: f64 = 320.0;

/// The peak bytes per triangle a flat render is checked against: with the wide form, or
/// (`binary`) with the binary tree alone.
pub fn render_bytes_per_triangle(binary: bool) -> f64 {
    if binary { RENDER_BYTES_PER_TRIANGLE_BINARY } else { RENDER_BYTES_PER_TRIANGLE }
}

/// The whole file at `path`, refusing one longer than `limit` bytes: a path that never ends
/// (`/dev/zero`, a FIFO fed without end) is an error once past it, not a read until memory runs
/// out.
pub fn read_at_most(path: &std::path::Path, limit: u64) -> std::io::Result<Vec<u8>> {
    use std::io::Read as _;
    let mut file = std::fs::File::open(path)?;
    // Room for the whole file up front where its size is known: growing by doubling copied a
    // 20 MB file about twice over and took as long as parsing it.
    let size = file.metadata().ok().map(|m| m.len()).filter(|&n| n <= limit);
    let mut bytes = Vec::with_capacity(size.map_or(0, |n| usize::try_from(n).unwrap_or(0)));
    file.by_ref().take(limit.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(std::io::Error::other(format!("longer than {:.1} GB", limit as f64 / 1e9)));
    }
    Ok(bytes)
}

/// The longest text file worth reading whole: a quarter of the memory available (parsing keeps
/// copies of the text beside what it makes), and no limit where that is unknown.
pub fn text_file_limit() -> u64 {
    available_bytes().map_or(u64::MAX, |a| a / 4)
}

use std::path::Path;

fn status_kib(field: &str) -> Option<u64> {
    kib_field(&std::fs::read_to_string("/proc/self/status").ok()?, field)
}

/// The value of a `Name:   1234 kB` line of a `/proc` file.
fn kib_field(text: &str, field: &str) -> Option<u64> {
    let line = text.lines().find(|l| l.starts_with(field))?;
    line[field.len()..].trim().trim_end_matches("kB").trim().parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_stop_at_the_limit() {
        let path = std::env::temp_dir().join(format!("arbor-memory-read-{}", std::process::id()));
        std::fs::write(&path, b"0123456789").unwrap();
        assert_eq!(read_at_most(&path, 10).unwrap(), b"0123456789");
        assert!(read_at_most(&path, 9).unwrap_err().to_string().starts_with("longer than"));
        std::fs::remove_file(&path).unwrap();
        if std::path::Path::new("/dev/zero").exists() {
            assert!(read_at_most(std::path::Path::new("/dev/zero"), 1 << 20).is_err());
        }
    }

    #[test]
    fn more_than_the_machine_has_does_not_fit() {
        let Some(available) = available_bytes() else { return }; // not Linux
        assert!(available > 0);
        assert!(check_fits("a small thing", 1e3).is_ok());
        let err = check_fits("--procedural city:1e15", 1e18).unwrap_err().to_string();
        assert!(err.starts_with("--procedural city:1e15 needs about 1000000000.0 GB"), "{err}");
    }

    /// A v2 group inside a limited parent, and a v1 group whose path the container does not
    /// show (its group is the mount's root).
    #[test]
    fn cgroup_limits_are_read_up_the_tree() {
        let root = std::env::temp_dir().join(format!("arbor-memory-cgroup-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let job = root.join("sys/fs/cgroup/slurm/job_7/step_0");
        std::fs::create_dir_all(&job).unwrap();
        let write = |dir: &Path, name: &str, text: &str| std::fs::write(dir.join(name), text).unwrap();
        write(&job, "memory.max", "max\n");
        write(&job, "memory.current", "100\n");
        let parent = job.parent().unwrap();
        write(parent, "memory.max", "4000\n");
        write(parent, "memory.current", "1000\n");
        assert_eq!(cgroup_available_bytes(&root, "0::/slurm/job_7/step_0\n"), Some(3000));
        assert_eq!(cgroup_available_bytes(&root, "0::/\n"), None, "no limit at the root");
        let v1 = root.join("sys/fs/cgroup/memory");
        std::fs::create_dir_all(&v1).unwrap();
        write(&v1, "memory.limit_in_bytes", "2000\n");
        write(&v1, "memory.usage_in_bytes", "500\n");
        assert_eq!(cgroup_available_bytes(&root, "4:memory:/kubepods/pod1/abc\n"), Some(1500));
        // Both: the least.
        let both = "4:memory:/x\n0::/slurm/job_7/step_0\n";
        assert_eq!(cgroup_available_bytes(&root, both), Some(1500));
        write(&v1, "memory.limit_in_bytes", "9223372036854771712\n");
        assert_eq!(cgroup_available_bytes(&root, "4:memory:/\n"), None, "v1's no limit");
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn touching_memory_raises_the_peak() {
        let Some(before) = peak_rss_bytes() else { return }; // not Linux
        let block = vec![1u8; 64 << 20];
        std::hint::black_box(&block);
        // Other tests' threads allocate meanwhile: read the current size before the peak.
        let now = rss_bytes().expect("read before");
        let after = peak_rss_bytes().expect("read before");
        assert!(after >= before && after >= 64 << 20, "{before} -> {after}");
        assert!(now <= after, "current {now} above peak {after}");
    }
}
