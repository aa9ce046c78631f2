//! Outputs that would destroy what a run reads: `-o` naming the scene's own texture, a merge
//! writing over one of its pieces, `--report` naming the scene. Each is refused before any work,
//! whatever path leads there (relative, absolute, through a symbolic link: see
//! [`crate::atomic_file::replaces`]).
//!
//! A frame sequence's outputs are a pattern over a range of frames that may hold billions of
//! names, so they are not listed: for each file that must not be replaced, the frame numbers
//! whose name could be that file are read back out of its path (the pattern's text before and
//! after the number must match), and only those names are compared.

use std::ops::Range;
use std::path::{Path, PathBuf};

use super::frames::{frame_path, has_frame_pattern, pattern_parts};
use crate::atomic_file::replaces;

/// A file of a run, as the user named it: what it is to the run (`the scene`, `a texture`,
/// `-o`, `--report`) and its path.
#[derive(Clone, Debug)]
pub struct Named {
    pub what: String,
    pub path: PathBuf,
}

impl Named {
    pub fn new(what: impl Into<String>, path: impl Into<PathBuf>) -> Named {
        Named { what: what.into(), path: path.into() }
    }
}

/// An output that would replace a file the run reads, or another of its outputs.
#[derive(Debug, thiserror::Error)]
#[error("{} {}: {} {} {}; nothing was written: choose another name", output.what, output.path.display(), written(output, *frame), other.what, other.path.display())]
pub struct Overwrite {
    pub output: Named,
    /// The frame whose output it is, where the output is a frame pattern.
    pub frame: Option<u32>,
    pub other: Named,
}

/// `it would overwrite`, or for a frame pattern `frame F's output, NAME, would overwrite`.
fn written(output: &Named, frame: Option<u32>) -> String {
    match frame {
        None => "it would overwrite".to_owned(),
        Some(f) => format!("frame {f}'s output, {}, would overwrite", frame_path(&output.path, f).display()),
    }
}

/// Checks that no output replaces an input or another output. `outputs` are written for every
/// frame of `frames` where their path has a frame pattern (`out_%04d.exr`), else once; `inputs`
/// are read. Streams (`/dev/stdout`, a FIFO) never collide: nothing is replaced there.
pub fn check_overwrites(outputs: &[Named], frames: Option<&Range<u32>>, inputs: &[Named]) -> Result<(), Overwrite> {
    for (i, out) in outputs.iter().enumerate() {
        for input in inputs {
            if let Some(frame) = collides(out, frames, &input.path) {
                return Err(Overwrite { output: out.clone(), frame, other: input.clone() });
            }
        }
        // Each pair of outputs both ways round, for the one that is a pattern. Two patterns (an
        // image and its state, `OUT.partial.exr`) never name one file.
        for other in &outputs[i + 1..] {
            if let Some(frame) = collides(out, frames, &other.path) {
                return Err(Overwrite { output: out.clone(), frame, other: other.clone() });
            }
            if let Some(frame) = collides(other, frames, &out.path) {
                return Err(Overwrite { output: other.clone(), frame, other: out.clone() });
            }
        }
    }
    Ok(())
}

/// Whether writing `out` (over `frames` where it is a pattern) replaces `file`: `Some(None)`
/// for a plain output, `Some(Some(frame))` for the frame whose output it is.
fn collides(out: &Named, frames: Option<&Range<u32>>, file: &Path) -> Option<Option<u32>> {
    match frames.filter(|_| has_frame_pattern(&out.path)) {
        None => replaces(&out.path, file).then_some(None),
        Some(frames) => frames_naming(&out.path, file, frames)
            .into_iter()
            .find(|&f| replaces(&frame_path(&out.path, f), file))
            .map(Some),
    }
}

/// The frames of `frames` whose name by `pattern` might be `file`: the number read out of each
/// spelling of `file` (as given, absolute, with its links resolved) that matches a spelling of
/// the pattern (as given, absolute, its folder's links resolved) around its frame number.
fn frames_naming(pattern: &Path, file: &Path, frames: &Range<u32>) -> Vec<u32> {
    let mut files = vec![file.to_path_buf()];
    files.extend(std::path::absolute(file).ok());
    files.extend(std::fs::canonicalize(file).ok());
    files.extend(canonical_folder(file));
    let mut patterns = vec![pattern.to_path_buf()];
    patterns.extend(std::path::absolute(pattern).ok());
    patterns.extend(canonical_folder(pattern).filter(|p| has_frame_pattern(p)));
    let mut found = Vec::new();
    for p in &patterns {
        let p = p.to_string_lossy();
        let Some((before, after)) = pattern_parts(&p) else { continue };
        for f in &files {
            let f = f.to_string_lossy();
            let Some(digits) = f.strip_prefix(before).and_then(|rest| rest.strip_suffix(after)) else { continue };
            if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
                continue;
            }
            if let Ok(n) = digits.parse::<u32>() {
                if frames.contains(&n) && !found.contains(&n) {
                    found.push(n);
                }
            }
        }
    }
    found
}

/// `path` with its folder's links resolved (its last component kept), where the folder exists.
fn canonical_folder(path: &Path) -> Option<PathBuf> {
    let name = path.file_name()?;
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    Some(std::fs::canonicalize(dir).ok()?.join(name))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("arbor-overwrite-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn plain_outputs_collide_with_inputs_and_each_other() {
        let d = scratch("plain");
        let sky = d.join("sky.exr");
        std::fs::write(&sky, b"sky").unwrap();
        let inputs = [Named::new("the scene", d.join("s.toml")), Named::new("the environment map", &sky)];
        let ok = [Named::new("-o", d.join("out.exr")), Named::new("--report", d.join("r.json"))];
        assert!(check_overwrites(&ok, None, &inputs).is_ok());
        // Through `..` and a link.
        std::fs::create_dir_all(d.join("sub")).unwrap();
        let e = check_overwrites(&[Named::new("-o", d.join("sub/../sky.exr"))], None, &inputs).unwrap_err();
        assert!(e.to_string().contains("would overwrite the environment map"), "{e}");
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(&sky, d.join("link.exr")).unwrap();
            assert!(check_overwrites(&[Named::new("-o", d.join("link.exr"))], None, &inputs).is_err());
        }
        let same = [Named::new("-o", d.join("x.png")), Named::new("--report", d.join("x.png"))];
        let e = check_overwrites(&same, None, &[]).unwrap_err().to_string();
        assert!(e.starts_with(&format!("-o {}: it would overwrite --report", d.join("x.png").display())), "{e}");
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn a_frame_pattern_collides_at_the_frame_that_names_the_file() {
        let d = scratch("frames");
        let tex = d.join("tex_0042.png");
        std::fs::write(&tex, b"t").unwrap();
        let inputs = [Named::new("a texture", &tex)];
        let out = [Named::new("-o", d.join("tex_%04d.png"))];
        let e = check_overwrites(&out, Some(&(0..4_000_000_000)), &inputs).unwrap_err();
        assert_eq!(e.frame, Some(42));
        assert!(check_overwrites(&out, Some(&(0..42)), &inputs).is_ok());
        assert!(check_overwrites(&out, Some(&(43..100)), &inputs).is_ok());
        // `%d` is not padded: tex_0042 is not its frame 42.
        assert!(check_overwrites(&[Named::new("-o", d.join("tex_%d.png"))], Some(&(0..100)), &inputs).is_ok());
        // Relative spellings meet absolute ones.
        let cwd = std::env::current_dir().unwrap();
        let rel = pathdiff(&d, &cwd).join("tex_%04d.png");
        assert!(check_overwrites(&[Named::new("-o", rel)], Some(&(0..100)), &inputs).is_err());
        let _ = std::fs::remove_dir_all(&d);
    }

    /// `path` relative to `base`, through `..`s.
    fn pathdiff(path: &Path, base: &Path) -> PathBuf {
        let ups = base.components().count();
        let mut p: PathBuf = (0..ups).map(|_| "..").collect();
        p.push(path.strip_prefix("/").unwrap());
        p
    }
}
