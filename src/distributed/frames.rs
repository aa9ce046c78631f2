//! Frame-number patterns in output names: `out_%04d.exr` becomes `out_0007.exr` for frame 7.

use std::path::{Path, PathBuf};

/// Whether `path` holds a frame-number pattern: `%d`, or `%0Nd` with N digits (`%04d`, `%010d`).
/// A `%` in any other place is kept as it is (there is no `%%` escape).
pub fn has_frame_pattern(path: impl AsRef<Path>) -> bool {
    find_frame_pattern(&path.as_ref().to_string_lossy()).is_some()
}

/// `path` with its first frame-number pattern (`%d` or `%0Nd`, as in printf) replaced by
/// `frame`, zero-padded to N digits; `path` itself when it has none.
pub fn frame_path(path: impl AsRef<Path>, frame: u32) -> PathBuf {
    let text = path.as_ref().to_string_lossy();
    match find_frame_pattern(&text) {
        Some((range, width)) => PathBuf::from(format!("{}{frame:0width$}{}", &text[..range.start], &text[range.end..])),
        None => path.as_ref().to_path_buf(),
    }
}

/// The text of `path` before and after its first frame-number pattern, where it has one.
pub fn pattern_parts(path: &str) -> Option<(&str, &str)> {
    let (range, _) = find_frame_pattern(path)?;
    Some((&path[..range.start], &path[range.end..]))
}

/// Widest zero padding a frame pattern may ask for: a file name is at most 255 bytes.
const MAX_FRAME_WIDTH: usize = 255;

/// The byte range and zero-padding width of the first `%d` or `%0Nd` in `s`.
fn find_frame_pattern(s: &str) -> Option<(std::ops::Range<usize>, usize)> {
    let bytes = s.as_bytes();
    for (i, _) in s.match_indices('%') {
        match bytes.get(i + 1..) {
            Some([b'd', ..]) => return Some((i..i + 2, 0)),
            Some([b'0', rest @ ..]) => {
                let digits = rest.iter().take_while(|b| b.is_ascii_digit()).count();
                if rest.get(digits) == Some(&b'd') {
                    let width = s[i + 2..i + 2 + digits].parse::<usize>().unwrap_or(0).min(MAX_FRAME_WIDTH);
                    return Some((i..i + 3 + digits, width));
                }
            }
            _ => {}
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_patterns_take_any_width() {
        let cases = [
            ("f_%04d.png", 7, "f_0007.png"),
            ("f_%d.png", 7, "f_7.png"),
            ("f_%010d.exr", 42, "f_0000000042.exr"),
            ("f_%0d.png", 7, "f_7.png"),
            ("f_%00d.png", 7, "f_7.png"),
            ("%02d/f_%03d.png", 5, "05/f_%03d.png"),
            ("f_100%.png", 5, "f_100%.png"),
            ("f_%4d.png", 5, "f_%4d.png"),
        ];
        for (name, frame, expected) in cases {
            assert_eq!(frame_path(name, frame), PathBuf::from(expected), "{name}");
            assert_eq!(has_frame_pattern(name), name != expected, "{name}");
        }
    }
}
