//! Image files: linear float RGB [`Image`]s written as EXR (float32, lossless ZIP) or as 8-bit
//! sRGB PNG, and EXR read back for golden-image tests.
//!
//! Writes are atomic ([`crate::atomic_file`]): a failed write leaves the target untouched and no
//! temporary file behind.
//!
//! PNG encoding applies the exact piecewise sRGB transfer function (IEC 61966-2-1), clamps to
//! [0, 1] (NaN becomes 0) and rounds to the nearest 8-bit code. No tonemapping: that is the
//! caller's choice, made before writing.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use crate::atomic_file::{AtomicWriteError, write_atomic};

/// A linear RGB image, row-major, row 0 at the top (the convention of our reference images).
///
/// Invariant expected by every consumer: `pixels.len() == width * height`. The fields are public
/// so that tests can build images freely; [`write_image`] checks the invariant and returns
/// [`ImageError::BadSize`] instead of panicking.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<[f32; 3]>,
}

impl Image {
    /// A black image of `width` x `height` pixels.
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, pixels: vec![[0.0; 3]; width as usize * height as usize] }
    }

    /// The pixel at column `x`, row `y` (row 0 at the top); `None` outside the image.
    pub fn get(&self, x: u32, y: u32) -> Option<[f32; 3]> {
        if x >= self.width || y >= self.height {
            return None;
        }
        self.pixels.get(y as usize * self.width as usize + x as usize).copied()
    }

    /// Per-channel mean over all pixels, accumulated in f64 in row-major order; zero when empty.
    pub fn mean(&self) -> [f64; 3] {
        let mut sum = [0.0f64; 3];
        for p in &self.pixels {
            for c in 0..3 {
                sum[c] += f64::from(p[c]);
            }
        }
        let n = self.pixels.len().max(1) as f64;
        sum.map(|s| s / n)
    }

    fn check_size(&self, path: &Path) -> Result<(), ImageError> {
        let expected = self.width as usize * self.height as usize;
        if expected == 0 || self.pixels.len() != expected {
            return Err(ImageError::BadSize {
                path: path.to_path_buf(),
                width: self.width,
                height: self.height,
                pixels: self.pixels.len(),
            });
        }
        Ok(())
    }
}

/// What went wrong reading or writing an image; every variant names the file. The underlying
/// cause is the error's `source()`, not repeated in its message, so `{:#}` prints it once.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("{}: unsupported image file extension (supported: .exr, .png)", path.display())]
    UnsupportedExtension { path: PathBuf },
    #[error(
        "{}: image of {width}x{height} has {pixels} pixels (must be width*height, and not zero)",
        path.display()
    )]
    BadSize { path: PathBuf, width: u32, height: u32, pixels: usize },
    #[error("{}: {what}", path.display())]
    Io {
        path: PathBuf,
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: cannot {what} EXR", path.display())]
    Exr {
        path: PathBuf,
        what: &'static str,
        #[source]
        source: exr::error::Error,
    },
    #[error("{}: cannot encode PNG", path.display())]
    Png {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Exr,
    Png,
}

impl Format {
    /// By the file name's ending, case-insensitive.
    fn of(path: &Path) -> Result<Self, ImageError> {
        let name = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
        if name.ends_with(".png") {
            Ok(Format::Png)
        } else if name.ends_with(".exr") {
            Ok(Format::Exr)
        } else {
            Err(ImageError::UnsupportedExtension { path: path.to_path_buf() })
        }
    }
}

/// Writes `image` to `path`: 8-bit sRGB PNG if the file name ends in `.png`, float32 linear RGB
/// EXR if it ends in `.exr` (both case-insensitive), else [`ImageError::UnsupportedExtension`].
///
/// Atomic (see the module header): on success the target holds the whole image; on error it is
/// untouched and no temporary file remains. An existing target is replaced.
pub fn write_image(path: impl AsRef<Path>, image: &Image) -> Result<(), ImageError> {
    let path = path.as_ref();
    let format = Format::of(path)?;
    image.check_size(path)?;
    // A write that fails in the encoder (a full disk, a quota) is an I/O error, as one that
    // fails in the flush after it: the same retry helps both.
    write_atomic(path, |out| match format {
        Format::Exr => encode_exr(out, image).map_err(|source| match source {
            exr::error::Error::Io(source) => io_error(path, "cannot write", source),
            source => ImageError::Exr { path: path.to_path_buf(), what: "encode", source },
        }),
        Format::Png => encode_png(out, image).map_err(|source| match source {
            image::ImageError::IoError(source) => io_error(path, "cannot write", source),
            source => ImageError::Png { path: path.to_path_buf(), source },
        }),
    })
    .map_err(|e| match e {
        AtomicWriteError::Io { what, source } => io_error(path, what, source),
        AtomicWriteError::Write(e) => e,
    })
}

/// Checks that `path` names an image format [`write_image`] can write, before any work is spent
/// on the image.
pub fn check_output_path(path: impl AsRef<Path>) -> Result<(), ImageError> {
    Format::of(path.as_ref()).map(|_| ())
}

/// Whether `path` holds a whole image of `width` x `height` in the format its name says: a
/// regular file that decodes to the end (every PNG chunk's checksum, every EXR block) at that
/// size. What `--skip-existing` asks of an output before it skips it: a file cut short by a
/// full disk or an interrupted copy is not whole.
pub fn is_whole_image(path: &Path, width: u32, height: u32) -> bool {
    if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
        return false;
    }
    match Format::of(path) {
        Ok(Format::Exr) => read_exr(path).is_ok_and(|i| (i.width, i.height) == (width, height)),
        Ok(Format::Png) => {
            let Ok(file) = File::open(path) else { return false };
            let Ok(decoder) = image::codecs::png::PngDecoder::new(std::io::BufReader::new(file)) else { return false };
            use image::ImageDecoder;
            if decoder.dimensions() != (width, height) {
                return false;
            }
            let mut pixels = vec![0; decoder.total_bytes() as usize];
            decoder.read_image(&mut pixels).is_ok()
        }
        Err(_) => false,
    }
}

fn io_error(path: &Path, what: &'static str, source: std::io::Error) -> ImageError {
    ImageError::Io { path: path.to_path_buf(), what, source }
}

fn encode_exr(out: &mut BufWriter<File>, image: &Image) -> Result<(), exr::error::Error> {
    use exr::prelude::{Encoding, SpecificChannels, Vec2, WritableImage};
    let width = image.width as usize;
    let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
        let [r, g, b] = image.pixels[y * width + x];
        (r, g, b)
    });
    // ZIP is lossless for f32 (unlike PXR24 or B44), so a round trip is bit-exact.
    let exr_image =
        exr::prelude::Image::from_encoded_channels((width, image.height as usize), Encoding::SMALL_LOSSLESS, channels);
    // Encoded in memory: the encoder seeks back to write its offset tables, which a FIFO or a
    // device (an output written in place, see `atomic_file`) cannot do.
    let mut encoded = std::io::Cursor::new(Vec::new());
    exr_image.write().to_buffered(&mut encoded)?;
    std::io::Write::write_all(out, encoded.get_ref())?;
    Ok(())
}

fn encode_png(out: &mut BufWriter<File>, image: &Image) -> Result<(), image::ImageError> {
    use image::ImageEncoder;
    let bytes: Vec<u8> = image.pixels.iter().flat_map(|p| p.map(srgb_encode)).collect();
    image::codecs::png::PngEncoder::new(out).write_image(&bytes, image.width, image.height, image::ColorType::Rgb8)?;
    Ok(())
}

/// Linear value to 8-bit sRGB: clamp to [0, 1] (NaN to 0), the exact IEC 61966-2-1 curve
/// (linear segment below 0.0031308), then round to nearest.
pub fn srgb_encode(linear: f32) -> u8 {
    let c = f64::from(linear);
    // NaN would pass through `clamp`; it becomes black.
    let c = if c.is_nan() { 0.0 } else { c.clamp(0.0, 1.0) };
    let v = if c <= 0.0031308 { 12.92 * c } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 };
    (v * 255.0).round() as u8
}

/// 8-bit sRGB code to linear value: the exact inverse curve of [`srgb_encode`] before rounding.
pub fn srgb_decode(code: u8) -> f32 {
    let v = f64::from(code) / 255.0;
    let c = if v <= 0.04045 { v / 12.92 } else { ((v + 0.055) / 1.055).powf(2.4) };
    c as f32
}

/// Reads the R, G and B channels of the first valid layer of an EXR file at its largest
/// resolution level, converted to f32 (other channels are ignored; a file without R, G and B is
/// an error). Pixel (x, y) is relative to the layer's data window, row 0 at the top.
pub fn read_exr(path: impl AsRef<Path>) -> Result<Image, ImageError> {
    use exr::prelude::{ReadChannels, ReadLayers, Vec2, read};
    let path = path.as_ref();
    let exr_image = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgb_channels(
            // EXR sizes are bounded by i32, so the casts to u32 cannot truncate.
            |size: Vec2<usize>, _| Image::new(size.width() as u32, size.height() as u32),
            |image: &mut Image, Vec2(x, y): Vec2<usize>, (r, g, b): (f32, f32, f32)| {
                let i = y * image.width as usize + x;
                image.pixels[i] = [r, g, b];
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|source| match source {
            // exr's I/O error displays its cause and also gives it as its source: said twice.
            exr::error::Error::Io(source) => io_error(path, "cannot read", source),
            source => ImageError::Exr { path: path.to_path_buf(), what: "read", source },
        })?;
    Ok(exr_image.layer_data.channel_data.pixels)
}

#[cfg(test)]
mod tests {
    use std::fs;

    use super::*;

    /// A fresh, empty directory under the system temp dir, unique to this test and process.
    fn scratch_dir(test: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("arbor-image_io-{test}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn dir_entries(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> =
            fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        names.sort();
        names
    }

    /// Values that stress a float round trip: tiny, huge, negative, subnormal, non-finite.
    fn test_image() -> Image {
        let (width, height) = (7, 5);
        let special = [1e-30, 3.0e38, -2.5, f32::MIN_POSITIVE / 8.0, f32::INFINITY, f32::NAN, 0.1, -0.0];
        let pixels = (0..width * height)
            .map(|i| {
                let s = |k: u32| special[((i * 3 + k) as usize) % special.len()] * (1.0 + i as f32 / 7.0);
                [s(0), s(1), s(2)]
            })
            .collect();
        Image { width, height, pixels }
    }

    #[test]
    fn exr_round_trip_is_bit_exact() {
        let dir = scratch_dir("exr_round_trip");
        let path = dir.join("a.EXR");
        let image = test_image();
        write_image(&path, &image).unwrap();
        let back = read_exr(&path).unwrap();
        assert_eq!((back.width, back.height), (image.width, image.height));
        let bits = |im: &Image| im.pixels.iter().flat_map(|p| p.map(f32::to_bits)).collect::<Vec<_>>();
        assert_eq!(bits(&back), bits(&image));
        assert_eq!(dir_entries(&dir), ["a.EXR"], "no temporary file may remain");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn png_round_trip_within_one_code() {
        let dir = scratch_dir("png_round_trip");
        let path = dir.join("b.Png");
        let (width, height) = (16u32, 3u32);
        let pixels = (0..width * height)
            .map(|i| {
                let t = i as f32 / (width * height - 1) as f32;
                [t, t * t, 1.0 - t]
            })
            .collect();
        let image = Image { width, height, pixels };
        write_image(&path, &image).unwrap();
        assert_eq!(dir_entries(&dir), ["b.Png"], "no temporary file may remain");
        let png =
            image::load_from_memory_with_format(&fs::read(&path).unwrap(), image::ImageFormat::Png).unwrap().to_rgb8();
        assert_eq!(png.dimensions(), (width, height));
        for (y, row) in png.rows().enumerate() {
            for (x, px) in row.enumerate() {
                let expected = image.get(x as u32, y as u32).unwrap();
                for c in 0..3 {
                    // Row 0 of the file must be row 0 of the image (top), not flipped.
                    assert_eq!(px[c], srgb_encode(expected[c]), "pixel ({x}, {y}) channel {c}");
                    let encoded = srgb_encode(srgb_decode(px[c]));
                    assert_eq!(encoded, px[c], "decode then encode must be the identity on codes");
                    let got = srgb_decode(px[c]);
                    let want = srgb_decode(srgb_encode(expected[c]));
                    assert!((got - want).abs() <= 1.0 / 255.0);
                    // The code is within half a step of the exact encoded value.
                    let exact = srgb_exact(expected[c]);
                    assert!((f64::from(px[c]) / 255.0 - exact).abs() <= 0.5 / 255.0 + 1e-12);
                }
            }
        }
        fs::remove_dir_all(&dir).unwrap();
    }

    fn srgb_exact(c: f32) -> f64 {
        let c = f64::from(c).clamp(0.0, 1.0);
        if c <= 0.0031308 { 12.92 * c } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 }
    }

    #[test]
    fn srgb_encode_known_values() {
        assert_eq!(srgb_encode(0.0), 0);
        assert_eq!(srgb_encode(1.0), 255);
        // 1.055 * 0.5^(1/2.4) - 0.055 = 0.735357 -> 187.52 -> 188.
        assert_eq!(srgb_encode(0.5), 188);
        // Linear segment: 0.002 * 12.92 * 255 = 6.589 -> 7 (the power curve would give 9).
        assert_eq!(srgb_encode(0.002), 7);
        assert_eq!(srgb_encode(0.0031308), 10);
        assert_eq!(srgb_encode(-1.0), 0);
        assert_eq!(srgb_encode(2.0), 255);
        assert_eq!(srgb_encode(f32::NAN), 0);
        assert_eq!(srgb_encode(f32::INFINITY), 255);
        assert!((srgb_decode(188) - 0.5029).abs() < 1e-4);
        assert_eq!(srgb_decode(0), 0.0);
        assert_eq!(srgb_decode(255), 1.0);
    }

    #[test]
    fn unsupported_extension_is_an_error_naming_the_file() {
        let dir = scratch_dir("unsupported");
        for name in ["c.jpg", "c", "c.exr.bak", "png"] {
            let path = dir.join(name);
            let err = write_image(&path, &test_image()).unwrap_err();
            assert!(matches!(err, ImageError::UnsupportedExtension { .. }), "{name}: {err}");
            let msg = err.to_string();
            assert!(msg.contains(name) && msg.contains(".exr") && msg.contains(".png"), "{msg}");
        }
        assert!(dir_entries(&dir).is_empty());
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_size_is_an_error() {
        let dir = scratch_dir("bad_size");
        let mut image = test_image();
        image.pixels.pop();
        let err = write_image(dir.join("d.exr"), &image).unwrap_err();
        assert!(matches!(err, ImageError::BadSize { .. }), "{err}");
        let err = write_image(dir.join("d.png"), &Image::new(0, 4)).unwrap_err();
        assert!(matches!(err, ImageError::BadSize { .. }), "{err}");
        assert!(dir_entries(&dir).is_empty());
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn missing_folders_are_made_and_a_file_in_the_way_is_an_error() {
        let dir = scratch_dir("missing_dir");
        fs::write(dir.join("blocker"), b"").unwrap();
        for name in ["e.exr", "e.png"] {
            let path = dir.join("blocker").join(name);
            let err = write_image(&path, &test_image()).unwrap_err();
            assert!(matches!(err, ImageError::Io { .. }), "{err}");
            assert!(err.to_string().contains(&*path.to_string_lossy()), "{err}");
            write_image(dir.join("new/sub").join(name), &test_image()).unwrap();
        }
        assert_eq!(dir_entries(&dir), ["blocker", "new"]);
        assert_eq!(dir_entries(&dir.join("new/sub")), ["e.exr", "e.png"]);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn overwrite_replaces_the_target_and_leaves_no_temp() {
        let dir = scratch_dir("overwrite");
        let path = dir.join("f.exr");
        write_image(&path, &Image::new(3, 2)).unwrap();
        let image = test_image();
        write_image(&path, &image).unwrap();
        assert_eq!(read_exr(&path).unwrap().width, image.width);
        assert_eq!(dir_entries(&dir), ["f.exr"]);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn read_exr_errors_name_the_file() {
        let dir = scratch_dir("read_err");
        let path = dir.join("garbage.exr");
        fs::write(&path, b"not an exr").unwrap();
        let err = read_exr(&path).unwrap_err();
        assert!(err.to_string().contains("garbage.exr"), "{err}");
        let err = read_exr(dir.join("absent.exr")).unwrap_err();
        assert!(err.to_string().contains("absent.exr"), "{err}");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn reads_the_cornell_reference() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/reference/cornell-box/cornell_spp4096.exr");
        if !path.exists() {
            assert!(std::env::var("CI").as_deref() != Ok("true"), "{} is missing (CI=true)", path.display());
            eprintln!("skipping: reference image {} is missing", path.display());
            return;
        }
        let image = read_exr(path).unwrap();
        assert_eq!((image.width, image.height), (256, 256));
        let mean = image.mean();
        for (c, want) in [0.240133, 0.141122, 0.059978].into_iter().enumerate() {
            assert!((mean[c] - want).abs() < 1e-4, "channel {c}: mean {} vs {want}", mean[c]);
        }
    }
}
