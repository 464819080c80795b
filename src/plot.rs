//! Falling error curves on log-log axes, with a target line: the plot `converge` writes, and
//! the runtime benches' near-camera error against time.

use std::ops::Range;

use image::RgbImage;
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};

const WIDTH: u32 = 900;
const HEIGHT: u32 = 600;
/// Plotters' default family: registering the compiled-in font under it covers every text
/// style plotters picks by itself (there are no system fonts behind it).
const FONT: &str = "sans-serif";

/// Series colours, in the order the series come (the target line is red).
const COLOURS: [RGBColor; 8] = [
    RGBColor(31, 90, 180),
    RGBColor(230, 130, 20),
    RGBColor(40, 150, 70),
    RGBColor(130, 60, 170),
    RGBColor(0, 160, 170),
    RGBColor(140, 90, 40),
    RGBColor(220, 90, 170),
    RGBColor(90, 90, 90),
];

#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("the plot's compiled-in font cannot be read")]
    Font,
    #[error("cannot draw the plot: {0}")]
    Draw(String),
}

/// One curve: its legend and its (seconds, relative error) points.
pub struct Series<'a> {
    pub label: &'a str,
    pub points: &'a [(f64, f64)],
}

/// `series` (the first in blue), the target error when there is one, `x_desc` under the
/// time axis. Points that cannot sit on log axes (error 0 after the reference's noise is
/// removed, say) are left out of the drawing; the JSON and CSV keep them.
pub fn error_curves(title: &str, x_desc: &str, series: &[Series], target: Option<f64>) -> Result<RgbImage, PlotError> {
    register_font(FONT, FontStyle::Normal, epaint_default_fonts::HACK_REGULAR).map_err(|_| PlotError::Font)?;
    let positive = |v: f64| v.is_finite() && v > 0.0;
    let shown: Vec<(&str, Vec<(f64, f64)>)> = series
        .iter()
        .map(|s| (s.label, s.points.iter().copied().filter(|&(t, e)| positive(t) && positive(e)).collect()))
        .collect();
    let target = target.filter(|&t| positive(t));
    let xs = decades(shown.iter().flat_map(|s| s.1.iter().map(|p| p.0)));
    let ys = decades(shown.iter().flat_map(|s| s.1.iter().map(|p| p.1)).chain(target));

    let mut pixels = vec![0u8; (WIDTH * HEIGHT * 3) as usize];
    draw(&mut pixels, title, x_desc, &shown, target, xs, ys).map_err(|e| PlotError::Draw(e.to_string()))?;
    RgbImage::from_raw(WIDTH, HEIGHT, pixels)
        .ok_or_else(|| PlotError::Draw("the pixel buffer has the wrong size".into()))
}

type DrawResult = Result<(), DrawingAreaErrorKind<<BitMapBackend<'static> as DrawingBackend>::ErrorType>>;

fn draw(
    pixels: &mut [u8],
    title: &str,
    x_desc: &str,
    shown: &[(&str, Vec<(f64, f64)>)],
    target: Option<f64>,
    xs: Range<f64>,
    ys: Range<f64>,
) -> DrawResult {
    {
        let root = BitMapBackend::with_buffer(pixels, (WIDTH, HEIGHT)).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, (FONT, 20))
            .margin(20)
            .x_label_area_size(50)
            .y_label_area_size(80)
            .build_cartesian_2d(xs.clone().log_scale(), ys.clone().log_scale())?;
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc("relative RMS error")
            .label_style((FONT, 14))
            .axis_desc_style((FONT, 15))
            .x_label_formatter(&|v| number(*v))
            .y_label_formatter(&|v| percent(*v))
            .draw()?;
        for (k, (label, points)) in shown.iter().enumerate() {
            let colour = COLOURS[k % COLOURS.len()];
            chart
                .draw_series(LineSeries::new(points.iter().copied(), colour.stroke_width(2)))?
                .label(*label)
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 24, y)], colour.stroke_width(2)));
            chart.draw_series(points.iter().map(|&p| Circle::new(p, 4, colour.filled())))?;
        }
        if let Some(t) = target {
            let red = RGBColor(200, 40, 40);
            chart
                .draw_series(DashedLineSeries::new([(xs.start, t), (xs.end, t)], 10, 6, red.stroke_width(2)))?
                .label(format!("target {}", percent(t)))
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 24, y)], red.stroke_width(2)));
        }
        chart
            .configure_series_labels()
            .position(legend_corner(shown, target, &xs, &ys))
            .label_font((FONT, 14))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
        root.present()?;
    }
    Ok(())
}

/// The corner of the plot the legend covers fewest points in (the upper right first, then
/// the other corners: a curve that falls from the upper left leaves the upper right free;
/// one that rises does not). A corner is the legend's size: about a third of the plot's
/// width and, per line, a fifteenth of its height (log axes: fractions of decades). A
/// target line counts against the corners it runs through.
fn legend_corner(
    shown: &[(&str, Vec<(f64, f64)>)],
    target: Option<f64>,
    xs: &Range<f64>,
    ys: &Range<f64>,
) -> SeriesLabelPosition {
    let fraction = |v: f64, r: &Range<f64>| (v.ln() - r.start.ln()) / (r.end.ln() - r.start.ln());
    let lines = shown.len() + usize::from(target.is_some());
    let (w, h) = (0.35, (0.06 * lines as f64 + 0.04).min(0.5));
    let corners = [
        (SeriesLabelPosition::UpperRight, true, true),
        (SeriesLabelPosition::UpperLeft, false, true),
        (SeriesLabelPosition::LowerRight, true, false),
        (SeriesLabelPosition::LowerLeft, false, false),
    ];
    let inside = |(x, y): (f64, f64), right: bool, upper: bool| {
        let (fx, fy) = (fraction(x, xs), fraction(y, ys));
        (if right { fx >= 1.0 - w } else { fx <= w }) && (if upper { fy >= 1.0 - h } else { fy <= h })
    };
    let covered = |right: bool, upper: bool| {
        let points = shown.iter().flat_map(|s| s.1.iter()).filter(|&&p| inside(p, right, upper)).count();
        let line = target.is_some_and(|t| {
            let fy = fraction(t, ys);
            if upper { fy >= 1.0 - h } else { fy <= h }
        });
        points + if line { usize::MAX / 2 } else { 0 }
    };
    // The first corner of the fewest covered points.
    let best = (0..corners.len()).min_by_key(|&k| (covered(corners[k].1, corners[k].2), k)).unwrap_or(0);
    corners[best].0.clone()
}

/// The whole decades holding `values` (at least one), so a log axis always has labelled
/// powers of ten at both ends; 0.1–1 when there is nothing to show.
fn decades(values: impl Iterator<Item = f64>) -> Range<f64> {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if !(lo.is_finite() && hi.is_finite()) {
        return 0.1..1.0;
    }
    let (a, b) = (lo.log10().floor(), hi.log10().ceil());
    // A hair wider, so the powers of ten at the ends are inside the axis and get labels.
    10f64.powf(a) / EDGE..10f64.powf(if b > a { b } else { a + 1.0 }) * EDGE
}

/// How far past the end decades an axis reaches.
const EDGE: f64 = 1.02;

/// A tick label: three decimals at most, no trailing zeros; an exponent below 0.001.
fn number(v: f64) -> String {
    if v != 0.0 && v.abs() < 1e-3 {
        return format!("{v:.0e}");
    }
    format!("{v:.3}").trim_end_matches('0').trim_end_matches('.').to_string()
}

fn percent(v: f64) -> String {
    format!("{}%", number(v * 100.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decades_cover_the_values_with_whole_powers_of_ten() {
        let r = decades([0.013, 0.4].into_iter());
        assert!((r.start * EDGE - 0.01).abs() < 1e-15 && (r.end / EDGE - 1.0).abs() < 1e-12, "{r:?}");
        // A single power of ten still gets a decade.
        let r = decades([10.0].into_iter());
        assert!((r.start * EDGE - 10.0).abs() < 1e-12 && (r.end / EDGE - 100.0).abs() < 1e-9, "{r:?}");
        assert_eq!(decades(std::iter::empty()), 0.1..1.0);
    }

    /// A falling curve leaves the upper right to the legend; a rising one (high at the
    /// right, low at the left) sends it to the upper left.
    #[test]
    fn the_legend_goes_where_the_curves_are_not() {
        let (xs, ys) = (0.1..100.0, 0.01..1.0);
        let falling = vec![(0.2, 0.9), (1.0, 0.1), (10.0, 0.03), (90.0, 0.012)];
        let rising: Vec<(f64, f64)> = falling.iter().map(|&(x, y)| (100.0 / x * 0.1, y)).collect();
        let corner = |points: Vec<(f64, f64)>| format!("{:?}", legend_corner(&[("a", points)], None, &xs, &ys));
        assert_eq!(corner(falling), "UpperRight");
        // Mirrored in time: high at the right, low at the left.
        assert_eq!(corner(rising), "UpperLeft");
    }

    #[test]
    fn labels_are_short() {
        assert_eq!(number(2.0), "2");
        assert_eq!(number(0.25), "0.25");
        assert_eq!(number(0.0004), "4e-4");
        assert_eq!(number(150.0), "150");
        assert_eq!(percent(0.05), "5%");
    }
}
