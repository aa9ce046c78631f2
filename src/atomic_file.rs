//! Atomic file output: nothing is ever half-written.
//!
//! The content goes to a hidden temporary file beside the target
//! (`.<stem>.tmp<pid>-<n>.<ext>`: same directory, so the rename stays on one file system; the
//! counter keeps concurrent writes from one process apart; the target's extension is kept for
//! writers that choose a format by it), which is created exclusively, synced, then renamed over
//! the target. On any error the temporary is removed and the target is untouched; only a
//! process killed mid-write can leave a temporary behind.

use std::fs::{self, File, OpenOptions};
use std::io::{self, BufWriter};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// A failed atomic write: a file-system step (`what` says which), or the caller's own writer.
#[derive(Debug)]
pub enum AtomicWriteError<E> {
    Io { what: &'static str, source: io::Error },
    Write(E),
}

/// The temporary path for `path`.
pub fn temp_path(path: &Path) -> PathBuf {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let stem = path.file_stem().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let ext = path.extension().map(|e| format!(".{}", e.to_string_lossy())).unwrap_or_default();
    path.with_file_name(format!(".{stem}.tmp{}-{n}{ext}", std::process::id()))
}

/// Calls `write` with a fresh temporary path, then renames the file it wrote over `path`.
/// `write` must create the file itself (for writers that only take a path); its own errors are
/// [`AtomicWriteError::Write`].
pub fn replace_via_temp<E>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), AtomicWriteError<E>>,
) -> Result<(), AtomicWriteError<E>> {
    let tmp = temp_path(path);
    let result = write(&tmp).and_then(|()| {
        fs::rename(&tmp, path)
            .map_err(|source| AtomicWriteError::Io { what: "cannot rename the temporary file over", source })
    });
    if result.is_err() {
        // Best effort: the temporary may not exist (its creation failed), which is fine.
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// Writes `path` through `write`, which gets a buffered, exclusively created temporary file;
/// the data is flushed and synced before the rename publishes it.
pub fn write_atomic<E>(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> Result<(), E>,
) -> Result<(), AtomicWriteError<E>> {
    replace_via_temp(path, |tmp| {
        let io = |what| move |source| AtomicWriteError::Io { what, source };
        let file = OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(tmp)
            .map_err(io("cannot create a temporary file beside"))?;
        let mut out = BufWriter::new(file);
        write(&mut out).map_err(AtomicWriteError::Write)?;
        let file =
            out.into_inner().map_err(|e| AtomicWriteError::Io { what: "cannot write", source: e.into_error() })?;
        file.sync_all().map_err(io("cannot sync"))
    })
}

#[cfg(test)]
mod tests {
    use std::io::Write;

    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("arbor-atomic-{name}-{}", std::process::id()));
        fs::create_dir_all(&d).unwrap();
        d
    }

    fn leftovers(d: &Path) -> Vec<String> {
        fs::read_dir(d)
            .unwrap()
            .filter_map(|e| e.ok()?.file_name().into_string().ok())
            .filter(|n| n.contains(".tmp"))
            .collect()
    }

    #[test]
    fn writes_replace_and_failures_leave_the_target_untouched() {
        let d = dir("basic");
        let target = d.join("out.json");
        write_atomic::<io::Error>(&target, |f| f.write_all(b"one")).unwrap();
        write_atomic::<io::Error>(&target, |f| f.write_all(b"two")).unwrap();
        assert_eq!(fs::read(&target).unwrap(), b"two");
        let failed = write_atomic(&target, |f| {
            f.write_all(b"half").unwrap();
            Err("encoder failed")
        });
        assert!(matches!(failed, Err(AtomicWriteError::Write("encoder failed"))));
        assert_eq!(fs::read(&target).unwrap(), b"two");
        assert!(leftovers(&d).is_empty(), "{:?}", leftovers(&d));
        let missing = write_atomic::<io::Error>(&d.join("no/such/dir.txt"), |_| Ok(()));
        assert!(matches!(missing, Err(AtomicWriteError::Io { what: "cannot create a temporary file beside", .. })));
    }

    #[test]
    fn temp_names_are_hidden_distinct_and_keep_the_extension() {
        let (a, b) = (temp_path(Path::new("/x/plot.png")), temp_path(Path::new("/x/plot.png")));
        assert_ne!(a, b);
        let name = a.file_name().unwrap().to_string_lossy().into_owned();
        assert!(name.starts_with(".plot.tmp") && name.ends_with(".png"), "{name}");
        assert_eq!(a.parent(), Some(Path::new("/x")));
    }
}
