//! The CPU's render loop: every pixel's samples, rows in parallel, into a [`Film`] of the whole
//! image or of a rectangle of it.

use std::ops::Range;

use glam::Vec2;
use rayon::prelude::*;

use super::RenderScene;
use super::film::Film;
use super::rng::Rng;

impl RenderScene {
    /// Adds samples `samples` of every pixel to `film`, rows in parallel; calls `progress` with
    /// the rays of each finished row. Returns the rays traced. The result depends only on the
    /// seed and the sample indices, not on the thread count.
    pub fn render(
        &self,
        film: &mut Film,
        seed: u64,
        max_depth: u32,
        samples: std::ops::Range<u32>,
        progress: &(dyn Fn(u64) + Sync),
    ) -> u64 {
        let abandon = &|| false;
        self.render_rows(film, &Rows { origin: (0, 0), seed, max_depth, samples, filter: &|_| true, progress, abandon })
    }

    /// [`RenderScene::render`] for the film's rows that `rows` names, with its seed, depth and
    /// samples. A pixel's samples may be added by several calls, rows in any order, and the film
    /// is the same as long as each pixel gets its samples in increasing order. Once
    /// `rows.abandon` says yes, the rows stop where they are: the film is then partly rendered,
    /// for the caller to drop.
    pub fn render_rows(&self, film: &mut Film, rows: &Rows<'_>) -> u64 {
        let Rows { origin, seed, max_depth, ref samples, filter, progress, abandon } = *rows;
        let width = self.width as u64;
        film.rows_mut()
            .filter(|(y, _)| filter(*y))
            .map(|(y, row)| {
                let mut rays = 0u64;
                let y = y + origin.1;
                for (x, px) in row.iter_mut().enumerate() {
                    if abandon() {
                        break;
                    }
                    let x = x as u32 + origin.0;
                    let pixel = y as u64 * width + x as u64;
                    for s in samples.clone() {
                        let mut rng = Rng::for_sample(seed, pixel, s as u64);
                        let film_pos = Vec2::new(x as f32, y as f32) + rng.next_vec2();
                        let ray = self.camera.ray(film_pos, rng.next_vec2());
                        let (mut l, r) = self.radiance(ray, &mut rng, max_depth);
                        if let Some(c) = self.sample_clamp {
                            // NaN stays NaN, for the film to count.
                            let m = l.max_element();
                            if m > c {
                                l *= c / m;
                            }
                        }
                        px.add(l);
                        rays += r as u64;
                    }
                }
                progress(rays);
                rays
            })
            .sum()
    }
}

/// What one call of [`RenderScene::render_rows`] renders: a slice of a pass of the CPU's loop.
#[derive(Clone)]
pub struct Rows<'a> {
    /// The image's pixel at the film's pixel (0, 0) (a film of a rectangle of the image).
    pub origin: (u32, u32),
    pub seed: u64,
    pub max_depth: u32,
    /// The sample indices each pixel gets.
    pub samples: Range<u32>,
    /// The film's rows to render: those `y` where `filter(y)` holds.
    pub filter: &'a (dyn Fn(u32) -> bool + Sync),
    /// Hears of the rays of each finished row.
    pub progress: &'a (dyn Fn(u64) + Sync),
    /// Asked at every pixel: yes stops the rows there ([`RenderScene::render_rows`]).
    pub abandon: &'a (dyn Fn() -> bool + Sync),
}
