//! Detection on real photographs (third-party, in `../shared/real-images/`, never copied into
//! the repository; every test skips with a message when the folder is absent).
//!
//! References:
//! - circle grids: the centres OpenCV's `findCirclesGrid` finds on every photo (`opencv_circle_grids.csv`,
//!   written by OpenCV 5.0 with patternSize (7, 7), (7, 13) asymmetric and (5, 5) asymmetric);
//! - dense plates: the dots of OpenCV's `SimpleBlobDetector` (minArea 10) that its lattice walk
//!   labels and that lie wholly inside the image (01: 6597, 02: 1321, 05: 4418); the lattice
//!   residual is that of a robust degree-5 polynomial in the grid indices (OpenCV's blob
//!   centres: 0.0167 px on 01, 0.0228 px on 05 per axis);
//! - IR dots: the counts before the detector was made robust (OpenCV's default blob detector
//!   finds 4, 15 and 2 of them).

use deltaz_measure::detect::Polarity;
use deltaz_measure::grid::walk_grid;
use deltaz_measure::{measure_file, MeasureParams, Measurement};
use nalgebra::{DMatrix, DVector, Vector2};
use std::path::PathBuf;

/// The photo folder, or `None` (a visible skip, [`deltaz_testkit::require`]) when it is absent.
pub(super) fn photos() -> Option<PathBuf> {
    deltaz_testkit::shared_data("real-images")
}

fn measure_photo(path: &std::path::Path, polarity: Polarity) -> Measurement {
    let mut params = MeasureParams::default();
    params.detect.polarity = polarity;
    measure_file(path, &params).unwrap()
}

/// Every circle of OpenCV's `findCirclesGrid` found within 0.25 px, no other target inside the
/// board (its convex hull grown by half a grid step), on all 11 grid photos.
#[test]
fn circle_grid_photos_as_opencv() {
    let Some(dir) = photos() else { return };
    let reference = include_str!("opencv_circle_grids.csv");
    let mut grids: std::collections::BTreeMap<&str, Vec<Vector2<f64>>> = Default::default();
    for line in reference.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        grids
            .entry(f[0])
            .or_default()
            .push(Vector2::new(f[2].parse().unwrap(), f[3].parse().unwrap()));
    }
    let (mut found, mut total) = (0, 0);
    for (image, circles) in &grids {
        let sub = if image.starts_with("acircles") {
            "asymmetric_circles"
        } else {
            "circles"
        };
        let m = measure_photo(
            &dir.join(format!("opencv_extra/{sub}/{image}.png")),
            Polarity::Dark,
        );
        let centres: Vec<Vector2<f64>> = m
            .targets
            .iter()
            .map(|t| Vector2::new(t.col, t.row))
            .collect();
        let nearest = |p: &Vector2<f64>| {
            centres
                .iter()
                .map(|c| (c - p).norm())
                .fold(f64::INFINITY, f64::min)
        };
        let hits = circles.iter().filter(|p| nearest(p) < 0.25).count();
        // The board: inside the hull of the grid, grown by half a step.
        let step = circles
            .iter()
            .map(|p| {
                circles
                    .iter()
                    .filter(|q| *q != p)
                    .map(|q| (q - p).norm())
                    .fold(f64::INFINITY, f64::min)
            })
            .sum::<f64>()
            / circles.len() as f64;
        let hull = convex_hull(circles);
        let false_inside = centres
            .iter()
            .filter(|c| {
                hull_distance(&hull, c) > -step / 2.0
                    && circles.iter().all(|p| (p - *c).norm() >= 1.5)
            })
            .count();
        println!(
            "{image}: {hits}/{} circles, {false_inside} false inside the board, {} targets, rejected {}",
            circles.len(),
            m.targets.len(),
            m.rejection_counts()
        );
        assert_eq!(false_inside, 0, "{image}");
        found += hits;
        total += circles.len();
    }
    println!("circle grids: {found} of {total} (OpenCV: {total})");
    // 640 of 641: circles2's top-right circle is cut by a pasted patch (rejected as not
    // elliptical); OpenCV's grid fit places it all the same.
    assert!(found + 1 >= total, "{found} of {total}");
}

/// The convex hull (counter-clockwise in image coordinates' own orientation) of points.
fn convex_hull(points: &[Vector2<f64>]) -> Vec<Vector2<f64>> {
    let mut p = points.to_vec();
    p.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    let cross = |o: &Vector2<f64>, a: &Vector2<f64>, b: &Vector2<f64>| (a - o).perp(&(b - o));
    let mut hull: Vec<Vector2<f64>> = Vec::new();
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &Vector2<f64>>> = if pass == 0 {
            Box::new(p.iter())
        } else {
            Box::new(p.iter().rev())
        };
        for q in iter {
            while hull.len() >= start + 2
                && cross(&hull[hull.len() - 2], &hull[hull.len() - 1], q) <= 0.0
            {
                hull.pop();
            }
            hull.push(*q);
        }
        hull.pop();
    }
    hull
}

/// Signed distance of `p` from the hull's boundary: positive inside.
fn hull_distance(hull: &[Vector2<f64>], p: &Vector2<f64>) -> f64 {
    (0..hull.len())
        .map(|k| {
            let (a, b) = (hull[k], hull[(k + 1) % hull.len()]);
            let e = b - a;
            e.perp(&(p - a)) / e.norm()
        })
        .fold(f64::INFINITY, f64::min)
}

/// The dots labelled by the lattice walk from the dot nearest the image centre.
fn lattice(dots: &[Vector2<f64>], centre: Vector2<f64>) -> Vec<(Vector2<f64>, (i32, i32))> {
    let start = (0..dots.len())
        .min_by(|&a, &b| {
            (dots[a] - centre)
                .norm()
                .total_cmp(&(dots[b] - centre).norm())
        })
        .unwrap();
    let labels = walk_grid(
        dots,
        start,
        (1000, 1000),
        Vector2::x(),
        Vector2::y(),
        (2000, 2000),
    );
    dots.iter()
        .zip(labels)
        .filter_map(|(d, l)| l.map(|l| (*d, l)))
        .collect()
}

/// The per-axis RMS of a robust degree-5 polynomial fit of the centres against their grid
/// indices (points beyond 5 times the median distance dropped, four rounds), and the number
/// dropped.
fn lattice_residual(labelled: &[(Vector2<f64>, (i32, i32))]) -> (f64, usize) {
    const DEG: i32 = 5;
    let scale = labelled
        .iter()
        .map(|(_, (r, c))| ((r - 1000).abs().max((c - 1000).abs()) + 1) as f64)
        .fold(0.0, f64::max);
    let row = |&(r, c): &(i32, i32)| -> Vec<f64> {
        let (u, v) = (f64::from(c - 1000) / scale, f64::from(r - 1000) / scale);
        (0..=DEG)
            .flat_map(|p| (0..=DEG - p).map(move |q| u.powi(p) * v.powi(q)))
            .collect()
    };
    let mut keep = vec![true; labelled.len()];
    let mut residuals = vec![0.0; labelled.len()];
    let mut rms = 0.0;
    for _ in 0..4 {
        let rows: Vec<usize> = (0..labelled.len()).filter(|&k| keep[k]).collect();
        let design_all = DMatrix::from_fn(
            labelled.len(),
            ((DEG + 1) * (DEG + 2) / 2) as usize,
            |k, j| row(&labelled[k].1)[j],
        );
        let design = design_all.select_rows(&rows);
        let svd = design.clone().svd(true, true);
        let mut sq = vec![0.0; labelled.len()];
        for axis in 0..2 {
            let b = DVector::from_iterator(rows.len(), rows.iter().map(|&k| labelled[k].0[axis]));
            let coef = svd.solve(&b, 1e-12).unwrap();
            let predicted = &design_all * coef;
            for k in 0..labelled.len() {
                sq[k] += (labelled[k].0[axis] - predicted[k]).powi(2);
            }
        }
        for k in 0..labelled.len() {
            residuals[k] = sq[k].sqrt();
        }
        let mut inliers: Vec<f64> = rows.iter().map(|&k| residuals[k]).collect();
        inliers.sort_by(f64::total_cmp);
        let limit = (5.0 * inliers[inliers.len() / 2]).max(0.05);
        rms = (rows.iter().map(|&k| sq[k]).sum::<f64>() / (2.0 * rows.len() as f64)).sqrt();
        for k in 0..labelled.len() {
            keep[k] = residuals[k] < limit;
        }
    }
    (rms, keep.iter().filter(|k| !**k).count())
}

/// The dense plates: ≥ 99 % of the dots wholly inside the image found, ≤ 1 % false
/// detections (targets off the lattice); the two precise plates (01, 05) fit the lattice to
/// ≤ 0.015 px per axis.
#[test]
fn dense_dot_plates() {
    let Some(dir) = photos() else { return };
    for (name, reference, precise) in [
        ("dot_pattern_01", 6597, true),
        ("dot_pattern_02", 1321, false),
        ("dot_pattern_05", 4418, true),
    ] {
        let path = dir.join(format!("discorpy/{name}.jpg"));
        let m = measure_photo(&path, Polarity::Dark);
        let dots: Vec<Vector2<f64>> = m
            .targets
            .iter()
            .map(|t| Vector2::new(t.col, t.row))
            .collect();
        let (w, h) = image::image_dimensions(&path).unwrap();
        let labelled = lattice(&dots, Vector2::new(f64::from(w) / 2.0, f64::from(h) / 2.0));
        let off = dots.len() - labelled.len();
        let (rms, dropped) = lattice_residual(&labelled);
        println!(
            "{name}: {} of {reference} dots on the lattice ({:.2} %), {off} off it, lattice residual {rms:.4} px per axis ({dropped} beyond 5x median), rejected {}",
            labelled.len(),
            100.0 * labelled.len() as f64 / f64::from(reference),
            m.rejection_counts()
        );
        assert!(
            labelled.len() as f64 >= 0.99 * f64::from(reference),
            "{name}"
        );
        assert!(
            off as f64 <= 0.01 * dots.len() as f64,
            "{name}: {off} false"
        );
        if precise {
            assert!(rms <= 0.015, "{name}: {rms}");
            assert!(
                dropped as f64 <= 0.06 * labelled.len() as f64,
                "{name}: {dropped}"
            );
        }
    }
}

/// The projected IR dots: at least as many as before the detector was made robust.
#[test]
fn infrared_dots() {
    let Some(dir) = photos() else { return };
    for (name, before) in [
        ("d435i_Infrared", 3639),
        ("ipad_Infrared_01", 540),
        ("ipad_Infrared_02", 505),
    ] {
        let m = measure_photo(&dir.join(format!("ir-dots/{name}.png")), Polarity::Bright);
        println!(
            "{name}: {} dots (before: {before}), rejected {}",
            m.targets.len(),
            m.rejection_counts()
        );
        assert!(m.targets.len() >= before, "{name}");
    }
}

/// The boards on the grid photos: every circle labelled, in OpenCV's order (see
/// `measure::board`: seen from the front, then column 0 at the left), and on the symmetric boards
/// the same labels when the image border cuts 30 % of the board off.
#[test]
fn circle_grid_boards_labelled() {
    use deltaz_host::io::observations::read_observations;
    use deltaz_measure::board::Board;
    let Some(dir) = photos() else { return };
    let reference = include_str!("opencv_circle_grids.csv");
    let tmp = tempfile::tempdir().unwrap();
    let cases = [
        ("circles/circles1", "circles:7x7", 7),
        ("circles/circles2", "circles:7x7", 7),
        ("circles/circles3", "circles:7x7", 7),
        ("circles/circles4", "circles:7x7", 7),
        ("circles/circles5", "circles:7x7", 7),
        ("circles/circles6", "circles:7x7", 7),
        ("circles/circles7", "circles:7x7", 7),
        ("asymmetric_circles/acircles1", "acircles:7x13", 7),
        ("asymmetric_circles/acircles2", "acircles:7x13", 7),
        ("asymmetric_circles/acircles3", "acircles:7x13", 7),
        ("asymmetric_circles/acircles4", "acircles:5x5", 5),
    ];
    for (image, spec, cols) in cases {
        let stem = image.rsplit('/').next().unwrap();
        let opencv: Vec<Vector2<f64>> = reference
            .lines()
            .filter(|l| l.starts_with(&format!("{stem},")))
            .map(|l| {
                let f: Vec<&str> = l.split(',').collect();
                Vector2::new(f[2].parse().unwrap(), f[3].parse().unwrap())
            })
            .collect();
        let path = dir.join(format!("opencv_extra/{image}.png"));
        let board: Board = spec.parse().unwrap();
        let mut params = MeasureParams::default();
        params.detect.polarity = Polarity::Dark;
        params.board = Some(board);
        let obs = deltaz_host::workflows::observations::measure_images(
            std::slice::from_ref(&path),
            &params,
            None,
        )
        .unwrap()
        .observations;
        assert_eq!(obs.len(), opencv.len(), "{image}");
        // Our index of each OpenCV circle.
        let ours: Vec<usize> = opencv
            .iter()
            .map(|p| {
                let o = obs
                    .iter()
                    .find(|o| (Vector2::new(o.col, o.row) - p).norm() < 0.25)
                    .unwrap_or_else(|| panic!("{image}: OpenCV's {p} not labelled"));
                let (r, c) = o.point[1..].split_once('c').unwrap();
                r.parse::<usize>().unwrap() * cols + c.parse::<usize>().unwrap()
            })
            .collect();
        assert!(
            ours.iter().enumerate().all(|(k, &o)| o == k),
            "{image}: not in OpenCV's order: {ours:?}"
        );
        if spec.starts_with("acircles") {
            // Cut-off asymmetric boards: see the unit test of `measure::board` (synthetic).
            continue;
        }

        // Cut the board's right part off: the circles left keep their labels.
        let full = image::open(&path).unwrap();
        let right = opencv.iter().map(|p| p.x).fold(0.0, f64::max);
        let left = opencv.iter().map(|p| p.x).fold(f64::INFINITY, f64::min);
        let cut = (left + 0.7 * (right - left)) as u32;
        let cropped = tmp.path().join(format!("{stem}.png"));
        full.crop_imm(0, 0, cut, full.height())
            .save(&cropped)
            .unwrap();
        let out = tmp.path().join(format!("{stem}.csv"));
        let status = std::process::Command::new(env!("CARGO_BIN_EXE_deltaz"))
            .args(["measure", "--dark", "--board", spec, "--out"])
            .arg(&out)
            .arg(&cropped)
            .output()
            .unwrap();
        assert!(
            status.status.success(),
            "{image} cut at {cut}: {}",
            String::from_utf8_lossy(&status.stderr)
        );
        let part = read_observations(&out).unwrap();
        let inside = opencv
            .iter()
            .filter(|p| p.x < f64::from(cut) - 25.0)
            .count();
        assert!(
            part.len() >= inside && part.len() < opencv.len(),
            "{image}: {} of {inside}",
            part.len()
        );
        for o in &part {
            let same = obs.iter().find(|f| f.point == o.point).unwrap();
            assert!(
                (same.col - o.col).hypot(same.row - o.row) < 0.05,
                "{image} cut: {} moved",
                o.point
            );
        }
    }
    println!("boards: 11 of 11 labelled in OpenCV's order; 7 of 7 cut symmetric boards labelled as whole");
}

/// `calibrate camera --board ... --plots DIR --json`: one JSON object on stdout, the residual of
/// every labelled circle next to camera.json, and the residual plots of every view.
#[test]
fn board_calibration_writes_residuals_plots_and_json() {
    use deltaz_host::io::observations::read_observations;
    let Some(dir) = photos() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("camera.json");
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .args(["calibrate", "camera", "--board", "circles:7x7", "--images"])
        .arg(dir.join("opencv_extra/circles"))
        .arg("--out")
        .arg(&out)
        .arg("--plots")
        .arg(tmp.path().join("plots"))
        .args(["--json", "--quiet"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success() && stderr.is_empty(), "{stderr}");
    let json: serde_json::Value = serde_json::from_slice(&run.stdout).expect("one JSON object");
    let views = json["stations"].as_array().unwrap().len();
    let observations = read_observations(&out.with_extension("obs.csv")).unwrap();
    let residuals = std::fs::read_to_string(out.with_extension("residuals.csv")).unwrap();
    assert_eq!(residuals.lines().count() - 1, observations.len());
    assert_eq!(observations.len(), 49 * views, "7 × 7 circles per view");
    let vectors = std::fs::read_to_string(tmp.path().join("plots/residual_vectors.svg")).unwrap();
    assert_eq!(vectors.matches(": RMS ").count(), views);
    let histogram =
        std::fs::read_to_string(tmp.path().join("plots/residual_histogram.svg")).unwrap();
    let rejected = residuals.lines().filter(|l| l.ends_with(",1")).count();
    assert!(histogram.contains(&format!(
        "Residuals: {} coordinates",
        2 * (observations.len() - rejected)
    )));
}

/// A board must match its declared geometry: every grid photo is refused under another kind or
/// a smaller size (the message naming the grid found; a larger board may be one cut off by the
/// border, which the rendered boards of `board_geometry` test), and `calibrate camera --board acircles:7x7` on the
/// symmetric photos calibrates nothing.
#[test]
fn wrong_boards_refused_on_photos() {
    use deltaz_measure::board::Board;
    let Some(dir) = photos() else { return };
    let cases = [
        (
            "circles/circles",
            1..=7,
            &["acircles:7x7", "circles:6x7", "circles:7x6"][..],
            "a circles:7x7 grid",
        ),
        (
            "asymmetric_circles/acircles",
            1..=3,
            &["circles:7x13", "acircles:7x12", "acircles:6x13"][..],
            "an acircles:7x13 grid",
        ),
        (
            "asymmetric_circles/acircles",
            4..=4,
            &["circles:5x5", "acircles:4x5", "acircles:5x4"][..],
            "an acircles:5x5 grid",
        ),
    ];
    for (stem, numbers, specs, found) in cases {
        for k in numbers {
            let path = dir.join(format!("opencv_extra/{stem}{k}.png"));
            for spec in specs {
                let mut params = MeasureParams::default();
                params.detect.polarity = Polarity::Dark;
                params.board = Some(spec.parse::<Board>().unwrap());
                let measured = deltaz_host::workflows::observations::measure_images(
                    std::slice::from_ref(&path),
                    &params,
                    None,
                )
                .unwrap();
                let name = format!("{stem}{k} as {spec}");
                assert!(measured.observations.is_empty(), "{name}: accepted");
                let err = measured.failed.join("\n");
                assert!(
                    err.contains(&format!("no {spec} board")) && err.contains(found),
                    "{name}: {err}"
                );
            }
        }
    }
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("camera.json");
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .args(["calibrate", "camera", "--board", "acircles:7x7", "--images"])
        .arg(dir.join("opencv_extra/circles"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success() && !out.exists(), "{err}");
    assert!(
        err.contains("found in 0 image(s)") && err.contains("form a circles:7x7 grid"),
        "{err}"
    );
}
