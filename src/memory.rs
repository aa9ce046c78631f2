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

fn status_kib(field: &str) -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with(field))?;
    line[field.len()..].trim().trim_end_matches("kB").trim().parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

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
