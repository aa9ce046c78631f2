//! Plots of the reports (SVG or PNG, by plotters).

use anyhow::{Context, Result, bail};
use arbor::atomic_file::{self, AtomicWriteError};
use std::path::Path;

use crate::report::atomic_error;

#[derive(Clone, Copy, PartialEq)]
pub(crate) enum PlotFormat {
    Svg,
    Png,
}

pub(crate) fn plot_format(path: &Path) -> Result<PlotFormat> {
    match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("svg") => Ok(PlotFormat::Svg),
        Some("png") => Ok(PlotFormat::Png),
        _ => bail!("--plot {}: the name must end in .svg or .png", path.display()),
    }
}

/// Fonts plotters may use for labels, first found wins.
pub(crate) const FONT_PATHS: [&str; 3] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
];

/// A named curve of (x, y) points.
pub(crate) type Series = (String, Vec<(f64, f64)>);

pub(crate) fn write_plot(path: &Path, title: &str, labels: (&str, &str), series: &[Series], log: bool) -> Result<()> {
    use plotters::prelude::*;
    let font = FONT_PATHS
        .iter()
        .find_map(|p| std::fs::read(p).ok())
        .context("the plot needs the DejaVu Sans font (Debian package fonts-dejavu-core)")?;
    // plotters keeps registered fonts for the whole process.
    plotters::style::register_font("sans-serif", FontStyle::Normal, Box::leak(font.into_boxed_slice()))
        .map_err(|_| anyhow::anyhow!("DejaVu Sans could not be read as a font"))?;
    // plotters creates the file itself and picks PNG by the extension, which the temporary keeps.
    let format = plot_format(path)?;
    atomic_file::replace_via_temp(path, |tmp| {
        match format {
            PlotFormat::Svg => {
                draw_chart(SVGBackend::new(tmp, (900, 600)).into_drawing_area(), title, labels, series, log)
            }
            PlotFormat::Png => {
                draw_chart(BitMapBackend::new(tmp, (900, 600)).into_drawing_area(), title, labels, series, log)
            }
        }
        .map_err(AtomicWriteError::Write)
    })
    .map_err(atomic_error)
    .with_context(|| format!("writing {}", path.display()))
}

/// A logarithmic axis's range around `lo..=hi` (both positive), with a fifth of a decade of
/// margin. plotters labels a logarithmic axis from the powers of ten inside it (then their
/// multiples), so a range that holds none is widened to the nearer one, with a margin so that
/// its label is not on the edge.
pub(crate) fn log_range(lo: f64, hi: f64) -> std::ops::Range<f64> {
    let (lo, hi) = (lo * 0.8, hi * 1.25);
    // The first power of ten clear of the bottom, and the last one clear of it from below.
    let above = 10f64.powf((lo * 1.1).log10().ceil());
    let below = 10f64.powf((lo / 1.1).log10().floor());
    if above * 1.1 <= hi {
        return lo..hi;
    }
    if lo / below <= above / hi { below * 0.8..hi } else { lo..above * 1.25 }
}

/// A linear axis's range around `lo..=hi` with 3% of margin; a single value (a zero error, a
/// constant SAH) gets a range around it instead of an empty one.
pub(crate) fn linear_range(lo: f64, hi: f64) -> (f64, f64) {
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    if hi > lo {
        let pad = (hi - lo) * 0.03;
        // An axis of values that are all positive starts at zero or above, never below it.
        let bottom = if lo >= 0.0 { (lo - pad).max(0.0) } else { lo - pad };
        return (bottom, hi + pad);
    }
    let pad = if lo == 0.0 { 1.0 } else { lo.abs() * 0.05 };
    (if lo >= 0.0 { (lo - pad).max(0.0) } else { lo - pad }, hi + pad)
}

/// A tick label with at most four significant digits and no binary-to-decimal noise
/// (0.30000000000000004 is written 0.3), in scientific notation outside 1e-3..1e6.
pub(crate) fn tick_label(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let magnitude = v.abs().log10().floor() as i32;
    if !(-3..6).contains(&magnitude) {
        let s = format!("{v:.3e}");
        let (mantissa, exponent) = s.split_once('e').unwrap_or((&s, "0"));
        return format!("{}e{exponent}", trim_zeros(mantissa));
    }
    let decimals = (3 - magnitude).max(0) as usize;
    trim_zeros(&format!("{v:.decimals$}")).to_string()
}

/// "1.500" -> "1.5", "2.000" -> "2"; text without a decimal point is kept.
pub(crate) fn trim_zeros(s: &str) -> &str {
    if s.contains('.') { s.trim_end_matches('0').trim_end_matches('.') } else { s }
}

/// One curve per series, with points marked; log-log axes when every value is positive and
/// `log` is asked for, otherwise a logarithmic x axis when it spans more than a factor of 30.
pub(crate) fn draw_chart<DB: plotters::prelude::DrawingBackend>(
    root: plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    (x_desc, y_desc): (&str, &str),
    series: &[Series],
    log: bool,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    use plotters::prelude::*;
    let err = |e: &dyn std::fmt::Display| anyhow::anyhow!("{e}");
    let points: Vec<&(f64, f64)> = series.iter().flat_map(|s| &s.1).collect();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut builder = ChartBuilder::on(&root);
    builder.caption(title, ("sans-serif", 22)).margin(12).x_label_area_size(40).y_label_area_size(70);
    // The same drawing for both coordinate systems, whose chart types differ.
    macro_rules! draw {
        ($chart:expr) => {{
            let mut chart = $chart.map_err(|e| err(&e))?;
            chart
                .configure_mesh()
                .x_desc(x_desc)
                .y_desc(y_desc)
                .x_label_formatter(&|v| tick_label(*v))
                .y_label_formatter(&|v| tick_label(*v))
                .draw()
                .map_err(|e| err(&e))?;
            for (k, (name, pts)) in series.iter().enumerate() {
                let color = Palette99::pick(k).to_rgba();
                // Markers only where the curve is sparse enough to show them.
                let marks = if pts.len() <= 60 { pts.clone() } else { Vec::new() };
                chart
                    .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))
                    .map_err(|e| err(&e))?
                    .label(name.clone())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(2)));
                chart.draw_series(marks.iter().map(|&p| Circle::new(p, 3, color.filled()))).map_err(|e| err(&e))?;
            }
            chart
                .configure_series_labels()
                // Error and SAH fall with time, so the upper right is where curves are least.
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(|e| err(&e))?;
        }};
    }
    if log && points.iter().all(|p| p.0 > 0.0 && p.1 > 0.0) && !points.is_empty() {
        let (x_min, x_max) = points.iter().fold((f64::INFINITY, 0.0f64), |a, p| (a.0.min(p.0), a.1.max(p.0)));
        let (y_min, y_max) = points.iter().fold((f64::INFINITY, 0.0f64), |a, p| (a.0.min(p.1), a.1.max(p.1)));
        draw!(builder.build_cartesian_2d(log_range(x_min, x_max).log_scale(), log_range(y_min, y_max).log_scale()));
    } else {
        let x_min = points.iter().map(|p| p.0).fold(f64::INFINITY, f64::min);
        let x_max = points.iter().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max);
        let x_max = if x_max > 0.0 { x_max } else { 1.0 };
        let (y_min, y_max) = linear_range(
            points.iter().map(|p| p.1).fold(f64::INFINITY, f64::min),
            points.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max),
        );
        if x_min > 0.0 && x_max > 30.0 * x_min {
            // Times spanning orders of magnitude (a sequential optimiser beside a parallel one).
            draw!(builder.build_cartesian_2d((x_min * 0.8..x_max * 1.25).log_scale(), y_min..y_max));
        } else {
            draw!(builder.build_cartesian_2d(0.0..x_max * 1.05, y_min..y_max));
        }
    }
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_labels_are_short_and_exact_looking() {
        assert_eq!(tick_label(0.1 + 0.2), "0.3");
        assert_eq!(tick_label(0.30000000000000004), "0.3");
        assert_eq!(tick_label(2.0), "2");
        assert_eq!(tick_label(1.5), "1.5");
        assert_eq!(tick_label(130.87), "130.9");
        assert_eq!(tick_label(0.0125), "0.0125");
        assert_eq!(tick_label(0.00012346), "1.235e-4");
        assert_eq!(tick_label(2.5e7), "2.5e7");
        assert_eq!(tick_label(-0.25), "-0.25");
        assert_eq!(tick_label(0.0), "0");
    }

    #[test]
    fn a_log_axis_always_holds_a_power_of_ten_away_from_its_ends() {
        let powers = |r: std::ops::Range<f64>| {
            (-20..20).filter(|&k| r.start < 10f64.powi(k) * 0.9 && 10f64.powi(k) * 1.1 < r.end).count()
        };
        for (lo, hi) in [(0.3, 0.5), (0.011, 0.019), (2.0, 3.0), (70.0, 95.0), (1e-6, 1e-3), (5.0, 5.0)] {
            let r = log_range(lo, hi);
            assert!(r.start <= lo && r.end >= hi, "{lo}..{hi} -> {r:?}");
            assert!(powers(r.clone()) >= 1, "{lo}..{hi} -> {r:?}");
            assert!(r.end / r.start < hi / lo * 20.0, "{lo}..{hi} -> {r:?} squeezes the curve");
        }
    }

    #[test]
    fn a_linear_axis_is_never_empty() {
        for (lo, hi) in [(0.0, 0.0), (5.0, 5.0), (-2.0, -2.0), (1.0, 3.0), (f64::INFINITY, f64::NEG_INFINITY)] {
            let (a, b) = linear_range(lo, hi);
            assert!(a < b, "{lo}..{hi} -> {a}..{b}");
            if lo.is_finite() {
                assert!(a <= lo && b >= hi, "{lo}..{hi} -> {a}..{b}");
            }
        }
        assert_eq!(linear_range(0.0, 0.0).0, 0.0, "zero errors stay on an axis that starts at zero");
    }
}
