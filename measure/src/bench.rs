//! Detection timings (`deltaz bench-measure`): rendered dot grids (radius 3-10 px, blur σ 1 px,
//! noise σ 2 DN, gradient background) measured by both centre methods and, as the peer, by
//! OpenCV's `SimpleBlobDetector` in the same run, each with its error against the true centres,
//! and by radius against the Cramér-Rao bound of the centre ([`super::crlb`]). Speed is
//! reported, never asserted.

use super::crlb::rms_bound_8bit;
use super::detect::GrayView;
use super::{measure, CentreMethod, MeasureParams};
use crate::render::{Background, Scene, Spot};
use std::time::Instant;

/// A grid of `cols × rows` dots filling a `width × height` image, radii cycling through
/// `radii`, sub-pixel phases spread over the grid.
pub fn dot_grid(width: usize, height: usize, cols: usize, rows: usize, radii: &[f64]) -> Scene {
    let (pc, pr) = (
        width as f64 / (cols as f64 + 1.0),
        height as f64 / (rows as f64 + 1.0),
    );
    let mut spots = Vec::with_capacity(cols * rows);
    for j in 1..=rows {
        for i in 1..=cols {
            let phase = ((i * 7 + j * 13) % 10) as f64 / 10.0;
            let radius = radii[(i + 3 * j) % radii.len()];
            spots.push(Spot::circle(
                i as f64 * pc + phase,
                j as f64 * pr + 0.7 * phase,
                radius,
                160.0,
            ));
        }
    }
    Scene {
        width,
        height,
        spots,
        background: Background {
            level: 40.0,
            slope_col: 10.0 / width as f64,
            slope_row: 0.0,
            ripple: 4.0,
            ripple_period: width as f64 / 3.0,
        },
        falloff: 0.2,
        blur_sigma: 1.0,
        noise_sigma: 2.0,
        seed: 11,
    }
}

/// The benchmark's two images: 768 × 512 with 440 dots of radius 3-10 px and 12 MP with 4,000.
pub fn cases() -> [(&'static str, Scene); 2] {
    let radii = [3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0];
    [
        ("768 x 512, 440 dots", dot_grid(768, 512, 22, 20, &radii)),
        (
            "4000 x 3000, 4000 dots",
            dot_grid(4000, 3000, 80, 50, &radii),
        ),
    ]
}

/// Each true centre's distance (px) from its nearest found centre, `None` when none is within
/// 0.5 px.
pub fn centre_errors(scene: &Scene, found: &[(f64, f64)]) -> Vec<Option<f64>> {
    // Found centres by cell of 32 pixels, so that matching stays linear.
    let cell = 32.0;
    let mut cells: std::collections::HashMap<(i64, i64), Vec<(f64, f64)>> = Default::default();
    for &(c, r) in found {
        cells
            .entry(((c / cell).floor() as i64, (r / cell).floor() as i64))
            .or_default()
            .push((c, r));
    }
    scene
        .spots
        .iter()
        .map(|s| {
            let (kc, kr) = ((s.col / cell).floor() as i64, (s.row / cell).floor() as i64);
            let best = (-1..=1)
                .flat_map(|dc| (-1..=1).map(move |dr| (kc + dc, kr + dr)))
                .filter_map(|k| cells.get(&k))
                .flatten()
                .map(|&(c, r)| (c - s.col).hypot(r - s.row))
                .fold(f64::INFINITY, f64::min);
            (best < 0.5).then_some(best)
        })
        .collect()
}

/// The RMS of the errors that were found, and how many were.
fn rms_of(errors: impl Iterator<Item = Option<f64>>) -> (f64, usize) {
    let (sum, n) = errors
        .flatten()
        .fold((0.0, 0), |(sum, n), e| (sum + e * e, n + 1));
    ((sum / n.max(1) as f64).sqrt(), n)
}

/// Dots per radius whose Cramér-Rao bound is computed (the bound varies only with the
/// illumination and the sub-pixel phase, so a sample gives its RMS to a fraction of a percent).
const BOUND_SAMPLE: usize = 40;

/// The Cramér-Rao bound on the RMS centre error (px) of the dots of `radius` in `scene`, over
/// about [`BOUND_SAMPLE`] of them spread over the image, for 8-bit images (NaN when a Fisher
/// matrix is singular).
fn bound_of_radius(scene: &Scene, radius: f64) -> f64 {
    let of_radius: Vec<usize> = (0..scene.spots.len())
        .filter(|&i| scene.spots[i].semi_a == radius)
        .collect();
    let step = of_radius.len().div_ceil(BOUND_SAMPLE).max(1);
    let sample = of_radius.into_iter().step_by(step);
    rms_bound_8bit(scene, sample, MeasureParams::default().margin).unwrap_or(f64::NAN)
}

/// OpenCV's `SimpleBlobDetector` on the same image through `python3` (the script
/// `opencv_peer.py`): best time (s) and the keypoints; `Err` says why it could not run.
fn opencv_peer(img: &image::GrayImage, repeats: usize) -> Result<(f64, Vec<(f64, f64)>), String> {
    let dir = std::env::temp_dir().join(format!("deltaz-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
    let (png, script) = (dir.join("image.png"), dir.join("opencv_peer.py"));
    let run = || -> Result<std::process::Output, String> {
        img.save(&png).map_err(|e| e.to_string())?;
        std::fs::write(&script, include_str!("opencv_peer.py")).map_err(|e| e.to_string())?;
        std::process::Command::new("python3")
            .arg(&script)
            .arg(&png)
            .arg(repeats.to_string())
            .output()
            .map_err(|e| format!("python3: {e}"))
    };
    let output = run();
    let _ = std::fs::remove_dir_all(&dir);
    let output = output?;
    if !output.status.success() {
        let err = String::from_utf8_lossy(&output.stderr);
        return Err(err.lines().last().unwrap_or("failed").to_owned());
    }
    let text = String::from_utf8_lossy(&output.stdout);
    let mut lines = text.lines();
    let time = lines
        .next()
        .and_then(|l| l.trim().parse().ok())
        .ok_or("no time printed")?;
    let points = lines
        .filter_map(|l| {
            let mut it = l.split_whitespace().map(str::parse::<f64>);
            Some((it.next()?.ok()?, it.next()?.ok()?))
        })
        .collect();
    Ok((time, points))
}

/// Time `measure` on each case, best of `repeats`, with the centre error against the truth;
/// OpenCV's blob detector as the peer when `python3 -c "import cv2"` works.
pub fn run(repeats: usize) -> String {
    let mut report = String::from(
        "| image | method | found | RMS error (px) | time (ms) | µs per dot | × OpenCV |\n|---|---|---|---|---|---|---|\n",
    );
    let mut notes = String::new();
    let mut by_radius_notes = String::from(
        "\nRMS error by radius against the Cramér-Rao bound of the centre (noise σ² + 1/12 DN², \
         10 parameters as the template fit's, the renderer's image differentiated numerically):\n\
         | image | method | radius (px) | RMS error (px) | bound (px) | × bound |\n|---|---|---|---|---|---|\n",
    );
    for (name, scene) in cases() {
        let mut radii: Vec<f64> = scene.spots.iter().map(|s| s.semi_a).collect();
        radii.sort_by(f64::total_cmp);
        radii.dedup();
        let bounds: Vec<f64> = radii.iter().map(|&r| bound_of_radius(&scene, r)).collect();
        let img = scene.render().to_u8();
        let view = GrayView {
            width: scene.width,
            height: scene.height,
            pixels: img.as_raw().as_slice(),
            dn: 1.0,
        };
        let peer = opencv_peer(&img, repeats);
        let mut rows = Vec::new();
        for method in [CentreMethod::Template, CentreMethod::Gravity] {
            let params = MeasureParams {
                method,
                ..MeasureParams::default()
            };
            let mut best = f64::INFINITY;
            let mut found = Vec::new();
            let mut label = format!("{method:?}");
            for _ in 0..repeats.max(1) {
                let start = Instant::now();
                let m = measure(&view, &params);
                best = best.min(start.elapsed().as_secs_f64());
                found = m.targets.iter().map(|t| (t.col, t.row)).collect();
                let passes: Vec<u32> = m
                    .targets
                    .iter()
                    .filter_map(|t| Some(t.fit?.passes))
                    .collect();
                if !passes.is_empty() {
                    let mean = passes.iter().sum::<u32>() as f64 / passes.len() as f64;
                    label = format!("{method:?} ({mean:.1} passes)");
                }
            }
            rows.push((label, best, found));
        }
        match &peer {
            Ok((time, points)) => {
                rows.push(("OpenCV SimpleBlobDetector".into(), *time, points.clone()))
            }
            Err(why) => notes.push_str(&format!("{name}: OpenCV peer skipped: {why}\n")),
        }
        let peer_time = peer.as_ref().ok().map(|p| p.0);
        for (method, time, found) in rows {
            let errors = centre_errors(&scene, &found);
            let (rms, matched) = rms_of(errors.iter().copied());
            for (&radius, bound) in radii.iter().zip(&bounds) {
                let of_radius = scene.spots.iter().zip(&errors);
                let (e, _) = rms_of(
                    of_radius
                        .filter(|(s, _)| s.semi_a == radius)
                        .map(|(_, e)| *e),
                );
                by_radius_notes.push_str(&format!(
                    "| {name} | {method} | {radius} | {e:.4} | {bound:.4} | {:.2} |\n",
                    e / bound
                ));
            }
            let ratio = peer_time.map_or("-".to_owned(), |t| format!("{:.2}", time / t));
            report.push_str(&format!(
                "| {name} | {method} | {matched}/{} | {rms:.4} | {:.1} | {:.2} | {ratio} |\n",
                scene.spots.len(),
                time * 1e3,
                time * 1e6 / found.len().max(1) as f64,
            ));
        }
    }
    report.push_str(&by_radius_notes);
    report.push_str(&notes);
    report
}
