//! A back of the library's own, not the host's model: each section a cosine-bell trunk with
//! a Gaussian groove, rotated by θ(y) about a point 50 mm deep and shifted by u(y), sampled on
//! a square lattice straight along the camera's rays (no projector model, no perspective
//! detail): the symmetry line and the rotation come back within a few σ of the exact values,
//! and a comparison of two scans flags a real change and not the noise.

use deltaz_surface::{
    analyse, compare, thin, BackAnalysis, CommonShare, Frame, Options, ScanPoint, SurfaceError,
};
use nalgebra::{DMatrix, Matrix3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// The rotation (rad) and shift (mm) at height y; `scale` grows the curve.
fn curve(y: f64, scale: f64) -> (f64, f64) {
    let g = (-0.5 * ((y - 60.0) / 90.0).powi(2)).exp();
    (scale * 0.12 * g, scale * 15.0 * g)
}

/// The section's point at arc parameter s, rotated and shifted (x, z).
fn section(s: f64, y: f64, scale: f64) -> (f64, f64) {
    grooved(s, y, scale, 5.0)
}

/// The section with a groove `groove` mm deep.
fn grooved(s: f64, y: f64, scale: f64, groove: f64) -> (f64, f64) {
    let h = 90.0 * ((std::f64::consts::PI * s / 340.0).cos() - 1.0)
        - groove * (-0.5 * (s / 15.0).powi(2)).exp();
    let (theta, u) = curve(y, scale);
    let (sin, cos) = theta.sin_cos();
    (
        u + s * cos - (h + 50.0) * sin,
        -1400.0 - 50.0 + s * sin + (h + 50.0) * cos,
    )
}

/// The surface's z at (x, y): Newton on s.
fn depth(x: f64, y: f64, scale: f64) -> f64 {
    z_at(x, |s| section(s, y, scale))
}

/// The z of a section given as (x, z) at arc length s, at x: Newton on s.
fn z_at(x: f64, section: impl Fn(f64) -> (f64, f64)) -> f64 {
    let mut s = x;
    for _ in 0..40 {
        let (a, b) = (section(s).0, section(s + 1e-4).0);
        s -= (a - x) / ((b - a) / 1e-4);
    }
    section(s).1
}

/// A scan: a 15 mm lattice over ±150 × ±250 mm, σ 0.3 mm in z, a common shift of σ 0.2 mm.
fn scan(scale: f64, seed: u64) -> Frame {
    scan_with(scale, seed, 0.3, 15.0)
}

/// A scan whose points stray by `noise` (mm, in z) while their covariance states 0.3, on a
/// lattice `spacing` apart.
fn scan_with(scale: f64, seed: u64, noise: f64, spacing: f64) -> Frame {
    sampled(|x, y| depth(x, y, scale), seed, noise, spacing)
}

/// The surface z(x, y) sampled as [`scan_with`] does.
fn sampled(z: impl Fn(f64, f64) -> f64, seed: u64, noise: f64, spacing: f64) -> Frame {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, noise).unwrap();
    let common = Normal::new(0.0, 0.2).unwrap().sample(&mut rng);
    let mut points = Vec::new();
    let [ni, nj] = [150.0, 250.0].map(|e: f64| (e / spacing).floor() as i32);
    for j in -nj..=nj {
        for i in -ni..=ni {
            let (x, y) = (spacing * f64::from(i), spacing * f64::from(j));
            let z = z(x, y) + noise.sample(&mut rng) + common;
            let covariance = Matrix3::from_diagonal(&Vector3::new(1e-4, 1e-4, 0.09));
            points.push(ScanPoint {
                position: Vector3::new(x, y, z),
                covariance,
                ray: Some([i, j]),
            });
        }
    }
    Frame {
        points,
        calibration: Some(7),
        common: CommonShare::Shift(Matrix3::from_diagonal(&Vector3::new(0.0, 0.0, 0.04))),
    }
}

/// The RMS of error/σ over the values pushed.
#[derive(Default)]
struct ErrorOverSigma {
    squares: f64,
    count: f64,
}

impl ErrorOverSigma {
    fn push(&mut self, error: f64, sigma: f64) {
        self.squares += (error / sigma).powi(2);
        self.count += 1.0;
    }

    fn rms(&self) -> f64 {
        (self.squares / self.count).sqrt()
    }
}

fn exact(y: f64, scale: f64) -> (f64, f64) {
    let (theta, _) = curve(y, scale);
    (section(0.0, y, scale).0, theta.to_degrees())
}

#[test]
fn symmetry_line_and_rotation_of_a_rotated_section() {
    let (mut zx, mut zr) = (ErrorOverSigma::default(), ErrorOverSigma::default());
    for seed in 0..10 {
        let a = analyse(&[scan(1.0, seed)], &Options::standing()).unwrap();
        assert!(a.levels.len() >= 15, "{} levels", a.levels.len());
        for l in &a.levels {
            let (x, r) = exact(l.y, 1.0);
            zx.push(l.symmetry_x - x, l.symmetry_x_sigma);
            zr.push(l.rotation_deg - r, l.rotation_sigma_deg);
        }
        let peak = a
            .levels
            .iter()
            .map(|l| exact(l.y, 1.0).1)
            .fold(0.0, f64::max);
        assert!((a.rotation_max_deg - peak).abs() < 4.0 * a.rotation_max_deg_sigma + 0.3);
    }
    let (zx, zr) = (zx.rms(), zr.rms());
    assert!(
        zx < 1.6 && zr < 1.6,
        "RMS error/σ: symmetry line {zx:.2}, rotation {zr:.2}"
    );
}

/// Points without their rays (a cloud from elsewhere) are meshed over what the camera sees: on
/// a lattice the Delaunay triangulation of their directions keeps the same back and finds the
/// same spacing, and the analysis reads the same line and rotation within a tenth of their σ.
#[test]
fn points_without_rays_are_meshed_over_what_the_camera_sees() {
    let labelled = scan(1.0, 3);
    let mut unlabelled = labelled.clone();
    for p in &mut unlabelled.points {
        p.ray = None;
    }
    let [a, b] = [labelled, unlabelled].map(|f| analyse(&[f], &Options::standing()).unwrap());
    assert_eq!((a.points, a.levels.len()), (b.points, b.levels.len()));
    assert!((a.spacing_mm - b.spacing_mm).abs() < 0.05 * a.spacing_mm);
    for (p, q) in a.levels.iter().zip(&b.levels) {
        assert!((p.symmetry_x - q.symmetry_x).abs() < 0.1 * p.symmetry_x_sigma);
        assert!((p.rotation_deg - q.rotation_deg).abs() < 0.1 * p.rotation_sigma_deg);
    }
}

/// The surface's misfit along the symmetry line is what the groove leaves out of the fit, not
/// the points' noise: none on the 15 mm lattice beyond the noise's scatter, and on a 25 mm
/// lattice the noisy scans' estimates scatter about the noiseless scan's residual RMS.
#[test]
fn misfit_is_the_detail_not_the_noise() {
    let misfit = |noise: f64, seed: u64, spacing: f64| {
        analyse(
            &[scan_with(1.0, seed, noise, spacing)],
            &Options::standing(),
        )
        .unwrap()
        .misfit_mm
    };
    let resolved: Vec<f64> = (0..10).map(|seed| misfit(0.3, seed, 15.0)).collect();
    let exact = misfit(0.0, 0, 25.0);
    let noisy: Vec<f64> = (0..10).map(|seed| misfit(0.3, seed, 25.0)).collect();
    eprintln!("misfit at 15 mm: noisy {resolved:.3?}");
    let mean = noisy.iter().sum::<f64>() / 10.0;
    eprintln!("misfit: noiseless {exact:.3} mm, noisy {noisy:.3?}");
    // The noise's own scatter: the excess over about 240 residuals, about 10 % of σ² = 0.09.
    assert!(
        resolved.iter().all(|&m| m < 0.15),
        "resolved: {resolved:.3?}"
    );
    assert!(exact > 0.3, "noiseless misfit {exact:.3} mm");
    assert!(
        (mean - exact).abs() < 0.2 * exact,
        "mean {mean:.3} mm against {exact:.3}"
    );
}

#[test]
fn comparison_flags_a_change_not_noise() {
    let analysed = |scale: f64, seed: u64| -> BackAnalysis {
        analyse(&[scan(scale, seed)], &Options::standing()).unwrap()
    };
    let (before, again, worse) = (analysed(1.0, 1), analysed(1.0, 2), analysed(1.5, 3));
    let flagged = |c: &deltaz_surface::Comparison, name: &str| {
        c.indices
            .iter()
            .find(|i| i.name == name)
            .unwrap()
            .exceeds_noise
    };
    let same = compare(&before, &again);
    let changed = compare(&before, &worse);
    assert!(!flagged(&same, "|rotation_max_deg|"));
    assert!(flagged(&changed, "|rotation_max_deg|"));
    let rotation = changed
        .indices
        .iter()
        .find(|i| i.name == "|rotation_max_deg|")
        .unwrap();
    assert!(
        (rotation.change - 0.5 * 0.12f64.to_degrees()).abs() < 1.0,
        "{rotation:?}"
    );
    assert!(!changed.levels.is_empty());
    // The analysis serialises with the fields and reads back.
    let json = serde_json::to_value(&before).unwrap();
    for field in [
        "levels",
        "rotation_max_deg",
        "rotation_max_deg_sigma",
        "rotation_rms_deg",
        "lateral_deviation_max_mm",
        "lateral_deviation_rms_mm",
        "trunk_imbalance_mm",
        "trunk_imbalance_mm_sigma",
    ] {
        assert!(json.get(field).is_some(), "{field}");
    }
    for field in [
        "y",
        "symmetry_x",
        "symmetry_x_sigma",
        "rotation_deg",
        "rotation_sigma_deg",
    ] {
        assert!(json["levels"][0].get(field).is_some(), "{field}");
    }
    let back: BackAnalysis = serde_json::from_value(json).unwrap();
    assert_eq!(back, before);
}

#[test]
fn thinning_keeps_one_point_per_cell() {
    let dense: Vec<Vector3<f64>> = (0..100)
        .flat_map(|j| {
            (0..100).map(move |i| Vector3::new(f64::from(i) * 1.5, f64::from(j) * 1.5, 0.0))
        })
        .collect();
    let kept = thin(&dense, 15.0);
    assert_eq!(kept.len(), 11 * 11);
    for (i, [c, r]) in kept {
        let p = dense[i];
        assert!(
            (p.x - 15.0 * f64::from(c)).abs() <= 1.5 && (p.y - 15.0 * f64::from(r)).abs() <= 1.5
        );
    }
    // A frame thinned keeps those points, each with its cell as its ray and its rows of the
    // common share (here each row holds its point's index and axis).
    let frame = Frame {
        points: dense
            .iter()
            .map(|&position| ScanPoint {
                position,
                covariance: Matrix3::identity(),
                ray: None,
            })
            .collect(),
        calibration: Some(3),
        common: CommonShare::Core {
            covariance: DMatrix::identity(1, 1),
            sensitivity: DMatrix::from_fn(3 * dense.len(), 1, |r, _| r as f64),
        },
    };
    let thinned = frame.thinned(15.0);
    assert_eq!(thinned.calibration, Some(3));
    for (k, (i, node)) in thin(&dense, 15.0).into_iter().enumerate() {
        assert_eq!(thinned.points[k].position, dense[i]);
        assert_eq!(thinned.points[k].ray, Some(node));
        for axis in 0..3 {
            assert_eq!(
                thinned.common.sensitivity(k)[(axis, 0)],
                (3 * i + axis) as f64
            );
        }
    }
}

/// A trunk cut off 75 mm right of the spine, where the symmetry window barely fits: a level
/// whose best symmetry point is the searched range's end (the true one may lie beyond it) is
/// not a level, so each scan either gives its levels within a few σ of the exact line or says
/// that it found none, never a line 30 σ off (as the range's end gave before).
#[test]
fn a_trunk_cut_close_to_the_spine() {
    let mut analysed = 0;
    for seed in 0..5 {
        let mut frame = scan(1.0, seed);
        frame.points.retain(|p| p.position.x < 80.0);
        match analyse(&[frame], &Options::standing()) {
            Ok(a) => {
                analysed += 1;
                for l in &a.levels {
                    let z = (l.symmetry_x - exact(l.y, 1.0).0) / l.symmetry_x_sigma;
                    assert!(z.abs() < 4.0, "seed {seed}, y {:.0}: error/σ {z:.1}", l.y);
                }
            }
            Err(e) => assert!(matches!(e, SurfaceError::NoLevels), "seed {seed}: {e}"),
        }
    }
    assert!(analysed >= 1, "no scan analysed");
}

/// The asymmetry map is odd about the symmetry line (a side against its mirror image, and the
/// mirror image against the side), so its largest value is read on the +x side: positive when
/// that side comes toward the camera, on every scan, where either side's cell may be the
/// larger by the noise. Two scans of one back then compare like for like: read on either side,
/// half of such pairs were flagged as a change of twice the value.
#[test]
fn the_largest_asymmetry_reads_the_right_side() {
    for scale in [1.0, -1.0] {
        let scans: Vec<BackAnalysis> = (0..10)
            .map(|seed| analyse(&[scan(scale, seed)], &Options::standing()).unwrap())
            .collect();
        for (seed, a) in scans.iter().enumerate() {
            let (largest, at) = (a.asymmetry_max_mm.unwrap(), a.asymmetry_max_at.unwrap());
            let line = a
                .levels
                .iter()
                .min_by(|p, q| (p.y - at[1]).abs().total_cmp(&(q.y - at[1]).abs()));
            assert!(at[0] > line.unwrap().symmetry_x, "seed {seed}: at {at:?}");
            assert!(
                largest * scale > 3.0 * a.asymmetry_max_mm_sigma.unwrap(),
                "scale {scale}, seed {seed}: {largest:.2} mm"
            );
        }
        let z: Vec<f64> = scans
            .chunks(2)
            .map(|pair| {
                let c = compare(&pair[0], &pair[1]);
                let name = "asymmetry_max_mm";
                let largest = c.indices.iter().find(|i| i.name == name).unwrap();
                largest.change / largest.sigma
            })
            .collect();
        let rms = (z.iter().map(|z| z * z).sum::<f64>() / z.len() as f64).sqrt();
        assert!(rms < 1.5, "scale {scale}: change/σ {z:.2?}");
    }
}

/// A top edge that cuts the levels obliquely (the trunk's outline or the pattern's field seen
/// through a turned lattice): a level near it holds one side of the trunk only, its candidates
/// all far from the line. It is left out; before, the chain bent the line to it over the levels
/// about it (40-60 σ off at the top on these cuts).
#[test]
fn a_top_edge_cut_obliquely() {
    for (top, slope) in [(200.0, 0.5), (150.0, -0.4), (200.0, -0.4)] {
        for seed in 0..5 {
            let mut frame = scan(1.0, seed);
            frame
                .points
                .retain(|p| p.position.y < top + slope * p.position.x);
            let a = analyse(&[frame], &Options::standing()).unwrap();
            assert!(a.levels.len() >= 20, "{} levels", a.levels.len());
            for l in &a.levels {
                let z = (l.symmetry_x - exact(l.y, 1.0).0) / l.symmetry_x_sigma;
                assert!(
                    z.abs() < 4.0,
                    "cut {top} + {slope} x, seed {seed}, y {:.0}: error/σ {z:.1}",
                    l.y
                );
            }
        }
    }
}

/// A section with two mirror axes: an arc (radius 400 mm) with a groove either side 90 mm
/// apart, one of them between two ridges (so that the section is not symmetric about the
/// middle), is mirror symmetric about either groove within the symmetry window, as the convex
/// sections of a back bent forward are about two axes. The chain prefers the groove between
/// the ridges by 3-45 nats over eight scans, and where it is by less than 10 (the analysis'
/// threshold), the levels say the line is ambiguous, with the other groove as the rival, and
/// the σ of the line and of the rotation hold half the two grooves' difference. The largest
/// rotation's magnitude is the same about either groove, and so is its σ: ambiguous or not,
/// it reads the groove's within 3 σ, σ under 1° (measured 6.68-6.86 ± 0.33-0.36° against
/// 6.45°; with the largest level's own rival its σ was 6.7° on the three ambiguous scans).
/// On a trunk whose sections are not arcs (this file's back) no level is ambiguous.
#[test]
fn two_mirror_axes_make_the_line_ambiguous() {
    const R: f64 = 400.0;
    // Middle, depth and width of each groove (a ridge's depth negative), along the arc's
    // normal there.
    let grooves = [
        (-45.0, 3.0, 6.0),
        (-60.0, -1.5, 4.0),
        (-30.0, -1.5, 4.0),
        (45.0, 3.0, 6.0),
    ];
    // (x, z) at arc length s.
    let section = |s: f64| {
        let depth: f64 = grooves
            .iter()
            .map(|(c, d, w)| d * (-0.5 * ((s - c) / w).powi(2)).exp())
            .sum();
        let (sin, cos) = (s / R).sin_cos();
        (R * sin - depth * sin, -1400.0 - R + R * cos - depth * cos)
    };
    let surface = |x: f64, _y: f64| z_at(x, section);
    let analysed = |seed: u64| {
        let frame = sampled(surface, seed, 0.3, 15.0);
        analyse(&[frame], &Options::standing()).unwrap()
    };
    let groove = |s: f64| R * (s / R).sin();
    // The section's slope at either groove: tan θ = −x / √(R² − x²).
    let tilt = |x: f64| (-x / (R * R - x * x).sqrt()).atan().to_degrees();
    let scans: Vec<BackAnalysis> = (0..8).map(analysed).collect();
    let mut flagged = 0;
    for (k, a) in scans.iter().enumerate() {
        for l in &a.levels {
            let x = l.symmetry_x;
            assert!(
                (x - groove(-45.0)).abs() < 5.0,
                "scan {k}, y {:.0}: line {x:.1}",
                l.y
            );
            if let Some(rival) = l.symmetry_x_rival {
                assert!(
                    (rival - groove(45.0)).abs() < 5.0,
                    "scan {k}: rival {rival:.1}"
                );
                let half = 0.5 * (tilt(groove(-45.0)) - tilt(groove(45.0)));
                let (sx, sr) = (l.symmetry_x_sigma, l.rotation_sigma_deg);
                assert!(
                    sx > 0.95 * 0.5 * (groove(45.0) - groove(-45.0)) && sr > 0.95 * half,
                    "scan {k}, y {:.0}: σ {sx:.1} mm, {sr:.2}°, half the grooves' {half:.2}°",
                    l.y
                );
                flagged += 1;
            }
        }
        let (largest, sigma) = (a.rotation_max_deg.abs(), a.rotation_max_deg_sigma);
        let either = tilt(groove(-45.0)).abs();
        assert!(
            sigma < 1.0 && (largest - either).abs() < 3.0 * sigma,
            "scan {k}: largest rotation {largest:.2} ± {sigma:.2}°, either groove's {either:.2}°"
        );
    }
    assert!(flagged >= 20, "{flagged} levels ambiguous");
    for seed in 0..4 {
        let a = analyse(&[scan(1.0, seed)], &Options::standing()).unwrap();
        let flagged = a.levels.iter().filter(|l| l.symmetry_x_rival.is_some());
        assert_eq!(
            flagged.count(),
            0,
            "seed {seed}: the trunk's line ambiguous"
        );
    }
}

/// A lone level: where the trunk's left side is out of view over a band (its levels too narrow
/// to be levels), one level is left below it at the bottom of the scan. Nothing chains it to
/// the line (a line of one level may take any point its own section allows), so it is left
/// out: every level kept has another within 1.5 spacings and lies within a few σ of the line.
/// Without the rule four scans of five keep it.
#[test]
fn a_lone_level_is_left_out() {
    for seed in 0..5 {
        let mut frame = scan(1.0, seed);
        let hidden = |p: &Vector3<f64>| p.x < 0.0 && (-220.0..-160.0).contains(&p.y);
        frame.points.retain(|p| !hidden(&p.position));
        let a = analyse(&[frame], &Options::standing()).unwrap();
        assert!(
            a.levels.len() >= 20,
            "seed {seed}: {} levels",
            a.levels.len()
        );
        for (k, l) in a.levels.iter().enumerate() {
            let others = a.levels.iter().enumerate().filter(|&(j, _)| j != k);
            let nearest = others.fold(f64::INFINITY, |d, (_, m)| d.min((m.y - l.y).abs()));
            assert!(
                nearest < 1.5 * a.spacing_mm,
                "seed {seed}, y {:.0}: alone, {nearest:.0} mm from the next level",
                l.y
            );
            let z = (l.symmetry_x - exact(l.y, 1.0).0) / l.symmetry_x_sigma;
            assert!(z.abs() < 4.0, "seed {seed}, y {:.0}: error/σ {z:.1}", l.y);
        }
    }
}

/// Wild points: three points of a scan moved along the line of sight (6, −10 and 14 mm, as a
/// misidentified dot or a centroid pulled by a highlight moves them) are found and left out of
/// the fit, exactly those, each placed and off the surface by most of its move, and the
/// symmetry line and rotation are the scan's without the three within a twentieth of their σ;
/// the clean scan has none.
#[test]
fn wild_points_are_left_out_of_the_fit() {
    for seed in 0..3 {
        let clean = scan(1.0, seed);
        let wild = [100, 300, 450];
        let mut moved = clean.clone();
        for (i, by) in wild.into_iter().zip([6.0, -10.0, 14.0]) {
            moved.points[i].position.z += by;
        }
        let others: Vec<usize> = (0..clean.points.len())
            .filter(|i| !wild.contains(i))
            .collect();
        let without = clean.only(&others);
        // Standing, the analysis axes are the camera's x and y.
        let at = wild.map(|i| [0, 1].map(|k| clean.points[i].position[k]));
        let [a, b, c] =
            [clean, moved, without].map(|f| analyse(&[f], &Options::standing()).unwrap());
        assert!(a.wild.is_empty(), "seed {seed}: {:?}", a.wild);
        let found: Vec<[usize; 2]> = b.wild.iter().map(|w| [w.frame, w.point]).collect();
        assert_eq!(found, wild.map(|i| [0, i]), "seed {seed}");
        // Each where it lies, off the surface by most of its move (the surface follows a
        // point a little).
        for ((w, q), by) in b.wild.iter().zip(at).zip([6.0, -10.0, 14.0]) {
            assert!(
                (w.at[0] - q[0]).abs() < 1.0 && (w.at[1] - q[1]).abs() < 1.0,
                "seed {seed}: {w:?}"
            );
            assert!(
                w.residual_mm / by > 0.5 && w.residual_mm / by < 1.0,
                "seed {seed}: {w:?}, moved {by} mm"
            );
        }
        assert_eq!(b.levels.len(), c.levels.len(), "seed {seed}");
        for (l, m) in b.levels.iter().zip(&c.levels) {
            let dx = (l.symmetry_x - m.symmetry_x) / m.symmetry_x_sigma;
            let dr = (l.rotation_deg - m.rotation_deg) / m.rotation_sigma_deg;
            assert!(
                dx.abs() < 0.05 && dr.abs() < 0.05,
                "seed {seed}, y {:.0}: line {dx:.2} σ, rotation {dr:.2} σ",
                l.y
            );
        }
    }
}

/// A wall 400 mm behind the back, seen around it (the lattice's rays beyond the back, a larger
/// surface than it): left out as a plane, listed with its size and depth, and the back is
/// analysed as if alone.
#[test]
fn a_wall_behind_is_left_out() {
    let alone = scan(1.0, 4);
    assert_eq!(alone.points.len(), 21 * 33);
    let mut with_wall = alone.clone();
    let behind = alone.points.iter().map(|p| p.position.z).sum::<f64>() / 693.0 - 400.0;
    for j in -30_i32..=30 {
        for i in -20_i32..=20 {
            if i.abs() > 10 || j.abs() > 16 {
                with_wall.points.push(ScanPoint {
                    position: Vector3::new(15.0 * f64::from(i), 15.0 * f64::from(j), behind),
                    covariance: alone.points[0].covariance,
                    ray: Some([i, j]),
                });
            }
        }
    }
    let [a, b] = [alone, with_wall].map(|f| analyse(&[f], &Options::standing()).unwrap());
    assert!(a.planes_left_out.is_empty());
    let [wall] = &b.planes_left_out[..] else {
        panic!("{:?}", b.planes_left_out)
    };
    assert_eq!((wall.frame, wall.points), (0, 41 * 61 - 21 * 33));
    assert!((wall.beyond_mm - 400.0).abs() < 5.0, "{wall:?}");
    assert_eq!((a.points, a.spacing_mm), (b.points, b.spacing_mm));
    assert_eq!(a.levels.len(), b.levels.len());
    for (p, q) in a.levels.iter().zip(&b.levels) {
        assert!(
            (p.symmetry_x - q.symmetry_x).abs() < 1e-9 * p.symmetry_x_sigma,
            "{p:?} {q:?}"
        );
        assert!((p.rotation_deg - q.rotation_deg).abs() < 1e-9 * p.rotation_sigma_deg);
    }
}

/// A surface of even curvature has no back's symmetry line: each section is about as
/// symmetric about any position across it, asymmetric by its noise alone. A paraboloid, a
/// steeper one and a cylinder scattering by their stated σ are refused standing and bent
/// forward on every draw, their asymmetry about once the noise's (where the line settled on the
/// noise tens of mm off at σ of a few mm), and so is a noise-free paraboloid; the library's
/// back reads tens.
#[test]
fn a_surface_without_a_back_is_refused() {
    type Surface = fn(f64, f64) -> f64;
    let surfaces: [(&str, Surface); 3] = [
        ("paraboloid", |x, y| {
            -1500.0 + 0.0005 * x * x + 0.0003 * y * y
        }),
        ("steep paraboloid", |x, y| {
            -1500.0 + 0.002 * x * x + 0.0003 * y * y
        }),
        ("cylinder", |x, _| -1500.0 + 0.0015 * x * x),
    ];
    let postures = || [Options::standing(), Options::forward_bent()];
    let mut noisy: Vec<f64> = Vec::new();
    for (name, z) in surfaces {
        for seed in 0..9 {
            // The last draw without noise.
            let noise = if seed < 8 { 0.3 } else { 0.0 };
            for options in postures() {
                let asymmetry = match analyse(&[sampled(z, seed, noise, 20.0)], &options) {
                    Err(SurfaceError::LineUndetermined { asymmetry, chi }) => {
                        // Their σ as they scatter: χ about 1 (without noise, under it).
                        assert!(chi < 1.3, "{name}, draw {seed}: χ {chi}");
                        asymmetry
                    }
                    other => panic!("{name}, draw {seed}: {other:?}"),
                };
                if noise > 0.0 {
                    noisy.push(asymmetry);
                } else {
                    assert!(asymmetry < 0.01, "{name} without noise: {asymmetry}");
                }
            }
        }
    }
    let mean = noisy.iter().sum::<f64>() / noisy.len() as f64;
    let most = noisy.iter().fold(0.0, |a: f64, &b| a.max(b));
    eprintln!(
        "featureless surfaces: asymmetry {mean:.2} times the noise's on average, {most:.2} at most \
         ({} analyses)",
        noisy.len()
    );
    assert!((0.4..1.6).contains(&mean), "{mean}");
    for seed in 0..4 {
        for options in postures() {
            let a = analyse(&[scan(1.0, seed)], &options).unwrap();
            assert!(a.asymmetry_over_noise > 30.0, "{}", a.asymmetry_over_noise);
        }
    }
}

/// A back whose features are faint (a 1 mm groove): bent forward its line is flagged
/// (`line_faint`), and rightly, its rotation's errors several times their σ; standing it is
/// not, its σ holding; the usual 5 mm groove is not flagged bent forward.
#[test]
fn faint_features_are_flagged_bent_forward() {
    let faint = |x: f64, y: f64| z_at(x, |s| grooved(s, y, 1.0, 1.0));
    for options in [Options::standing(), Options::forward_bent()] {
        let bent = options.posture == deltaz_surface::Posture::ForwardBent;
        let mut z = ErrorOverSigma::default();
        for seed in 50..60 {
            // A draw may be refused (its asymmetry under 3).
            let Ok(a) = analyse(&[sampled(faint, seed, 0.3, 20.0)], &options) else {
                continue;
            };
            assert_eq!(a.line_faint(), bent, "{}", a.asymmetry_over_noise);
            for l in &a.levels {
                let (_, truth) = exact(l.y, 1.0);
                z.push(l.rotation_deg - truth, l.rotation_sigma_deg);
            }
        }
        let z = z.rms();
        eprintln!("a 1 mm groove, bent forward {bent}: rotation's RMS error/σ {z:.2}");
        assert!(if bent { z > 2.0 } else { z < 1.3 }, "{z}");
        let usual = analyse(&[scan(1.0, 3)], &options).unwrap();
        assert!(!usual.line_faint(), "{}", usual.asymmetry_over_noise);
    }
}

/// A back whose spinous groove fades out toward its top (5 mm deep up to 100 mm, none from
/// 200 mm): where it is gone the sections are nearly as symmetric about any point as a
/// featureless surface's (most of their asymmetry under the refusal's 3 times the noise: 61 of
/// 73 levels, 0.9-5.6), yet each is chained to the grooved levels below, and its σ holds (RMS
/// error/σ 1.12 standing, 1.30 bent forward), six times the grooved levels'. So such levels are
/// kept, not refused one by one as a featureless surface is as a whole.
#[test]
fn levels_past_a_fading_groove_keep_honest_sigma() {
    let groove = |y: f64| 5.0 * ((200.0 - y) / 100.0).clamp(0.0, 1.0);
    let fading = move |x: f64, y: f64| z_at(x, |s| grooved(s, y, 1.0, groove(y)));
    for options in [Options::standing(), Options::forward_bent()] {
        // Error/σ of the line and the rotation and the rotation's σ past the groove; the
        // grooved levels' σ.
        let (mut zx, mut zr) = (ErrorOverSigma::default(), ErrorOverSigma::default());
        let (mut past, mut grooved) = (vec![], vec![]);
        for seed in 0..20 {
            let a = analyse(&[sampled(fading, seed, 0.3, 15.0)], &options).unwrap();
            for l in &a.levels {
                if l.y < 100.0 {
                    grooved.push(l.rotation_sigma_deg);
                } else if l.y >= 195.0 {
                    let (x, r) = exact(l.y, 1.0);
                    zx.push(l.symmetry_x - x, l.symmetry_x_sigma);
                    zr.push(l.rotation_deg - r, l.rotation_sigma_deg);
                    past.push(l.rotation_sigma_deg);
                }
            }
        }
        let (n, zx, zr) = (zx.count, zx.rms(), zr.rms());
        let (past, grooved) = (median(past), median(grooved));
        eprintln!(
            "{:?}, past a fading groove ({n} levels): RMS error/σ line {zx:.2}, rotation {zr:.2}; \
             rotation's σ {past:.2}° against {grooved:.2}° where grooved",
            options.posture
        );
        assert!(n >= 30.0, "{n} levels past the groove");
        assert!(
            (0.7..1.5).contains(&zx) && (0.7..1.5).contains(&zr),
            "{zx:.2}, {zr:.2}"
        );
        assert!(past > 3.0 * grooved, "{past:.2}° against {grooved:.2}°");
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}
