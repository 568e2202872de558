//! The parts every plot of [`super::plots`] shares: tick labels, titles that fit their figure,
//! one legend per figure in a strip outside the data, and arrowheads.

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// Font family of every text.
pub const FAMILY: &str = "sans-serif";

/// How wide a text of `chars` characters is drawn at `size` px, at most: sans-serif glyphs
/// average about 0.55 em, digits and capitals up to 0.6 em.
pub fn text_width(chars: usize, size: f64) -> f64 {
    0.6 * size * chars as f64
}

/// A tick label: an integer without decimals ("100", not "100.0"), otherwise the shortest of up
/// to 6 decimals that shows the value ("0.25", "2.5"); −0 is 0.
pub fn tick(v: &f64) -> String {
    let text = format!("{:.6}", v);
    let text = text.trim_end_matches('0').trim_end_matches('.');
    match text {
        "-0" => "0".to_owned(),
        t => t.to_owned(),
    }
}

/// Colour-bar tick labels from −limit to +limit: "0" at 0, the others with as many decimals as
/// the bar's tick step needs (plotters puts about ten ticks on the bar).
pub fn bar_tick(limit: f64) -> impl Fn(&f64) -> String {
    let step = 2.0 * limit / 10.0;
    let decimals = (-step.log10().floor()).clamp(0.0, 9.0) as usize;
    move |v: &f64| {
        if v.abs() < 1e-6 * limit {
            "0".to_owned()
        } else {
            format!("{v:.decimals$}")
        }
    }
}

/// The lines of a title `text` in a `width` px figure at `size` px: one line when it fits,
/// else two, split at the last ", " or ": " that leaves the first line fitting.
pub fn title_lines(text: &str, width: f64, size: f64) -> Vec<String> {
    let fits = |t: &str| text_width(t.chars().count(), size) <= width;
    if fits(text) {
        return vec![text.to_owned()];
    }
    let split = text
        .rmatch_indices([',', ':'])
        .map(|(i, _)| i)
        .find(|&i| fits(&text[..=i]));
    match split {
        Some(i) => vec![text[..=i].to_owned(), text[i + 1..].trim().to_owned()],
        None => vec![text.to_owned()],
    }
}

/// The font size (px) at which every line of `lines` fits `width` px, at most `size`.
fn fitting_size(lines: &[String], width: f64, size: f64) -> f64 {
    let longest = lines.iter().map(|l| l.chars().count()).max().unwrap_or(1);
    size.min(width / (0.6 * longest.max(1) as f64))
        .floor()
        .max(6.0)
}

/// Draws `text` centred at the top of `area` as one or two lines that fit its width
/// ([`title_lines`]), shrunk if a line still would not fit.
pub fn draw_title<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    text: &str,
    size: f64,
) -> anyhow::Result<()> {
    let width = f64::from(area.dim_in_pixel().0) - 8.0;
    let lines = title_lines(text, width, size);
    let size = fitting_size(&lines, width, size);
    let centre = area.dim_in_pixel().0 as i32 / 2;
    let style = TextStyle::from((FAMILY, size).into_font()).pos(Pos::new(HPos::Center, VPos::Top));
    for (k, line) in lines.iter().enumerate() {
        let y = 4 + k as i32 * (size * 1.25) as i32;
        area.draw_text(line, &style, (centre, y))
            .map_err(|e| anyhow::anyhow!("drawing a plot: {e:?}"))?;
    }
    Ok(())
}

/// How a legend entry is drawn.
#[derive(Debug, Clone, Copy)]
pub enum Sample {
    /// A line of this colour and width, this many px long.
    Line(RGBColor, u32, i32),
    /// An arrow of this colour.
    Arrow(RGBColor),
    /// A filled disc.
    Dot(RGBColor),
    /// A cross.
    Cross(RGBColor),
    /// A ring with a cross in it.
    Marked(RGBColor),
    /// A filled square.
    Square(RGBColor),
}

/// Rows of a legend strip (px).
pub const LEGEND_ROW: i32 = 26;

/// Draws one legend for a whole figure in `area` (a strip beside the data, never over it):
/// the entries left to right, each a sample and its label at `size` px, in rows of
/// [`LEGEND_ROW`] px: an entry that would not fit the row starts the next.
pub fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    entries: &[(Sample, String)],
    size: f64,
) -> anyhow::Result<()> {
    let fail = |e| anyhow::anyhow!("drawing a plot: {e:?}");
    let width = area.dim_in_pixel().0 as i32;
    let style = TextStyle::from((FAMILY, size).into_font()).pos(Pos::new(HPos::Left, VPos::Center));
    let (mut x, mut y) = (8, LEGEND_ROW / 2);
    for (sample, label) in entries {
        let sample_width = match sample {
            Sample::Line(_, _, length) => *length,
            _ => 16,
        };
        let entry = sample_width + 6 + text_width(label.chars().count(), size) as i32;
        if x > 8 && x + entry > width {
            (x, y) = (8, y + LEGEND_ROW);
        }
        match *sample {
            Sample::Line(colour, stroke, length) => area.draw(&PathElement::new(
                vec![(x, y), (x + length, y)],
                colour.stroke_width(stroke),
            )),
            Sample::Arrow(colour) => {
                let tip = (x + 16, y);
                area.draw(&PathElement::new(vec![(x, y), tip], colour.stroke_width(1)))
                    .and_then(|()| {
                        area.draw(&PathElement::new(
                            arrowhead(tip, (1.0, 0.0), 5.0),
                            colour.stroke_width(1),
                        ))
                    })
            }
            Sample::Dot(colour) => area.draw(&Circle::new((x + 8, y), 2, colour.filled())),
            Sample::Cross(colour) => area.draw(&Cross::new((x + 8, y), 3, colour)),
            Sample::Marked(colour) => area
                .draw(&Circle::new((x + 8, y), 4, colour.stroke_width(1)))
                .and_then(|()| area.draw(&Cross::new((x + 8, y), 3, colour))),
            Sample::Square(colour) => area.draw(&Rectangle::new(
                [(x + 2, y - 5), (x + 14, y + 5)],
                colour.filled(),
            )),
        }
        .map_err(fail)?;
        x += sample_width + 6;
        area.draw_text(label, &style, (x, y)).map_err(fail)?;
        x += text_width(label.chars().count(), size) as i32 + 18;
    }
    Ok(())
}

/// The two barbs of an arrowhead at pixel `tip` for a vector pointing along `direction` (pixel
/// axes, any length): a polyline barb, tip, barb, `length` px back at ±25°.
pub fn arrowhead(tip: (i32, i32), direction: (f64, f64), length: f64) -> Vec<(i32, i32)> {
    let norm = direction.0.hypot(direction.1).max(1e-12);
    let (dx, dy) = (direction.0 / norm, direction.1 / norm);
    let (sin, cos) = 25f64.to_radians().sin_cos();
    let barb = |s: f64| {
        let (bx, by) = (dx * cos - s * dy * sin, s * dx * sin + dy * cos);
        (
            tip.0 - (length * bx).round() as i32,
            tip.1 - (length * by).round() as i32,
        )
    };
    vec![barb(1.0), tip, barb(-1.0)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_as_short_as_their_values() {
        assert_eq!(tick(&100.0), "100");
        assert_eq!(tick(&-4.0), "-4");
        assert_eq!(tick(&0.25), "0.25");
        assert_eq!(tick(&-0.0), "0");
        assert_eq!(tick(&1e-7), "0");
        let bar = bar_tick(8.566);
        assert_eq!(
            (bar(&8.0), bar(&-2.0), bar(&1e-9)),
            ("8".into(), "-2".into(), "0".into())
        );
        let fine = bar_tick(0.19);
        assert_eq!((fine(&0.05), fine(&-0.1)), ("0.05".into(), "-0.10".into()));
    }

    /// A title too wide for its figure is split after a comma, each line fitting.
    #[test]
    fn long_titles_wrap_to_fit() {
        let text = "Torso, frame 2: 1234 points, Z error against truth RMS 0.123 mm, largest |Z error against truth| 0.456 mm";
        assert_eq!(title_lines(text, 2000.0, 13.0).len(), 1);
        let lines = title_lines(text, 700.0, 13.0);
        assert_eq!(lines.len(), 2, "{lines:?}");
        assert!(lines
            .iter()
            .all(|l| text_width(l.chars().count(), 13.0) <= 700.0));
        assert_eq!(lines.concat().replace(' ', ""), text.replace(' ', ""));
    }

    /// The barbs lie behind the tip, symmetric about the vector.
    #[test]
    fn arrowheads_point_along_the_vector() {
        let head = arrowhead((100, 50), (3.0, 0.0), 5.0);
        assert_eq!(head[1], (100, 50));
        assert!(head[0].0 < 100 && head[2].0 < 100);
        assert_eq!(head[0].1 - 50, 50 - head[2].1);
        let down = arrowhead((0, 0), (0.0, 2.0), 5.0);
        assert!(down[0].1 < 0 && down[2].1 < 0);
    }
}
