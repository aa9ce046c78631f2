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

/// Memory the system can give this process now without swapping (`MemAvailable` of
/// `/proc/meminfo`, Linux), bytes; `None` where unknown.
pub fn available_bytes() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    kib_field(&info, "MemAvailable:").map(|k| k * 1024)
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
    let mut bytes = Vec::new();
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
