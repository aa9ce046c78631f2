//! Time against error: how fast each BVH builder's renders converge to a reference image, counting
//! the BVH build in the time (`bvh-bench --converge`).
//!
//! For each builder, the scene is rendered at doubling sample counts (1, 2, 4, ... spp). A render
//! of `n` spp is the first `n` samples of every pixel, the same whichever builder traced them, so
//! the error at a sample count differs between builders only where their hits do; the time is
//! what differs. One point of a curve is what a user rendering `n` spp with that builder would
//! wait: the BVH build plus the render.
//!
//! - A fixed builder builds once; its curve renders sample ranges `[0, 1), [1, 2), [2, 4), ...`
//!   into one film and times each, so the point at `n` spp costs the build plus the render
//!   time of samples `0..n`, as a separate render of `n` spp would.
//! - `auto` decides how long to optimise from the render's length, measured on its device
//!   (on the CPU while rendering, `arbor::render::refine`; on the GPU before,
//!   `gpu::trace::build_auto`), so each of its points is a separate build and render with that
//!   point's sample count, its optimisation counted in the render's time.
//! - On the GPU every point is a separate render of `0..n` samples (its film is read back once
//!   per render); the tree is built (as `render --device gpu` builds it) and uploaded once per
//!   curve for a fixed builder, per point for `auto`, and that time counts as build time.
//!
//! Every render goes through [`arbor::device::Renderer`], the entry point `render` uses.
//!
//! Errors, over every pixel and channel against the reference `r`:
//! - relative MSE: the mean of `(x - r)² / (r² + 0.01)` (the 0.01 keeps dark pixels from
//!   dominating; the usual form in the denoising literature);
//! - mean absolute error: the mean of `|x - r|`.
//!
//! The reference is an independent image (e.g. another renderer's) or a render at many samples
//! with another seed, so that its noise does not correlate with the curves'. Its own noise puts
//! a floor under the measured error: with `k` times the last point's samples, about `1/k` of that
//! point's relative MSE.
//!
//! Comparing builders at equal time ([`compare_auto`]): the curves are sampled at different
//! times, so each builder's sample count at a time is interpolated between its points, and the
//! error there is read from one model fitted to all points, `c/spp + floor` ([`ErrorModel`]).
//! Only times where every curve has points are compared. The relative MSE falls as `1/spp`, so
//! a ratio of 1.1 in relative MSE is about 10% more time for the same error.

use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use arbor::bvh::Tracing;
use arbor::device::{BuilderChoice, Device, DeviceError, RenderedFrame, Renderer};
use arbor::image_io::Image;
use arbor::render::film::Film;
use arbor::render::first_frame_time;
use arbor::scene::{RenderSettings, Scene};

/// The relative MSE's guard against division by a dark reference pixel.
const REL_MSE_EPSILON: f64 = 0.01;

/// What to measure. `Default`: 1 to 64 spp, depth 8, seed 0.
#[derive(Clone, Debug)]
pub struct ConvergeConfig {
    /// Sample counts: `start_spp`, doubled while at most `render.spp`.
    pub start_spp: u32,
    /// The renders: `spp` is the last point's, `max_depth` and `seed` (the scene's usually)
    /// every point's (the rendered reference takes another seed); no time limit.
    pub render: RenderSettings,
    /// The form the CPU traces in. Default: the best this CPU has.
    pub tracing: Tracing,
}

impl Default for ConvergeConfig {
    fn default() -> Self {
        Self { start_spp: 1, render: RenderSettings { spp: 64, ..Default::default() }, tracing: Tracing::best() }
    }
}

impl ConvergeConfig {
    /// The sample counts of a curve's points.
    pub fn spp_steps(&self) -> Vec<u32> {
        std::iter::successors(Some(self.start_spp.max(1)), |&n| n.checked_mul(2))
            .take_while(|&n| n <= self.render.spp)
            .collect()
    }

    /// The settings of the point at `spp`.
    fn at(&self, spp: u32) -> RenderSettings {
        RenderSettings { spp, time: None, ..self.render }
    }
}

/// One point of a curve.
#[derive(Clone, Debug, Serialize)]
pub struct ConvergePoint {
    pub spp: u32,
    /// BVH build plus render, seconds.
    pub time_s: f64,
    /// The BVH build's part of `time_s`.
    pub build_s: f64,
    pub rel_mse: f64,
    pub mae: f64,
    /// Samples dropped because they were NaN or infinite (0 in a correct render).
    pub non_finite: u64,
}

/// One builder on one device.
#[derive(Clone, Debug, Serialize)]
pub struct ConvergeCurve {
    pub builder: String,
    pub device: String,
    /// What the builder did (for `auto`, its decision at the last point).
    pub detail: String,
    pub points: Vec<ConvergePoint>,
}

/// `auto` against the best fixed builder on the same device at equal time, where all that
/// device's curves overlap.
#[derive(Clone, Debug, Serialize)]
pub struct AutoComparison {
    pub device: String,
    /// The largest ratio of auto's relative MSE to the lowest of the fixed builders'.
    pub worst_ratio_rel_mse: f64,
    /// Where it is, seconds, and which fixed builder was best there.
    pub worst_at_time_s: f64,
    pub best_fixed_there: String,
    /// The same for the mean absolute error.
    pub worst_ratio_mae: f64,
    /// The time range compared, seconds.
    pub compared_from_s: f64,
    pub compared_to_s: f64,
    /// The relative MSE model the ratios come from.
    pub rel_mse_model: ErrorModel,
    /// At each sample count, `auto`'s time (build and render) over the fastest fixed
    /// builder's at that count: the end-to-end ratio a user sees.
    pub wall_ratios: Vec<WallRatio>,
}

/// `auto`'s end-to-end time against the fastest fixed builder's at one sample count.
#[derive(Clone, Debug, Serialize)]
pub struct WallRatio {
    pub spp: u32,
    pub ratio: f64,
    pub best_fixed: String,
}

/// At each sample count of `auto`'s curve, its time over the fastest fixed builder's there.
fn wall_ratios(auto: &ConvergeCurve, fixed: &[&ConvergeCurve]) -> Vec<WallRatio> {
    auto.points
        .iter()
        .filter_map(|p| {
            let (best, name) = fixed
                .iter()
                .filter_map(|c| Some((c.points.iter().find(|q| q.spp == p.spp)?.time_s, &c.builder)))
                .min_by(|a, b| a.0.total_cmp(&b.0))?;
            Some(WallRatio { spp: p.spp, ratio: p.time_s / best.max(1e-12), best_fixed: name.clone() })
        })
        .collect()
}

/// Relative MSE and mean absolute error of `image` against `reference` (see the module docs).
///
/// # Panics
/// If the sizes differ (callers check them with a message first).
pub fn image_error(image: &Image, reference: &Image) -> (f64, f64) {
    assert_eq!((image.width, image.height), (reference.width, reference.height), "image sizes differ");
    let (sq, abs) = image
        .pixels
        .par_iter()
        .zip(&reference.pixels)
        .map(|(x, r)| {
            let mut s = (0.0, 0.0);
            for c in 0..3 {
                let (x, r) = (f64::from(x[c]), f64::from(r[c]));
                s.0 += (x - r) * (x - r) / (r * r + REL_MSE_EPSILON);
                s.1 += (x - r).abs();
            }
            s
        })
        .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    let n = (3 * image.pixels.len()).max(1) as f64;
    (sq / n, abs / n)
}

/// Renders `scene` at `spp` samples with `seed` (a reference) on the CPU, traced as `tracing`
/// says; returns it and the seconds taken.
pub fn render_reference(
    scene: &Scene,
    spp: u32,
    max_depth: u32,
    seed: u64,
    tracing: Tracing,
) -> Result<(Image, f64), DeviceError> {
    let t = Instant::now();
    let settings = RenderSettings { spp, max_depth, seed, ..Default::default() };
    let builder = BuilderChoice::Fixed("lbvh+prbvh".parse().expect("a builder name"));
    let mut renderer = Renderer::new(Device::Cpu, scene, &builder, tracing, &settings, 1, first_frame_time(scene))?;
    let frame = renderer.render(&settings, &|_| {})?;
    Ok((frame.film.mean(), t.elapsed().as_secs_f64()))
}

/// The curve of `choice` on `device` against `reference`; `progress` hears of each point.
///
/// Every point is rendered through [`Renderer`], as `render` renders. A fixed builder builds
/// once per curve and each point carries on from the last ([`Renderer::render_more`]: both
/// devices add the samples between them); `auto` builds for each
/// point's sample count. GPU kernel compilation, paid once per process and variant, is left
/// out of the build's time. On the GPU, samples `auto` timed while building count once, in the
/// build; on the CPU, `auto` optimises while rendering, and that time counts in the render's.
pub fn measure_curve(
    scene: &Scene,
    choice: &BuilderChoice,
    device: Device,
    reference: &Image,
    config: &ConvergeConfig,
    progress: &mut dyn FnMut(&ConvergePoint),
) -> Result<ConvergeCurve, DeviceError> {
    let time = first_frame_time(scene);
    let build = |spp: u32| -> Result<(Renderer, f64), DeviceError> {
        let t = Instant::now();
        let renderer = Renderer::new(device, scene, choice, config.tracing, &config.at(spp), 1, time)?;
        let build_s = (t.elapsed().as_secs_f64() - renderer.compile_seconds()).max(0.0);
        Ok((renderer, build_s))
    };
    let mut points = Vec::new();
    let mut detail = String::new();
    let mut fixed: Option<(Renderer, f64, Option<RenderedFrame>)> = None;
    for spp in config.spp_steps() {
        let frame = match choice {
            BuilderChoice::Fixed(_) => {
                if fixed.is_none() {
                    let (renderer, build_s) = build(config.render.spp)?;
                    fixed = Some((renderer, build_s, None));
                }
                let (renderer, build_s, last) = fixed.as_mut().expect("built above");
                detail.clone_from(&renderer.build_report().builder);
                let frame = match last.take() {
                    None => renderer.render(&config.at(spp), &|_| {})?,
                    Some(f) => renderer.render_more(f, &config.at(spp), &|_| {})?,
                };
                points.push(point(&frame.film, reference, spp, *build_s, *build_s + frame.seconds));
                frame
            }
            BuilderChoice::Auto => {
                let (mut renderer, build_s) = build(spp)?;
                detail.clone_from(&renderer.build_report().builder);
                let frame = renderer.render(&config.at(spp), &|_| {})?;
                // On the CPU, what `auto` decided while it rendered.
                if let Some(r) = renderer.refine_report() {
                    detail = r.to_string();
                }
                let render_s = frame.seconds - frame.timed_seconds;
                points.push(point(&frame.film, reference, spp, build_s, build_s + render_s));
                frame
            }
        };
        if let Some((_, _, last)) = fixed.as_mut() {
            *last = Some(frame);
        }
        progress(points.last().expect("just pushed"));
    }
    Ok(ConvergeCurve { builder: choice.to_string(), device: device.name().into(), detail, points })
}

fn point(film: &Film, reference: &Image, spp: u32, build_s: f64, time_s: f64) -> ConvergePoint {
    let (rel_mse, mae) = image_error(&film.mean(), reference);
    ConvergePoint { spp, time_s, build_s, rel_mse, mae, non_finite: film.non_finite_count() }
}

/// The curves of several runs of the same builders (each run a `Vec` in the same builder
/// order), point by point: the point of median time. Errors barely differ between runs (same
/// samples), so the median time is the run's figure that matters, and a point keeps its own
/// run's errors with it.
pub fn median_of_runs(mut runs: Vec<Vec<ConvergeCurve>>) -> Vec<ConvergeCurve> {
    let Some(mut merged) = runs.pop() else { return Vec::new() };
    for (k, curve) in merged.iter_mut().enumerate() {
        for (i, point) in curve.points.iter_mut().enumerate() {
            let mut candidates: Vec<ConvergePoint> =
                runs.iter().filter_map(|r| r.get(k)?.points.get(i).cloned()).chain([point.clone()]).collect();
            candidates.sort_by(|a, b| a.time_s.total_cmp(&b.time_s));
            *point = candidates.swap_remove(candidates.len() / 2);
        }
    }
    merged
}

/// The expected error of an `spp`-sample render, `c · spp^-exponent + floor`: Monte Carlo
/// variance, and with it the relative MSE, falls as `1/spp` (exponent 1), the mean absolute
/// error as `1/√spp` (exponent ½); the reference's own noise (or bias) is the floor.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct ErrorModel {
    pub c: f64,
    pub exponent: f64,
    pub floor: f64,
}

impl ErrorModel {
    /// Fits the model to every point of `curves` by least squares on relative residuals
    /// (`Σ ((c/spp + floor - e)/e)²`), both terms kept non-negative. All builders render the
    /// same samples, so one model serves every curve.
    pub fn fit(curves: &[ConvergeCurve], exponent: f64, error: impl Fn(&ConvergePoint) -> f64) -> Option<ErrorModel> {
        let pts: Vec<(f64, f64)> = curves
            .iter()
            .flat_map(|c| &c.points)
            .map(|p| ((p.spp as f64).powf(-exponent), error(p)))
            .filter(|&(_, e)| e > 0.0 && e.is_finite())
            .collect();
        if pts.is_empty() {
            return None;
        }
        // Weighted sums with weights 1/e²: normal equations of (c, floor).
        let (mut sxx, mut sx, mut s1, mut sxe, mut se) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &(x, e) in &pts {
            let w = 1.0 / (e * e);
            sxx += w * x * x;
            sx += w * x;
            s1 += w;
            sxe += w * x * e;
            se += w * e;
        }
        let det = sxx * s1 - sx * sx;
        let (c, floor) = if det.abs() > 1e-12 * sxx * s1 {
            ((sxe * s1 - sx * se) / det, (sxx * se - sx * sxe) / det)
        } else {
            (f64::NAN, f64::NAN)
        };
        Some(if c.is_finite() && floor.is_finite() && c >= 0.0 && floor >= 0.0 {
            ErrorModel { c, exponent, floor }
        } else if floor < 0.0 || !floor.is_finite() {
            ErrorModel { c: sxe / sxx, exponent, floor: 0.0 }
        } else {
            ErrorModel { c: 0.0, exponent, floor: se / s1 }
        })
    }

    pub fn at(&self, spp: f64) -> f64 {
        self.c * spp.powf(-self.exponent) + self.floor
    }
}

/// The samples a curve would have taken by time `t`, interpolating its points linearly in
/// log(time)–log(spp); `None` outside its points.
pub fn spp_at(points: &[ConvergePoint], t: f64) -> Option<f64> {
    if let [only] = points {
        return (only.time_s == t).then_some(only.spp as f64);
    }
    let i = points.windows(2).position(|w| w[0].time_s <= t && t <= w[1].time_s)?;
    let (a, b) = (&points[i], &points[i + 1]);
    let (ta, tb) = (a.time_s.max(1e-12).ln(), b.time_s.max(1e-12).ln());
    let (sa, sb) = ((a.spp as f64).ln(), (b.spp as f64).ln());
    let f = if tb > ta { (t.max(1e-12).ln() - ta) / (tb - ta) } else { 1.0 };
    Some((sa + f * (sb - sa)).exp())
}

/// Compares the `auto` curve with the best fixed builder at equal time, at every point time
/// where all curves have points, device by device. A device is left out without an `auto`
/// curve; [`auto_not_compared`] says why one with an `auto` curve is left out.
///
/// The error at time `t` is the fitted model's at the samples the builder had taken by `t`
/// ([`spp_at`]), not the measured error interpolated: at a few spp the measured error jumps
/// with each firefly, and because every builder renders the same samples, those jumps would
/// shift with each curve's timing and be read as differences between builders. With the model,
/// the ratio of relative MSEs is at most the ratio of samples per second, whatever the noise.
pub fn compare_auto(curves: &[ConvergeCurve]) -> Vec<AutoComparison> {
    let mut devices: Vec<&str> = curves.iter().map(|c| c.device.as_str()).collect();
    devices.dedup();
    devices.iter().filter_map(|d| compare_auto_on(curves.iter().filter(|c| c.device == *d).collect()).ok()).collect()
}

/// The devices with an `auto` curve that [`compare_auto`] leaves out, each with the reason.
pub fn auto_not_compared(curves: &[ConvergeCurve]) -> Vec<(String, &'static str)> {
    let mut devices: Vec<&str> = curves.iter().filter(|c| c.builder == "auto").map(|c| c.device.as_str()).collect();
    devices.dedup();
    devices
        .into_iter()
        .filter_map(|d| {
            let why = compare_auto_on(curves.iter().filter(|c| c.device == d).collect()).err()?;
            Some((d.to_string(), why))
        })
        .collect()
}

/// [`compare_auto`] for the curves of one device, or why they cannot be compared.
fn compare_auto_on(curves: Vec<&ConvergeCurve>) -> Result<AutoComparison, &'static str> {
    let auto = *curves.iter().find(|c| c.builder == "auto").ok_or("no auto curve")?;
    let fixed: Vec<&ConvergeCurve> = curves.iter().filter(|c| c.builder != "auto").copied().collect();
    if fixed.is_empty() {
        return Err("no fixed builder to compare with");
    }
    let mut from = 0.0f64;
    let mut to = f64::INFINITY;
    for c in fixed.iter().chain([&auto]) {
        let (Some(a), Some(b)) = (c.points.first(), c.points.last()) else { return Err("a curve has no points") };
        from = from.max(a.time_s);
        to = to.min(b.time_s);
    }
    if from > to {
        return Err(
            "no time at which every curve has an image: a build ended after another builder's last image (a higher --max-spp makes the curves overlap)",
        );
    }
    let owned: Vec<ConvergeCurve> = curves.iter().map(|&c| c.clone()).collect();
    let zero = "every error is zero";
    let mse = ErrorModel::fit(&owned, 1.0, |p| p.rel_mse).ok_or(zero)?;
    let mae = ErrorModel::fit(&owned, 0.5, |p| p.mae).ok_or(zero)?;
    let times: Vec<f64> =
        curves.iter().flat_map(|c| c.points.iter().map(|p| p.time_s)).filter(|t| (from..=to).contains(t)).collect();
    let mut result: Option<AutoComparison> = None;
    let mut worst_mae = 0.0f64;
    for t in times {
        let Some(ours) = spp_at(&auto.points, t) else { continue };
        let Some((best, name)) = fixed
            .iter()
            .filter_map(|c| Some((spp_at(&c.points, t)?, c.builder.clone())))
            .max_by(|a, b| a.0.total_cmp(&b.0))
        else {
            continue;
        };
        let r_mse = mse.at(ours) / mse.at(best).max(1e-300);
        worst_mae = worst_mae.max(mae.at(ours) / mae.at(best).max(1e-300));
        if result.as_ref().is_none_or(|r| r_mse > r.worst_ratio_rel_mse) {
            result = Some(AutoComparison {
                device: auto.device.clone(),
                worst_ratio_rel_mse: r_mse,
                worst_at_time_s: t,
                best_fixed_there: name,
                worst_ratio_mae: 0.0,
                compared_from_s: from,
                compared_to_s: to,
                rel_mse_model: mse,
                wall_ratios: Vec::new(),
            });
        }
    }
    result
        .map(|r| AutoComparison { worst_ratio_mae: worst_mae, wall_ratios: wall_ratios(auto, &fixed), ..r })
        .ok_or("no time at which every curve has an image")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn curve(name: &str, pts: Vec<ConvergePoint>) -> ConvergeCurve {
        ConvergeCurve { builder: name.into(), device: "cpu".into(), detail: String::new(), points: pts }
    }

    #[test]
    fn error_of_identical_images_is_zero_and_of_a_doubled_one_is_known() {
        let mut a = Image::new(2, 1);
        a.pixels = vec![[1.0, 0.5, 0.0], [2.0, 2.0, 2.0]];
        assert_eq!(image_error(&a, &a), (0.0, 0.0));
        let mut b = a.clone();
        b.pixels = a.pixels.iter().map(|p| p.map(|c| 2.0 * c)).collect();
        let (mse, mae) = image_error(&b, &a);
        let expect_mse = (1.0 / 1.01 + 0.25 / 0.26 + 3.0 * 4.0 / 4.01) / 6.0;
        assert!((mse - expect_mse).abs() < 1e-9, "{mse} vs {expect_mse}");
        assert!((mae - 7.5 / 6.0).abs() < 1e-9);
    }

    fn q(spp: u32, time_s: f64) -> ConvergePoint {
        ConvergePoint {
            spp,
            time_s,
            build_s: 0.0,
            rel_mse: 1.0 / spp as f64,
            mae: 1.0 / (spp as f64).sqrt(),
            non_finite: 0,
        }
    }

    #[test]
    fn samples_at_a_time_interpolate_in_log_log() {
        let pts = vec![q(1, 1.0), q(4, 4.0)];
        assert!((spp_at(&pts, 2.0).unwrap() - 2.0).abs() < 1e-12);
        assert_eq!(spp_at(&pts, 0.5), None);
        assert_eq!(spp_at(&pts, 5.0), None);
    }

    #[test]
    fn the_error_model_recovers_c_and_the_floor() {
        let pts = [1, 2, 4, 8, 16, 32].map(|n| ConvergePoint { rel_mse: 0.5 / n as f64 + 0.01, ..q(n, n as f64) });
        let m = ErrorModel::fit(&[curve("a", pts.to_vec())], 1.0, |p| p.rel_mse).unwrap();
        assert!((m.c - 0.5).abs() < 1e-9 && (m.floor - 0.01).abs() < 1e-9, "{m:?}");
    }

    #[test]
    fn auto_twice_as_slow_is_about_twice_the_error() {
        let steps = [1u32, 2, 4, 8];
        let best = curve("lbvh", steps.iter().map(|&n| q(n, n as f64)).collect());
        let slow = curve("binned-sah", steps.iter().map(|&n| q(n, 1.5 * n as f64)).collect());
        let auto = curve("auto", steps.iter().map(|&n| q(n, 2.0 * n as f64)).collect());
        let c = compare_auto(&[best, slow, auto]).pop().unwrap();
        assert!((c.worst_ratio_rel_mse - 2.0).abs() < 1e-9, "{c:?}");
        assert!((c.worst_ratio_mae - 2f64.sqrt()).abs() < 1e-2, "{c:?}");
        assert_eq!(c.best_fixed_there, "lbvh");
        assert_eq!((c.compared_from_s, c.compared_to_s), (2.0, 8.0));
        // End to end, at every sample count: twice the fastest fixed builder's time.
        assert_eq!(c.wall_ratios.iter().map(|w| w.spp).collect::<Vec<_>>(), steps);
        assert!(c.wall_ratios.iter().all(|w| (w.ratio - 2.0).abs() < 1e-12 && w.best_fixed == "lbvh"), "{c:?}");
    }

    #[test]
    fn noise_in_the_measured_error_does_not_read_as_a_difference() {
        // Same samples, same errors (one a firefly spike), same timing: a ratio of 1.
        let pts: Vec<ConvergePoint> = [(1, 0.3), (2, 0.5), (4, 0.16), (8, 0.13)]
            .map(|(n, e)| ConvergePoint { rel_mse: e, ..q(n, n as f64) })
            .to_vec();
        let mut late = pts.clone();
        late.iter_mut().for_each(|p| p.time_s *= 1.02);
        let c = compare_auto(&[curve("lbvh", pts), curve("auto", late)]).pop().unwrap();
        assert!(c.worst_ratio_rel_mse < 1.03, "{c:?}");
    }

    #[test]
    fn auto_is_compared_with_its_own_device_only() {
        let steps = [1u32, 2, 4, 8];
        let on = |name: &str, device: &str, k: f64| ConvergeCurve {
            device: device.into(),
            ..curve(name, steps.iter().map(|&n| q(n, k * n as f64)).collect())
        };
        // The GPU's lbvh is 4x faster than anything on the CPU; the CPU's auto must still be
        // compared with the CPU's lbvh (ratio 2), not with it.
        let c = compare_auto(&[
            on("lbvh", "cpu", 1.0),
            on("auto", "cpu", 2.0),
            on("lbvh", "gpu", 0.25),
            on("auto", "gpu", 0.25),
        ]);
        assert_eq!(c.len(), 2);
        assert_eq!(c[0].device, "cpu");
        assert!((c[0].worst_ratio_rel_mse - 2.0).abs() < 1e-9, "{c:?}");
        assert_eq!(c[1].device, "gpu");
        assert!((c[1].worst_ratio_rel_mse - 1.0).abs() < 1e-9, "{c:?}");
    }

    #[test]
    fn curves_that_do_not_overlap_in_time_say_so() {
        let steps = |k: f64, from: f64| curve("x", [1u32, 2, 4].iter().map(|&n| q(n, from + k * n as f64)).collect());
        // A slow build: binned-sah's first image comes after lbvh's last one.
        let lbvh = ConvergeCurve { builder: "lbvh".into(), ..steps(0.001, 0.0) };
        let binned = ConvergeCurve { builder: "binned-sah".into(), ..steps(0.001, 0.01) };
        let auto = ConvergeCurve { builder: "auto".into(), ..steps(0.001, 0.0) };
        let curves = [lbvh.clone(), binned, auto.clone()];
        assert!(compare_auto(&curves).is_empty());
        let why = auto_not_compared(&curves);
        assert_eq!(why.len(), 1);
        assert_eq!(why[0].0, "cpu");
        assert!(why[0].1.contains("no time at which every curve has an image"), "{why:?}");
        // Overlapping curves are compared, and nothing is said of them.
        assert_eq!(compare_auto(&[lbvh.clone(), auto.clone()]).len(), 1);
        assert!(auto_not_compared(&[lbvh, auto.clone()]).is_empty());
        // auto alone has nothing to be compared with.
        assert_eq!(auto_not_compared(&[auto])[0].1, "no fixed builder to compare with");
    }

    #[test]
    fn runs_merge_to_the_median_time_point() {
        let run = |t: f64| vec![curve("lbvh", vec![q(1, t), q(2, 2.0 * t)])];
        let merged = median_of_runs(vec![run(3.0), run(1.0), run(2.0)]);
        assert_eq!(merged[0].points.iter().map(|p| p.time_s).collect::<Vec<_>>(), vec![2.0, 4.0]);
    }

    #[test]
    fn spp_steps_double_up_to_the_maximum() {
        let c = ConvergeConfig {
            start_spp: 1,
            render: RenderSettings { spp: 20, ..Default::default() },
            ..Default::default()
        };
        assert_eq!(c.spp_steps(), vec![1, 2, 4, 8, 16]);
    }
}
