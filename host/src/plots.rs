//! Plots of a calibration (SVG, drawn with plotters): the residual vectors of every image, the
//! residual histogram against the expected normal distribution, and the projector rays' miss
//! distances. Every plot has axes with units, a title with its figures and a legend.

use crate::residuals::{per_image_rms, Residual};
use anyhow::{anyhow, Result};
use plotters::prelude::*;

/// Font of titles and labels.
const FONT: (&str, u32) = ("sans-serif", 13);

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

/// Residual vectors of every image on its sensor (one panel per image), magnified by one
/// common scale shown by the legend's 1 px arrow; rejected observations in grey.
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
    let scale = arrow_scale(largest, w.min(h), 0.12);
    let mut svg = String::new();
    {
        let panel_w = 380;
        let panel_h = (f64::from(panel_w) * h / w) as u32 + 70;
        let root = SVGBackend::with_string(
            &mut svg,
            (panel_w * cols as u32, panel_h * rows as u32 + 30),
        )
        .into_drawing_area();
        root.fill(&WHITE).map_err(plot_error)?;
        let (top, body) = root.split_vertically(30);
        top.titled(
            &format!(
                "Image residuals (observed − computed), magnified {scale}×: largest {largest:.2} px"
            ),
            FONT,
        )
        .map_err(plot_error)?;
        for (panel, (image, rms)) in body.split_evenly((rows, cols)).iter().zip(&images) {
            let mut chart = ChartBuilder::on(panel)
                .caption(format!("{image}: RMS {rms:.3} px"), FONT)
                .margin(6)
                .x_label_area_size(32)
                .y_label_area_size(44)
                .build_cartesian_2d(-0.05 * w..1.05 * w, 1.05 * h..-0.05 * h)
                .map_err(plot_error)?;
            chart
                .configure_mesh()
                .disable_mesh()
                .x_desc("col (px)")
                .y_desc("row (px)")
                .x_label_formatter(&|v| format!("{v:.0}"))
                .y_label_formatter(&|v| format!("{v:.0}"))
                .label_style(("sans-serif", 10))
                .draw()
                .map_err(plot_error)?;
            let own = residuals.iter().filter(|r| r.image == *image);
            chart
                .draw_series(own.clone().map(|r| {
                    let [c, row] = r.observed;
                    let colour = if r.rejected {
                        &RGBColor(160, 160, 160)
                    } else {
                        &RED
                    };
                    PathElement::new(
                        vec![(c, row), (c + scale * r.v[0], row + scale * r.v[1])],
                        colour.stroke_width(1),
                    )
                }))
                .map_err(plot_error)?
                .label(format!("residual × {scale}"))
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], RED));
            chart
                .draw_series(
                    own.map(|r| Circle::new((r.observed[0], r.observed[1]), 1, BLACK.filled())),
                )
                .map_err(plot_error)?
                .label("target")
                .legend(|(x, y)| Circle::new((x + 8, y), 2, BLACK.filled()));
            // The scale arrow: 1 px of residual, bottom left.
            let (x0, y0) = (0.0, 1.02 * h);
            chart
                .draw_series(std::iter::once(PathElement::new(
                    vec![(x0, y0), (x0 + scale, y0)],
                    BLUE.stroke_width(2),
                )))
                .map_err(plot_error)?
                .label("1 px")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLUE.stroke_width(2)));
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .label_font(("sans-serif", 10))
                .draw()
                .map_err(plot_error)?;
        }
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
        let root = SVGBackend::with_string(&mut svg, (640, 420)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_error)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!("Residuals: {n} coordinates, RMS {rms:.3} px (outer bins hold the tails)"),
                FONT,
            )
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d(-4.0..4.0, 0.0..top)
            .map_err(plot_error)?;
        chart
            .configure_mesh()
            .x_desc("residual / RMS (residual in px divided by the RMS)")
            .y_desc("count")
            .draw()
            .map_err(plot_error)?;
        chart
            .draw_series(counts.iter().enumerate().map(|(i, c)| {
                let x = (i as f64 - f64::from(HALF_BINS)) * BIN;
                Rectangle::new([(x, 0.0), (x + BIN, *c as f64)], RED.mix(0.5).filled())
            }))
            .map_err(plot_error)?
            .label("observed")
            .legend(|(x, y)| Rectangle::new([(x, y - 5), (x + 14, y + 5)], RED.mix(0.5).filled()));
        chart
            .draw_series(LineSeries::new(
                (0..=160).map(|k| {
                    let x = -4.0 + f64::from(k) * 0.05;
                    (x, expected(x))
                }),
                BLUE.stroke_width(2),
            ))
            .map_err(plot_error)?
            .label("expected: normal, σ = RMS")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLUE.stroke_width(2)));
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(plot_error)?;
        root.present().map_err(plot_error)?;
    }
    Ok((svg, counts))
}

/// The projector rays' miss distances: each ray's RMS and largest distance from its plane points
/// (mm), by ray id.
pub fn ray_misses(rays: &[(u16, f64, f64)]) -> Result<String> {
    let top = rays.iter().map(|r| r.2).fold(0.0, f64::max).max(1e-6) * 1.1;
    let last = rays.iter().map(|r| f64::from(r.0)).fold(1.0, f64::max);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (720, 420)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_error)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!(
                    "Projector rays: miss distance from their plane points ({} rays)",
                    rays.len()
                ),
                FONT,
            )
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(56)
            .build_cartesian_2d(0.0..last * 1.02, 0.0..top)
            .map_err(plot_error)?;
        chart
            .configure_mesh()
            .x_desc("ray id (row × 100 + column)")
            .y_desc("miss distance (mm)")
            .draw()
            .map_err(plot_error)?;
        chart
            .draw_series(
                rays.iter()
                    .map(|r| Cross::new((f64::from(r.0), r.2), 2, BLUE)),
            )
            .map_err(plot_error)?
            .label("largest")
            .legend(|(x, y)| Cross::new((x + 8, y), 3, BLUE));
        chart
            .draw_series(
                rays.iter()
                    .map(|r| Circle::new((f64::from(r.0), r.1), 2, RED.filled())),
            )
            .map_err(plot_error)?
            .label("RMS")
            .legend(|(x, y)| Circle::new((x + 8, y), 3, RED.filled()));
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(plot_error)?;
        root.present().map_err(plot_error)?;
    }
    Ok(svg)
}

/// Writes plots into `dir` (created if missing), all or nothing; their paths.
pub fn write_plots(
    dir: &std::path::Path,
    plots: &[(&str, String)],
) -> Result<Vec<std::path::PathBuf>> {
    std::fs::create_dir_all(dir).map_err(|e| anyhow!("{}: cannot create: {e}", dir.display()))?;
    let paths: Vec<std::path::PathBuf> = plots.iter().map(|(name, _)| dir.join(name)).collect();
    let files: Vec<(&std::path::Path, &[u8])> = paths
        .iter()
        .zip(plots)
        .map(|(p, (_, svg))| (p.as_path(), svg.as_bytes()))
        .collect();
    crate::io::atomic::write_all_atomic(&files)?;
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
}
