//! Morton codes with 21 bits per axis, interleaved x-y-z from the most significant used bit.
//!
//! Karras 2012 (section 4) sorts primitives by the Morton code of their centroid, normalised to
//! the bounds of all centroids; the paper uses 30 bits, Meister & Bittner 2018 (section 6) use
//! "60-bit Morton codes", 20 bits per axis. We keep 21 bits per axis, 63 bits in all: the extra
//! bit per axis is free in a `u64`, and bit 63 stays 0.

use glam::Vec3;

use super::Aabb;

/// Bits per axis.
pub const MORTON_BITS: u32 = 21;
const MORTON_MAX: u32 = (1 << MORTON_BITS) - 1;

/// Spreads the low 21 bits of `v` so that bit `k` lands on bit `3k`.
#[inline]
pub fn spread_bits_3(v: u32) -> u64 {
    let mut x = (v & MORTON_MAX) as u64;
    x = (x | (x << 32)) & 0x001f_0000_0000_ffff;
    x = (x | (x << 16)) & 0x001f_0000_ff00_00ff;
    x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x << 2)) & 0x1249_2492_4924_9249;
    x
}

/// Morton code of integer grid coordinates, each clamped to 21 bits.
#[inline]
pub fn morton_encode(x: u32, y: u32, z: u32) -> u64 {
    (spread_bits_3(x) << 2) | (spread_bits_3(y) << 1) | spread_bits_3(z)
}

/// Maps points inside `bounds` to the 2²¹ grid per axis. An axis of zero extent maps to 0.
#[derive(Clone, Copy, Debug)]
pub struct MortonQuantizer {
    origin: Vec3,
    scale: Vec3,
}

impl MortonQuantizer {
    pub fn new(bounds: &Aabb) -> Self {
        let extent = bounds.extent();
        let cells = (1u32 << MORTON_BITS) as f32;
        let scale = Vec3::select(extent.cmpgt(Vec3::ZERO), Vec3::splat(cells) / extent, Vec3::ZERO);
        // An extent below about 2^-106 overflows `cells / extent`: such an axis gets the largest
        // power of two instead, and uses fewer of its bits (at 1e-33, 17 of 21), where a zero
        // scale put every primitive in one cell and left the tree to index order. An all-NaN
        // or infinite extent gives a zero or NaN scale; `as u32` below maps NaN to 0 and
        // saturates, so no input can index out of the grid.
        let largest = Vec3::splat(2f32.powi(127));
        let scale =
            Vec3::select(scale.is_finite_mask(), scale, Vec3::select(scale.cmpgt(Vec3::ZERO), largest, Vec3::ZERO));
        // Rounded down to a power of two (clearing the mantissa): then `(p - origin) * scale`
        // rounds only in the subtraction, which every IEEE device rounds alike, and the GPU
        // build gets the same codes as this one whatever its compiler fuses. It costs at most
        // one of the 21 bits per axis.
        let pow2 = |s: f32| if s.is_normal() { f32::from_bits(s.to_bits() & 0xff80_0000) } else { 0.0 };
        Self { origin: bounds.min, scale: Vec3::new(pow2(scale.x), pow2(scale.y), pow2(scale.z)) }
    }

    /// `(origin, scale)`: a point's grid coordinates are `(p - origin) * scale`, truncated.
    pub fn parts(&self) -> (Vec3, Vec3) {
        (self.origin, self.scale)
    }

    #[inline]
    pub fn code(&self, p: Vec3) -> u64 {
        let q = (p - self.origin) * self.scale;
        let c = |v: f32| (v as u32).min(MORTON_MAX);
        morton_encode(c(q.x), c(q.y), c(q.z))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spread_naive(v: u32) -> u64 {
        (0..21).fold(0u64, |acc, k| acc | ((((v >> k) & 1) as u64) << (3 * k)))
    }

    #[test]
    fn spread_matches_bit_by_bit() {
        for v in [0u32, 1, 2, 3, 0x15_5555, 0x0a_aaaa, MORTON_MAX, 123_456, 0xffff_ffff] {
            assert_eq!(spread_bits_3(v), spread_naive(v & MORTON_MAX), "v = {v:#x}");
        }
    }

    #[test]
    fn codes_use_63_bits_and_interleave_x_first() {
        assert_eq!(morton_encode(MORTON_MAX, MORTON_MAX, MORTON_MAX), (1u64 << 63) - 1);
        assert_eq!(morton_encode(1, 0, 0), 0b100);
        assert_eq!(morton_encode(0, 1, 0), 0b010);
        assert_eq!(morton_encode(0, 0, 1), 0b001);
    }

    #[test]
    fn quantizer_covers_the_grid_and_survives_degenerate_bounds() {
        let b = Aabb::new(Vec3::ZERO, Vec3::new(2.0, 0.0, 1.0));
        let q = MortonQuantizer::new(&b);
        assert_eq!(q.code(Vec3::ZERO), 0);
        assert_eq!(q.code(b.max), morton_encode(MORTON_MAX, 0, MORTON_MAX));
        // A tiny extent (2^-120) still spreads points over the grid, with fewer bits.
        let tiny = Aabb::new(Vec3::ZERO, Vec3::splat(2f32.powi(-120)));
        let t = MortonQuantizer::new(&tiny);
        assert_eq!(t.code(tiny.max * 0.5), morton_encode(64, 64, 64));
        let nan = MortonQuantizer::new(&Aabb::new(Vec3::splat(f32::NAN), Vec3::splat(f32::NAN)));
        assert_eq!(nan.code(Vec3::ONE), 0);
        assert_eq!(q.code(Vec3::splat(f32::NAN)), 0);
    }
}
