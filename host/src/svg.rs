//! Two plain SVG plots for the demo report (no fonts or system libraries needed): residual vectors
//! per image, and an error map of a reconstructed plate.

use std::fmt::Write;

/// One image's residual vectors: (col, row) of each observation and its residual (pixels).
#[derive(Debug, Clone, PartialEq)]
pub struct ResidualPanel {
    /// Panel title (the image's name).
    pub title: String,
    /// Sensor width and height (pixels).
    pub size: (f64, f64),
    /// (col, row, dcol, drow) per observation.
    pub vectors: Vec<(f64, f64, f64, f64)>,
}

const PANEL_W: f64 = 384.0;

/// Residual vectors per image, side by side, each exaggerated by `scale` (stated on the plot).
pub fn residual_vectors(panels: &[ResidualPanel], scale: f64) -> String {
    let panel_h = panels
        .iter()
        .map(|p| PANEL_W * p.size.1 / p.size.0)
        .fold(0.0, f64::max);
    let width = PANEL_W * panels.len() as f64 + 10.0 * (panels.len() as f64 + 1.0);
    let height = panel_h + 60.0;
    let mut svg = header(width, height);
    let _ = writeln!(
        svg,
        r#"<text x="10" y="{:.1}" font-size="13">residual vectors × {scale}</text>"#,
        height - 10.0
    );
    for (k, panel) in panels.iter().enumerate() {
        let x0 = 10.0 + k as f64 * (PANEL_W + 10.0);
        let s = PANEL_W / panel.size.0;
        let h = panel.size.1 * s;
        let _ = writeln!(
            svg,
            r##"<rect x="{x0:.1}" y="25" width="{PANEL_W:.1}" height="{h:.1}" fill="none" stroke="#888"/><text x="{x0:.1}" y="18" font-size="13">{}</text>"##,
            escape(&panel.title)
        );
        for (col, row, dc, dr) in &panel.vectors {
            let (x, y) = (x0 + col * s, 25.0 + row * s);
            let (x2, y2) = (x + dc * scale * s, y + dr * scale * s);
            let _ = writeln!(
                svg,
                r##"<circle cx="{x:.1}" cy="{y:.1}" r="1.2" fill="#333"/><line x1="{x:.1}" y1="{y:.1}" x2="{x2:.1}" y2="{y2:.1}" stroke="#c0392b" stroke-width="1"/>"##
            );
        }
    }
    svg + "</svg>\n"
}

/// A map of points (x, y) coloured by their error (mm), blue negative to red positive, with the
/// colour range stated; `title` on top.
pub fn error_map(title: &str, points: &[(f64, f64, f64)]) -> String {
    let (w, h) = (560.0, 460.0);
    let mut svg = header(w, h);
    let (xmin, xmax) = range(points.iter().map(|p| p.0));
    let (ymin, ymax) = range(points.iter().map(|p| p.1));
    let limit = points.iter().map(|p| p.2.abs()).fold(1e-9, f64::max);
    let s = (480.0 / (xmax - xmin).max(1e-9)).min(360.0 / (ymax - ymin).max(1e-9));
    let _ = writeln!(
        svg,
        r#"<text x="10" y="18" font-size="13">{}</text><text x="10" y="{:.1}" font-size="12">colour: error from −{limit:.3} mm (blue) to +{limit:.3} mm (red); x right, y up</text>"#,
        escape(title),
        h - 10.0
    );
    for (x, y, e) in points {
        let cx = 40.0 + (x - xmin) * s;
        let cy = 40.0 + (ymax - y) * s;
        let t = (e / limit).clamp(-1.0, 1.0);
        let (r, b) = if t >= 0.0 {
            (255.0, 255.0 * (1.0 - t))
        } else {
            (255.0 * (1.0 + t), 255.0)
        };
        let g = 255.0 * (1.0 - t.abs());
        let _ = writeln!(
            svg,
            r##"<circle cx="{cx:.1}" cy="{cy:.1}" r="5" fill="rgb({r:.0},{g:.0},{b:.0})" stroke="#555" stroke-width="0.5"/>"##
        );
    }
    svg + "</svg>\n"
}

fn header(w: f64, h: f64) -> String {
    format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w:.0}\" height=\"{h:.0}\" viewBox=\"0 0 {w:.0} {h:.0}\" font-family=\"sans-serif\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n"
    )
}

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    values.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
        (a.min(v), b.max(v))
    })
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn residual_plot_draws_every_vector_scaled() {
        let panel = ResidualPanel {
            title: "p1 <plate>".into(),
            size: (768.0, 512.0),
            vectors: vec![(0.0, 0.0, 1.0, 0.0), (384.0, 256.0, 0.0, -0.5)],
        };
        let svg = residual_vectors(&[panel.clone(), panel], 100.0);
        assert_eq!(svg.matches("<line").count(), 4);
        assert!(svg.contains("p1 &lt;plate&gt;"));
        // 1 px × 100 at 0.5 drawing units per pixel = 50 units: from x 10 to 60.
        assert!(
            svg.contains(r#"x1="10.0" y1="25.0" x2="60.0" y2="25.0""#),
            "{svg}"
        );
        assert!(svg.ends_with("</svg>\n"));
    }

    #[test]
    fn error_map_colours_by_sign() {
        let svg = error_map(
            "plate",
            &[(0.0, 0.0, -1.0), (10.0, 10.0, 1.0), (5.0, 5.0, 0.0)],
        );
        assert!(svg.contains("rgb(0,0,255)") && svg.contains("rgb(255,0,0)"));
        assert!(svg.contains("rgb(255,255,255)"));
    }
}
