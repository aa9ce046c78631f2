//! What part of a render one job takes: a rectangle of the image and a range of sample indices
//! ([`Region`]), and the fixed order in which `render --tile I/N` cuts an image into N
//! rectangles ([`tile_rect`]). Every sample has its own random stream (seed, pixel, sample), so
//! any set of regions that covers each pixel's samples once renders exactly the samples one
//! whole render would (docs/distributed.md).

use std::ops::Range;

/// A rectangle of the image: columns `x0..x1` and rows `y0..y1`, row 0 at the top.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Rect {
    pub x0: u32,
    pub y0: u32,
    pub x1: u32,
    pub y1: u32,
}

impl Rect {
    /// The whole of a `width` x `height` image.
    pub fn full(width: u32, height: u32) -> Rect {
        Rect { x0: 0, y0: 0, x1: width, y1: height }
    }

    pub fn width(&self) -> u32 {
        self.x1 - self.x0
    }

    pub fn height(&self) -> u32 {
        self.y1 - self.y0
    }

    pub fn pixel_count(&self) -> u64 {
        u64::from(self.width()) * u64::from(self.height())
    }

    pub fn is_empty(&self) -> bool {
        self.x1 <= self.x0 || self.y1 <= self.y0
    }

    /// Whether it lies inside a `width` x `height` image and holds at least one pixel.
    pub fn fits(&self, width: u32, height: u32) -> bool {
        !self.is_empty() && self.x1 <= width && self.y1 <= height
    }

    /// Whether the two share a pixel.
    pub fn overlaps(&self, other: &Rect) -> bool {
        self.x0 < other.x1 && other.x0 < self.x1 && self.y0 < other.y1 && other.y0 < self.y1
    }
}

impl std::fmt::Display for Rect {
    /// `X0,Y0,X1,Y1`, as `--crop` takes it.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{},{},{},{}", self.x0, self.y0, self.x1, self.y1)
    }
}

/// A rectangle of the image and the sample indices of each of its pixels to render.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Region {
    pub rect: Rect,
    pub samples: Range<u32>,
}

/// The grid `--tile I/N` cuts a `width` x `height` image into: `(columns, rows)` with
/// `columns × rows = n`, the factorisation whose tiles are closest to square (ties: fewer
/// columns), among those with at most one tile per pixel each way. `None` where there is none
/// (more tiles than pixels along both sides).
pub fn tile_grid(n: u32, width: u32, height: u32) -> Option<(u32, u32)> {
    let aspect = |cols: u32, rows: u32| {
        let (w, h) = (f64::from(width) / f64::from(cols), f64::from(height) / f64::from(rows));
        (w / h).ln().abs()
    };
    (1..=n)
        .filter(|c| n % c == 0)
        .map(|c| (c, n / c))
        .filter(|&(c, r)| c <= width && r <= height)
        .min_by(|a, b| aspect(a.0, a.1).total_cmp(&aspect(b.0, b.1)).then(a.0.cmp(&b.0)))
}

/// Tile `i` of `n` ([`tile_grid`]), in row-major order from the top left: tile `i` is column
/// `i % columns` and row `i / columns`; column `c` spans pixels `⌊c·W/columns⌋` to
/// `⌊(c+1)·W/columns⌋`, and likewise for rows, so tiles differ in size by at most a pixel each
/// way and cover the image once. `None` where `i >= n` or there is no grid.
pub fn tile_rect(i: u32, n: u32, width: u32, height: u32) -> Option<Rect> {
    let (cols, rows) = tile_grid(n, width, height)?;
    if i >= n {
        return None;
    }
    let (c, r) = (i % cols, i / cols);
    let cut = |k: u32, parts: u32, len: u32| (u64::from(k) * u64::from(len) / u64::from(parts)) as u32;
    Some(Rect {
        x0: cut(c, cols, width),
        x1: cut(c + 1, cols, width),
        y0: cut(r, rows, height),
        y1: cut(r + 1, rows, height),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_cover_the_image_once_in_row_major_order() {
        for (n, w, h) in [(1, 7, 5), (4, 512, 512), (6, 640, 360), (7, 100, 3), (12, 13, 11), (9, 3, 3)] {
            let mut hits = vec![0u32; (w * h) as usize];
            let tiles: Vec<Rect> = (0..n).map(|i| tile_rect(i, n, w, h).unwrap()).collect();
            for t in &tiles {
                assert!(t.fits(w, h), "{n} tiles of {w}x{h}: {t}");
                for y in t.y0..t.y1 {
                    for x in t.x0..t.x1 {
                        hits[(y * w + x) as usize] += 1;
                    }
                }
            }
            assert!(hits.iter().all(|&k| k == 1), "{n} tiles of {w}x{h}");
            // Row-major: the first tile is at the top left, and rows go down.
            assert_eq!((tiles[0].x0, tiles[0].y0), (0, 0));
            assert!(tiles.windows(2).all(|p| (p[0].y0, p[0].x0) < (p[1].y0, p[1].x0)));
        }
        assert_eq!(tile_grid(4, 512, 512), Some((2, 2)));
        assert_eq!(tile_grid(2, 1920, 1080), Some((2, 1)));
        assert_eq!(tile_grid(7, 100, 3), Some((7, 1)));
        assert_eq!(tile_grid(10, 3, 3), None);
        assert_eq!(tile_rect(4, 4, 512, 512), None);
    }
}
