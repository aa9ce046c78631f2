//! Random numbers for rendering: one independent stream per (seed, pixel, sample), so an image
//! depends on the seed and the sample count only, never on threads or scheduling.
//!
//! The stream is PCG32 (O'Neill 2014, XSH-RR output); its start state is a hash of the triple.

use glam::Vec2;

/// A PCG32 stream.
#[derive(Clone, Debug)]
pub struct Rng {
    state: u64,
}

const MULTIPLIER: u64 = 6_364_136_223_846_793_005;
const INCREMENT: u64 = 1_442_695_040_888_963_407;

/// SplitMix64's finaliser: a bijective mix of 64 bits.
fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

impl Rng {
    /// The stream of sample `sample` of pixel `pixel` under `seed`.
    pub fn for_sample(seed: u64, pixel: u64, sample: u64) -> Self {
        let mut rng =
            Rng { state: mix(mix(seed ^ 0x0061_7262_6f72).wrapping_add(pixel).rotate_left(23) ^ mix(sample)) };
        rng.next_u32();
        rng
    }

    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old.wrapping_mul(MULTIPLIER).wrapping_add(INCREMENT);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        xorshifted.rotate_right((old >> 59) as u32)
    }

    /// Uniform in [0, 1): 24 random bits, so 1.0 is never returned.
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }

    pub fn next_vec2(&mut self) -> Vec2 {
        Vec2::new(self.next_f32(), self.next_f32())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_are_reproducible_and_distinct() {
        let a: Vec<u32> = (0..8)
            .map({
                let mut r = Rng::for_sample(1, 2, 3);
                move |_| r.next_u32()
            })
            .collect();
        let b: Vec<u32> = (0..8)
            .map({
                let mut r = Rng::for_sample(1, 2, 3);
                move |_| r.next_u32()
            })
            .collect();
        assert_eq!(a, b);
        for other in [Rng::for_sample(1, 2, 4), Rng::for_sample(1, 3, 3), Rng::for_sample(2, 2, 3)] {
            let mut o = other;
            assert_ne!(a[0], o.next_u32());
        }
    }

    #[test]
    fn uniform_mean_and_range() {
        let mut r = Rng::for_sample(0, 0, 0);
        let n = 100_000;
        let xs: Vec<f32> = (0..n).map(|_| r.next_f32()).collect();
        assert!(xs.iter().all(|&x| (0.0..1.0).contains(&x)));
        let mean = xs.iter().map(|&x| x as f64).sum::<f64>() / n as f64;
        // Standard error of the mean of U(0,1) is 1/sqrt(12 n) ≈ 0.0009; allow 4 of them.
        assert!((mean - 0.5).abs() < 0.004, "{mean}");
    }
}
