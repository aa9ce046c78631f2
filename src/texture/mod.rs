//! Image textures: loading (PNG, JPEG, TGA, BMP through `image`; EXR; Radiance HDR), and
//! bilinear lookups with repeat, clamp or mirror wrapping.
//!
//! A texture keeps one stored form for both devices: 8-bit RGBA packed in one `u32` a texel
//! (images of 8 or 16 bits a channel), or f32 RGBA in four (EXR and HDR files). The GPU gets the
//! same words (`gpu::texture::gpu_texture_data`) and `shaders/trace.wgsl` reads them as [`Texture::sample`]
//! does, so the devices agree. 8-bit colour is decoded from sRGB at lookup time when the use
//! asks for it (a base colour), and read as is for data (an alpha mask): one file may be both,
//! and is loaded once ([`TextureCache`]).
//!
//! **Coordinates.** `(u, v)` as OBJ's `vt` gives them: `v` up from the image's bottom row.
//! Texel centres sit at half-integers; a lookup interpolates the four nearest, each wrapped
//! ([`Wrap`]) on its own, so a repeating texture is seamless across its edges. Colours are
//! decoded before they are interpolated.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{Vec2, Vec3, Vec4};

pub mod environment;

/// Rec. 709 luminance.
pub fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

/// How a texture's coordinates outside [0, 1] map into it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Wrap {
    /// Tiles the plane (OBJ's and glTF's default).
    Repeat = 0,
    /// Holds the edge texels (MTL `-clamp on`, glTF `CLAMP_TO_EDGE`).
    Clamp = 1,
    /// Tiles with every other copy mirrored (glTF `MIRRORED_REPEAT`).
    Mirror = 2,
}

/// A use of a texture: which one ([`crate::scene::Scene::textures`]), wrapped how, and
/// whether its 8-bit colour is sRGB-encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TextureRef {
    pub texture: u32,
    pub wrap: Wrap,
    pub srgb: bool,
}

/// The texels' stored form.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TexelFormat {
    /// `r | g << 8 | b << 16 | a << 24`, one word a texel.
    Rgba8,
    /// f32 RGBA as bits, four words a texel.
    Rgba32F,
}

/// An image texture, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    pub source: PathBuf,
    pub width: u32,
    pub height: u32,
    pub format: TexelFormat,
    pub texels: Vec<u32>,
    /// Whether the file had an alpha channel: masks read it, else its first channel.
    pub has_alpha: bool,
}

/// Why an image file (a texture, an environment map) cannot be used; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum TextureError {
    #[error("{}: cannot read: {error}", path.display())]
    Read { path: PathBuf, error: String },
    #[error("{}: {message}", path.display())]
    Invalid { path: PathBuf, message: String },
    #[error(transparent)]
    Memory(#[from] crate::memory::OutOfMemory),
}

/// Texels at most in one texture: 2^28 (16384²).
const MAX_TEXELS: u64 = 1 << 28;

impl Texture {
    /// Reads an image file: PNG, JPEG, TGA or BMP (8-bit RGBA; 16-bit images are rounded to 8),
    /// or EXR or Radiance HDR (f32, linear). Its size is read first and checked against the
    /// memory available.
    pub fn load(path: &Path) -> Result<Self, TextureError> {
        let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
        if !matches!(ext.as_deref(), Some("png" | "jpg" | "jpeg" | "tga" | "bmp" | "exr" | "hdr")) {
            let message = "is not a supported image: give a .png, .jpg, .tga, .bmp, .exr or .hdr file".into();
            return Err(TextureError::Invalid { path: path.to_owned(), message });
        }
        // Before anything opens it: opening a named pipe waits for a writer for ever.
        crate::memory::regular_file_len(path)
            .map_err(|e| TextureError::Read { path: path.to_owned(), error: e.to_string() })?;
        if ext.as_deref() != Some("exr") {
            return Self::decode(|| reader(path), path, ext.as_deref() == Some("hdr"));
        }
        let (width, height) = exr_size(path)?;
        check_size(path, width, height, true)?;
        let image = crate::image_io::read_exr(path)
            .map_err(|e| TextureError::Read { path: path.to_owned(), error: chain(&e) })?;
        let texels = float_texels(image.pixels.iter().map(|p| [p[0], p[1], p[2], 1.0]));
        Self::finished(path, width, height, TexelFormat::Rgba32F, texels, false)
    }

    /// Decodes an image held in memory (a glTF file's embedded PNG or JPEG), 8-bit; `name`
    /// stands for its path in messages.
    pub fn from_bytes(bytes: &[u8], name: &Path) -> Result<Self, TextureError> {
        let format =
            image::guess_format(bytes).map_err(|e| TextureError::Read { path: name.to_owned(), error: chain(&e) })?;
        let open = || {
            let mut r = image::io::Reader::with_format(std::io::Cursor::new(bytes), format);
            r.limits(decoder_limits());
            Ok(r)
        };
        Self::decode(open, name, false)
    }

    /// Decodes through `image` what `open` reads (afresh each call: once for the size, once for
    /// the texels), as f32 where `float`.
    fn decode<R: std::io::BufRead + std::io::Seek>(
        open: impl Fn() -> Result<image::io::Reader<R>, TextureError>,
        path: &Path,
        float: bool,
    ) -> Result<Self, TextureError> {
        let read = |error: String| TextureError::Read { path: path.to_owned(), error };
        let (width, height) = open()?.into_dimensions().map_err(|e| read(chain(&e)))?;
        check_size(path, width, height, float)?;
        let image = open()?.decode().map_err(|e| read(chain(&e)))?;
        if float {
            let texels = float_texels(image.into_rgb32f().pixels().map(|p| [p[0], p[1], p[2], 1.0]));
            return Self::finished(path, width, height, TexelFormat::Rgba32F, texels, false);
        }
        let has_alpha = image.color().has_alpha();
        let texels = image.into_rgba8().pixels().map(|p| u32::from_le_bytes(p.0)).collect();
        Self::finished(path, width, height, TexelFormat::Rgba8, texels, has_alpha)
    }

    /// The texture, once its float texels (if any) are known to be finite.
    fn finished(
        path: &Path,
        width: u32,
        height: u32,
        format: TexelFormat,
        texels: Vec<u32>,
        has_alpha: bool,
    ) -> Result<Self, TextureError> {
        if format == TexelFormat::Rgba32F
            && let Some(i) = texels.iter().position(|&w| !f32::from_bits(w).is_finite())
        {
            let (x, y) = ((i / 4) % width as usize, (i / 4) / width as usize);
            let message = format!("texel ({x}, {y}) is not finite");
            return Err(TextureError::Invalid { path: path.to_owned(), message });
        }
        Ok(Self { source: path.to_owned(), width, height, format, texels, has_alpha })
    }

    /// The largest value of each colour channel over the texels, as stored (8-bit colour as
    /// code / 255, which its sRGB decoding never exceeds): what an emission texture can
    /// multiply a radiance by.
    pub fn brightest(&self) -> Vec3 {
        match self.format {
            TexelFormat::Rgba8 => {
                let max = self.texels.iter().fold([0u8; 3], |m, &w| {
                    let [r, g, b, _] = w.to_le_bytes();
                    [m[0].max(r), m[1].max(g), m[2].max(b)]
                });
                Vec3::from(max.map(|c| f32::from(c) / 255.0))
            }
            TexelFormat::Rgba32F => self.texels.chunks_exact(4).fold(Vec3::ZERO, |m, w| {
                m.max(Vec3::new(f32::from_bits(w[0]), f32::from_bits(w[1]), f32::from_bits(w[2])))
            }),
        }
    }

    /// Bytes the texels take.
    pub fn bytes(&self) -> usize {
        self.texels.len() * 4
    }

    /// The texel at index `i` (row-major, row 0 at the top), its RGB decoded by `srgb` (the
    /// table of [`srgb_table`]) where given.
    #[inline(always)]
    fn texel(&self, i: u32, srgb: Option<&[f32; 256]>) -> Vec4 {
        let i = i as usize;
        match self.format {
            TexelFormat::Rgba8 => {
                let [r, g, b, a] = self.texels[i].to_le_bytes();
                let c = |v: u8| srgb.map_or(f32::from(v) / 255.0, |t| t[v as usize]);
                Vec4::new(c(r), c(g), c(b), f32::from(a) / 255.0)
            }
            TexelFormat::Rgba32F => {
                let w = &self.texels[4 * i..4 * i + 4];
                Vec4::new(f32::from_bits(w[0]), f32::from_bits(w[1]), f32::from_bits(w[2]), f32::from_bits(w[3]))
            }
        }
    }

    /// The bilinear lookup at `uv` (module docs).
    pub fn sample(&self, uv: Vec2, wrap: Wrap, srgb: bool) -> Vec4 {
        // Wrapped in f32 first, so that huge coordinates do not overflow the integer index.
        let (x, y) = (uv.x * self.width as f32 - 0.5, (1.0 - uv.y) * self.height as f32 - 0.5);
        let (x0, y0) = (floor(x), floor(y));
        let (fx, fy) = (x - x0, y - y0);
        let (c0, c1) = wrap_pair(x0, self.width, wrap);
        let (r0, r1) = wrap_pair(y0, self.height, wrap);
        let table = srgb.then(srgb_table);
        let (w0, w1) = (r0 * self.width, r1 * self.width);
        let top = self.texel(w0 + c0, table) * (1.0 - fx) + self.texel(w0 + c1, table) * fx;
        let bottom = self.texel(w1 + c0, table) * (1.0 - fx) + self.texel(w1 + c1, table) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// Coverage at `uv` for a cut-out: the alpha channel where the file has one, else its first
    /// channel (a grey mask).
    pub fn coverage(&self, uv: Vec2, wrap: Wrap) -> f32 {
        let t = self.sample(uv, wrap, false);
        if self.has_alpha { t.w } else { t.x }
    }
}

/// [`crate::image_io::srgb_decode`] of every code, computed once: a lookup reads 12 of them,
/// and the curve's `powf` would cost more than the rest of the lookup.
pub(crate) fn srgb_table() -> &'static [f32; 256] {
    static TABLE: std::sync::LazyLock<[f32; 256]> =
        std::sync::LazyLock::new(|| std::array::from_fn(|c| crate::image_io::srgb_decode(c as u8)));
    &TABLE
}

/// An EXR file's size, from its header (its first layer's).
pub(crate) fn exr_size(path: &Path) -> Result<(u32, u32), TextureError> {
    let meta = exr::meta::MetaData::read_from_file(path, false)
        .map_err(|e| TextureError::Read { path: path.to_owned(), error: chain(&e) })?;
    let header = meta
        .headers
        .first()
        .ok_or_else(|| TextureError::Invalid { path: path.to_owned(), message: "has no image layer".into() })?;
    Ok((header.layer_size.width() as u32, header.layer_size.height() as u32))
}

/// An error unless a `width` × `height` texture (f32 where `float`) has 1 to [`MAX_TEXELS`]
/// texels and fits in memory, with the decoder's RGBA copy beside it while it converts.
fn check_size(path: &Path, width: u32, height: u32, float: bool) -> Result<(), TextureError> {
    let count = u64::from(width) * u64::from(height);
    if count == 0 || count > MAX_TEXELS {
        let message = format!("is {width}x{height}: a texture must have 1 to 2^28 texels");
        return Err(TextureError::Invalid { path: path.to_owned(), message });
    }
    let bytes = count as f64 * if float { 16.0 + 16.0 } else { 4.0 + 16.0 };
    Ok(crate::memory::check_fits(&format!("{}: a texture of {width}x{height}", path.display()), bytes)?)
}

/// `x.floor()` without the call to libm's `floorf` that baseline x86-64 (no SSE4.1 `roundss`)
/// compiles it to: a float of magnitude 2^23 or more is an integer already, and one below
/// converts to `i32` exactly. NaN stays NaN.
#[inline(always)]
fn floor(x: f32) -> f32 {
    if x.abs() < 8_388_608.0 {
        let t = x as i32 as f32;
        if t > x { t - 1.0 } else { t }
    } else {
        x
    }
}

/// Indices `i` and `i + 1` (`i` an integer-valued f32) wrapped into `0..n`.
#[inline(always)]
fn wrap_pair(i: f32, n: u32, wrap: Wrap) -> (u32, u32) {
    let a = wrap_index(i, n, wrap);
    match wrap {
        // The next column is the first past the last: no second remainder to take.
        Wrap::Repeat => (a, if a + 1 == n { 0 } else { a + 1 }),
        _ => (a, wrap_index(i + 1.0, n, wrap)),
    }
}

/// Index `i` (an integer-valued f32) wrapped into `0..n`, as `shaders/trace.wgsl` wraps it: by
/// `floor`, which is cheaper than a remainder (`fmodf`) and rounds alike on both devices.
#[inline(always)]
fn wrap_index(i: f32, n: u32, wrap: Wrap) -> u32 {
    let nf = n as f32;
    let k = match wrap {
        Wrap::Clamp => i.clamp(0.0, nf - 1.0),
        Wrap::Repeat => i - nf * floor(i / nf),
        Wrap::Mirror => {
            let m = i - 2.0 * nf * floor(i / (2.0 * nf));
            if m >= nf { 2.0 * nf - 1.0 - m } else { m }
        }
    };
    // The rounding of a huge or tiny `i` can leave `k` just outside `0..n`.
    (k.max(0.0) as u32).min(n - 1)
}

fn float_texels(pixels: impl Iterator<Item = [f32; 4]>) -> Vec<u32> {
    pixels.flat_map(|p| p.map(f32::to_bits)).collect()
}

fn reader(path: &Path) -> Result<image::io::Reader<std::io::BufReader<std::fs::File>>, TextureError> {
    let read = |error: String| TextureError::Read { path: path.to_owned(), error };
    let mut r = image::io::Reader::open(path)
        .map_err(|e| read(e.to_string()))?
        .with_guessed_format()
        .map_err(|e| read(e.to_string()))?;
    r.limits(decoder_limits());
    Ok(r)
}

/// The decoder's own allocations are bounded too (its default is 512 MiB).
fn decoder_limits() -> image::io::Limits {
    let mut limits = image::io::Limits::default();
    limits.max_alloc = Some(crate::memory::available_bytes().unwrap_or(u64::MAX).min(1 << 34));
    limits
}

/// An error and its sources, joined by `: `.
pub(crate) fn chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut source = e.source();
    while let Some(inner) = source {
        s.push_str(": ");
        s.push_str(&inner.to_string());
        source = inner.source();
    }
    s
}

/// Textures loaded once each, however many materials name them.
#[derive(Default)]
pub struct TextureCache {
    pub textures: Vec<Arc<Texture>>,
    by_path: HashMap<PathBuf, u32>,
}

impl TextureCache {
    /// The index of the texture at `path`, loaded the first time it is asked for.
    pub fn get(&mut self, path: &Path) -> Result<u32, TextureError> {
        let key = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_owned());
        if let Some(&i) = self.by_path.get(&key) {
            return Ok(i);
        }
        let texture = Texture::load(path)?;
        Ok(self.insert(key, texture))
    }

    /// The index of an image held in memory, decoded the first time `key` (the file holding
    /// it and where in it) is asked for; `bytes` fails with the caller's own error, which a
    /// failure to decode becomes too.
    pub fn get_embedded<E: From<TextureError>>(
        &mut self,
        key: PathBuf,
        bytes: impl FnOnce() -> Result<Vec<u8>, E>,
    ) -> Result<u32, E> {
        if let Some(&i) = self.by_path.get(&key) {
            return Ok(i);
        }
        let texture = Texture::from_bytes(&bytes()?, &key)?;
        Ok(self.insert(key, texture))
    }

    fn insert(&mut self, key: PathBuf, texture: Texture) -> u32 {
        self.textures.push(Arc::new(texture));
        let i = self.textures.len() as u32 - 1;
        self.by_path.insert(key, i);
        i
    }
}

/// An 8-bit RGBA texture whose texel `(x, y)` is `f(x, y)`, for the unit tests here and of the
/// GPU's packing.
#[cfg(test)]
pub(crate) fn test_texture(width: u32, height: u32, f: impl Fn(u32, u32) -> [u8; 4]) -> Texture {
    let texels =
        (0..height).flat_map(|y| (0..width).map(move |x| (x, y))).map(|(x, y)| u32::from_le_bytes(f(x, y))).collect();
    Texture { source: "t".into(), width, height, format: TexelFormat::Rgba8, texels, has_alpha: true }
}

#[cfg(test)]
mod tests {
    use super::*;

    use super::test_texture as texture;

    #[test]
    fn texel_centres_are_exact_and_v_is_up() {
        let t = texture(4, 2, |x, y| [(x * 60) as u8, (y * 200) as u8, 7, 255]);
        // Column 1, bottom row (row 1): v = 0.25 is the bottom row's centre.
        let s = t.sample(Vec2::new(1.5 / 4.0, 0.25), Wrap::Clamp, false);
        assert!((s.x - 60.0 / 255.0).abs() < 1e-6 && (s.y - 200.0 / 255.0).abs() < 1e-6, "{s}");
        // Halfway between columns 1 and 2.
        let s = t.sample(Vec2::new(0.5, 0.75), Wrap::Clamp, false);
        assert!((s.x - 90.0 / 255.0).abs() < 1e-6 && s.y.abs() < 1e-6, "{s}");
    }

    #[test]
    fn wraps_repeat_clamp_and_mirror() {
        assert_eq!([-1.0, 0.0, 3.0, 4.0, 9.0].map(|i| wrap_index(i, 4, Wrap::Repeat)), [3, 0, 3, 0, 1]);
        assert_eq!([-1.0, 0.0, 3.0, 4.0, 9.0].map(|i| wrap_index(i, 4, Wrap::Clamp)), [0, 0, 3, 3, 3]);
        assert_eq!([-1.0, 0.0, 3.0, 4.0, 9.0].map(|i| wrap_index(i, 4, Wrap::Mirror)), [0, 0, 3, 3, 1]);
        assert_eq!(wrap_index(-1e-30, 4, Wrap::Repeat), 3);
        // A repeating texture is seamless: at u = 0 the left and right edge texels mix evenly.
        let t = texture(4, 1, |x, _| {
            [
                if x == 0 {
                    200
                } else if x == 3 {
                    100
                } else {
                    0
                },
                0,
                0,
                255,
            ]
        });
        let s = t.sample(Vec2::new(0.0, 0.5), Wrap::Repeat, false);
        assert!((s.x - 150.0 / 255.0).abs() < 1e-6, "{s}");
        let far = t.sample(Vec2::new(1e6, 0.5), Wrap::Repeat, false);
        assert!(far.is_finite());
    }

    /// The libm-free floor is `f32::floor`, and the pair of wrapped indices each index wrapped
    /// alone, for every wrap, across several periods either side of zero and at large values.
    #[test]
    fn fast_floor_and_wrapped_pairs_match_the_plain_forms() {
        let xs = (-3000..3000).map(|i| i as f32 * 0.37).chain([8388607.5, -8388607.5, 1e9, -1e9, 0.0, -0.0, -1e-30]);
        for x in xs {
            assert_eq!(floor(x), x.floor(), "{x}"); // (the sign of a zero aside)
        }
        assert!(floor(f32::NAN).is_nan());
        for wrap in [Wrap::Repeat, Wrap::Clamp, Wrap::Mirror] {
            for n in [1, 2, 5] {
                for i in -40..40 {
                    let i = i as f32;
                    let pair = wrap_pair(i, n, wrap);
                    assert_eq!(pair, (wrap_index(i, n, wrap), wrap_index(i + 1.0, n, wrap)), "{wrap:?} {n} {i}");
                    let want = match wrap {
                        Wrap::Repeat => i.rem_euclid(n as f32) as u32,
                        Wrap::Clamp => i.clamp(0.0, n as f32 - 1.0) as u32,
                        Wrap::Mirror => {
                            let m = i.rem_euclid(2.0 * n as f32) as u32;
                            if m >= n { 2 * n - 1 - m } else { m }
                        }
                    };
                    assert_eq!(pair.0, want, "{wrap:?} {n} {i}");
                }
            }
        }
    }

    #[test]
    fn srgb_decodes_colour_not_alpha() {
        let t = texture(1, 1, |_, _| [128, 128, 128, 128]);
        let s = t.sample(Vec2::splat(0.5), Wrap::Repeat, true);
        assert!((s.x - crate::image_io::srgb_decode(128)).abs() < 1e-7, "{s}");
        assert!((s.w - 128.0 / 255.0).abs() < 1e-7, "{s}");
        assert!((t.coverage(Vec2::splat(0.5), Wrap::Repeat) - 128.0 / 255.0).abs() < 1e-7);
    }
}
