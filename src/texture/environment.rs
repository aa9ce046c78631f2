//! Environment maps' data: an equirectangular (latitude-longitude) image of the radiance
//! arriving from every direction, read from EXR or Radiance HDR, and the tables its directions
//! are drawn from. How a direction maps to the image, and how the tables are sampled, is the
//! renderer's (`render::environment`, whose docs give the convention and the sampling method).
//!
//! **Tables** (Pharr, Jakob and Humphreys, *Physically Based Rendering*, 4th ed., §12.5.2 and
//! A.5.3): a piecewise-constant density over the `(u, v)` square with a marginal CDF over rows
//! of cells and each row's conditional CDF. Departure: the cells are not the texels. Mitsuba 3
//! puts texel column `j` at `u = (j + 0.5) / W` and row `i` at `v = i / (H - 1)`, and the
//! radiance between four neighbouring texel centres is their bilinear interpolant; a cell is one
//! such patch ([`sampling_rows`] rows of `W` cells, the last column's patch wrapping round to
//! column 0), weighted by the mean luminance of its four corners (the mean of the interpolant
//! over the patch) times the mean of `sin θ` over its rows (its share of solid angle). The
//! density is then positive wherever the radiance is, which keeps light sampling alone unbiased,
//! and follows it within each patch as closely as a constant can. Sums are taken in f64 and
//! stored as f32, the form both devices sample from (`shaders/trace.wgsl` reads the same
//! arrays).

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use glam::{Mat3, Vec3};

use super::{chain, exr_size, luminance};
use crate::image_io::Image;

/// An environment map with its sampling distribution.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvironmentMap {
    /// The file it came from (for messages and the scene's hash).
    pub source: PathBuf,
    pub width: u32,
    pub height: u32,
    /// Linear RGB radiance, row-major, row 0 at the top (straight up). Finite, non-negative.
    pub texels: Vec<[f32; 3]>,
    /// The map's frame from the world's (the inverse of the scene's `rotate`).
    pub map_from_world: Mat3,
    pub world_from_map: Mat3,
    pub distribution: Distribution,
}

/// How directions are drawn from a map: [`Sampling::Luminance`] renders use; the uniform one is
/// the baseline the tests and benchmarks compare it with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sampling {
    /// In proportion to luminance × sin θ (the module docs).
    Luminance,
    /// Uniformly over the sphere (every cell weighted by its solid angle only).
    Uniform,
}

/// A piecewise-constant density over the unit square, one constant per cell (module docs:
/// `width` x [`sampling_rows`]`(height)` cells, each the patch between four texel centres), and
/// the CDFs that sample it.
#[derive(Clone, Debug, PartialEq)]
pub struct Distribution {
    /// The density over `(u, v)` in each cell, row-major: it integrates to 1 over the square.
    pub pdf: Vec<f32>,
    /// The cell rows' CDF: `sampling_rows(height) + 1` values rising from 0 to exactly 1.
    pub marginal: Vec<f32>,
    /// Each cell row's CDF over its cells: `width + 1` values a row, from 0 to exactly 1 (all 0
    /// in a row of no weight, which the marginal never picks).
    pub conditional: Vec<f32>,
}

/// Rows of cells in the distribution of a map `height` texels high: the `height - 1` intervals
/// between its rows' centres, or one for a single row, whose radiance is then the same at
/// every `v`.
pub fn sampling_rows(height: u32) -> u32 {
    height.saturating_sub(1).max(1)
}

/// Why a map cannot be used: each names the file (the error of any image file).
pub type EnvironmentError = super::TextureError;

/// Bytes a map holds per texel once loaded: its radiance, its cell's density and row CDF (about
/// a cell a texel), and the decoder's own copy while it is read.
pub const BYTES_PER_TEXEL: f64 = 12.0 + 4.0 + 4.0 + 16.0;

/// Texels at most: 2^28 (a 23170² map), well past the 16k × 8k of the largest skies published.
const MAX_TEXELS: u64 = 1 << 28;

impl EnvironmentMap {
    /// Reads an EXR (`.exr`) or Radiance HDR (`.hdr`) file, turned by `world_from_map` (a
    /// rotation), sampled as `sampling` says.
    pub fn load(path: &Path, world_from_map: Mat3, sampling: Sampling) -> Result<Self, EnvironmentError> {
        let invalid = |message: String| EnvironmentError::Invalid { path: path.to_owned(), message };
        let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
        if !matches!(ext.as_deref(), Some("exr" | "hdr")) {
            return Err(invalid("is not an environment map: give an .exr or .hdr file".into()));
        }
        // Before anything opens it: opening a named pipe waits for a writer for ever.
        crate::memory::regular_file_len(path)
            .map_err(|e| EnvironmentError::Read { path: path.to_owned(), error: e.to_string() })?;
        let (width, height) = if ext.as_deref() == Some("exr") { exr_size(path)? } else { hdr_size(path)? };
        let texels = u64::from(width) * u64::from(height);
        if texels == 0 || texels > MAX_TEXELS {
            return Err(invalid(format!("is {width}x{height}: a map must have 1 to 2^28 texels")));
        }
        crate::memory::check_fits(
            &format!("{}: an environment map of {width}x{height}", path.display()),
            texels as f64 * BYTES_PER_TEXEL,
        )?;
        let image = match ext.as_deref() {
            Some("exr") => crate::image_io::read_exr(path)
                .map_err(|e| EnvironmentError::Read { path: path.to_owned(), error: chain(&e) })?,
            _ => read_hdr(path)?,
        };
        Self::new(path.to_owned(), image, world_from_map, sampling).map_err(invalid)
    }

    /// A map of `image` (row 0 at the top), checked: every texel finite; negative components
    /// (left by some HDR tools' filtering) are taken as 0.
    pub fn new(source: PathBuf, image: Image, world_from_map: Mat3, sampling: Sampling) -> Result<Self, String> {
        let Image { width, height, pixels } = image;
        if width == 0 || height == 0 || pixels.len() != width as usize * height as usize {
            return Err(format!("has {} pixels for {width}x{height}", pixels.len()));
        }
        if let Some(i) = pixels.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
            let (x, y) = (i % width as usize, i / width as usize);
            return Err(format!("pixel ({x}, {y}) is {:?}: radiance must be finite", pixels[i]));
        }
        let texels: Vec<[f32; 3]> = pixels.into_iter().map(|p| p.map(|c| c.max(0.0))).collect();
        let distribution = Distribution::new(width, height, &texels, sampling);
        Ok(Self {
            source,
            width,
            height,
            texels,
            map_from_world: world_from_map.transpose(),
            world_from_map,
            distribution,
        })
    }

    /// The same map drawn from as `sampling` says (the tests' and benchmarks' baseline).
    pub fn with_sampling(&self, sampling: Sampling) -> Self {
        Self { distribution: Distribution::new(self.width, self.height, &self.texels, sampling), ..self.clone() }
    }

    /// Whether the map is black everywhere: it lights nothing and is never sampled.
    pub fn is_black(&self) -> bool {
        self.distribution.marginal.last() != Some(&1.0)
    }

    /// Bytes the map holds (its texels and distribution).
    pub fn bytes(&self) -> usize {
        self.texels.len() * 12
            + (self.distribution.pdf.len() + self.distribution.marginal.len()) * 4
            + self.distribution.conditional.len() * 4
    }
}

impl Distribution {
    /// The distribution of a `width` x `height` map's `texels` (module docs).
    pub fn new(width: u32, height: u32, texels: &[[f32; 3]], sampling: Sampling) -> Self {
        let (w, h, rows) = (width as usize, height as usize, sampling_rows(height) as usize);
        let lum: Vec<f32> = texels.iter().map(|&t| luminance(Vec3::from(t)).max(0.0)).collect();
        let mut weights = vec![0.0f64; w * rows];
        for r in 0..rows {
            // The mean of sin θ over the row's θ from π r / rows to π (r + 1) / rows.
            let (theta0, theta1) = (PI * r as f64 / rows as f64, PI * (r + 1) as f64 / rows as f64);
            let sin_theta = ((theta0.cos() - theta1.cos()) / (theta1 - theta0)).max(0.0);
            let (r0, r1) = (r, (r + 1).min(h - 1));
            for c in 0..w {
                let value = match sampling {
                    Sampling::Uniform => 1.0,
                    Sampling::Luminance => {
                        let c1 = (c + 1) % w;
                        let corners = [r0 * w + c, r0 * w + c1, r1 * w + c, r1 * w + c1];
                        0.25 * corners.iter().map(|&i| f64::from(lum[i])).sum::<f64>()
                    }
                };
                weights[r * w + c] = value * sin_theta;
            }
        }
        let row_sums: Vec<f64> = weights.chunks(w).map(|row| row.iter().sum()).collect();
        let total: f64 = row_sums.iter().sum();
        let mut conditional = vec![0.0f32; rows * (w + 1)];
        let mut marginal = vec![0.0f32; rows + 1];
        let mut pdf = vec![0.0f32; w * rows];
        if !(total > 0.0 && total.is_finite()) {
            return Self { pdf, marginal, conditional };
        }
        let scale = (w * rows) as f64 / total;
        for r in 0..rows {
            let cdf = &mut conditional[r * (w + 1)..(r + 1) * (w + 1)];
            if row_sums[r] > 0.0 {
                let mut acc = 0.0;
                for c in 0..w {
                    acc += weights[r * w + c];
                    cdf[c + 1] = (acc / row_sums[r]) as f32;
                    pdf[r * w + c] = (weights[r * w + c] * scale) as f32;
                }
                cdf[w] = 1.0;
            }
        }
        let mut acc = 0.0;
        for r in 0..rows {
            acc += row_sums[r];
            marginal[r + 1] = (acc / total) as f32;
        }
        marginal[rows] = 1.0;
        Self { pdf, marginal, conditional }
    }
}

fn open(path: &Path) -> Result<std::io::BufReader<std::fs::File>, EnvironmentError> {
    let file = std::fs::File::open(path)
        .map_err(|e| EnvironmentError::Read { path: path.to_owned(), error: e.to_string() })?;
    Ok(std::io::BufReader::new(file))
}

/// A Radiance HDR file's size, from its header.
fn hdr_size(path: &Path) -> Result<(u32, u32), EnvironmentError> {
    let decoder = image::codecs::hdr::HdrDecoder::new(open(path)?)
        .map_err(|e| EnvironmentError::Read { path: path.to_owned(), error: chain(&e) })?;
    let meta = decoder.metadata();
    Ok((meta.width, meta.height))
}

/// A Radiance HDR (RGBE) file, row 0 at the top.
fn read_hdr(path: &Path) -> Result<Image, EnvironmentError> {
    let err = |e: image::ImageError| EnvironmentError::Read { path: path.to_owned(), error: chain(&e) };
    let decoder = image::codecs::hdr::HdrDecoder::new(open(path)?).map_err(err)?;
    let meta = decoder.metadata();
    let pixels = decoder.read_image_hdr().map_err(err)?;
    Ok(Image { width: meta.width, height: meta.height, pixels: pixels.into_iter().map(|p| p.0).collect() })
}
