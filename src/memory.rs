//! The process's memory as the kernel counts it, for reports (peak memory per triangle) and for
//! refusing work that would not fit before it allocates; and the one reader of whole files,
//! which refuses what is not a regular file before opening it.
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
/// group has a memory limit ([`cgroup_available_bytes`]) or the process a resource limit
/// ([`rlimit_available_bytes`]). Under Slurm or Kubernetes the job's cgroup limit, not the
/// machine, is what ends a job that asks too much; under `ulimit -v` an allocation past the
/// limit fails and the process aborts.
pub fn available_bytes() -> Option<u64> {
    let machine = std::fs::read_to_string("/proc/meminfo").ok().and_then(|info| kib_field(&info, "MemAvailable:"));
    let machine = machine.map(|k| k * 1024);
    let cgroup =
        std::fs::read_to_string("/proc/self/cgroup").ok().and_then(|c| cgroup_available_bytes(Path::new("/"), &c));
    let read = |name: &str| std::fs::read_to_string(Path::new("/proc/self").join(name)).ok();
    let rlimit = read("limits").zip(read("status")).and_then(|(l, s)| rlimit_available_bytes(&l, &s));
    [machine, cgroup, rlimit].into_iter().flatten().min()
}

/// What the process's resource limits leave unused, bytes: `limits` is the text of
/// `/proc/self/limits` and `status` of `/proc/self/status`. The address space's soft limit
/// (`RLIMIT_AS`, `ulimit -v`) less `VmSize`, and the data segment's (`RLIMIT_DATA`, `ulimit -d`,
/// which since Linux 4.7 counts every private writable mapping) less `VmData`; the lesser of
/// the two, `None` where neither is limited. Both count address space reserved and not yet
/// touched (thread stacks, the allocator's arenas), as the kernel does when it refuses a
/// mapping.
///
/// Read from `/proc` like the rest of this module, not by `getrlimit`: the same numbers, with
/// no `unsafe` and no dependency on `libc`.
pub fn rlimit_available_bytes(limits: &str, status: &str) -> Option<u64> {
    let soft_limit = |name: &str| -> Option<u64> {
        let rest = limits.lines().find_map(|l| l.strip_prefix(name))?;
        // "unlimited", or bytes.
        rest.split_whitespace().next()?.parse().ok()
    };
    let left = |name: &str, used: &str| {
        soft_limit(name).map(|limit| limit.saturating_sub(kib_field(status, used).unwrap_or(0) * 1024))
    };
    [left("Max address space", "VmSize:"), left("Max data size", "VmData:")].into_iter().flatten().min()
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
#[derive(Clone, Debug, thiserror::Error)]
#[error("{what} needs about {} of memory, and {} is available", shown(*bytes), shown(*available as f64))]
pub struct OutOfMemory {
    /// What needs the memory, as the user knows it (a file, a line, a key).
    pub what: String,
    pub bytes: f64,
    pub available: u64,
}

/// `bytes` for a message: in GB to one decimal, or below 1 GB in MB (a limit of 200 MB is not
/// "0.0 GB").
fn shown(bytes: f64) -> String {
    if bytes >= 1e9 { format!("{:.1} GB", bytes / 1e9) } else { format!("{:.0} MB", bytes / 1e6) }
}

/// Peak bytes per triangle of a flat scene rendered on the CPU, its BVH built and collapsed and
/// the wide form it traces derived: the peak measured on a large city with several builders
/// (docs/benchmarks.md, "Memory"), with room to spare.
pub const RENDER_BYTES_PER_TRIANGLE: f64 = 480.0;

/// [`RENDER_BYTES_PER_TRIANGLE`] where only the binary tree is kept: a render, on the CPU or
/// the GPU, that traces the binary tree (measured before the wide forms existed). A GPU render
/// of the wide form is checked against [`RENDER_BYTES_PER_TRIANGLE`]: on lavapipe, whose device
/// memory is the host's, its peak was 1.22 times the binary form's (docs/benchmarks.md).
pub const RENDER_BYTES_PER_TRIANGLE_BINARY: f64 = 320.0;

/// Peak bytes per instance of a render as instances (the CPU's two levels), besides its meshes'
/// BVHs: the scene's object, the instance, its share of the top-level BVH and of what is built
/// beside it. 520 and 536 were measured on 3 and 10 million scattered boxes; with room.
pub const RENDER_BYTES_PER_INSTANCE: f64 = 640.0;

/// The peak bytes per triangle a flat render is checked against: with the wide form, or
/// (`binary`) with the binary tree alone.
pub fn render_bytes_per_triangle(binary: bool) -> f64 {
    if binary { RENDER_BYTES_PER_TRIANGLE_BINARY } else { RENDER_BYTES_PER_TRIANGLE }
}

/// Bytes a text file is taken to need per byte once read and parsed: the text, and the copies
/// and structures parsing makes beside it (a quarter of the memory available is the longest
/// file read whole, [`text_file_limit`]).
pub const TEXT_BYTES_PER_BYTE: f64 = 4.0;

/// The whole of the regular file at `path` (OBJ, MTL, PLY, glTF): refused before it is opened
/// where it is not a regular file ([`regular_file_len`]), and where its text read and parsed
/// would not fit in memory ([`TEXT_BYTES_PER_BYTE`]; an error of kind
/// [`std::io::ErrorKind::OutOfMemory`] whose payload is the [`OutOfMemory`]).
pub fn read_file(path: &Path) -> std::io::Result<Vec<u8>> {
    let len = regular_file_len(path)?;
    let what = format!("its {:.1} MB, read and parsed,", len as f64 / 1e6);
    check_fits(&what, len as f64 * TEXT_BYTES_PER_BYTE)
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::OutOfMemory, e))?;
    read_limited(std::fs::File::open(path)?, Some(len), text_file_limit())
}

thread_local! {
    /// The regular files [`regular_file_len`] looked at on this thread (every reader here, and
    /// the texture and sky map readers, look there before they open a file) while
    /// [`recording_reads`] runs.
    static READS: std::cell::RefCell<Option<Vec<std::path::PathBuf>>> = const { std::cell::RefCell::new(None) };
}

/// Runs `f`, and returns with its result every regular file that [`regular_file_len`] looked at
/// on this thread meanwhile, so every file a scene's loading read or was about to (its MTL
/// files and glTF buffers beside the files the scene names), even where loading then failed:
/// what a render, and its report, must not overwrite.
pub fn recording_reads<T>(f: impl FnOnce() -> T) -> (T, Vec<std::path::PathBuf>) {
    let outer = READS.with(|r| r.borrow_mut().replace(Vec::new()));
    let result = f();
    let read = READS.with(|r| r.borrow_mut().take()).unwrap_or_default();
    // A recording around this one hears of these reads too.
    let outer = outer.map(|mut o| {
        o.extend(read.iter().cloned());
        o
    });
    READS.with(|r| *r.borrow_mut() = outer);
    (result, read)
}

fn note_read(path: &Path) {
    READS.with(|r| {
        if let Some(list) = r.borrow_mut().as_mut() {
            list.push(path.to_path_buf());
        }
    });
}

/// [`read_file`] that also reads a named pipe to its end: the scene file, which a user may give
/// as `render <(generate) ...`. A pipe longer than [`text_file_limit`] is an error of kind
/// [`std::io::ErrorKind::OutOfMemory`] once past it, not a read until memory runs out. A folder
/// is an error of kind [`std::io::ErrorKind::IsADirectory`].
pub fn read_file_or_pipe(path: &Path) -> std::io::Result<Vec<u8>> {
    let meta = std::fs::metadata(path)?;
    if !is_fifo(&meta) {
        return read_file(path);
    }
    read_limited(std::fs::File::open(path)?, None, text_file_limit())
}

/// The whole of the regular file at `path`, checked as [`read_file`] checks it but against
/// `limit` bytes rather than the memory available: a longer file is an error of kind
/// [`std::io::ErrorKind::OutOfMemory`] (a limit is the memory's, as [`text_file_limit`] is),
/// found from its length before it is opened.
pub fn read_at_most(path: &Path, limit: u64) -> std::io::Result<Vec<u8>> {
    let len = regular_file_len(path)?;
    if len > limit {
        return Err(longer_than(limit));
    }
    read_limited(std::fs::File::open(path)?, Some(len), limit)
}

/// The first `len` bytes of the regular file at `path` (a glTF buffer of `byteLength` bytes):
/// an error of kind [`std::io::ErrorKind::UnexpectedEof`] where it holds fewer; bytes past
/// them are never read, however many there are.
pub fn read_prefix(path: &Path, len: u64) -> std::io::Result<Vec<u8>> {
    let held = regular_file_len(path)?;
    if held < len {
        let message = format!("holds {held} bytes, fewer than {len}");
        return Err(std::io::Error::new(std::io::ErrorKind::UnexpectedEof, message));
    }
    use std::io::Read as _;
    let mut bytes = Vec::with_capacity(usize::try_from(len).unwrap_or(0));
    std::fs::File::open(path)?.take(len).read_to_end(&mut bytes)?;
    if (bytes.len() as u64) < len {
        let message = format!("ended after {} bytes, before {len} (did it shrink?)", bytes.len());
        return Err(std::io::Error::new(std::io::ErrorKind::UnexpectedEof, message));
    }
    Ok(bytes)
}

/// The length of the regular file at `path` (links followed), from its metadata: anything else
/// is an error before it is opened, which for a named pipe waits for a writer for ever, and
/// which for a device may never end (`/dev/zero`). A folder is an error of kind
/// [`std::io::ErrorKind::IsADirectory`], the rest of kind [`std::io::ErrorKind::InvalidInput`].
pub fn regular_file_len(path: &Path) -> std::io::Result<u64> {
    use std::io::{Error, ErrorKind};
    let meta = std::fs::metadata(path)?;
    if meta.is_file() {
        note_read(path);
        return Ok(meta.len());
    }
    if meta.is_dir() {
        return Err(Error::new(ErrorKind::IsADirectory, "is a directory, not a regular file"));
    }
    Err(Error::new(ErrorKind::InvalidInput, format!("is {}, not a regular file", kind_of(&meta))))
}

/// What a file that is not regular nor a folder is, for messages.
fn kind_of(meta: &std::fs::Metadata) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt as _;
        let t = meta.file_type();
        if t.is_fifo() {
            return "a named pipe (FIFO)";
        }
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    let _ = meta;
    "a special file"
}

fn is_fifo(meta: &std::fs::Metadata) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt as _;
        meta.file_type().is_fifo()
    }
    #[cfg(not(unix))]
    {
        let _ = meta;
        false
    }
}

/// `file` read to its end, refusing more than `limit` bytes; `size` is its length where known,
/// the room taken up front: growing by doubling copied a 20 MB file about twice over and took
/// as long as parsing it.
fn read_limited(file: std::fs::File, size: Option<u64>, limit: u64) -> std::io::Result<Vec<u8>> {
    use std::io::Read as _;
    let room = size.filter(|&n| n <= limit).map_or(0, |n| usize::try_from(n).unwrap_or(0));
    let mut bytes = Vec::with_capacity(room);
    file.take(limit.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(longer_than(limit));
    }
    Ok(bytes)
}

fn longer_than(limit: u64) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::OutOfMemory, format!("longer than {}", shown(limit as f64)))
}

/// The longest text file worth reading whole: a quarter of the memory available (parsing keeps
/// copies of the text beside what it makes, [`TEXT_BYTES_PER_BYTE`]), and no limit where that
/// is unknown.
pub fn text_file_limit() -> u64 {
    available_bytes().map_or(u64::MAX, |a| (a as f64 / TEXT_BYTES_PER_BYTE) as u64)
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
    fn reads_stop_at_the_limit_and_refuse_what_is_not_a_regular_file() {
        use std::io::ErrorKind;
        let dir = std::env::temp_dir().join(format!("arbor-memory-read-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("ten");
        std::fs::write(&path, b"0123456789").unwrap();
        let open = || std::fs::File::open(&path).unwrap();
        assert_eq!(read_limited(open(), Some(10), 10).unwrap(), b"0123456789");
        let long = read_limited(open(), None, 9).unwrap_err();
        assert!(long.kind() == ErrorKind::OutOfMemory && long.to_string().starts_with("longer than"), "{long}");
        assert_eq!(read_at_most(&path, 10).unwrap(), b"0123456789");
        assert_eq!(read_at_most(&path, 9).unwrap_err().kind(), ErrorKind::OutOfMemory);
        assert_eq!(read_file(&path).unwrap(), b"0123456789");
        assert_eq!(read_file_or_pipe(&path).unwrap(), b"0123456789");
        assert_eq!(read_prefix(&path, 4).unwrap(), b"0123");
        assert_eq!(read_prefix(&path, 11).unwrap_err().kind(), ErrorKind::UnexpectedEof);
        assert_eq!(read_file(&dir).unwrap_err().kind(), ErrorKind::IsADirectory);
        assert_eq!(read_file_or_pipe(&dir).unwrap_err().kind(), ErrorKind::IsADirectory);
        assert_eq!(read_file(&dir.join("none")).unwrap_err().kind(), ErrorKind::NotFound);
        if Path::new("/dev/zero").exists() {
            let zero = read_file(Path::new("/dev/zero")).unwrap_err();
            assert_eq!(zero.kind(), ErrorKind::InvalidInput);
            assert_eq!(zero.to_string(), "is a character device, not a regular file");
            assert!(read_prefix(Path::new("/dev/zero"), 4).is_err());
            assert_eq!(read_at_most(Path::new("/dev/zero"), 1 << 20).unwrap_err().kind(), ErrorKind::InvalidInput);
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The address space's and the data segment's soft limits, less what the process maps;
    /// `unlimited` is no limit.
    #[test]
    fn resource_limits_leave_the_limit_less_what_is_mapped() {
        let limits = "Limit                     Soft Limit           Hard Limit           Units     \n\
                      Max data size             unlimited            unlimited            bytes     \n\
                      Max address space         204800000            unlimited            bytes     \n";
        let status = "Name:\trender\nVmSize:\t  100000 kB\nVmData:\t   50000 kB\n";
        assert_eq!(rlimit_available_bytes(limits, status), Some(204_800_000 - 102_400_000));
        let data = limits.replace("Max data size             unlimited", "Max data size             60000000 ");
        assert_eq!(rlimit_available_bytes(&data, status), Some(60_000_000 - 51_200_000));
        let none = limits.replace("204800000", "unlimited");
        assert_eq!(rlimit_available_bytes(&none, status), None);
        let over = limits.replace("204800000", "1000");
        assert_eq!(rlimit_available_bytes(&over, status), Some(0));
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
