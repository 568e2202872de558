//! Plots of a calibration (SVG, drawn with plotters): the residual vectors of every image, the
//! residual histogram against the expected normal distribution, and the projector rays' miss
//! distances, and accuracy maps of reconstructed plates and test objects. Every plot has axes
//! with units, a title with its figures and a legend.

use super::plot_parts::{
    arrowhead, bar_tick, draw_legend, draw_title, tick, Sample, FAMILY, LEGEND_ROW,
};
use super::residuals::{per_image_rms, Residual};
use anyhow::{anyhow, Result};
use plotters::prelude::*;
use std::ops::Range;

/// Font of titles and labels.
const FONT: (&str, u32) = (FAMILY, 13);

/// Height (px) of a figure's title strip (two lines) and of its legend strip.
const TITLE_STRIP: u32 = 40;
const LEGEND_STRIP: u32 = LEGEND_ROW as u32;

fn plot_error<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("drawing a plot: {e:?}")
}

/// A length in the plot for residuals: the largest residual is drawn as `fraction` of
/// `extent`, rounded down to 1, 2 or 5 × 10ⁿ; 1 px of residual becomes that many px.
fn arrow_scale(largest: f64, extent: f64, fraction: f64) -> f64 {
    let raw = fraction * extent / largest.max(1e-9);
    let decade = 10f64.powf(raw.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * decade)
        .find(|s| *s <= raw)
        .unwrap_or(decade)
}

/// The residual length (px, 1, 0.5, 0.2, 0.1, ...) the scale bar shows: 1 px when it is drawn
/// at most `room` screen px long, else the largest round fraction that is.
fn scale_bar_px(screen_per_px: f64, room: f64) -> f64 {
    (0..12)
        .flat_map(|e| [1.0, 0.5, 0.2].map(|m| m * 10f64.powi(-e)))
        .find(|length| length * screen_per_px <= room)
        .unwrap_or(1e-12)
}

/// The axis ranges of the residual panels: the sensor, every active residual vector's tip at
/// `scale` and a margin (8 % of the span), so that nothing leaves a panel; one range for every
/// panel, so that one scale bar holds for all.
fn panel_ranges<'a>(
    residuals: impl Iterator<Item = &'a Residual>,
    (w, h): (f64, f64),
    scale: f64,
) -> (Range<f64>, Range<f64>) {
    let (mut x, mut y) = ((0.0_f64, w), (0.0_f64, h));
    for r in residuals {
        let t = if r.rejected { 0.0 } else { scale };
        let (c, row) = (r.observed[0] + t * r.v[0], r.observed[1] + t * r.v[1]);
        x = (x.0.min(r.observed[0]).min(c), x.1.max(r.observed[0]).max(c));
        y = (
            y.0.min(r.observed[1]).min(row),
            y.1.max(r.observed[1]).max(row),
        );
    }
    let pad = |(lo, hi): (f64, f64)| {
        let m = 0.08 * (hi - lo);
        lo - m..hi + m
    };
    (pad(x), pad(y))
}

/// Colour of residual vectors and of rejected observations' markers.
const RESIDUAL: RGBColor = RED;
const REJECTED: RGBColor = RGBColor(200, 0, 200);

/// Residual vectors of every image on its sensor (one panel per image), magnified by one
/// common scale, each with an arrowhead at its tip; observations rejected as gross errors are
/// marked where they were observed (a ring with a cross, no vector: theirs would be off the
/// scale). One legend for the figure, above the panels: the vector, the target, the rejected
/// marker and a scale bar of 1 px of residual (a round fraction of it at high magnification,
/// so that it always fits).
pub fn residual_vectors(residuals: &[Residual], width: u32, height: u32) -> Result<String> {
    let images = per_image_rms(residuals);
    let cols = (images.len() as f64).sqrt().ceil().max(1.0) as usize;
    let rows = images.len().div_ceil(cols).max(1);
    let (w, h) = (f64::from(width), f64::from(height));
    let largest = residuals
        .iter()
        .filter(|r| !r.rejected)
        .map(Residual::norm)
        .fold(0.0, f64::max);
    let rejected = residuals.iter().filter(|r| r.rejected).count();
    let scale = arrow_scale(largest, w.min(h), 0.12);
    let (x_range, y_range) = panel_ranges(residuals.iter(), (w, h), scale);
    let mut svg = String::new();
    {
        let panel_w = 380;
        let panel_h = (f64::from(panel_w) * h / w) as u32 + 70;
        let figure_w = panel_w * cols as u32;
        let root = SVGBackend::with_string(
            &mut svg,
            (
                figure_w,
                panel_h * rows as u32 + TITLE_STRIP + 2 * LEGEND_STRIP,
            ),
        )
        .into_drawing_area();
        root.fill(&WHITE).map_err(plot_error)?;
        let (top, rest) = root.split_vertically(TITLE_STRIP);
        let (legend, body) = rest.split_vertically(2 * LEGEND_STRIP);
        draw_title(
            &top,
            &format!(
                "Image residuals (observed − computed), magnified {}×: largest {largest:.2} px{}",
                tick(&scale),
                if rejected > 0 {
                    format!(", {rejected} rejected")
                } else {
                    String::new()
                }
            ),
            f64::from(FONT.1),
        )?;
        // Screen px per px of the sensor, the same in every panel (one range for all).
        let mut screen_per_px = None;
        for (panel, (image, rms)) in body.split_evenly((rows, cols)).iter().zip(&images) {
            let own = residuals.iter().filter(|r| r.image == *image);
            let mut chart = ChartBuilder::on(panel)
                .caption(format!("{image}: RMS {rms:.3} px"), FONT)
                .margin(6)
                .x_label_area_size(32)
                .y_label_area_size(44)
                .build_cartesian_2d(x_range.clone(), y_range.end..y_range.start)
                .map_err(plot_error)?;
            chart
                .configure_mesh()
                .disable_mesh()
                .x_desc("col (px)")
                .y_desc("row (px)")
                .x_label_formatter(&|v| format!("{v:.0}"))
                .y_label_formatter(&|v| format!("{v:.0}"))
                .label_style((FAMILY, 10))
                .draw()
                .map_err(plot_error)?;
            let (px, py) = chart.plotting_area().get_pixel_range();
            let kx = f64::from(px.end - px.start) / (x_range.end - x_range.start);
            let ky = f64::from(py.end - py.start) / (y_range.end - y_range.start);
            screen_per_px.get_or_insert(kx);
            // The sensor's outline.
            chart
                .draw_series(std::iter::once(Rectangle::new(
                    [(0.0, 0.0), (w, h)],
                    RGBColor(200, 200, 200).stroke_width(1),
                )))
                .map_err(plot_error)?;
            let active = own.clone().filter(|r| !r.rejected);
            chart
                .draw_series(active.clone().map(|r| {
                    let [c, row] = r.observed;
                    PathElement::new(
                        vec![(c, row), (c + scale * r.v[0], row + scale * r.v[1])],
                        RESIDUAL.stroke_width(1),
                    )
                }))
                .map_err(plot_error)?;
            chart
                .draw_series(active.map(|r| {
                    let [c, row] = r.observed;
                    let (dx, dy) = (kx * scale * r.v[0], ky * scale * r.v[1]);
                    let length = (0.5 * dx.hypot(dy)).clamp(1.0, 5.0);
                    EmptyElement::at((c + scale * r.v[0], row + scale * r.v[1]))
                        + PathElement::new(
                            arrowhead((0, 0), (dx, dy), length),
                            RESIDUAL.stroke_width(1),
                        )
                }))
                .map_err(plot_error)?;
            chart
                .draw_series(own.clone().filter(|r| r.rejected).map(|r| {
                    EmptyElement::at((r.observed[0], r.observed[1]))
                        + Circle::new((0, 0), 4, REJECTED.stroke_width(1))
                        + Cross::new((0, 0), 3, REJECTED)
                }))
                .map_err(plot_error)?;
            chart
                .draw_series(
                    own.map(|r| Circle::new((r.observed[0], r.observed[1]), 1, BLACK.filled())),
                )
                .map_err(plot_error)?;
        }
        let screen_per_px = scale * screen_per_px.unwrap_or(1.0);
        let bar = scale_bar_px(screen_per_px, 120.0);
        let mut entries = vec![
            (
                Sample::Arrow(RESIDUAL),
                format!("residual × {}", tick(&scale)),
            ),
            (Sample::Dot(BLACK), "target".to_owned()),
        ];
        if rejected > 0 {
            entries.push((
                Sample::Marked(REJECTED),
                "rejected as a gross error (not in the adjustment; in the residuals CSV)"
                    .to_owned(),
            ));
        }
        entries.push((
            Sample::Line(BLUE, 2, (bar * screen_per_px).round().max(1.0) as i32),
            format!("{} px of residual", tick(&bar)),
        ));
        draw_legend(&legend, &entries, 10.0)?;
        root.present().map_err(plot_error)?;
    }
    Ok(svg)
}

/// The colour bar's limit for signed errors: the largest |error|, so that 0 is white and the bar
/// runs symmetrically from −limit (blue) to +limit (red).
fn colour_limit(errors: impl Iterator<Item = f64>) -> f64 {
    errors.map(f64::abs).fold(0.0, f64::max).max(1e-9)
}

/// The colour of a zero error on the accuracy maps: a light grey, so that a marker of no error
/// stands out from the white page.
const ZERO: RGBColor = RGBColor(215, 215, 215);

/// An accuracy map: each point at its (X, Y) in mm, coloured by its error component `what`
/// (mm; e.g. "Z error") against truth or a reference, with a colour bar from −largest |error|
/// (blue) through 0 (light grey, `ZERO`) to +largest (red). For plates and test objects alike.
pub fn accuracy_map(title: &str, what: &str, points: &[(f64, f64, f64)]) -> Result<String> {
    let span = |values: &mut dyn Iterator<Item = f64>| {
        let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
        let (lo, hi) = if lo <= hi { (lo, hi) } else { (0.0, 1.0) };
        let m = 0.05 * (hi - lo).max(1e-6);
        lo - m..hi + m
    };
    // Equal mm per pixel on both axes: the shorter side widens to the plotting area's shape.
    let (mut x_range, mut y_range) = (
        span(&mut points.iter().map(|p| p.0)),
        span(&mut points.iter().map(|p| p.1)),
    );
    // The map's plotting area (px): 620 − 2 × 10 margin − 56 labels by 570 − 40 title − 20 − 40.
    const AREA: (f64, f64) = (544.0, 470.0);
    let (dx, dy) = (x_range.end - x_range.start, y_range.end - y_range.start);
    let per_px = (dx / AREA.0).max(dy / AREA.1);
    let widen = |r: Range<f64>, to: f64| {
        let extra = 0.5 * (to - (r.end - r.start));
        r.start - extra..r.end + extra
    };
    x_range = widen(x_range, per_px * AREA.0);
    y_range = widen(y_range, per_px * AREA.1);
    let limit = colour_limit(points.iter().map(|p| p.2));
    let colours = DerivedColorMap::new(&[BLUE, ZERO, RED]);
    let colour = |e: f64| colours.get_color_normalized(e, -limit, limit);
    let rms = (points.iter().map(|p| p.2 * p.2).sum::<f64>() / points.len().max(1) as f64).sqrt();
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (720, 570)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_error)?;
        let (top, body) = root.split_vertically(TITLE_STRIP);
        draw_title(
            &top,
            &format!(
                "{title}: {} points, {what} RMS {rms:.3} mm, largest |{what}| {limit:.3} mm",
                points.len()
            ),
            f64::from(FONT.1),
        )?;
        let (map, bar) = body.split_horizontally(620);
        let mut chart = ChartBuilder::on(&map)
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(56)
            .build_cartesian_2d(x_range, y_range)
            .map_err(plot_error)?;
        chart
            .configure_mesh()
            .x_desc("X (mm)")
            .y_desc("Y (mm)")
            .x_label_formatter(&tick)
            .y_label_formatter(&tick)
            .draw()
            .map_err(plot_error)?;
        chart
            .draw_series(points.iter().map(|&(x, y, e)| {
                EmptyElement::at((x, y))
                    + Circle::new((0, 0), 4, colour(e).filled())
                    + Circle::new((0, 0), 4, RGBColor(60, 60, 60).stroke_width(1))
            }))
            .map_err(plot_error)?;
        let mut bar_chart = ChartBuilder::on(&bar)
            .margin_top(10)
            .margin_bottom(50)
            .margin_right(50)
            .y_label_area_size(0)
            .right_y_label_area_size(45)
            .build_cartesian_2d(0.0..1.0, -limit..limit)
            .map_err(plot_error)?
            .set_secondary_coord(0.0..1.0, -limit..limit);
        bar_chart
            .configure_secondary_axes()
            .y_desc(format!("{what} (mm)"))
            .y_label_formatter(&bar_tick(limit))
            .label_style((FAMILY, 10))
            .draw()
            .map_err(plot_error)?;
        const STEPS: usize = 64;
        bar_chart
            .draw_series((0..STEPS).map(|k| {
                let step = 2.0 * limit / STEPS as f64;
                let lo = -limit + k as f64 * step;
                Rectangle::new(
                    [(0.0, lo), (1.0, lo + step)],
                    colour(lo + 0.5 * step).filled(),
                )
            }))
            .map_err(plot_error)?;
        root.present().map_err(plot_error)?;
    }
    Ok(svg)
}

/// The normal density at `x` (mean 0, σ 1).
fn normal_density(x: f64) -> f64 {
    (-0.5 * x * x).exp() / (2.0 * std::f64::consts::PI).sqrt()
}

/// Histogram of the adjusted residual coordinates divided by their RMS, against the count the
/// normal distribution expects in each bin; the counts per bin are returned with the SVG.
pub fn residual_histogram(residuals: &[Residual]) -> Result<(String, Vec<usize>)> {
    let values: Vec<f64> = residuals
        .iter()
        .filter(|r| !r.rejected)
        .flat_map(|r| r.v)
        .collect();
    let n = values.len();
    let rms = (values.iter().map(|v| v * v).sum::<f64>() / n.max(1) as f64).sqrt();
    const BIN: f64 = 0.25;
    const HALF_BINS: i32 = 16;
    let mut counts = vec![0usize; 2 * HALF_BINS as usize];
    for v in &values {
        let bin = (v / rms.max(1e-300) / BIN).floor() as i32 + HALF_BINS;
        if let Ok(i) = usize::try_from(bin.clamp(0, 2 * HALF_BINS - 1)) {
            counts[i] += 1;
        }
    }
    let expected = |x: f64| n as f64 * BIN * normal_density(x);
    let top = counts
        .iter()
        .map(|c| *c as f64)
        .fold(expected(0.0), f64::max)
        * 1.1;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (640, 420 + LEGEND_STRIP)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_error)?;
        let (title, rest) = root.split_vertically(TITLE_STRIP);
        let (legend, body) = rest.split_vertically(LEGEND_STRIP);
        draw_title(
            &title,
            &format!("Residuals: {n} coordinates, RMS {rms:.3} px (outer bins hold the tails)"),
            f64::from(FONT.1),
        )?;
        let mut chart = ChartBuilder::on(&body)
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d(-4.0..4.0, 0.0..top)
            .map_err(plot_error)?;
        chart
            .configure_mesh()
            .x_desc("residual / RMS (residual in px divided by the RMS)")
            .y_desc("count")
            .x_label_formatter(&tick)
            .y_label_formatter(&tick)
            .draw()
            .map_err(plot_error)?;
        chart
            .draw_series(counts.iter().enumerate().map(|(i, c)| {
                let x = (i as f64 - f64::from(HALF_BINS)) * BIN;
                Rectangle::new([(x, 0.0), (x + BIN, *c as f64)], RED.mix(0.5).filled())
            }))
            .map_err(plot_error)?;
        chart
            .draw_series(LineSeries::new(
                (0..=160).map(|k| {
                    let x = -4.0 + f64::from(k) * 0.05;
                    (x, expected(x))
                }),
                BLUE.stroke_width(2),
            ))
            .map_err(plot_error)?;
        draw_legend(
            &legend,
            &[
                (
                    Sample::Square(RGBColor(255, 128, 128)),
                    "observed".to_owned(),
                ),
                (
                    Sample::Line(BLUE, 2, 16),
                    "expected: normal, σ = RMS".to_owned(),
                ),
            ],
            12.0,
        )?;
        root.present().map_err(plot_error)?;
    }
    Ok((svg, counts))
}

/// A ray's miss distances from its plate points (mm): RMS and largest, or `None` for a ray seen
/// on one plate only, whose line runs through its points by construction (not determined).
pub type RayMiss = (u16, Option<(f64, f64)>);

/// The projector rays' miss distances: each ray's RMS and largest distance from its plate points
/// (mm), by ray id; rays seen on one plate only are marked in a band below 0, "not determined",
/// never as a miss of 0.
pub fn ray_misses(rays: &[RayMiss]) -> Result<String> {
    let determined = || rays.iter().filter_map(|&(id, m)| m.map(|m| (id, m)));
    let top = determined().map(|(_, m)| m.1).fold(0.0, f64::max).max(1e-6) * 1.1;
    let last = rays.iter().map(|r| f64::from(r.0)).fold(1.0, f64::max);
    let undetermined: Vec<u16> = (rays.iter())
        .filter(|r| r.1.is_none())
        .map(|r| r.0)
        .collect();
    // The band of the undetermined rays, below the axis's 0.
    let band = if undetermined.is_empty() {
        0.0
    } else {
        0.08 * top
    };
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (720, 420 + LEGEND_STRIP)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_error)?;
        let (title, rest) = root.split_vertically(TITLE_STRIP);
        let (legend, body) = rest.split_vertically(LEGEND_STRIP);
        draw_title(
            &title,
            &format!(
                "Projector rays: miss distance from their plane points ({} rays{})",
                rays.len(),
                match undetermined.len() {
                    0 => String::new(),
                    n => format!(", {n} seen on one plate, their miss not determined"),
                }
            ),
            f64::from(FONT.1),
        )?;
        let mut chart = ChartBuilder::on(&body)
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(56)
            .build_cartesian_2d(0.0..last * 1.02, -band..top)
            .map_err(plot_error)?;
        chart
            .configure_mesh()
            .x_desc("ray id (row × 100 + column)")
            .y_desc("miss distance (mm)")
            .x_label_formatter(&tick)
            .y_label_formatter(&|v| if *v < 0.0 { String::new() } else { tick(v) })
            .draw()
            .map_err(plot_error)?;
        chart
            .draw_series(determined().map(|(id, m)| Cross::new((f64::from(id), m.1), 2, BLUE)))
            .map_err(plot_error)?;
        chart
            .draw_series(
                determined().map(|(id, m)| Circle::new((f64::from(id), m.0), 2, RED.filled())),
            )
            .map_err(plot_error)?;
        chart
            .draw_series(undetermined.iter().map(|&id| {
                // 5 px wide whatever the number of rays, in the middle of the band.
                EmptyElement::at((f64::from(id), -0.5 * band))
                    + Rectangle::new([(-2, -4), (2, 4)], UNDETERMINED.filled())
            }))
            .map_err(plot_error)?;
        let mut entries = vec![
            (Sample::Cross(BLUE), "largest".to_owned()),
            (Sample::Dot(RED), "RMS".to_owned()),
        ];
        if !undetermined.is_empty() {
            entries.push((
                Sample::Square(UNDETERMINED),
                "seen on one plate: miss not determined (band below 0)".to_owned(),
            ));
        }
        draw_legend(&legend, &entries, 12.0)?;
        root.present().map_err(plot_error)?;
    }
    Ok(svg)
}

/// The colour of the rays whose miss distance is not determined.
const UNDETERMINED: RGBColor = RGBColor(150, 150, 150);

/// Writes `files` and, with `dir`, the plots into it (created if missing), all or nothing: when
/// any write fails, no file is created or changed and a directory created here is removed.
/// Returns the plots' paths.
pub fn write_with_plots<N: AsRef<str>>(
    files: &[(&std::path::Path, &[u8])],
    dir: Option<&std::path::Path>,
    plots: &[(N, String)],
) -> Result<Vec<std::path::PathBuf>> {
    let Some(dir) = dir else {
        crate::io::atomic::write_all_atomic(files)?;
        return Ok(Vec::new());
    };
    let created = !dir.exists();
    std::fs::create_dir_all(dir).map_err(|e| anyhow!("{}: cannot create: {e}", dir.display()))?;
    let paths: Vec<std::path::PathBuf> = plots
        .iter()
        .map(|(name, _)| dir.join(name.as_ref()))
        .collect();
    let all: Vec<(&std::path::Path, &[u8])> = files
        .iter()
        .copied()
        .chain(
            paths
                .iter()
                .zip(plots)
                .map(|(p, (_, svg))| (p.as_path(), svg.as_bytes())),
        )
        .collect();
    crate::io::atomic::write_all_atomic(&all).inspect_err(|_| {
        if created {
            let _ = std::fs::remove_dir_all(dir);
        }
    })?;
    Ok(paths)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn residual(image: &str, v: [f64; 2]) -> Residual {
        Residual {
            image: image.into(),
            point: "T".into(),
            observed: [100.0, 200.0],
            v,
            rejected: false,
        }
    }

    #[test]
    fn scale_is_a_round_number_that_fits() {
        assert_eq!(arrow_scale(1.7, 512.0, 0.12), 20.0);
        assert_eq!(arrow_scale(0.02, 512.0, 0.12), 2000.0);
        assert!(arrow_scale(3.0, 512.0, 0.12) * 3.0 <= 0.12 * 512.0);
    }

    /// Normal residuals fill the bins as the normal density says; every value is counted once.
    #[test]
    fn histogram_counts_every_coordinate() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let normal = Normal::new(0.0, 0.5).unwrap();
        let r: Vec<Residual> = (0..4000)
            .map(|i| {
                residual(
                    if i % 2 == 0 { "a" } else { "b" },
                    [normal.sample(&mut rng), normal.sample(&mut rng)],
                )
            })
            .collect();
        let (svg, counts) = residual_histogram(&r).unwrap();
        assert_eq!(counts.iter().sum::<usize>(), 8000);
        // The two bins next to 0 hold 2 · 0.25 · φ(0.125) · 8000 ≈ 1587, ± a few σ of a count.
        let centre = counts[15] + counts[16];
        assert!((centre as f64 - 1587.0).abs() < 120.0, "{centre}");
        assert!(svg.contains("residual / RMS") && svg.contains("expected: normal"));
        let vectors = residual_vectors(&r, 768, 512).unwrap();
        assert!(
            vectors.contains("col (px)") && vectors.contains("a: RMS") && vectors.contains("1 px")
        );
    }

    /// Vectors at the sensor's corners pointing outwards, the largest 3 px: every tip lies inside
    /// its panel's axis ranges (with the old fixed 5 % margin the corner tips ran outside).
    #[test]
    fn residual_vectors_stay_inside_their_panels() {
        let (w, h) = (768.0, 512.0);
        let at = |image: &str, observed: [f64; 2], v: [f64; 2]| Residual {
            observed,
            ..residual(image, v)
        };
        let r = vec![
            at("a", [0.0, 0.0], [-2.0, -2.0]),
            at("a", [w, h], [3.0, 0.5]),
            at("b", [w, 0.0], [1.0, -3.0]),
            at("b", [0.0, h], [-0.2, 2.9]),
        ];
        let scale = arrow_scale(3.0_f64.hypot(0.5), h, 0.12);
        for image in ["a", "b"] {
            let own: Vec<&Residual> = r.iter().filter(|x| x.image == image).collect();
            let (x, y) = panel_ranges(own.iter().copied(), (w, h), scale);
            for q in &own {
                for t in [0.0, scale] {
                    let (c, row) = (q.observed[0] + t * q.v[0], q.observed[1] + t * q.v[1]);
                    assert!(x.start < c && c < x.end, "{image}: col {c} outside {x:?}");
                    assert!(
                        y.start < row && row < y.end,
                        "{image}: row {row} outside {y:?}"
                    );
                }
            }
            // The sensor itself is inside too.
            assert!(x.start < 0.0 && x.end > w && y.start < 0.0 && y.end > h);
        }
        // The largest tip would leave the old fixed range −5 %..105 % of the sensor.
        assert!(w + scale * 3.0 > 1.05 * w);
        let svg = residual_vectors(&r, 768, 512).unwrap();
        // One red vector and one arrowhead (a 3-point polyline) per residual, plus the one
        // legend's arrow (shaft and head) for the whole figure.
        assert_eq!(
            svg.matches(r##"stroke="#FF0000""##).count(),
            2 * r.len() + 2,
            "{svg}"
        );
    }

    /// One marker per point coloured on a bar from −largest |error| (blue) to +largest (red):
    /// the extreme points take the bar's end colours, a zero error is white.
    #[test]
    fn accuracy_map_marks_every_point_on_the_colour_bar() {
        let points: Vec<(f64, f64, f64)> = (0..30)
            .map(|i| {
                let (x, y) = (f64::from(i % 6) * 20.0 - 50.0, f64::from(i / 6) * 15.0);
                (x, y, 0.01 * (f64::from(i) - 10.0))
            })
            .collect();
        assert_eq!(colour_limit(points.iter().map(|p| p.2)), 0.19);
        let svg = accuracy_map("test plate", "Z error", &points).unwrap();
        // Each point: a filled disc and its outline.
        assert_eq!(svg.matches(r#"r="4""#).count(), 2 * points.len(), "{svg}");
        // i = 29 (+0.19) is the bar's top colour, red; i = 10 (0) light grey; i = 0 (−0.10)
        // bluish.
        assert!(svg.contains(r##"r="4" opacity="1" fill="#FF0000""##));
        assert!(svg.contains(r##"r="4" opacity="1" fill="#D7D7D7""##));
        // −0.10 of ±0.19: 0.10 / 0.19 of the way from grey to blue: red and green
        // 215 · 0.09 / 0.19 ≈ 102, blue 215 + 40 · 0.10 / 0.19 ≈ 236.
        assert!(svg.contains(r##"r="4" opacity="1" fill="#6666EC""##));
        assert!(
            svg.contains("X (mm)") && svg.contains("Z error (mm)") && svg.contains("30 points")
        );
        assert!(svg.contains("largest |Z error| 0.190 mm"));
    }
}
