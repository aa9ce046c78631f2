//! The film: per-pixel accumulation of radiance samples with a box filter (a pixel is the plain
//! mean of the samples taken inside it, the convention of our reference renders), plus what a
//! statistical golden-image test needs: per-pixel standard errors and a count of non-finite
//! samples.
//!
//! **Exact sums.** Each pixel keeps the sum of its samples *exactly*, as a 128-bit fixed-point
//! integer in units of 2^-[`FRACTION_BITS`] ([`PixelAccum::sum`]), and a sample count; the mean
//! is that sum rounded once. Integer addition is associative, so any way of splitting a render
//! (tiles, sample ranges, passes, checkpoints, devices' passes merged on the host) and merging
//! the pieces in any order gives the same sums, and so the same image, bit for bit: what
//! `render --merge` promises (docs/distributed.md). Each sample is rounded to the nearest
//! multiple of 2^-50 (about 8.9 × 10^-16) before it is added, an absolute error far below what
//! an f32 image stores for any pixel brighter than 10^-8; samples of magnitude 2^44 (about
//! 1.8 × 10^13) or more are dropped and counted with the non-finite ones, which keeps any sum of
//! up to 2^32 samples inside the integer. The sums of squares, which only the standard errors
//! read, stay f64: `(Σx² − (Σx)²/n) / (n − 1)`, whose cancellation is harmless in f64 at the
//! sample counts we use.
//!
//! Determinism: floating-point sums depend on their order, so the film never lets the thread
//! count decide one. Parallel rendering either owns whole rows ([`Film::rows_mut`], split with
//! rayon, each pixel fed by one thread in sample order) or renders [`FilmTile`]s merged by
//! [`Film::add_tile`] in an order the caller fixes (e.g. tile index, after a `collect`).
//!
//! Non-finite samples (any channel NaN or ±∞) are counted and dropped whole: one NaN would
//! otherwise poison its pixel for good, and a mean that silently excludes them would hide a bug,
//! so the count is kept ([`Film::non_finite_count`]) for tests to assert it is zero.

use glam::Vec3;
use rayon::prelude::*;

use crate::image_io::Image;

/// Bits after the binary point of [`PixelAccum::sum`]'s fixed-point sums.
pub const FRACTION_BITS: i32 = 50;

/// Samples whose magnitude reaches `2^SAMPLE_LIMIT_LOG2` are dropped (counted as non-finite), so
/// that 2^32 samples, each at most 2^(44+50) units, sum to less than 2^127.
pub const SAMPLE_LIMIT_LOG2: i32 = 44;

/// A channel of a sample in units of 2^-[`FRACTION_BITS`], rounded to the nearest (ties to
/// even); `None` where it is not finite or too large to sum ([`SAMPLE_LIMIT_LOG2`]).
#[inline]
pub fn to_fixed(v: f32) -> Option<i128> {
    let v = f64::from(v);
    // Exact: a power of two times an f32 is an f64 for every finite f32.
    (v.abs() < 2f64.powi(SAMPLE_LIMIT_LOG2)).then(|| (v * 2f64.powi(FRACTION_BITS)).round_ties_even() as i128)
}

/// A fixed-point sum as an f64 (rounded once, to the nearest).
#[inline]
pub fn fixed_to_f64(sum: i128) -> f64 {
    sum as f64 * 2f64.powi(-FRACTION_BITS)
}

/// The running sums of one pixel.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PixelAccum {
    /// Exact sum of the finite samples, per channel, in units of 2^-[`FRACTION_BITS`] (see the
    /// module docs).
    pub sum: [i128; 3],
    /// Sum of the squares of the finite samples, per channel.
    pub sum_sq: [f64; 3],
    /// Number of finite samples (those in `sum`).
    pub count: u64,
    /// Number of samples dropped because a channel was NaN, infinite or too large to sum.
    pub non_finite: u64,
}

impl PixelAccum {
    /// Adds one sample; a sample with any non-finite (or out-of-range) channel only bumps
    /// `non_finite`.
    #[inline]
    pub fn add(&mut self, rgb: Vec3) {
        let (Some(r), Some(g), Some(b)) = (to_fixed(rgb.x), to_fixed(rgb.y), to_fixed(rgb.z)) else {
            self.non_finite += 1;
            return;
        };
        for (c, q) in [r, g, b].into_iter().enumerate() {
            let v = f64::from(rgb[c]);
            self.sum[c] += q;
            self.sum_sq[c] += v * v;
        }
        self.count += 1;
    }

    /// Adds the sums of `other` (of the same pixel, rendered separately): exact for the sums,
    /// and so for the mean, in any order.
    pub fn merge(&mut self, other: &PixelAccum) {
        for c in 0..3 {
            self.sum[c] += other.sum[c];
            self.sum_sq[c] += other.sum_sq[c];
        }
        self.count += other.count;
        self.non_finite += other.non_finite;
    }

    /// The sum of channel `c` as an f64.
    pub fn sum_f64(&self, c: usize) -> f64 {
        fixed_to_f64(self.sum[c])
    }

    /// Mean of the finite samples; black when there are none.
    pub fn mean(&self) -> [f32; 3] {
        if self.count == 0 {
            return [0.0; 3];
        }
        let n = self.count as f64;
        std::array::from_fn(|c| (self.sum_f64(c) / n) as f32)
    }

    /// Standard error of the mean, `sqrt(s² / n)` with the unbiased sample variance `s²`.
    /// With fewer than two samples the variance is unknown and this is `+∞`, so that a
    /// statistical comparison can never take an unsampled pixel for an exact one.
    pub fn stderr(&self) -> [f32; 3] {
        if self.count < 2 {
            return [f32::INFINITY; 3];
        }
        let n = self.count as f64;
        std::array::from_fn(|c| {
            let sum = self.sum_f64(c);
            // Rounding can push a zero variance slightly negative.
            let var = ((self.sum_sq[c] - sum * sum / n) / (n - 1.0)).max(0.0);
            (var / n).sqrt() as f32
        })
    }
}

/// The film: one [`PixelAccum`] per pixel, row-major, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Film {
    width: u32,
    height: u32,
    pixels: Vec<PixelAccum>,
}

impl Film {
    /// An empty film (no samples) of `width` x `height` pixels; either may be zero.
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, pixels: vec![PixelAccum::default(); width as usize * height as usize] }
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    /// The accumulator of pixel (x, y), row 0 at the top; `None` outside the film.
    pub fn pixel(&self, x: u32, y: u32) -> Option<&PixelAccum> {
        (x < self.width && y < self.height).then(|| &self.pixels[self.index(x, y)])
    }

    /// All accumulators, row-major from the top row.
    pub fn pixels(&self) -> &[PixelAccum] {
        &self.pixels
    }

    /// All accumulators, row-major from the top row, to fill (a film read from a file).
    pub fn pixels_mut(&mut self) -> &mut [PixelAccum] {
        &mut self.pixels
    }

    fn index(&self, x: u32, y: u32) -> usize {
        y as usize * self.width as usize + x as usize
    }

    /// Adds a sample to pixel (x, y), row 0 at the top.
    ///
    /// Panics if (x, y) is outside the film: pixel coordinates come from the renderer's own
    /// loops, so one outside is a broken invariant, not bad input.
    #[inline]
    pub fn add_sample(&mut self, x: u32, y: u32, rgb: Vec3) {
        assert!(
            x < self.width && y < self.height,
            "film sample at ({x}, {y}) outside the {}x{} film",
            self.width,
            self.height
        );
        let i = self.index(x, y);
        self.pixels[i].add(rgb);
    }

    /// The rows as a rayon iterator of `(y, row)`, row 0 at the top, for rendering rows in
    /// parallel. Bit-identical to sequential rendering for any thread count, provided each
    /// pixel's samples are added in an order that does not depend on the thread.
    pub fn rows_mut(&mut self) -> impl IndexedParallelIterator<Item = (u32, &mut [PixelAccum])> + '_ {
        // `max(1)`: chunks of zero are refused; a zero-width film has no pixels, hence no rows.
        let width = (self.width as usize).max(1);
        self.pixels.par_chunks_mut(width).enumerate().map(|(y, row)| (y as u32, row))
    }

    /// An empty tile covering columns `x0..x0 + width` and rows `y0..y0 + height`, clipped to
    /// the film (so edge tiles may be smaller, or empty).
    pub fn tile(&self, x0: u32, y0: u32, width: u32, height: u32) -> FilmTile {
        let x0 = x0.min(self.width);
        let y0 = y0.min(self.height);
        let width = width.min(self.width - x0);
        let height = height.min(self.height - y0);
        FilmTile {
            film_size: (self.width, self.height),
            x0,
            y0,
            width,
            height,
            pixels: vec![PixelAccum::default(); width as usize * height as usize],
        }
    }

    /// Merges a tile made by [`Film::tile`] on a film of this size. Merging is exact while each
    /// pixel receives one tile; when several tiles overlap a pixel, merge them in a fixed order
    /// (not completion order) to stay bit-identical across thread counts.
    ///
    /// Panics if the tile was made for a film of another size (a broken invariant).
    pub fn add_tile(&mut self, tile: &FilmTile) {
        assert_eq!(
            tile.film_size,
            (self.width, self.height),
            "tile made for a {:?} film merged into a {}x{} film",
            tile.film_size,
            self.width,
            self.height
        );
        self.merge_rect(&tile.pixels, tile.width, (tile.x0, tile.y0));
    }

    /// Merges `pixels`, rows of `width` that fit inside this film from `origin` on.
    fn merge_rect(&mut self, pixels: &[PixelAccum], width: u32, origin: (u32, u32)) {
        for (y, row) in pixels.chunks((width as usize).max(1)).enumerate() {
            let start = self.index(origin.0, origin.1 + y as u32);
            for (dst, src) in self.pixels[start..start + row.len()].iter_mut().zip(row) {
                dst.merge(src);
            }
        }
    }

    /// Merges another film of the same size, pixel by pixel (e.g. a later progressive pass).
    ///
    /// Panics if the sizes differ (a broken invariant).
    pub fn merge(&mut self, other: &Film) {
        assert_eq!((self.width, self.height), (other.width, other.height), "merging films of different sizes");
        for (dst, src) in self.pixels.iter_mut().zip(&other.pixels) {
            dst.merge(src);
        }
    }

    /// Merges `other` (of the same size) and empties it, pixels in parallel, in one pass over
    /// both: how the CPU's loop moves a finished pass's samples into the render's film.
    pub fn take_samples_from(&mut self, other: &mut Film) {
        assert_eq!((self.width, self.height), (other.width, other.height), "merging films of different sizes");
        self.pixels.par_iter_mut().zip(other.pixels.par_iter_mut()).for_each(|(to, from)| {
            to.merge(from);
            *from = PixelAccum::default();
        });
    }

    /// Merges `other`, a film of a rectangle of this one whose pixel (0, 0) is this one's
    /// `(x0, y0)`, pixel by pixel.
    ///
    /// Panics if it does not fit inside (a broken invariant: callers check pieces first).
    pub fn merge_at(&mut self, other: &Film, x0: u32, y0: u32) {
        assert!(
            x0 + other.width <= self.width && y0 + other.height <= self.height,
            "a {}x{} film at ({x0}, {y0}) outside a {}x{} film",
            other.width,
            other.height,
            self.width,
            self.height
        );
        self.merge_rect(&other.pixels, other.width, (x0, y0));
    }

    /// The image: each pixel the mean of its finite samples (black without any).
    pub fn mean(&self) -> Image {
        self.map_pixels(PixelAccum::mean)
    }

    /// Per-pixel, per-channel standard error of the mean (`+∞` below two samples, see
    /// [`PixelAccum::stderr`]).
    pub fn stderr(&self) -> Image {
        self.map_pixels(PixelAccum::stderr)
    }

    /// Total number of samples dropped as non-finite; a correct renderer keeps this at zero.
    pub fn non_finite_count(&self) -> u64 {
        self.pixels.iter().map(|p| p.non_finite).sum()
    }

    /// Total number of finite samples accumulated.
    pub fn sample_count(&self) -> u64 {
        self.pixels.iter().map(|p| p.count).sum()
    }

    fn map_pixels(&self, f: impl Fn(&PixelAccum) -> [f32; 3]) -> Image {
        Image { width: self.width, height: self.height, pixels: self.pixels.iter().map(f).collect() }
    }
}

/// A rectangle of the film rendered on its own (by one thread) and merged back with
/// [`Film::add_tile`]. Coordinates given to [`FilmTile::add_sample`] are the film's.
#[derive(Clone, Debug, PartialEq)]
pub struct FilmTile {
    film_size: (u32, u32),
    x0: u32,
    y0: u32,
    width: u32,
    height: u32,
    pixels: Vec<PixelAccum>,
}

impl FilmTile {
    /// The film pixels covered: `(x0, y0, width, height)`.
    pub fn bounds(&self) -> (u32, u32, u32, u32) {
        (self.x0, self.y0, self.width, self.height)
    }

    /// Adds a sample to film pixel (x, y), which must lie in the tile.
    ///
    /// Panics otherwise (a broken invariant, as for [`Film::add_sample`]).
    #[inline]
    pub fn add_sample(&mut self, x: u32, y: u32, rgb: Vec3) {
        let (tx, ty) = (x.wrapping_sub(self.x0), y.wrapping_sub(self.y0));
        assert!(tx < self.width && ty < self.height, "film sample at ({x}, {y}) outside the tile {:?}", self.bounds());
        self.pixels[ty as usize * self.width as usize + tx as usize].add(rgb);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_of_known_samples() {
        let mut film = Film::new(3, 2);
        film.add_sample(2, 0, Vec3::new(1.0, 2.0, 3.0));
        film.add_sample(2, 0, Vec3::new(3.0, 4.0, 5.0));
        film.add_sample(0, 1, Vec3::new(0.5, 0.25, -1.0));
        let mean = film.mean();
        assert_eq!((mean.width, mean.height), (3, 2));
        // Row 0 is the top row: (2, 0) is the third pixel of the image.
        assert_eq!(mean.pixels[2], [2.0, 3.0, 4.0]);
        assert_eq!(mean.get(0, 1), Some([0.5, 0.25, -1.0]));
        assert_eq!(mean.get(1, 1), Some([0.0; 3]), "no samples: black");
        assert_eq!(film.sample_count(), 3);
        assert_eq!(film.pixel(2, 0).unwrap().count, 2);
        assert_eq!(film.pixel(3, 0), None);
    }

    #[test]
    fn stderr_of_known_samples() {
        let mut film = Film::new(2, 1);
        // Samples 1, 2, 3, 4: mean 2.5, unbiased variance 5/3, stderr sqrt(5/12).
        for v in [1.0, 2.0, 3.0, 4.0] {
            film.add_sample(0, 0, Vec3::new(v, 2.0 * v, 7.0));
        }
        film.add_sample(1, 0, Vec3::ONE);
        let se = film.stderr();
        let want = (5.0f64 / 12.0).sqrt();
        assert!((f64::from(se.pixels[0][0]) - want).abs() < 1e-7);
        assert!((f64::from(se.pixels[0][1]) - 2.0 * want).abs() < 1e-6);
        assert_eq!(se.pixels[0][2], 0.0, "constant samples");
        assert_eq!(se.pixels[1], [f32::INFINITY; 3], "one sample: unknown");
    }

    #[test]
    fn non_finite_samples_are_counted_and_dropped() {
        let mut film = Film::new(1, 1);
        film.add_sample(0, 0, Vec3::splat(2.0));
        film.add_sample(0, 0, Vec3::new(f32::NAN, 1.0, 1.0));
        film.add_sample(0, 0, Vec3::new(1.0, f32::INFINITY, 1.0));
        film.add_sample(0, 0, Vec3::new(1.0, 1.0, f32::NEG_INFINITY));
        film.add_sample(0, 0, Vec3::splat(4.0));
        assert_eq!(film.non_finite_count(), 3);
        assert_eq!(film.sample_count(), 2);
        assert_eq!(film.mean().pixels[0], [3.0; 3]);
        assert!(film.stderr().pixels[0].iter().all(|s| s.is_finite()));
    }

    /// A deterministic, irregular sample value for pixel `i`, sample `s` (a hash, no RNG).
    fn sample_value(i: u64, s: u64) -> Vec3 {
        let mut h = i.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ s.wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
        let mut next = || {
            h ^= h >> 29;
            h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
            h ^= h >> 32;
            // Spread over several orders of magnitude so rounding depends on summation order.
            ((h >> 40) as f32 / (1u64 << 24) as f32) * 10f32.powi((h % 7) as i32 - 3)
        };
        Vec3::new(next(), next(), next())
    }

    const W: u32 = 37;
    const H: u32 = 23;
    const SPP: u64 = 17;

    fn sequential_film() -> Film {
        let mut film = Film::new(W, H);
        for y in 0..H {
            for x in 0..W {
                for s in 0..SPP {
                    film.add_sample(x, y, sample_value(u64::from(y * W + x), s));
                }
            }
        }
        film
    }

    fn bits(film: &Film) -> Vec<u64> {
        film.pixels()
            .iter()
            .flat_map(|p| {
                p.sum
                    .iter()
                    .flat_map(|&v| [v as u64, (v >> 64) as u64])
                    .chain(p.sum_sq.iter().map(|v| v.to_bits()))
                    .chain([p.count, p.non_finite])
            })
            .collect()
    }

    fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(f)
    }

    #[test]
    fn parallel_rows_equal_sequential_bit_for_bit() {
        let reference = bits(&sequential_film());
        for threads in [1, 2, 5] {
            let mut film = Film::new(W, H);
            in_pool(threads, || {
                film.rows_mut().for_each(|(y, row)| {
                    for (x, px) in row.iter_mut().enumerate() {
                        for s in 0..SPP {
                            px.add(sample_value(u64::from(y * W) + x as u64, s));
                        }
                    }
                })
            });
            assert_eq!(bits(&film), reference, "{threads} threads");
        }
    }

    #[test]
    fn parallel_tiles_equal_sequential_bit_for_bit() {
        let reference = bits(&sequential_film());
        for threads in [1, 3] {
            let mut film = Film::new(W, H);
            let tile_size = 8;
            let origins: Vec<(u32, u32)> =
                (0..H.div_ceil(tile_size)).flat_map(|ty| (0..W.div_ceil(tile_size)).map(move |tx| (tx, ty))).collect();
            let tiles: Vec<FilmTile> = in_pool(threads, || {
                origins
                    .par_iter()
                    .map(|&(tx, ty)| {
                        let mut tile = film.tile(tx * tile_size, ty * tile_size, tile_size, tile_size);
                        let (x0, y0, w, h) = tile.bounds();
                        for y in y0..y0 + h {
                            for x in x0..x0 + w {
                                for s in 0..SPP {
                                    tile.add_sample(x, y, sample_value(u64::from(y * W + x), s));
                                }
                            }
                        }
                        tile
                    })
                    .collect()
            });
            for tile in &tiles {
                film.add_tile(tile);
            }
            assert_eq!(bits(&film), reference, "{threads} threads");
        }
    }

    #[test]
    fn tiles_are_clipped_to_the_film() {
        let film = Film::new(10, 6);
        assert_eq!(film.tile(8, 4, 4, 4).bounds(), (8, 4, 2, 2));
        assert_eq!(film.tile(12, 0, 4, 4).bounds(), (10, 0, 0, 4));
        let mut empty = Film::new(0, 0);
        assert_eq!(empty.rows_mut().count(), 0);
        assert_eq!(empty.mean().pixels.len(), 0);
    }

    #[test]
    fn merge_adds_passes() {
        let mut a = Film::new(2, 2);
        let mut b = Film::new(2, 2);
        a.add_sample(1, 1, Vec3::splat(1.0));
        b.add_sample(1, 1, Vec3::splat(3.0));
        b.add_sample(0, 0, Vec3::splat(f32::NAN));
        a.merge(&b);
        assert_eq!(a.mean().get(1, 1), Some([2.0; 3]));
        assert_eq!(a.non_finite_count(), 1);
    }

    /// The fixed-point sums make any split of a pixel's samples merge to the same sums, in any
    /// order: here samples spread over ten orders of magnitude, where f64 sums would differ.
    #[test]
    fn merged_pieces_equal_one_pass_in_any_order() {
        let samples: Vec<Vec3> = (0..200).map(|s| sample_value(3, s) * 1e3).collect();
        let mut whole = PixelAccum::default();
        samples.iter().for_each(|&v| whole.add(v));
        let pieces: Vec<PixelAccum> = [0..7, 7..8, 8..150, 150..200]
            .into_iter()
            .map(|r| {
                let mut p = PixelAccum::default();
                samples[r].iter().for_each(|&v| p.add(v));
                p
            })
            .collect();
        for order in [[0, 1, 2, 3], [3, 1, 0, 2], [2, 3, 1, 0]] {
            let mut merged = PixelAccum::default();
            order.iter().for_each(|&i| merged.merge(&pieces[i]));
            assert_eq!((merged.sum, merged.count), (whole.sum, whole.count), "{order:?}");
            assert_eq!(merged.mean().map(f32::to_bits), whole.mean().map(f32::to_bits));
        }
    }

    #[test]
    fn fixed_point_rounds_to_nearest_and_refuses_what_it_cannot_hold() {
        assert_eq!(to_fixed(1.0), Some(1 << FRACTION_BITS));
        assert_eq!(to_fixed(-0.5), Some(-(1 << (FRACTION_BITS - 1))));
        // 2^-51 is half a unit: a tie, to even (0); 3 × 2^-52 is 0.75 units: 1.
        assert_eq!(to_fixed(2f32.powi(-51)), Some(0));
        assert_eq!(to_fixed(3.0 * 2f32.powi(-52)), Some(1));
        assert_eq!(to_fixed(3.0 * 2f32.powi(-51)), Some(2));
        assert_eq!(to_fixed(f32::MIN_POSITIVE), Some(0));
        let big = 2f32.powi(SAMPLE_LIMIT_LOG2);
        assert!(to_fixed(f32::from_bits(big.to_bits() - 1)).is_some());
        assert_eq!(to_fixed(big), None);
        assert_eq!(to_fixed(f32::NAN), None);
        let mut p = PixelAccum::default();
        p.add(Vec3::new(1.0, big, 1.0));
        assert_eq!((p.count, p.non_finite), (0, 1));
        assert_eq!(fixed_to_f64(to_fixed(0.1).unwrap()) as f32, 0.1);
    }
}
