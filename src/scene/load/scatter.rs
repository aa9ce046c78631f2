//! An object's `[objects.scatter]`: seeded random instances of the object, some orbiting.
//!
//! Scattered instances draw from a local SplitMix64 (Steele, Lea and Flood 2014, "Fast splittable
//! pseudorandom number generators"), not the renderer's PCG32 streams: a scene's layout must not
//! move when the renderer changes how it samples.

use std::f32::consts::TAU;

use glam::{Mat4, Vec3};

use super::Ctx;
use super::objects::MAX_OBJECTS;
use crate::scene::file::{S, ScatterFile};
use crate::scene::{Animation, Object, SceneError};

/// Most instances one `scatter` makes (each object is 112 bytes; whether they fit in memory is
/// checked too).
pub(super) const MAX_SCATTER: u64 = 10_000_000;
/// A scatter's orbit period when none is given, seconds.
const DEFAULT_PERIOD: f32 = 4.0;

/// An object's `[objects.scatter]`: `count` copies of `placed` (the object's parts: one, or a glTF
/// file's mesh nodes, which move as one) at seeded random points of the box [min, max], each
/// turned by a random angle about y, `round(moving · count)` of them orbiting.
pub(super) fn scatter(
    ctx: &Ctx,
    index: usize,
    s: &S<ScatterFile>,
    clock: bool,
    placed: &[Object],
    objects: &mut Vec<Object>,
) -> Result<(), SceneError> {
    let f = s.get_ref();
    let key = |k: &str| format!("objects[{index}].scatter.{k}");
    let missing = |k: &str| ctx.err(s.span(), key(k), format!("a scatter needs `{k}`"));
    let count_s = f.count.as_ref().ok_or_else(|| missing("count"))?;
    let count = *count_s.get_ref();
    if !(1..=MAX_SCATTER).contains(&count) {
        return Err(ctx.err(count_s.span(), key("count"), format!("{count} is not 1 to {MAX_SCATTER}")));
    }
    let seed = f.seed.as_ref().map_or(0, |s| *s.get_ref());
    let min_s = f.min.as_ref().ok_or_else(|| missing("min"))?;
    let (min, max) = scatter_box(ctx, &key, min_s, f.max.as_ref().ok_or_else(|| missing("max"))?)?;
    let (radius, moving, period) = orbit(ctx, &key, f, clock)?;
    // Radius 0: nothing moves, so no instance carries an animation.
    let mut left = if radius > 0.0 { (f64::from(moving) * count as f64).round() as u64 } else { 0 };
    let total = objects.len() as u64 + count * placed.len() as u64;
    if total > MAX_OBJECTS {
        let msg = format!("{count} instances make {total} objects in the scene, more than {MAX_OBJECTS}");
        return Err(ctx.err(count_s.span(), key("count"), msg));
    }
    let made = count * placed.len() as u64;
    let what = format!("a scatter of {made} objects");
    crate::memory::check_fits(&what, made as f64 * size_of::<Object>() as f64)
        .map_err(|e| ctx.memory_err(count_s.span(), key("count"), e))?;
    let mut rng = SplitMix64(seed);
    objects.reserve(made as usize);
    for i in 0..count {
        let u = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        // Clamped: min + (max - min) · u can round one ulp past max.
        let at = (min + (max - min) * u).clamp(min, max);
        let yaw = TAU * rng.next_f32();
        let phase = TAU * rng.next_f32();
        // Selection sampling (Knuth, TAOCP vol. 2, 3.4.2, Algorithm S): exactly the rounded
        // count moves, and every subset of that size is equally likely.
        let moves = rng.below(count - i) < left;
        left -= u64::from(moves);
        let instance = Mat4::from_translation(at) * Mat4::from_rotation_y(yaw);
        for part in placed {
            let world_from_object = instance * part.world_from_object;
            if !world_from_object.is_finite() {
                let msg = format!("instance {i} at {at}, after the object's own placement, overflows");
                return Err(ctx.err(min_s.span(), key("min"), msg));
            }
            objects.push(Object {
                mesh: part.mesh,
                world_from_object,
                material: part.material,
                animation: moves.then_some(Animation::Orbit { radius, period, phase }),
            });
        }
    }
    Ok(())
}

/// The box `[min, max]` instances are drawn in: finite, and not inside out.
fn scatter_box(
    ctx: &Ctx,
    key: &dyn Fn(&str) -> String,
    min_s: &S<[f32; 3]>,
    max_s: &S<[f32; 3]>,
) -> Result<(Vec3, Vec3), SceneError> {
    let min = ctx.vec3(min_s, &key("min"))?;
    let max = ctx.vec3(max_s, &key("max"))?;
    if min.cmpgt(max).any() {
        return Err(ctx.err(min_s.span(), key("min"), format!("{min} is above max {max} on some axis")));
    }
    if !(max - min).is_finite() {
        return Err(ctx.err(
            min_s.span(),
            key("min"),
            format!("the box from {min} to {max} is too large (it overflows)"),
        ));
    }
    Ok((min, max))
}

/// The orbits of the moving instances: `radius` (default 0: none moves), the fraction `moving`
/// (default all, where they have a radius) and `period`, which need the `[animation]` clock.
fn orbit(ctx: &Ctx, key: &dyn Fn(&str) -> String, f: &ScatterFile, clock: bool) -> Result<(f32, f32, f32), SceneError> {
    let radius = match &f.radius {
        Some(r) => ctx.number(r, &key("radius"), |x| x >= 0.0, "a radius >= 0")?,
        None => 0.0,
    };
    let moving = match &f.moving {
        Some(m) => ctx.number(m, &key("moving"), |x| (0.0..=1.0).contains(&x), "a fraction in [0, 1]")?,
        None if radius > 0.0 => 1.0,
        None => 0.0,
    };
    let period = match &f.period {
        Some(p) => ctx.number(p, &key("period"), |x| x > 0.0, "a period > 0 seconds")?,
        None => DEFAULT_PERIOD,
    };
    if let Some(r) = f.radius.as_ref().filter(|_| radius > 0.0 && !clock) {
        return Err(ctx.err(r.span(), key("radius"), "moving instances need an [animation] table (fps and frames)"));
    }
    Ok((radius, moving, period))
}

/// SplitMix64 (Steele, Lea and Flood 2014): one 64-bit state, every output a mix of it.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1): 24 random bits.
    fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u32 << 24) as f32)
    }

    /// Uniform in [0, n) by a 128-bit multiply (Lemire 2019) without the rejection step: the
    /// bias is below n / 2^64, nothing at the counts a scatter allows.
    fn below(&mut self, n: u64) -> u64 {
        ((u128::from(self.next_u64()) * u128::from(n)) >> 64) as u64
    }
}
