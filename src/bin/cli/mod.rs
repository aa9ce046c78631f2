//! What the command-line tools share (`render`, and `bvh-bench`, which includes this file by
//! path): standard output that survives a closed pipe, and `--threads`.

/// `println!` for the tools' reports, which does not panic when standard output fails: a
/// closed pipe (`| head`) is ignored, so the work, and the files it writes, go on (`println!`
/// would panic); any other failure (`> /dev/full`) is kept for [`stdout_error`], which the
/// tools check before they exit.
macro_rules! outln {
    ($($arg:tt)*) => {
        $crate::cli::write_stdout_line(format_args!($($arg)*))
    };
}
pub(crate) use outln;

static STDOUT_ERROR: std::sync::OnceLock<std::io::Error> = std::sync::OnceLock::new();

/// What [`outln!`] does: one line to standard output, flushed by the line.
pub fn write_stdout_line(line: std::fmt::Arguments) {
    use std::io::Write as _;
    if let Err(e) = writeln!(std::io::stdout(), "{line}") {
        if e.kind() != std::io::ErrorKind::BrokenPipe {
            let _ = STDOUT_ERROR.set(e);
        }
    }
}

/// The first error [`outln!`] met writing standard output, other than a closed pipe: a report
/// that did not arrive must not end in success.
pub fn stdout_error() -> Option<&'static std::io::Error> {
    STDOUT_ERROR.get()
}

/// Most worker threads `--threads` takes: far past any core count, and below the thousands at
/// which the pool's start-up alone takes seconds.
pub const MAX_THREADS: usize = 1024;

/// Sizes rayon's global pool from `--threads` (all cores when `None`).
pub fn init_threads(threads: Option<usize>) -> anyhow::Result<()> {
    let Some(n) = threads else { return Ok(()) };
    if !(1..=MAX_THREADS).contains(&n) {
        anyhow::bail!("--threads must be 1 to {MAX_THREADS}, not {n}");
    }
    rayon::ThreadPoolBuilder::new().num_threads(n).build_global().map_err(|e| anyhow::anyhow!("--threads: {e}"))
}
