//! The plots a technician reads (`--plots`), checked in their SVG: one legend per figure, in a
//! strip above the data; arrowheads on residual vectors; rejected observations marked and
//! explained, not drawn as long lines; a scale bar that fits at any magnification; integer
//! ticks without decimals and colour-bar ticks with the digits their step needs; zero errors
//! visible on the page; titles that fit their figure; rays seen on one plate shown as not
//! determined, never at a miss of 0.

use deltaz_host::report::plots::{accuracy_map, ray_misses, residual_histogram, residual_vectors};
use deltaz_host::report::residuals::Residual;

/// Every text of an SVG from plotters: (x, y, font size, content).
fn texts(svg: &str) -> Vec<(f64, f64, f64, String)> {
    let attribute = |tag: &str, name: &str| -> f64 {
        let tag = format!(" {tag}");
        let start = tag.find(&format!(" {name}=\"")).unwrap() + name.len() + 3;
        tag[start..].split('"').next().unwrap().parse().unwrap()
    };
    svg.split("<text ")
        .skip(1)
        .map(|t| {
            let (tag, rest) = t.split_once('>').unwrap();
            let content = rest.split("</text>").next().unwrap().trim().to_owned();
            let size = attribute(tag, "font-size");
            (attribute(tag, "x"), attribute(tag, "y"), size, content)
        })
        .collect()
}

/// The points of every polyline drawn in `colour` (`#RRGGBB`).
fn polylines(svg: &str, colour: &str) -> Vec<Vec<(i32, i32)>> {
    svg.split("<polyline ")
        .skip(1)
        .filter(|p| p.contains(&format!("stroke=\"{colour}\"")))
        .map(|p| {
            let points = p
                .split("points=\"")
                .nth(1)
                .unwrap()
                .split('"')
                .next()
                .unwrap();
            points
                .split_whitespace()
                .map(|xy| {
                    let (x, y) = xy.split_once(',').unwrap();
                    (x.parse().unwrap(), y.parse().unwrap())
                })
                .collect()
        })
        .collect()
}

/// The SVG's width and height (px).
fn size(svg: &str) -> (f64, f64) {
    let tag = svg.split("<svg ").nth(1).unwrap();
    let value = |name: &str| -> f64 {
        tag.split(&format!("{name}=\""))
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap()
            .parse()
            .unwrap()
    };
    (value("width"), value("height"))
}

fn residual(image: &str, observed: [f64; 2], v: [f64; 2], rejected: bool) -> Residual {
    Residual {
        image: image.into(),
        point: "T".into(),
        observed,
        v,
        rejected,
    }
}

/// Four images, 12 residuals each around 0.5 px, and one gross error in image `b`.
fn four_images(magnitude: f64) -> Vec<Residual> {
    let mut r = Vec::new();
    for (k, image) in ["a", "b", "c", "d"].into_iter().enumerate() {
        for j in 0..12 {
            let angle = f64::from(j) * 0.5 + k as f64;
            let at = [60.0 + 55.0 * f64::from(j), 40.0 + 38.0 * f64::from(j)];
            r.push(residual(
                image,
                at,
                [magnitude * angle.cos(), magnitude * angle.sin()],
                false,
            ));
        }
    }
    r.push(residual("b", [400.0, 250.0], [6.0, -4.0], true));
    r
}

#[test]
fn residual_vectors_one_legend_arrowheads_and_rejected_marked() {
    let r = four_images(0.5);
    let svg = residual_vectors(&r, 768, 512).unwrap();
    let all = texts(&svg);
    // One legend for the figure, its entries in a strip above every panel's caption.
    for label in ["target", "residual × ", "1 px of residual"] {
        let found: Vec<_> = all.iter().filter(|t| t.3.starts_with(label)).collect();
        assert_eq!(found.len(), 1, "{label}: {found:?}");
        let caption = all.iter().find(|t| t.3.starts_with("a: RMS")).unwrap();
        assert!(found[0].1 < caption.1, "{label} below the panels");
    }
    // The rejected observation is marked (a ring and a cross in its own colour, no vector) and
    // explained in the legend.
    assert_eq!(
        all.iter()
            .filter(|t| t.3.starts_with("rejected as a gross error"))
            .count(),
        1
    );
    // One marker in its panel, one in the legend: each a ring and a cross of two strokes.
    assert_eq!(svg.matches(r##"stroke="#C800C8""##).count(), 2 * 3);
    // Red: one shaft and one 3-point head per active residual, and the legend's arrow.
    let red = polylines(&svg, "#FF0000");
    let active = r.iter().filter(|x| !x.rejected).count();
    assert_eq!(red.len(), 2 * active + 2);
    assert_eq!(red.iter().filter(|p| p.len() == 3).count(), active + 1);
}

/// At a magnification of 50,000 the scale bar shows a round fraction of a pixel and stays
/// within its strip; at 50 it is 1 px.
#[test]
fn the_scale_bar_fits_at_any_magnification() {
    for magnitude in [0.5, 0.0005] {
        let svg = residual_vectors(&four_images(magnitude), 768, 512).unwrap();
        let (width, _) = size(&svg);
        let all = texts(&svg);
        let text = all
            .iter()
            .find(|t| t.3.ends_with(" px of residual"))
            .unwrap();
        let shown: f64 = text.3.split(' ').next().unwrap().parse().unwrap();
        let bars = polylines(&svg, "#0000FF");
        assert_eq!(bars.len(), 1, "{bars:?}");
        let [(x0, y0), (x1, y1)] = bars[0][..] else {
            panic!("{bars:?}")
        };
        assert_eq!(y0, y1);
        assert!(x0 > 0 && x1 > x0 && x1 - x0 <= 120 && f64::from(x1) < width);
        if magnitude > 0.1 {
            assert_eq!(shown, 1.0);
        } else {
            // The largest of 1, 0.5, 0.2 × 10⁻ⁿ px that fits: the next one up would not.
            let decade = 10f64.powf(shown.log10().floor());
            assert!([1.0, 2.0, 5.0]
                .iter()
                .any(|m| (shown / decade - m).abs() < 1e-9));
            assert!(
                shown < 0.01 && f64::from(x1 - x0) > 120.0 / 2.5,
                "{}",
                text.3
            );
        }
        assert!(
            (f64::from(y0) - text.1).abs() < 12.0,
            "the bar is in the legend strip"
        );
    }
}

/// Tick labels: integers without ".0" on the histogram's count and the rays' id axis; the
/// colour bar of ±8.566 mm in whole mm, of ±0.19 mm in hundredths.
#[test]
fn ticks_without_needless_digits() {
    let r = four_images(0.5);
    let (histogram, _) = residual_histogram(&r).unwrap();
    let rays: Vec<_> = (0..20u16)
        .map(|k| {
            (
                k * 100,
                Some((0.5 + f64::from(k) * 0.01, 1.0 + f64::from(k) * 0.02)),
            )
        })
        .collect();
    let misses = ray_misses(&rays).unwrap();
    for svg in [&histogram, &misses] {
        let labels: Vec<String> = texts(svg).into_iter().map(|t| t.3).collect();
        assert!(!labels.iter().any(|l| l.ends_with(".0")), "{labels:?}");
        assert!(labels.iter().any(|l| l == "0"), "{labels:?}");
    }
    assert!(texts(&misses).iter().any(|t| t.3 == "1000"));
    let points = |limit: f64| -> Vec<(f64, f64, f64)> {
        (0..30)
            .map(|i| {
                (
                    f64::from(i % 6),
                    f64::from(i / 6),
                    limit * (f64::from(i) / 29.0 * 2.0 - 1.0),
                )
            })
            .collect()
    };
    let coarse: Vec<String> = texts(&accuracy_map("t", "Z", &points(8.566)).unwrap())
        .into_iter()
        .map(|t| t.3)
        .collect();
    assert!(
        coarse.iter().any(|l| l == "8") && coarse.iter().any(|l| l == "-8"),
        "{coarse:?}"
    );
    assert!(!coarse.iter().any(|l| l.contains(".000")), "{coarse:?}");
    let fine: Vec<String> = texts(&accuracy_map("t", "Z", &points(0.19)).unwrap())
        .into_iter()
        .map(|t| t.3)
        .collect();
    assert!(
        fine.iter().any(|l| l == "0.10") && fine.iter().any(|l| l == "0"),
        "{fine:?}"
    );
}

/// A long title is set in lines that fit the figure; a zero error is a grey disc with a dark
/// outline, not white on the white page.
#[test]
fn titles_fit_and_zero_errors_show() {
    let points: Vec<(f64, f64, f64)> = (0..12)
        .map(|i| (f64::from(i), f64::from(i % 3), 0.0))
        .collect();
    let title = "Torso, frame 2 of the forward-bent posture, reconstructed through the device";
    let svg = accuracy_map(title, "Z error against truth", &points).unwrap();
    let (width, _) = size(&svg);
    let all = texts(&svg);
    let lines: Vec<_> = all.iter().filter(|t| t.1 < 40.0).collect();
    assert_eq!(lines.len(), 2, "{lines:?}");
    for (x, _, font, text) in &lines {
        let half = 0.6 * font * text.chars().count() as f64 / 2.0;
        assert!(x - half >= 0.0 && x + half <= width, "{text:?} at {x}");
    }
    assert!(
        svg.contains(r##"fill="#D7D7D7""##)
            && !svg.contains(r##"r="4" opacity="1" fill="#FFFFFF""##)
    );
    assert_eq!(
        svg.matches(r##"r="4" opacity="1" fill="none" stroke="#3C3C3C""##)
            .count(),
        points.len()
    );
}

/// Rays seen on one plate: a grey mark in a band below 0 and a legend entry, no RMS or largest
/// marker at 0 mm.
#[test]
fn rays_seen_on_one_plate_are_not_determined() {
    let rays = vec![
        (101, Some((0.4, 0.9))),
        (102, None),
        (103, Some((0.5, 1.1))),
        (104, None),
    ];
    let svg = ray_misses(&rays).unwrap();
    let all = texts(&svg);
    assert_eq!(
        all.iter()
            .filter(|t| t.3.starts_with("seen on one plate: miss not determined"))
            .count(),
        1
    );
    let title: Vec<&str> = all
        .iter()
        .filter(|t| t.1 < 40.0)
        .map(|t| t.3.as_str())
        .collect();
    let title = title.join(" ");
    assert!(
        title.contains("4 rays, 2 seen on one plate, their miss not determined"),
        "{title}"
    );
    // Markers: two RMS discs (and the legend's), two crosses; two grey marks and the legend's.
    assert_eq!(svg.matches(r##"fill="#FF0000""##).count(), 2 + 1);
    assert_eq!(svg.matches(r##"fill="#969696""##).count(), 2 + 1);
    let determined = ray_misses(&[(101, Some((0.4, 0.9)))]).unwrap();
    assert!(!determined.contains("not determined"));
}
