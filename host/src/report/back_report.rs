//! `report.html` of a back analysis: one self-contained page (inline SVG, no script, nothing
//! fetched) that a non-specialist can read: the measures with their σ, a topography map with
//! contour lines and the symmetry line, the rotation and lateral-deviation profiles with their σ
//! bands, the asymmetry map, the calibration's fingerprint and a plain statement that these are
//! surface measurements, not a diagnosis.

use crate::io::analysis_file::BackReport;
use anyhow::Result;
use deltaz_surface::{BackAnalysis, Comparison, Level, Map, Posture};
use plotters::prelude::*;
use std::fmt::Write as _;

fn plot_error<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow::anyhow!("drawing a plot: {e:?}")
}

/// Text for HTML.
fn escape(text: &str) -> String {
    text.chars()
        .map(|c| match c {
            '&' => "&amp;".to_owned(),
            '<' => "&lt;".to_owned(),
            '>' => "&gt;".to_owned(),
            '"' => "&quot;".to_owned(),
            '\'' => "&#39;".to_owned(),
            c => c.to_string(),
        })
        .collect()
}

/// `value ± σ` to the decimal of σ's first significant digit (1 to 3 decimals).
pub fn plus_minus(value: f64, sigma: f64) -> String {
    let decimals = if sigma > 0.0 && sigma.is_finite() {
        (-sigma.log10().floor()).clamp(1.0, 3.0) as usize
    } else {
        1
    };
    format!("{value:.decimals$} ± {sigma:.decimals$}")
}

/// The page.
pub fn report_html(report: &BackReport) -> Result<String> {
    let a = &report.analysis;
    let mut html = String::from(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <title>deltaz back surface report</title><style>\
         body{font-family:sans-serif;max-width:980px;margin:1em auto;color:#222}\
         table{border-collapse:collapse}td,th{padding:2px 10px;text-align:left}\
         tr:nth-child(even){background:#f3f3f3}.note{background:#fff6d6;padding:8px 12px;\
         border-left:4px solid #d9a400}figure{margin:1em 0}\
         </style></head><body>\n<h1>Back surface measurements</h1>\n",
    );
    html += "<p class=\"note\"><b>These are measurements of the back's surface, not a \
             diagnosis.</b> Surface rotation and the other indices describe the shape of the skin; \
             they are related to, but not the same as, the spine's curvature on a radiograph. \
             Each value is given with its standard deviation σ (about two in three repeated \
             measurements fall within ±σ).</p>\n";
    let _ = writeln!(
        html,
        "<p>Posture: {}; {} frame(s), {}, dot spacing {:.1} mm, \
         calibration {}. Points' covariance: {}. Surface fit χ {:.2} (about 1 when the points' \
         σ hold); its misfit along the symmetry line {:.2} mm, detail between the dots, which \
         the line's and the rotation's σ include.</p>",
        escape(&posture_text(a)),
        a.frames,
        escape(&points_text(a)),
        a.spacing_mm,
        escape(
            report
                .fingerprint
                .as_deref()
                .unwrap_or("not named by the clouds")
        ),
        escape(&report.covariance),
        a.fit_chi,
        a.misfit_mm
    );
    for note in report.notes.iter().cloned().chain(analysis_note(a)) {
        let _ = writeln!(html, "<p class=\"note\">{}</p>", escape(&note));
    }
    html += "<h2>Measures</h2>\n<table><tr><th>measure</th><th>value ± σ</th></tr>\n";
    for (name, value, sigma, unit) in indices(a) {
        let _ = writeln!(
            html,
            "<tr><td>{name}</td><td>{} {unit}</td></tr>",
            plus_minus(value, sigma)
        );
    }
    html += "</table>\n";
    if !a.sway.is_empty() {
        html += "<h2>Sway between frames</h2>\n<table><tr><th>frame</th>\
                 <th>rotation (°) about across, axis, depth</th><th>shift (mm)</th></tr>\n";
        for s in &a.sway {
            let pm = |v: [f64; 3], s: [f64; 3]| {
                (0..3)
                    .map(|k| plus_minus(v[k], s[k]))
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            let _ = writeln!(
                html,
                "<tr><td>{}</td><td>{}</td><td>{}</td></tr>",
                s.frame,
                pm(s.rotation_deg, s.rotation_sigma_deg),
                pm(s.translation_mm, s.translation_sigma_mm)
            );
        }
        html += "</table>\n";
    }
    let (topography, rotation) = surface_figures(a)?;
    let figures = [
        (
            "Topography: the depth of the back, contour lines every 5 mm, the symmetry line in \
             black, points left out of the surface fit as wild (if any) as crosses",
            topography,
        ),
        (
            "Surface rotation along the symmetry line (positive: the subject's right side \
             toward the camera), with its ±σ band",
            rotation,
        ),
        (
            "Lateral deviation of the symmetry line from the line through its ends, with its \
             ±σ band",
            profile_svg("lateral deviation (mm)", &a.levels, |l| {
                (l.lateral_deviation_mm, l.lateral_deviation_sigma_mm)
            })?,
        ),
        (
            "Asymmetry: the depth difference to the surface mirrored about the symmetry line \
             (positive: this side nearer the camera than its mirror), contour lines every 2 mm",
            map_svg(&a.asymmetry, "difference (mm)", None, &[], 2.0, true)?,
        ),
    ];
    for (caption, svg) in figures {
        let _ = writeln!(
            html,
            "<figure>{svg}<figcaption>{}</figcaption></figure>",
            escape(caption)
        );
    }
    html += "<h2>Levels</h2>\n";
    html += &ambiguity_note(&a.levels);
    html += "<table><tr><th>level y (mm)</th><th>symmetry x (mm)</th>\
             <th>rotation (°)</th><th>lateral deviation (mm)</th><th>other symmetry x (mm)</th></tr>\n";
    for l in &a.levels {
        let _ = writeln!(
            html,
            "<tr><td>{:.0}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            l.y,
            plus_minus(l.symmetry_x, l.symmetry_x_sigma),
            plus_minus(l.rotation_deg, l.rotation_sigma_deg),
            plus_minus(l.lateral_deviation_mm, l.lateral_deviation_sigma_mm),
            l.symmetry_x_rival
                .map_or(String::new(), |x| format!("{x:.1}"))
        );
    }
    html += "</table>\n<p>Clouds: ";
    html += &escape(
        &report
            .clouds
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", "),
    );
    html += ". Written by deltaz.</p>\n</body></html>\n";
    Ok(html)
}

/// What the reader of a comparison `c` of two analyses must know (each report with the name
/// it goes by: a path, a session), if anything: that two calibrations measured them, that
/// their dots lay at other spacings, that a symmetry line holds at fewer than half the levels.
/// `deltaz analyse compare` and the station say it alike.
pub fn comparison_notes(c: &Comparison, reports: [(&str, &BackReport); 2]) -> Vec<String> {
    let mut notes = Vec::new();
    let [(_, a), (_, b)] = reports;
    if let (Some(fa), Some(fb)) = (&a.fingerprint, &b.fingerprint) {
        if fa != fb {
            notes.push(format!("measured with two calibrations ({fa} and {fb})"));
        }
    }
    if c.scales_differ {
        notes.push(format!(
            "the dots lay {:.1} and {:.1} mm apart on the back: the surface is smoothed over a \
             length that follows the spacing, so the changes also hold that difference of \
             scale, beyond their σ (scan at the same distance)",
            c.spacings_mm[0], c.spacings_mm[1]
        ));
    }
    for ((name, _), lost) in reports.into_iter().zip(c.lines_lost) {
        if lost {
            notes.push(format!(
                "{name}: the symmetry line holds at fewer than half the back's levels, so a \
                 change may be the line's rather than the back's (capture again)"
            ));
        }
    }
    notes
}

/// The posture and the trunk's axis as the analysis took them, in the camera system: standing,
/// the vertical; bent forward, toward the head (taken the wrong way, the scoliometer's and the
/// rotation's signs turn).
pub fn posture_text(a: &BackAnalysis) -> String {
    let [x, y, z] = a.axes.axis;
    let posture = match a.posture {
        Posture::Standing => "standing, the vertical",
        Posture::ForwardBent => "bent forward (Adams position), the head toward",
    };
    format!("{posture} ({x:.2}, {y:.2}, {z:.2}) in the camera system")
}

/// The points the analysis measured the back by, and those apart from it it left out
/// ([`BackAnalysis::points_apart`]; the planes larger than the back are noted apart).
pub fn points_text(a: &BackAnalysis) -> String {
    let on = format!("{} points on the back", a.points);
    match a.points_apart {
        0 => on,
        n => format!("{on}, {n} apart from it left out (the arms, anything beside the subject)"),
    }
}

/// What the reader must know of the analysis, if anything: a profile that reads as a back
/// seen upside down ([`BackAnalysis::looks_upside_down`]), a line bent forward on faint
/// features ([`BackAnalysis::line_faint`]) and the levels where the symmetry line was not found
/// ([`BackAnalysis::levels_left_out`]). The report, `deltaz analyse back` and the station say
/// it alike.
pub fn analysis_note(a: &BackAnalysis) -> Option<String> {
    let mut notes = Vec::new();
    let upside_down = a.looks_upside_down().then(|| a.sagittal_mid_excess_deg());
    if let Some(excess) = upside_down.flatten() {
        notes.push(format!(
            "The back's sagittal profile is that of a back seen upside down: its slope is least \
             at mid height and steepest toward both ends ({excess:+.1}° from the middle third to \
             the outer ones, where a back standing reads +7 to +23°). If the cloud's +y points \
             to the feet (a camera mounted upside down, a scanner writing y down), every profile \
             here is reversed and the rotation's sign turned: analyse it again with --vertical \
             0,-1,0."
        ));
    }
    if a.line_faint() {
        notes.push(format!(
            "The symmetry line rests on faint features: the sections are only {:.1} times as \
             asymmetric as their noise makes them (under {}; backs bent forward mostly read 13 \
             or more), and bent forward the σ may then understate the errors several times (3-7 \
             times on a model back with a 1 mm spinous groove). A capture standing, or another \
             bent forward, tells whether the readings hold.",
            a.asymmetry_over_noise,
            deltaz_surface::analysis::FAINT
        ));
    }
    notes.extend(line_note(a));
    (!notes.is_empty()).then(|| notes.join(" "))
}

/// The levels where the symmetry line was not found, if any.
fn line_note(a: &BackAnalysis) -> Option<String> {
    let left_out = &a.levels_left_out;
    if left_out.is_empty() {
        return None;
    }
    let ys: Vec<String> = left_out.iter().map(|y| format!("{y:.0}")).collect();
    let mut note = format!(
        "The symmetry line was not found at {} of the {} levels where the back is measured \
         (y = {} mm): nothing is measured there, and a largest value may lie among them.",
        left_out.len(),
        left_out.len() + a.levels.len(),
        ys.join(", ")
    );
    if a.line_mostly_lost() {
        note += " It holds at fewer than half of them: the subject may not have faced the \
                 camera squarely (within about 3.5°), or part of the back was out of view or \
                 covered. Capture again.";
    }
    Some(note)
}

/// What the page says where the symmetry line is ambiguous (nothing where it is not).
fn ambiguity_note(levels: &[Level]) -> String {
    let ambiguous = levels
        .iter()
        .filter(|l| l.symmetry_x_rival.is_some())
        .count();
    if ambiguous == 0 {
        return String::new();
    }
    format!(
        "<p class=\"note\">At {ambiguous} of {} levels the back is about as nearly mirror \
         symmetric about a second line as about the symmetry line (the other symmetry x below): \
         the scan does not tell which one the spine follows there. The values at those levels, \
         and the measures taken from them, include the difference between the two in their \
         σ.</p>\n",
        levels.len()
    )
}

/// The two figures of a surface at a glance (SVG): the topography (depth colours, contour lines
/// every 5 mm, the symmetry line) and the surface rotation along the symmetry line with its ±σ
/// band.
pub fn surface_figures(a: &BackAnalysis) -> Result<(String, String)> {
    let wild: Vec<[f64; 2]> = a.wild.iter().map(|w| w.at).collect();
    Ok((
        map_svg(
            &a.topography,
            "depth (mm)",
            Some(&a.levels),
            &wild,
            5.0,
            false,
        )?,
        profile_svg("surface rotation (°)", &a.levels, |l| {
            (l.rotation_deg, l.rotation_sigma_deg)
        })?,
    ))
}

/// The summary measures: name, value, σ, unit (those the analysis has).
pub fn indices(a: &BackAnalysis) -> Vec<(&'static str, f64, f64, &'static str)> {
    let mut out = vec![
        (
            "largest surface rotation",
            a.rotation_max_deg,
            a.rotation_max_deg_sigma,
            "°",
        ),
        (
            "surface rotation, RMS over the levels",
            a.rotation_rms_deg,
            a.rotation_rms_deg_sigma,
            "°",
        ),
        (
            "largest lateral deviation",
            a.lateral_deviation_max_mm,
            a.lateral_deviation_max_mm_sigma,
            "mm",
        ),
        (
            "lateral deviation, RMS",
            a.lateral_deviation_rms_mm,
            a.lateral_deviation_rms_mm_sigma,
            "mm",
        ),
        (
            "trunk imbalance (top of the line across from its bottom)",
            a.trunk_imbalance_mm,
            a.trunk_imbalance_mm_sigma,
            "mm",
        ),
        (
            "trunk inclination",
            a.trunk_inclination_deg,
            a.trunk_inclination_deg_sigma,
            "°",
        ),
    ];
    let optional = [
        ("kyphosis angle", a.kyphosis_deg, a.kyphosis_deg_sigma, "°"),
        ("lordosis angle", a.lordosis_deg, a.lordosis_deg_sigma, "°"),
        (
            "largest angle of trunk rotation (virtual scoliometer)",
            a.atr_max_deg,
            a.atr_max_deg_sigma,
            "°",
        ),
        (
            "largest mirror asymmetry (the subject's right side nearer the camera than its mirror: +)",
            a.asymmetry_max_mm,
            a.asymmetry_max_mm_sigma,
            "mm",
        ),
    ];
    for (name, v, s, unit) in optional {
        if let (Some(v), Some(s)) = (v, s) {
            out.push((name, v, s, unit));
        }
    }
    out
}

/// The segments of the contour lines at multiples of `step` of a map's values (marching squares
/// over its grid cells).
fn contours(map: &Map, step: f64) -> Vec<[(f64, f64); 2]> {
    let (na, nv) = (map.a.len(), map.v.len());
    let at = |i: usize, j: usize| map.values.get(j * na + i).copied().flatten();
    let mut out = Vec::new();
    for j in 0..nv.saturating_sub(1) {
        for i in 0..na.saturating_sub(1) {
            let corners = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)];
            let Some(values) = corners
                .iter()
                .map(|&(i, j)| at(i, j))
                .collect::<Option<Vec<f64>>>()
            else {
                continue;
            };
            let (lo, hi) = values
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                    (a.min(v), b.max(v))
                });
            let mut level = (lo / step).ceil() * step;
            while level <= hi {
                let mut crossings = Vec::new();
                for e in 0..4 {
                    let (p, q) = (e, (e + 1) % 4);
                    let (vp, vq) = (values[p] - level, values[q] - level);
                    if (vp < 0.0) != (vq < 0.0) {
                        let t = vp / (vp - vq);
                        let (ip, jp) = corners[p];
                        let (iq, jq) = corners[q];
                        let lerp = |a: f64, b: f64| a + t * (b - a);
                        crossings.push((lerp(map.a[ip], map.a[iq]), lerp(map.v[jp], map.v[jq])));
                    }
                }
                for pair in crossings.chunks_exact(2) {
                    out.push([pair[0], pair[1]]);
                }
                level += step;
            }
        }
    }
    out
}

/// A map of `values` over (across, level) with contour lines every `step`, the symmetry line
/// of `levels` when given and a cross at each of `marks`; `diverging`: blue–white–red about 0,
/// else a sequential scale.
fn map_svg(
    map: &Map,
    what: &str,
    levels: Option<&[Level]>,
    marks: &[[f64; 2]],
    step: f64,
    diverging: bool,
) -> Result<String> {
    let finite: Vec<f64> = map.values.iter().flatten().copied().collect();
    if finite.is_empty() || map.a.len() < 2 || map.v.len() < 2 {
        return Ok(String::from("<p>(no map: too few points)</p>"));
    }
    let (lo, hi) = finite
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    let limit = lo.abs().max(hi.abs()).max(1e-6);
    let (lo, hi) = if diverging {
        (-limit, limit)
    } else {
        (lo, hi.max(lo + 1e-6))
    };
    let sequential = DerivedColorMap::new(&[
        RGBColor(40, 60, 150),
        RGBColor(70, 170, 190),
        RGBColor(240, 220, 120),
        RGBColor(200, 60, 40),
    ]);
    let centred = DerivedColorMap::new(&[
        RGBColor(40, 80, 200),
        RGBColor(235, 235, 235),
        RGBColor(200, 40, 40),
    ]);
    let colour = |v: f64| {
        if diverging {
            centred.get_color_normalized(v, lo, hi)
        } else {
            sequential.get_color_normalized(v, lo, hi)
        }
    };
    let (a0, a1) = (map.a[0], map.a[map.a.len() - 1]);
    let (v0, v1) = (map.v[0], map.v[map.v.len() - 1]);
    let (da, dv) = (
        (a1 - a0) / (map.a.len() - 1) as f64,
        (v1 - v0) / (map.v.len() - 1) as f64,
    );
    // Equal mm per pixel: the figure's height follows the map's shape.
    let width = 560u32;
    let height = ((f64::from(width - 120) * (v1 - v0) / (a1 - a0)).clamp(200.0, 900.0)) as u32 + 70;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (width + 110, height)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_error)?;
        let (body, bar) = root.split_horizontally(width);
        let mut chart = ChartBuilder::on(&body)
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(52)
            .build_cartesian_2d(a0 - da / 2.0..a1 + da / 2.0, v0 - dv / 2.0..v1 + dv / 2.0)
            .map_err(plot_error)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("across (mm; +: the subject's right)")
            .y_desc("level (mm)")
            .x_label_formatter(&|v| format!("{v:.0}"))
            .y_label_formatter(&|v| format!("{v:.0}"))
            .draw()
            .map_err(plot_error)?;
        let cells = map.v.iter().enumerate().flat_map(|(j, &v)| {
            map.a.iter().enumerate().filter_map(move |(i, &a)| {
                let value = map.values.get(j * map.a.len() + i).copied().flatten()?;
                Some((a, v, value))
            })
        });
        chart
            .draw_series(cells.map(|(a, v, value)| {
                Rectangle::new(
                    [(a - da / 2.0, v - dv / 2.0), (a + da / 2.0, v + dv / 2.0)],
                    colour(value).filled(),
                )
            }))
            .map_err(plot_error)?;
        chart
            .draw_series(
                contours(map, step)
                    .into_iter()
                    .map(|s| PathElement::new(s.to_vec(), RGBColor(60, 60, 60).stroke_width(1))),
            )
            .map_err(plot_error)?;
        if let Some(levels) = levels {
            chart
                .draw_series(LineSeries::new(
                    levels.iter().map(|l| (l.symmetry_x, l.y)),
                    BLACK.stroke_width(3),
                ))
                .map_err(plot_error)?;
        }
        chart
            .draw_series(
                marks
                    .iter()
                    .map(|&[a, v]| Cross::new((a, v), 6, BLACK.stroke_width(2))),
            )
            .map_err(plot_error)?;
        let mut bar_chart = ChartBuilder::on(&bar)
            .margin_top(10)
            .margin_bottom(46)
            .margin_right(10)
            .right_y_label_area_size(60)
            .build_cartesian_2d(0.0..1.0, lo..hi)
            .map_err(plot_error)?
            .set_secondary_coord(0.0..1.0, lo..hi);
        bar_chart
            .configure_secondary_axes()
            .y_desc(what)
            .y_label_formatter(&|v| format!("{v:.1}"))
            .label_style(("sans-serif", 13))
            .axis_desc_style(("sans-serif", 13))
            .draw()
            .map_err(plot_error)?;
        const STEPS: usize = 48;
        let h = (hi - lo) / STEPS as f64;
        bar_chart
            .draw_series((0..STEPS).map(|k| {
                let y = lo + k as f64 * h;
                Rectangle::new([(0.0, y), (1.0, y + h)], colour(y + h / 2.0).filled())
            }))
            .map_err(plot_error)?;
        root.present().map_err(plot_error)?;
    }
    Ok(svg)
}

/// A profile along the levels (level on the vertical axis, as on the back): the value and its
/// ±σ band.
fn profile_svg(what: &str, levels: &[Level], value: fn(&Level) -> (f64, f64)) -> Result<String> {
    if levels.len() < 2 {
        return Ok(String::from("<p>(no profile: too few levels)</p>"));
    }
    let points: Vec<(f64, f64, f64)> = levels
        .iter()
        .map(|l| {
            let (v, s) = value(l);
            (l.y, v, s)
        })
        .collect();
    let reach = points
        .iter()
        .map(|&(_, v, s)| v.abs() + s)
        .fold(0.0, f64::max)
        .max(1.0)
        * 1.1;
    let (y0, y1) = (points[0].0, points[points.len() - 1].0);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (420, 520)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_error)?;
        let mut chart = ChartBuilder::on(&root)
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(52)
            .build_cartesian_2d(-reach..reach, y0.min(y1)..y0.max(y1))
            .map_err(plot_error)?;
        chart
            .configure_mesh()
            .x_desc(what)
            .y_desc("level (mm)")
            .x_label_formatter(&|v| format!("{v:.1}"))
            .y_label_formatter(&|v| format!("{v:.0}"))
            .draw()
            .map_err(plot_error)?;
        let band: Vec<(f64, f64)> = points
            .iter()
            .map(|&(y, v, s)| (v + s, y))
            .chain(points.iter().rev().map(|&(y, v, s)| (v - s, y)))
            .collect();
        chart
            .draw_series(std::iter::once(Polygon::new(
                band,
                RGBColor(120, 160, 220).mix(0.4).filled(),
            )))
            .map_err(plot_error)?;
        chart
            .draw_series(std::iter::once(PathElement::new(
                vec![(0.0, y0), (0.0, y1)],
                RGBColor(150, 150, 150).stroke_width(1),
            )))
            .map_err(plot_error)?;
        chart
            .draw_series(LineSeries::new(
                points.iter().map(|&(y, v, _)| (v, y)),
                RGBColor(20, 60, 160).stroke_width(2),
            ))
            .map_err(plot_error)?;
        root.present().map_err(plot_error)?;
    }
    Ok(svg)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tilted plane's contours are straight lines where its value crosses each step.
    #[test]
    fn contours_of_a_plane() {
        let a: Vec<f64> = (0..5).map(f64::from).collect();
        let map = Map {
            v: a.clone(),
            values: (0..25).map(|k| Some(f64::from(k % 5))).collect(),
            sigmas: vec![None; 25],
            a,
        };
        let segments = contours(&map, 1.5);
        // value = a: the contours 1.5 and 3.0 are the lines a = 1.5 and a = 3, one segment in
        // each of the four cells they cross.
        for s in &segments {
            let a = s[0].0;
            assert!(
                [1.5, 3.0].contains(&a) && s[1].0 == a && s[0].1 != s[1].1,
                "{s:?}"
            );
        }
        assert_eq!(segments.len(), 8);
    }

    #[test]
    fn values_with_the_decimals_their_sigma_needs() {
        assert_eq!(plus_minus(1.234, 0.04), "1.23 ± 0.04");
        assert_eq!(plus_minus(10.3, 0.25), "10.3 ± 0.2");
        assert_eq!(plus_minus(0.05, 0.004), "0.050 ± 0.004");
        assert_eq!(plus_minus(150.0, 12.0), "150.0 ± 12.0");
    }

    #[test]
    fn ambiguous_levels_are_named() {
        let level = |rival: Option<f64>| -> Level {
            serde_json::from_value(serde_json::json!({
                "y": 0.0, "symmetry_x": 1.0, "symmetry_x_sigma": 0.5, "depth_mm": 0.0,
                "depth_sigma_mm": 0.1, "rotation_deg": 0.0, "rotation_sigma_deg": 0.1,
                "lateral_deviation_mm": 0.0, "lateral_deviation_sigma_mm": 0.1,
                "sagittal_slope_deg": 0.0, "sagittal_slope_sigma_deg": 0.1,
                "skin_angle_deg": null, "skin_angle_sigma_deg": null, "atr_deg": null,
                "atr_sigma_deg": null, "atr_window": null, "symmetry_x_rival": rival
            }))
            .unwrap()
        };
        assert_eq!(ambiguity_note(&[level(None), level(None)]), "");
        // A file of an older version, without the field, reads as unambiguous.
        let mut old = serde_json::to_value(level(None)).unwrap();
        old.as_object_mut().unwrap().remove("symmetry_x_rival");
        let old: Level = serde_json::from_value(old).unwrap();
        assert_eq!(old.symmetry_x_rival, None);
        let note = ambiguity_note(&[level(None), level(Some(-40.0)), level(Some(-41.0))]);
        assert!(note.contains("At 2 of 3 levels"), "{note}");
    }

    #[test]
    fn text_is_escaped() {
        assert_eq!(escape("a<b>&\"'"), "a&lt;b&gt;&amp;&quot;&#39;");
    }
}
