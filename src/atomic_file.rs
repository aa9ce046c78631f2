//! Atomic file output: nothing is ever half-written.
//!
//! The content goes to a hidden temporary file beside the target
//! (`.<stem>.tmp<pid>-<n>.<ext>`: same directory, so the rename stays on one file system; the
//! counter keeps concurrent writes from one process apart; the target's extension is kept for
//! writers that choose a format by it), which is created exclusively, synced, then renamed over
//! the target. On any error the temporary is removed and the target is untouched; only a
//! process killed mid-write can leave a temporary behind.
//!
//! Where the target is a symbolic link, the file it points to is replaced (the link stays a
//! link). Where it is an existing file that is not a regular one (a FIFO, a device), or any
//! existing path under `/dev` or `/proc` (`/dev/stdout` sent to a file), the content is written
//! into it as a stream: renaming over it would put a plain file where the device was, or
//! replace the file a shell redirected to. A stream cannot be atomic.

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

/// Where a write to a path lands ([`destination`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Destination {
    /// A regular file, existing or not (a symbolic link's target where the path is a link):
    /// written to a temporary beside it, then renamed over it.
    File(PathBuf),
    /// An existing file that is not a regular one (device, FIFO): written in place.
    Stream(PathBuf),
}

/// Where a write to `path` lands; an error for a directory.
pub fn destination(path: &Path) -> io::Result<Destination> {
    // `out/b.exr/` names a folder; the rename would fail only after the work.
    if path.as_os_str().as_encoded_bytes().ends_with(b"/") {
        return Err(io::Error::new(io::ErrorKind::IsADirectory, "it ends in /, so it names a folder"));
    }
    // `/dev/stdout` leads through `/proc/self/fd/1` to wherever the shell sent the output, a
    // regular file too (`> log`): written in place, as the shell's redirection expects, not
    // replaced by a rename.
    let kernel_path = path.starts_with("/dev") || path.starts_with("/proc");
    match fs::metadata(path) {
        Ok(m) if m.is_dir() => Err(io::Error::new(io::ErrorKind::IsADirectory, "it is a directory")),
        Ok(m) if m.is_file() && !kernel_path => Ok(Destination::File(follow_links(path)?)),
        Ok(_) => Ok(Destination::Stream(path.to_owned())),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(Destination::File(follow_links(path)?)),
        Err(e) => Err(e),
    }
}

/// Whether writing `out` would replace the file `other` (an input, or another output): both
/// lead to one regular file, through links and relative paths. Streams never do: two outputs
/// to `/dev/stdout` are two writes to one stream, and `/dev/stdin` is not replaced by a write.
pub fn replaces(out: &Path, other: &Path) -> bool {
    let key = |p: &Path| -> Option<PathBuf> {
        let Ok(Destination::File(target)) = destination(p) else { return None };
        let name = target.file_name()?;
        let dir = target.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
        // A folder the write would make has no canonical form yet: its absolute path serves.
        let dir = fs::canonicalize(dir).or_else(|_| std::path::absolute(dir)).ok()?;
        Some(dir.join(name))
    };
    matches!((key(out), key(other)), (Some(a), Some(b)) if a == b)
}

/// `path` with the symbolic links of its last component followed, to a path that is not a link
/// (a dangling link's target, which the write will create).
fn follow_links(path: &Path) -> io::Result<PathBuf> {
    let mut p = path.to_owned();
    // Linux's own limit on links followed.
    for _ in 0..40 {
        match fs::symlink_metadata(&p) {
            Ok(m) if m.file_type().is_symlink() => {
                let target = fs::read_link(&p)?;
                // A relative target is relative to the link's folder; `join` keeps an absolute one.
                p = p.parent().map_or_else(|| target.clone(), |dir| dir.join(&target));
            }
            _ => return Ok(p),
        }
    }
    Err(io::Error::other("too many levels of symbolic links"))
}

/// Checks before any work is spent that `path` can be written: not a directory, and a file
/// creatable (a temporary, removed again) in its folder or, where that is missing, in the
/// nearest folder that exists. It makes nothing: the write makes the missing folders, so a
/// run that fails after this check leaves none behind.
pub fn prepare(path: &Path) -> io::Result<()> {
    let Destination::File(target) = destination(path)? else { return Ok(()) };
    let mut dir = folder_of(&target).to_path_buf();
    // Up to a folder that exists, or to `.` or `/` (which fail below if they are gone).
    while !dir.exists() && folder_of(&dir) != dir {
        dir = folder_of(&dir).to_path_buf();
    }
    if !dir.is_dir() {
        return Err(io::Error::new(io::ErrorKind::NotADirectory, format!("{} is not a folder", dir.display())));
    }
    let tmp = temp_path(&dir.join(target.file_name().unwrap_or_default()));
    OpenOptions::new().write(true).create_new(true).open(&tmp)?;
    fs::remove_file(&tmp)
}

/// The folder `path` is in: `.` for a bare name.
fn folder_of(path: &Path) -> &Path {
    path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."))
}

/// The temporary path for `path`.
pub fn temp_path(path: &Path) -> PathBuf {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let stem = path.file_stem().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let ext = path.extension().map(|e| format!(".{}", e.to_string_lossy())).unwrap_or_default();
    path.with_file_name(format!(".{stem}.tmp{}-{n}{ext}", std::process::id()))
}

/// Calls `write` with a fresh temporary path, then renames the file it wrote over `path` (see
/// the module docs for links and streams; a stream's path is passed to `write` itself).
/// `write` must create the file itself (for writers that only take a path); its own errors are
/// [`AtomicWriteError::Write`].
pub fn replace_via_temp<E>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), AtomicWriteError<E>>,
) -> Result<(), AtomicWriteError<E>> {
    write_to(path, |to, _| write(to))
}

/// [`replace_via_temp`], telling `write` whether it writes a stream.
fn write_to<E>(
    path: &Path,
    write: impl FnOnce(&Path, bool) -> Result<(), AtomicWriteError<E>>,
) -> Result<(), AtomicWriteError<E>> {
    let target = match destination(path) {
        Ok(Destination::File(target)) => target,
        Ok(Destination::Stream(stream)) => return write(&stream, true),
        Err(source) => return Err(AtomicWriteError::Io { what: "cannot write", source }),
    };
    // The temporary keeps the extension asked for, which writers may choose a format by, even
    // where a link leads to a name without it.
    let named = path.extension().map_or_else(|| target.clone(), |e| target.with_extension(e));
    let tmp = temp_path(&named);
    fs::create_dir_all(folder_of(&target))
        .map_err(|source| AtomicWriteError::Io { what: "cannot make the folder of", source })?;
    let result = write(&tmp, false).and_then(|()| {
        fs::rename(&tmp, &target)
            .map_err(|source| AtomicWriteError::Io { what: "cannot rename the temporary file over", source })
    });
    if result.is_err() {
        // Best effort: the temporary may not exist (its creation failed), which is fine.
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// A stream to write into: the process's own stdout or stderr shared (so a `> log` keeps what
/// was printed before, where opening `/dev/stdout` anew would write from the file's start),
/// else the path opened for writing.
fn open_stream(path: &Path) -> io::Result<File> {
    #[cfg(unix)]
    {
        use std::os::fd::AsFd;
        if path == Path::new("/dev/stdout") {
            return Ok(File::from(io::stdout().as_fd().try_clone_to_owned()?));
        }
        if path == Path::new("/dev/stderr") {
            return Ok(File::from(io::stderr().as_fd().try_clone_to_owned()?));
        }
    }
    OpenOptions::new().write(true).open(path)
}

/// Writes `path` through `write`, which gets a buffered, exclusively created temporary file;
/// the data is flushed and synced before the rename publishes it.
pub fn write_atomic<E>(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> Result<(), E>,
) -> Result<(), AtomicWriteError<E>> {
    write_to(path, |to, stream| {
        let io = |what| move |source| AtomicWriteError::Io { what, source };
        let file = if stream {
            open_stream(to).map_err(io("cannot open"))?
        } else {
            OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(to)
                .map_err(io("cannot create a temporary file beside"))?
        };
        let mut out = BufWriter::new(file);
        write(&mut out).map_err(AtomicWriteError::Write)?;
        let file =
            out.into_inner().map_err(|e| AtomicWriteError::Io { what: "cannot write", source: e.into_error() })?;
        // A device or FIFO has nothing to sync (and /dev/null refuses to).
        if stream { Ok(()) } else { file.sync_all().map_err(io("cannot sync")) }
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
        // Missing folders are made by the write.
        write_atomic::<io::Error>(&d.join("no/such/dir.txt"), |f| f.write_all(b"deep")).unwrap();
        assert_eq!(fs::read(d.join("no/such/dir.txt")).unwrap(), b"deep");
        let blocked = write_atomic::<io::Error>(&d.join("out.json/x.txt"), |_| Ok(()));
        assert!(matches!(blocked, Err(AtomicWriteError::Io { .. })), "a file in the way of a folder");
    }

    #[cfg(unix)]
    #[test]
    fn links_are_followed_and_streams_written_in_place() {
        use std::os::unix::fs::{FileTypeExt, symlink};
        let d = dir("links");
        let real = d.join("real.json");
        fs::write(&real, b"old").unwrap();
        let link = d.join("link.json");
        let _ = fs::remove_file(&link);
        symlink("real.json", &link).unwrap();
        write_atomic::<io::Error>(&link, |f| f.write_all(b"new")).unwrap();
        assert!(fs::symlink_metadata(&link).unwrap().file_type().is_symlink(), "the link was replaced");
        assert_eq!(fs::read(&real).unwrap(), b"new");
        // A dangling link: the file it names is created.
        let dangling = d.join("dangling.json");
        let _ = fs::remove_file(&dangling);
        let _ = fs::remove_file(d.join("made.json"));
        symlink("made.json", &dangling).unwrap();
        write_atomic::<io::Error>(&dangling, |f| f.write_all(b"made")).unwrap();
        assert_eq!(fs::read(d.join("made.json")).unwrap(), b"made");
        // A link to a device: written through, the device and the link stay.
        let null = d.join("null.json");
        let _ = fs::remove_file(&null);
        symlink("/dev/null", &null).unwrap();
        assert_eq!(destination(&null).unwrap(), Destination::Stream(null.clone()));
        write_atomic::<io::Error>(&null, |f| f.write_all(b"gone")).unwrap();
        assert!(fs::symlink_metadata(&null).unwrap().file_type().is_symlink());
        assert!(fs::metadata("/dev/null").unwrap().file_type().is_char_device());
        // A link to a name without the extension: the temporary keeps the one asked for.
        let plain = d.join("plot-v2");
        fs::write(&plain, b"old").unwrap();
        let png = d.join("plot.png");
        let _ = fs::remove_file(&png);
        symlink("plot-v2", &png).unwrap();
        replace_via_temp::<io::Error>(&png, |tmp| {
            assert_eq!(tmp.extension(), Some("png".as_ref()));
            fs::write(tmp, b"png").map_err(|source| AtomicWriteError::Io { what: "test", source })
        })
        .unwrap();
        assert_eq!(fs::read(&plain).unwrap(), b"png");
        // Paths under /dev are streams, whatever they lead to.
        assert_eq!(destination(Path::new("/dev/stdout")).unwrap(), Destination::Stream("/dev/stdout".into()));
        assert_eq!(destination(Path::new("/dev")).unwrap_err().kind(), io::ErrorKind::IsADirectory);
        assert!(leftovers(&d).is_empty(), "{:?}", leftovers(&d));
    }

    #[test]
    fn prepare_makes_nothing_and_refuses_directories() {
        let d = dir("prepare");
        let _ = fs::remove_dir_all(d.join("a"));
        let nested = d.join("a/b/out.png");
        prepare(&nested).unwrap();
        assert!(!d.join("a").exists(), "prepare made a folder");
        assert!(leftovers(&d).is_empty());
        prepare(Path::new("bare-name.png")).unwrap();
        fs::write(d.join("file"), b"").unwrap();
        assert_eq!(prepare(&d.join("file/out.png")).unwrap_err().kind(), io::ErrorKind::NotADirectory);
        let err = prepare(&d).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::IsADirectory);
        // A name ending in / is a folder, whether or not it exists.
        let slash = PathBuf::from(format!("{}/", d.join("new.exr").display()));
        assert_eq!(prepare(&slash).unwrap_err().kind(), io::ErrorKind::IsADirectory);
        assert!(write_atomic::<io::Error>(&slash, |_| Ok(())).is_err());
        assert!(!d.join("new.exr").exists() && leftovers(&d).is_empty());
        assert!(matches!(
            write_atomic::<io::Error>(&d, |_| Ok(())),
            Err(AtomicWriteError::Io { what: "cannot write", .. })
        ));
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
