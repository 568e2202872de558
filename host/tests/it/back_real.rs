//! The real scoliotic backs (ten patients, upright and bent forward; see
//! `back_real_data`), thinned to 15 mm as a dot pattern would see them: every scan analysed,
//! the largest surface rotation (upright) and the virtual scoliometer (bent forward) against
//! the radiographic Cobb angle, on the aligned lattice (there also the rotation against the
//! dense scans' own) and wherever else it may fall. Without the data folder it skips visibly
//! ([`deltaz_testkit::require`]).

use crate::back_real_data::{cobb_angles, correlation, folder, read_ply, thinned, Lattice};
use crate::back_sim::Errors;
use deltaz_surface::{analyse, BackAnalysis, Level, Options};
use nalgebra::{Matrix3, Vector3};
use std::path::{Path, PathBuf};

const SPACING: f64 = 15.0;
/// The scans carry no σ: the structured-light scanner's is taken as 0.5 mm.
const SIGMA: f64 = 0.5;

/// One patient's two analyses.
struct Reading {
    name: String,
    cobb: f64,
    upright: BackAnalysis,
    bent: BackAnalysis,
}

impl Reading {
    fn rotation(&self) -> f64 {
        self.upright.rotation_max_deg.abs()
    }

    fn scoliometer(&self) -> f64 {
        let reading = self.bent.atr_max_deg;
        reading
            .expect("a forward-bent analysis reads the scoliometer")
            .abs()
    }

    /// The analysis bent forward or standing.
    fn pose(&self, bent: bool) -> &BackAnalysis {
        if bent {
            &self.bent
        } else {
            &self.upright
        }
    }

    fn asymmetry(&self) -> f64 {
        let largest = self.upright.asymmetry_max_mm;
        largest
            .expect("an upright analysis has an asymmetry map")
            .abs()
    }
}

/// A patient's two scans, read once.
struct Patient {
    name: String,
    cobb: f64,
    /// (file, vertices) standing and bent forward.
    upright: (PathBuf, Vec<Vector3<f64>>),
    bent: (PathBuf, Vec<Vector3<f64>>),
}

/// Every patient of the data set.
fn patients(dir: &Path) -> Vec<Patient> {
    let scan = |name: &str, pose: &str| {
        let path = dir.join(pose).join(format!("{name}.ply"));
        let points = read_ply(&path).unwrap();
        (path, points)
    };
    cobb_angles(dir)
        .into_iter()
        .map(|(name, cobb)| Patient {
            upright: scan(&name, "upright"),
            bent: scan(&name, "adams"),
            name,
            cobb,
        })
        .collect()
}

/// Every patient's scans thinned on `lattice` and analysed (an analysis that fails panics,
/// naming the scan).
fn readings(patients: &[Patient], lattice: Lattice) -> Vec<Reading> {
    let analysed = |(path, points): &(PathBuf, Vec<Vector3<f64>>), options: Options| {
        analyse(&[thinned(points, SPACING, lattice, SIGMA)], &options)
            .unwrap_or_else(|e| panic!("{} on {lattice:?}: {e}", path.display()))
    };
    patients
        .iter()
        .map(|p| Reading {
            upright: analysed(&p.upright, Options::standing()),
            bent: analysed(&p.bent, Options::forward_bent()),
            name: p.name.clone(),
            cobb: p.cobb,
        })
        .collect()
}

/// r(f, Cobb) over the patients.
fn r(readings: &[Reading], f: fn(&Reading) -> f64) -> f64 {
    let cobb: Vec<f64> = readings.iter().map(|p| p.cobb).collect();
    correlation(&readings.iter().map(f).collect::<Vec<_>>(), &cobb)
}

/// The fewest levels of any scan.
fn fewest_levels(readings: &[Reading]) -> usize {
    let levels = readings.iter().flat_map(|p| [&p.upright, &p.bent]);
    levels.map(|a| a.levels.len()).min().unwrap_or(0)
}

/// r(largest rotation, Cobb), r(scoliometer, Cobb) and r(largest asymmetry, Cobb) on
/// `lattice`, printed, with the floors every lattice holds: 14 levels or more on every scan
/// (the fewest 15-18 over the five placements), r(rotation) ≥ 0.6 and r(asymmetry) ≥ 0.8.
/// (Patient 10's upright scan keeps few: the trunk's left side is out of view over 140 mm above
/// its lowest level, which is then a lone level and left out.)
fn correlations(readings: &[Reading], lattice: Lattice) -> [f64; 3] {
    let measures: [fn(&Reading) -> f64; 3] =
        [Reading::rotation, Reading::scoliometer, Reading::asymmetry];
    let [rotation, atr, asymmetry] = measures.map(|f| r(readings, f));
    let fewest = fewest_levels(readings);
    let least = |bent: bool| {
        let over = readings.iter().map(|p| p.pose(bent).asymmetry_over_noise);
        over.fold(f64::INFINITY, f64::min)
    };
    let (upright, bent) = (least(false), least(true));
    let faint: Vec<&str> = readings
        .iter()
        .filter(|p| p.bent.line_faint())
        .map(|p| p.name.as_str())
        .collect();
    eprintln!("{lattice:?}, {} patients: fewest levels {fewest}, r(largest rotation, Cobb) = {rotation:.3}, r(scoliometer, Cobb) = {atr:.3}, r(largest asymmetry, Cobb) = {asymmetry:.3}; least asymmetry over the noise {upright:.1} upright, {bent:.1} bent forward (on faint features: {faint:?})", readings.len());
    assert!(fewest >= 14, "{lattice:?}: {fewest} levels");
    assert!(
        rotation >= 0.6,
        "{lattice:?}: r(largest rotation, Cobb) = {rotation:.3}"
    );
    assert!(
        asymmetry >= 0.8,
        "{lattice:?}: r(largest asymmetry, Cobb) = {asymmetry:.3}"
    );
    [rotation, atr, asymmetry]
}

// On the aligned lattice, rotation measured 0.691 and the scoliometer 0.678 at 15 mm: below the
// issue's 0.75. Removing the trunk's turn about the vertical (the mean or a linear fit of the
// rotation over the levels, the whole back's best plane or quadric, the width line at the
// pelvis, the shoulders or their mean) lowers r to 0.52-0.69: that turn itself follows the
// Cobb angle (r 0.74), it is the deformity, not the stance. The largest ISIS2 skin angle
// (±10 % of the line's length) gives 0.73; a symmetry window of a third of the width leaves
// too few levels, one of a fifth halves one back's largest rotation (23.6° to 11°; r 0.50).
// The mirror-asymmetry map's largest value (the depth of the rib or loin hump against its
// mirror image, across the whole width, read on the subject's right) measured 0.903, as the
// data set's own asymmetry method reports (0.75-0.91).
#[test]
fn real_backs_against_cobb() {
    let Some(dir) = folder() else { return };
    let lattice = Lattice::default();
    let scans = patients(&dir);
    let patients = readings(&scans, lattice);
    for p in &patients {
        eprintln!(
            "{}: Cobb {}°, largest rotation {:.1} ± {:.1}°, scoliometer {:.1} ± {:.1}°, \
             largest asymmetry {:.1} ± {:.1} mm",
            p.name,
            p.cobb,
            p.upright.rotation_max_deg,
            p.upright.rotation_max_deg_sigma,
            p.scoliometer(),
            p.bent.atr_max_deg_sigma.unwrap(),
            p.asymmetry(),
            p.upright.asymmetry_max_mm_sigma.unwrap()
        );
    }
    // Every patient the data set lists (ten here; more where it holds more).
    assert!(patients.len() >= 10, "{} patients", patients.len());
    let [_, atr, _] = correlations(&patients, lattice);
    assert!(atr >= 0.6, "r(scoliometer, Cobb) = {atr:.3}");
    rotation_against_the_dense_scans(&scans, &patients);
    against_a_denser_pattern(&scans, &patients);
    mirrored(&scans, &patients);
    turned(&scans, &patients);
    upside_down(&scans, &patients);
    without_rays(&scans, &patients);
    through_the_command(&scans[0], &patients[0]);
}

/// A dense scan through `deltaz analyse back` as a cloud from elsewhere (x y z in the camera
/// system, no σ, no frame in its header), thinned by the command (`--thin 15 --sigma 0.5`):
/// the same analysis as the scan thinned here, to the digit.
fn through_the_command(scan: &Patient, reading: &Reading) {
    let dir = tempfile::tempdir().unwrap();
    let points = &scan.upright.1;
    let mut text = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty double x\nproperty double y\n\
         property double z\nend_header\n",
        points.len()
    );
    for p in points {
        text += &format!("{} {} {}\n", p.x, p.y, p.z);
    }
    std::fs::write(dir.path().join("scan.ply"), text).unwrap();
    let (spacing, sigma) = (SPACING.to_string(), SIGMA.to_string());
    let out = crate::cli::deltaz_ok(
        dir.path(),
        &[
            "analyse", "back", "--cloud", "scan.ply", "--sigma", &sigma, "--thin", &spacing,
            "--out", "a", "--json",
        ],
    );
    let analysed: BackAnalysis = serde_json::from_slice(&out.stdout).unwrap();
    let here = &reading.upright;
    eprintln!(
        "{} through the command: {} levels, largest rotation {:.2}° ({:.2}° here)",
        scan.name,
        analysed.levels.len(),
        analysed.rotation_max_deg,
        here.rotation_max_deg
    );
    assert_eq!(analysed.points, here.points);
    assert_eq!(analysed.levels, here.levels);
    assert_eq!(analysed.rotation_max_deg, here.rotation_max_deg);
}

/// The same thinned scans as clouds from elsewhere (their points without their lattice nodes,
/// meshed over what the camera sees): every upright back analysed, its rotation profile that
/// of the lattice's mesh within a fraction of its σ at the levels both hold (RMS change/σ
/// under 0.75 over 10 levels or more; measured 0.02-0.12 over 14-26), and r(largest rotation,
/// Cobb) within 0.03 of it (0.686 against 0.691).
fn without_rays(scans: &[Patient], readings: &[Reading]) {
    let mut largest = Vec::new();
    for (p, reading) in scans.iter().zip(readings) {
        let mut frame = thinned(&p.upright.1, SPACING, Lattice::default(), SIGMA);
        for q in &mut frame.points {
            q.ray = None;
        }
        let a = analyse(&[frame], &Options::standing())
            .unwrap_or_else(|e| panic!("{} without rays: {e}", p.name));
        let change: Errors = changes(&reading.upright.levels, &a.levels, ROTATION, 0.0).collect();
        let (z, n) = (change.z(), change.count());
        eprintln!(
            "{} without rays: {} levels ({} with them), RMS change/σ {z:.2} over {n}, largest \
             rotation {:.1}° ({:.1}°)",
            p.name,
            a.levels.len(),
            reading.upright.levels.len(),
            a.rotation_max_deg,
            reading.upright.rotation_max_deg
        );
        assert!(n >= 10 && z < 0.75, "{}: {z:.2} over {n} levels", p.name);
        largest.push(a.rotation_max_deg.abs());
    }
    let cobb: Vec<f64> = readings.iter().map(|p| p.cobb).collect();
    let (r, with) = (correlation(&largest, &cobb), r(readings, Reading::rotation));
    eprintln!("without rays: r(largest rotation, Cobb) = {r:.3} ({with:.3} with them)");
    assert!((r - with).abs() < 0.03, "{r:.3} against {with:.3}");
}

/// A subject standing turned about the vertical: the surface rotation is the horizontal angle
/// of the surface's normal in the camera's frame, so turning the whole back by θ (about the
/// vertical through its centroid, the +x side toward the camera) turns every level's rotation
/// by θ. Turned by ±2.5° and ±3.5°, each upright back keeps 14 levels or more, its line holds
/// at over half of them, and its rotation profile (the turned analysis' interpolated at the
/// back's levels, [`at`]) moves by θ within σ (RMS of (change − θ)/σ under 1.25): measured
/// 0.06-1.02 per patient, the mean change within 0.14° of θ. Turned further the symmetry search
/// can lose the line: at +5° patient 10 holds a false axis at 20 of its 26 measured levels
/// (its rotation 10.6° below the turned back's), at −5° and up to +7° the others hold. The
/// subject must face the camera within about 3.5°. With the coarse search's odd part (not the
/// reflection about the normal) and no narrowed window at a waist the limit was 2.5°: at +3.5°
/// patient 10 kept 8 levels, at +5° patient 6 kept 9, on false axes.
fn turned(scans: &[Patient], original: &[Reading]) {
    let analysed = |scan: &Patient, theta: f64| {
        let points = &scan.upright.1;
        let (s, c) = theta.to_radians().sin_cos();
        let centre = points.iter().sum::<Vector3<f64>>() / points.len() as f64;
        let turned: Vec<Vector3<f64>> = points
            .iter()
            .map(|p| {
                let (dx, dz) = (p.x - centre.x, p.z - centre.z);
                Vector3::new(centre.x + c * dx - s * dz, p.y, centre.z + s * dx + c * dz)
            })
            .collect();
        let frame = thinned(&turned, SPACING, Lattice::default(), SIGMA);
        analyse(&[frame], &Options::standing())
            .unwrap_or_else(|e| panic!("{} turned {theta}°: {e}", scan.name))
    };
    for theta in [-3.5_f64, -2.5, 2.5, 3.5] {
        for (scan, reading) in scans.iter().zip(original) {
            let a = analysed(scan, theta);
            let change: Errors =
                changes(&reading.upright.levels, &a.levels, ROTATION, theta).collect();
            eprintln!(
                "{} turned {theta:+}°: {} levels, rotation change − turn {:+.2}° mean, RMS/σ {:.2} over {} levels",
                reading.name,
                a.levels.len(),
                change.mean(),
                change.z(),
                change.count()
            );
            assert!(
                a.levels.len() >= 14 && !a.line_mostly_lost(),
                "{} turned {theta}°",
                reading.name
            );
            assert!(
                change.z() < 1.25 && change.count() * 2 >= reading.upright.levels.len(),
                "{} turned {theta}°",
                reading.name
            );
        }
    }
}

/// Each back mirrored left to right is another back, with the opposite curve: its analysis
/// must be the mirror image of the back's, within σ, since the lattice, the surface's grid
/// and the support mask fall on it otherwise (upright the camera's x is mirrored, bent
/// forward its y: the trunk's axis lies along x). Per patient, the largest rotation and the
/// largest scoliometer reading change sign and keep their magnitude within 2.5 σ of the
/// difference, and the rotation profile's RMS of sum/σ over the levels both keep is under 2
/// (as between lattice placements, [`agree_within_sigma`]). Measured: rotation profiles
/// 0.00-0.07, the largest rotation and scoliometer reading 0.3 σ apart at most. This found
/// an ambiguous level whose two symmetry points were both refined onto one (patient 10:
/// 20.1 ± 0.6° against 25.2° mirrored, the profile 2.6; now 25.2 ± 2.5°). The largest
/// asymmetry is reported, not asserted: it is read on the map's cells, a grid step apart
/// from where the measured surface begins, and where a hump's peak falls between two cells
/// the mirror image reads it apart by 0.2-1.4 σ, and by 4.9 mm (4.4 σ) on patient 10. Two
/// remedies were measured and not kept: read between the cells (the largest within a step of
/// its cell), patient 10 came to 1.9 σ, but the value moved toward the measured surface's
/// edge, where the simulated backs' error/σ rose from 0.84-1.76 to 1.03-2.20; a σ term for
/// the cells' phase (|∂A/∂a| × step / √12) brought every mirror image within 1.4 σ, but put
/// the simulated curves' error/σ (against the truth at the same cell) at 0.32-0.50.
fn mirrored(scans: &[Patient], original: &[Reading]) {
    let mirror = |(path, points): &(PathBuf, Vec<Vector3<f64>>), axis: usize| {
        let flipped = points.iter().map(|p| {
            let mut q = *p;
            q[axis] = -q[axis];
            q
        });
        (path.clone(), flipped.collect())
    };
    let flipped: Vec<Patient> = scans
        .iter()
        .map(|p| Patient {
            name: p.name.clone(),
            cobb: p.cobb,
            upright: mirror(&p.upright, 0),
            bent: mirror(&p.bent, 1),
        })
        .collect();
    for (p, q) in original.iter().zip(readings(&flipped, Lattice::default())) {
        let largest: [(&str, [f64; 2], [f64; 2]); 3] = [
            (
                "largest rotation",
                [p.upright.rotation_max_deg, p.upright.rotation_max_deg_sigma],
                [q.upright.rotation_max_deg, q.upright.rotation_max_deg_sigma],
            ),
            (
                "largest scoliometer reading",
                [
                    p.bent.atr_max_deg.unwrap(),
                    p.bent.atr_max_deg_sigma.unwrap(),
                ],
                [
                    q.bent.atr_max_deg.unwrap(),
                    q.bent.atr_max_deg_sigma.unwrap(),
                ],
            ),
            (
                "largest asymmetry",
                [
                    p.upright.asymmetry_max_mm.unwrap(),
                    p.upright.asymmetry_max_mm_sigma.unwrap(),
                ],
                [
                    q.upright.asymmetry_max_mm.unwrap(),
                    q.upright.asymmetry_max_mm_sigma.unwrap(),
                ],
            ),
        ];
        let mut profile = Errors::default();
        for l in &p.upright.levels {
            // The levels lie alike: the mirror leaves the heights as they are.
            if let Some(m) = q.upright.levels.iter().find(|m| (m.y - l.y).abs() < 0.5) {
                let sigma = l.rotation_sigma_deg.hypot(m.rotation_sigma_deg);
                profile.push(l.rotation_deg + m.rotation_deg, sigma);
            }
        }
        let apart: Vec<String> = largest
            .iter()
            .map(|(name, [a, sa], [b, sb])| {
                let z = (a + b).abs() / sa.hypot(*sb);
                // The largest asymmetry is reported only (the doc above).
                let asserted = !name.ends_with("asymmetry");
                assert!(
                    !asserted || z < 2.5,
                    "{} mirrored: {name} {a:.1} ± {sa:.1} against {b:.1} ± {sb:.1}",
                    p.name
                );
                format!("{name} {a:+.1} ± {sa:.1} against {b:+.1} ± {sb:.1} ({z:.1} σ)")
            })
            .collect();
        eprintln!(
            "{} mirrored: rotation profile RMS sum/σ {:.2} over {} levels; {}",
            p.name,
            profile.z(),
            profile.count(),
            apart.join(", ")
        );
        assert!(
            profile.z() < 2.0 && profile.count() * 4 >= p.upright.levels.len() * 3,
            "{}",
            p.name
        );
    }
}

/// The surface rotation at 15 mm against the dense scan's own (40,000-55,000 points 1.5 mm
/// apart): at each level, the slope at the symmetry point of the quadratic fitted to the dense
/// points within 3 mm of the level and the symmetry window of the point. The two estimators
/// differ where the window is not symmetric (the mirror axis' tilt against a slope); measured,
/// per patient, 0.20-0.75° RMS over the levels, 2.3° at worst, and the largest rotations within
/// 1.2°. The dense scans' largest rotation correlates with the Cobb angle at 0.703 (the thinned
/// scans' at 0.691): below the 0.75 is the surface at the line, not the dot pattern.
fn rotation_against_the_dense_scans(scans: &[Patient], readings: &[Reading]) {
    let mut largest = Vec::new();
    for (scan, reading) in scans.iter().zip(readings) {
        let a = &reading.upright;
        let (mut errors, mut worst, mut dense_max) = (Errors::default(), 0.0_f64, 0.0_f64);
        for l in &a.levels {
            let dense = dense_rotation(&scan.upright.1, l, a.symmetry_window_mm);
            errors.push(l.rotation_deg - dense, l.rotation_sigma_deg);
            worst = worst.max((l.rotation_deg - dense).abs());
            dense_max = dense_max.max(dense.abs());
        }
        let (rms, thinned_max) = (errors.rms(), a.rotation_max_deg.abs());
        eprintln!(
            "{}: rotation against the dense scan {rms:.2}° RMS, {worst:.2}° at worst; \
             largest {thinned_max:.1}°, dense {dense_max:.1}°",
            reading.name
        );
        assert!(rms < 1.0 && worst < 2.5, "{}", reading.name);
        assert!((thinned_max - dense_max).abs() < 1.5, "{}", reading.name);
        largest.push(dense_max);
    }
    let cobb: Vec<f64> = readings.iter().map(|p| p.cobb).collect();
    let r = correlation(&largest, &cobb);
    eprintln!("r(the dense scans' largest rotation, Cobb) = {r:.3}");
}

/// The upright analyses at 15 mm against the same backs thinned to 7.5 mm on the same lattice,
/// the surface smoothed over the same length (`Options::smoothing` is in dot spacings): at
/// each level, the symmetry line and the rotation differ from the denser analysis' (between
/// its two levels about it, [`at`]) by what the 15 mm σ states, on real skin. Measured, per
/// patient, RMS of difference/σ 0.15-1.13 for the line (0.5-1.3 mm RMS; 6.5 mm on patient 10,
/// whose top levels are ambiguous, their σ holding both axes) and 0.22-1.25 for the rotation
/// (0.07-1.1° RMS); asserted under 1.5, on at least three levels in four. Each smoothed over
/// its own spacing, the two differ beyond σ on three backs (line up to 4.6, rotation up to
/// 4.6): the scale follows the spacing ([`deltaz_surface::compare`]).
fn against_a_denser_pattern(scans: &[Patient], readings: &[Reading]) {
    let denser_by = 2.0;
    let options = Options {
        smoothing: denser_by * Options::standing().smoothing,
        ..Options::standing()
    };
    for (scan, reading) in scans.iter().zip(readings) {
        let thinned = thinned(
            &scan.upright.1,
            SPACING / denser_by,
            Lattice::default(),
            SIGMA,
        );
        let denser = analyse(&[thinned], &options)
            .unwrap_or_else(|e| panic!("{} at 7.5 mm: {e}", scan.upright.0.display()));
        let [line, rotation] = [LINE, ROTATION].map(|field| {
            let mut errors = Errors::default();
            for l in &reading.upright.levels {
                if let (Some((value, sigma)), Some((reference, _))) =
                    (field(l), at(&denser.levels, l.y, field))
                {
                    errors.push(value - reference, sigma);
                }
            }
            errors
        });
        eprintln!(
            "{}: against 7.5 mm, {} levels: line {:.2} mm RMS (difference/σ {:.2}), rotation \
             {:.2}° ({:.2})",
            reading.name,
            line.count(),
            line.rms(),
            line.z(),
            rotation.rms(),
            rotation.z()
        );
        assert!(
            line.count() * 4 >= reading.upright.levels.len() * 3,
            "{}",
            reading.name
        );
        assert!(line.z() < 1.5 && rotation.z() < 1.5, "{}", reading.name);
    }
}

/// The slope (degrees) at `level`'s symmetry point of the quadratic in x fitted to the dense
/// `points` within 3 mm of the level and `window` of the point (camera system: standing, the
/// analysis axes are the camera's).
fn dense_rotation(points: &[Vector3<f64>], level: &Level, window: f64) -> f64 {
    let near =
        |p: &&Vector3<f64>| (p.y - level.y).abs() < 3.0 && (p.x - level.symmetry_x).abs() < window;
    let (mut normal, mut rhs) = (Matrix3::zeros(), Vector3::zeros());
    for p in points.iter().filter(near) {
        let d = p.x - level.symmetry_x;
        let row = Vector3::new(1.0, d, d * d);
        normal += row * row.transpose();
        rhs += row * p.z;
    }
    let c = normal
        .lu()
        .solve(&rhs)
        .expect("a level's dense strip fits a quadratic");
    c[1].atan().to_degrees()
}

/// Where the dots fall on a back is chance: shifted by half a spacing or turned by 7°, the
/// lattice still gives every scan 14 levels or more, and the correlations move by what the
/// lattice's sampling of ten backs allows. Measured (rotation, scoliometer, asymmetry):
/// aligned 0.69/0.68/0.90; these four 0.67-0.72, 0.63-0.69, 0.89-0.90. The rotation's and the
/// asymmetry's floors hold on each, and each back's largest asymmetry keeps its sign (the
/// side nearer the camera) on every placement. Bent forward, the lumbar sections of some
/// backs are convex arcs with two mirror axes, and the lattice decides which one the line
/// takes: those levels say so, and their σ holds both ([`agree_within_sigma`]). The
/// scoliometer's r is reported, not asserted, and so is each back's largest reading on each
/// placement: a lone level at the line's end, which moved one back's from +4.9 ± 2.1° to
/// −11.2 ± 0.6°, is left out (its five readings −4.0 to −5.7°), and so is a pair of levels
/// there across a gap (patient 2 read +15.2 ± 4.7° on one placement and −9.0 to −9.7° on the
/// others, the thoracic levels' reading or the lumbar ones'; now −9.0 to −9.7° on all five),
/// but the largest still moves where the line is ambiguous (patient 8: +1.9 ± 1.6° on one
/// placement, −2.8 to −5.6° on the others).
#[test]
fn real_backs_wherever_the_lattice_falls() {
    let Some(dir) = folder() else { return };
    let scans = patients(&dir);
    let placements = [
        ([0.5, 0.0], 0.0),
        ([0.0, 0.5], 0.0),
        ([0.5, 0.5], 0.0),
        ([0.3, 0.6], -7.0),
    ];
    let mut sides: Option<Vec<bool>> = None;
    let mut placed = vec![readings(&scans, Lattice::default())];
    for (offset, turn_deg) in placements {
        let lattice = Lattice { offset, turn_deg };
        let patients = readings(&scans, lattice);
        correlations(&patients, lattice);
        let nearer: Vec<bool> = patients
            .iter()
            .map(|p| p.upright.asymmetry_max_mm > Some(0.0))
            .collect();
        let first = sides.get_or_insert_with(|| nearer.clone());
        assert_eq!(&nearer, first, "{lattice:?}: the side nearer the camera");
        placed.push(patients);
    }
    // Standing square to the camera, every back's line holds at half its levels or more
    // (measured 54 % at the fewest: patient 10, 14 of 26 on two placements).
    for p in placed.iter().flatten() {
        let a = &p.upright;
        assert!(
            !a.line_mostly_lost(),
            "{}: the line at {} levels, not found at {}",
            p.name,
            a.levels.len(),
            a.levels_left_out.len()
        );
    }
    agree_within_sigma(&placed);
    for (i, patient) in placed[0].iter().enumerate() {
        let largest: Vec<String> = placed
            .iter()
            .map(|p| {
                let bent = &p[i].bent;
                let (atr, sigma) = (bent.atr_max_deg.unwrap(), bent.atr_max_deg_sigma.unwrap());
                format!("{atr:+.1} ± {sigma:.1}°")
            })
            .collect();
        eprintln!(
            "{}: largest scoliometer reading per placement {}",
            patient.name,
            largest.join(", ")
        );
    }
}

/// A level's value and σ, where it has one.
type Field = fn(&Level) -> Option<(f64, f64)>;

/// The symmetry line's field.
const LINE: Field = |l| Some((l.symmetry_x, l.symmetry_x_sigma));
/// The surface rotation's.
const ROTATION: Field = |l| Some((l.rotation_deg, l.rotation_sigma_deg));

/// The value of `field` at level y, linear between the two levels about it (None beyond the
/// ends, across a level left out, or where either has no value).
fn at(levels: &[Level], y: f64, field: Field) -> Option<(f64, f64)> {
    let k = levels.partition_point(|l| l.y < y);
    let (p, q) = (levels.get(k.checked_sub(1)?)?, levels.get(k)?);
    let ((a, sa), (b, sb)) = (field(p)?, field(q)?);
    let t = (y - p.y) / (q.y - p.y);
    (q.y - p.y < 1.5 * SPACING).then_some(((1.0 - t) * a + t * b, (1.0 - t) * sa + t * sb))
}

/// The changes of `field` from the levels `from` to `to` (interpolated there, [`at`]), less
/// `expected`, each with the σ of its two values.
fn changes<'a>(
    from: &'a [Level],
    to: &'a [Level],
    field: Field,
    expected: f64,
) -> impl Iterator<Item = (f64, f64)> + 'a {
    from.iter().filter_map(move |l| {
        let ((a, sa), (b, sb)) = (field(l)?, at(to, l.y, field)?);
        Some((b - a - expected, sa.hypot(sb)))
    })
}

/// Each patient's profiles on every two lattice placements agree within their σ, level by
/// level: the RMS of change/σ of the symmetry line and the rotation (standing) and the
/// scoliometer (bent forward) is under 2 on every patient. Measured 0.3-0.8 for the line and
/// the rotation, 0.9-1.5 for the scoliometer; without the rival axis' term in σ the line of
/// patient 10 (a second axis 45 mm aside over its upper back) was at 2.05 and its scoliometer
/// (two axes over 17 levels, the lattice taking either) at 7.3.
fn agree_within_sigma(placed: &[Vec<Reading>]) {
    // Each profile: its name, whether it is read bent forward, its field.
    let fields: [(&str, bool, Field); 3] = [
        ("symmetry line", false, LINE),
        ("rotation", false, ROTATION),
        ("scoliometer", true, |l| {
            Some((l.atr_deg?, l.atr_sigma_deg?))
        }),
    ];
    for (i, patient) in placed[0].iter().enumerate() {
        for (name, bent, field) in fields {
            let pairs = placed
                .iter()
                .enumerate()
                .flat_map(|(a, ra)| placed[a + 1..].iter().map(move |rb| (ra, rb)));
            let change: Errors = pairs
                .flat_map(|(ra, rb)| {
                    let (la, lb) = (&ra[i].pose(bent).levels, &rb[i].pose(bent).levels);
                    changes(la, lb, field, 0.0)
                })
                .collect();
            let (z, n) = (change.z(), change.count());
            eprintln!(
                "{}: {name}, RMS change/σ between placements {z:.2} ({n} levels)",
                patient.name
            );
            assert!(
                n >= 100 && z < 2.0,
                "{}: {name}: {z:.2} ({n} levels)",
                patient.name
            );
        }
    }
}

/// Each back turned upside down (a camera mounted so, or a cloud whose +y points to the feet:
/// (x, y) → (−x, −y)) is analysed as told, but its sagittal profile says so
/// ([`BackAnalysis::looks_upside_down`]); told `--vertical 0,-1,0`, it is the back again: the
/// largest rotation, its sign and σ, and the excess within 0.01 of the back's (the lattice falls
/// alike: its nodes are symmetric about the camera's axis). Measured: the mid-height excess +7 to +23°
/// standing, −6 to −22° upside down.
fn upside_down(scans: &[Patient], original: &[Reading]) {
    for (scan, reading) in scans.iter().zip(original) {
        let turned: Vec<Vector3<f64>> = scan
            .upright
            .1
            .iter()
            .map(|p| Vector3::new(-p.x, -p.y, p.z))
            .collect();
        let frame = || thinned(&turned, SPACING, Lattice::default(), SIGMA);
        let as_told = analyse(&[frame()], &Options::standing()).unwrap();
        let mut options = Options::standing();
        options.vertical = Some(-Vector3::y());
        let righted = analyse(&[frame()], &options).unwrap();
        let [(a, sa), (b, sb)] =
            [&reading.upright, &righted].map(|x| (x.rotation_max_deg, x.rotation_max_deg_sigma));
        eprintln!(
            "{} upside down: mid-height excess {:+.1}° (standing {:+.1}°, righted {:+.1}°); largest rotation righted {b:+.1} ± {sb:.1}° against {a:+.1} ± {sa:.1}°",
            scan.name,
            as_told.sagittal_mid_excess_deg().unwrap(),
            reading.upright.sagittal_mid_excess_deg().unwrap(),
            righted.sagittal_mid_excess_deg().unwrap(),
        );
        assert!(!reading.upright.looks_upside_down(), "{}", scan.name);
        assert!(as_told.looks_upside_down(), "{} upside down", scan.name);
        assert!(!righted.looks_upside_down(), "{} righted", scan.name);
        let excess = [&reading.upright, &righted].map(|x| x.sagittal_mid_excess_deg().unwrap());
        assert!(
            (a - b).abs() < 0.01 && (sa - sb).abs() < 0.01 && (excess[0] - excess[1]).abs() < 0.01,
            "{} righted",
            scan.name
        );
    }
}
