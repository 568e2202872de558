//! Objects never used in calibration, measured from their rendered images only (measure →
//! identify → reconstruct, [`crate::scan::scan_frames`]) with a system calibrated from rendered
//! images only (field → camera, plates → camera and projector, [`calibrate_from_images`]): a
//! sphere's radius and form error, a plane's flatness and the torso's error against its truth,
//! each against the floor propagated from the measured image noise and the calibration's
//! covariance, with the calibration's error common to all points carried through the fits.

use crate::scan::{error_at_floor, propagated, scan_frames, Instrument, Matched};
use deltaz_calib::system_adjustment::PointShares;
use deltaz_host::image_calibration::{calibrate_from_images, Known};
use deltaz_host::simulate::images::{true_rig, write_images, ImageSpec};
use deltaz_host::simulate::objects::{
    object_dots, object_frame, plate_depth, test_objects, Object,
};
use deltaz_host::simulate::Scenario;
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use std::sync::OnceLock;

/// The two geometries: the paper's, and a second with the projector 60 mm further from the
/// camera along X (the plates nearer, where the objects would be, hide distinct targets off the
/// sensor: the layout match then fails).
fn geometries() -> [(&'static str, Scenario); 2] {
    let mut second = Scenario::paper();
    second.rig.projector_centre[0] += 60.0;
    [("paper", Scenario::paper()), ("second", second)]
}

/// Each geometry's system calibrated from its rendered images, once for all the tests.
static CALIBRATED: [OnceLock<Instrument>; 2] =
    [const { OnceLock::new() }, const { OnceLock::new() }];

/// `scenario`'s field and plate images rendered (seed `seed`) and the system calibrated from
/// them alone ([`calibrate_from_images`]).
pub(crate) fn from_images(scenario: &Scenario, seed: u64) -> Instrument {
    let dir = tempfile::tempdir().unwrap();
    let spec = ImageSpec::default();
    write_images(scenario, seed, &spec, dir.path()).unwrap();
    let known = Known::simulated(scenario, &spec, seed).unwrap();
    let cal = calibrate_from_images(&dir.path().join("images"), &known).unwrap();
    let m = &cal.adjustment.model;
    let truth = scenario.camera.inner;
    println!(
        "{}: calibrated from images: f {:.4} mm (true {:.4}), centre {:.2?} mm (σ {:.3?}, true {:.2?}), \
         {} rays, σ0 targets {:.4} px, dots {:.4} px",
        scenario.name,
        m.inner.f,
        truth.f,
        m.centre.as_slice(),
        m.centre_sigma().as_slice(),
        scenario.rig.projector_centre,
        m.rays.len(),
        cal.adjustment.sigma_targets_px,
        m.sigma_dots_px
    );
    Instrument {
        rig: cal.rig,
        model: Some(cal.adjustment.model),
    }
}

/// The scans of the test objects whose names start with `kind`, rendered by geometry `k`'s
/// true rig and measured with its system calibrated from images: the instrument, the objects
/// and their matched dots, frame by frame (identified over the plates' depth ± 130 mm).
fn scanned(
    k: usize,
    scenario: &Scenario,
    kind: &str,
) -> (&'static Instrument, Vec<Object>, Vec<Vec<Matched>>) {
    let instrument = CALIBRATED[k].get_or_init(|| from_images(scenario, 3 + k as u64));
    let truth = true_rig(scenario);
    let depth = plate_depth(scenario);
    let objects: Vec<Object> = test_objects(depth)
        .into_iter()
        .filter(|(name, _)| name.starts_with(kind))
        .map(|(_, o)| o)
        .collect();
    let frames: Vec<_> = objects
        .iter()
        .enumerate()
        .map(|(j, o)| {
            let dots = object_dots(&truth, o);
            (object_frame(&truth, &dots, 70 + j as u64), dots)
        })
        .collect();
    let matched = scan_frames(
        &instrument.rig,
        &frames,
        (depth - 130.0, depth + 130.0),
        0.7,
    );
    (instrument, objects, matched)
}

/// Least-squares fit of a surface with `p` parameters by Gauss-Newton on the residuals
/// `residual(params, point) -> (distance, d distance / d params)`: the parameters, the
/// residuals and the Jacobian.
fn fit(
    start: DVector<f64>,
    points: &[Vector3<f64>],
    residual: impl Fn(&DVector<f64>, &Vector3<f64>) -> (f64, DVector<f64>),
) -> (DVector<f64>, DVector<f64>, DMatrix<f64>) {
    let mut x = start;
    let eval = |x: &DVector<f64>| {
        let rows: Vec<_> = points.iter().map(|p| residual(x, p)).collect();
        let r = DVector::from_iterator(rows.len(), rows.iter().map(|(d, _)| *d));
        let j = DMatrix::from_fn(rows.len(), x.len(), |i, k| rows[i].1[k]);
        (r, j)
    };
    for _ in 0..10 {
        let (r, j) = eval(&x);
        let step = (j.transpose() * &j)
            .lu()
            .solve(&(j.transpose() * r))
            .unwrap();
        x -= step;
    }
    let (r, j) = eval(&x);
    (x, r, j)
}

/// The covariance of the points' distances along `normals` (n × n): the share of the
/// calibration's core common to all, each point's own (image noise and its ray) on the diagonal.
fn normal_covariance(
    shares: &[PointShares],
    normals: &[Vector3<f64>],
    core: &DMatrix<f64>,
) -> DMatrix<f64> {
    let g = DMatrix::from_fn(shares.len(), core.nrows(), |i, k| {
        shares[i].common.column(k).dot(&normals[i])
    });
    let own = DVector::from_iterator(
        shares.len(),
        shares
            .iter()
            .zip(normals)
            .map(|(s, n)| (n.transpose() * (s.image + s.ray) * n)[0]),
    );
    &g * core * g.transpose() + DMatrix::from_diagonal(&own)
}

/// The expected sum of squared residuals of a least-squares fit with Jacobian `j` of
/// observations of covariance `sigma`: tr((I − H) Σ (I − H)), H = J (JᵀJ)⁻¹ Jᵀ.
fn expected_residual2(j: &DMatrix<f64>, sigma: &DMatrix<f64>) -> f64 {
    let n = j.nrows();
    let h = j * (j.transpose() * j).try_inverse().unwrap() * j.transpose();
    let m = DMatrix::identity(n, n) - h;
    (&m * sigma * &m).trace()
}

/// The RMS of the residuals and their floor (the expected squared residuals), over all frames:
/// their ratio checked to be in 0.8-1.25.
fn form_ratio(name: &str, fits: &[(DVector<f64>, f64)]) -> (f64, f64, f64) {
    let n: usize = fits.iter().map(|(r, _)| r.len()).sum();
    let residual2 = fits.iter().map(|(r, _)| r.norm_squared()).sum::<f64>() / n as f64;
    let floor2 = fits.iter().map(|(_, e)| e).sum::<f64>() / n as f64;
    let ratio = (residual2 / floor2).sqrt();
    println!(
        "{name}: {n} points, RMS {:.4} mm, floor {:.4} mm, ratio {ratio:.2}",
        residual2.sqrt(),
        floor2.sqrt()
    );
    assert!((0.8..=1.25).contains(&ratio), "{name}: RMS / floor {ratio}");
    (residual2.sqrt(), floor2.sqrt(), ratio)
}

/// A sphere of 300 mm radius in three frames, for each geometry: the fitted radius within 3 σ
/// of the truth, σ propagated from the image noise and the calibration (its common error
/// included) through the fit, and the form error (the RMS distance of the points from the
/// fitted sphere) at its floor.
#[test]
fn sphere_radius_and_form_from_images() {
    for (k, (geometry, scenario)) in geometries().iter().enumerate() {
        sphere(k, geometry, scenario);
    }
}

fn sphere(k: usize, geometry: &str, scenario: &Scenario) {
    let (instrument, objects, matched) = scanned(k, scenario, "sphere");
    let (_, shares) = propagated(instrument, &matched);
    let core = instrument.core();
    let mut fits = Vec::new();
    for ((object, frame), shares) in objects.iter().zip(&matched).zip(&shares) {
        let Object::Sphere { centre, radius } = *object else {
            unreachable!()
        };
        assert!(frame.len() > 60, "{} dots on the sphere", frame.len());
        let points: Vec<_> = frame.iter().map(|m| m.point).collect();
        // Start from the centroid pushed back along −Z by the truth's radius' order of magnitude.
        let mean = points.iter().sum::<Vector3<f64>>() / points.len() as f64;
        let start = DVector::from_vec(vec![mean.x, mean.y, mean.z - 100.0, 100.0]);
        let (x, r, j) = fit(start, &points, |x, p| {
            let d = p - Vector3::new(x[0], x[1], x[2]);
            let n = d.normalize();
            (
                d.norm() - x[3],
                DVector::from_vec(vec![-n.x, -n.y, -n.z, -1.0]),
            )
        });
        let c = Vector3::new(x[0], x[1], x[2]);
        let normals: Vec<_> = points.iter().map(|p| (p - c).normalize()).collect();
        let sigma = normal_covariance(shares, &normals, &core);
        // Sandwich covariance of the unweighted fit.
        let jtj_inv = (j.transpose() * &j).try_inverse().unwrap();
        let sigma_r = (&jtj_inv * j.transpose() * &sigma * &j * &jtj_inv)[(3, 3)].sqrt();
        let error = x[3] - radius;
        println!(
            "{geometry} sphere: radius error {error:+.4} mm, σ {sigma_r:.4} mm ({:.2} σ), centre off by {:.3} mm",
            error / sigma_r,
            (c - Vector3::from(centre)).norm()
        );
        assert!(
            error.abs() <= 3.0 * sigma_r,
            "radius error {error} mm, σ {sigma_r} mm"
        );
        fits.push((r, expected_residual2(&j, &sigma)));
    }
    form_ratio(&format!("{geometry} sphere form error"), &fits);
}

/// A plane tilted 0.06-0.14 rad at the plates' depth ± 15 mm in three frames, for each geometry: its flatness
/// (the RMS distance of the points from the fitted plane) at its floor.
#[test]
fn plane_flatness_from_images() {
    for (k, (geometry, scenario)) in geometries().iter().enumerate() {
        flatness(k, geometry, scenario);
    }
}

fn flatness(k: usize, geometry: &str, scenario: &Scenario) {
    let (instrument, objects, matched) = scanned(k, scenario, "plane");
    let (_, shares) = propagated(instrument, &matched);
    let core = instrument.core();
    let mut fits = Vec::new();
    for ((object, frame), shares) in objects.iter().zip(&matched).zip(&shares) {
        let Object::Plane { tilt, .. } = *object else {
            unreachable!()
        };
        let points: Vec<_> = frame.iter().map(|m| m.point).collect();
        let mean = points.iter().sum::<Vector3<f64>>() / points.len() as f64;
        let scatter: Matrix3<f64> = points
            .iter()
            .map(|p| (p - mean) * (p - mean).transpose())
            .sum();
        let eigen = scatter.symmetric_eigen();
        let normal = eigen
            .eigenvectors
            .column(eigen.eigenvalues.imin())
            .into_owned();
        let truth = Vector3::new(tilt.sin(), 0.0, tilt.cos());
        assert!(
            normal.dot(&truth).abs() > 0.99999,
            "normal {normal}, truth {truth}"
        );
        let r =
            DVector::from_iterator(points.len(), points.iter().map(|p| (p - mean).dot(&normal)));
        // The fit's Jacobian: the plane's offset and its two tilts (in-plane coordinates).
        let (u, w) = (
            eigen
                .eigenvectors
                .column((eigen.eigenvalues.imin() + 1) % 3),
            eigen
                .eigenvectors
                .column((eigen.eigenvalues.imin() + 2) % 3),
        );
        let j = DMatrix::from_fn(points.len(), 3, |i, c| match c {
            0 => 1.0,
            1 => (points[i] - mean).dot(&u),
            _ => (points[i] - mean).dot(&w),
        });
        let sigma = normal_covariance(shares, &vec![normal; points.len()], &core);
        fits.push((r, expected_residual2(&j, &sigma)));
    }
    form_ratio(&format!("{geometry} plane flatness"), &fits);
}

/// The torso in three frames, for each geometry: the points' error against the true surface points at the floor.
#[test]
fn torso_error_from_images() {
    for (k, (geometry, scenario)) in geometries().iter().enumerate() {
        let (instrument, _, matched) = scanned(k, scenario, "torso");
        error_at_floor(&format!("{geometry} torso"), instrument, &matched);
    }
}

/// `simulate --images`' object files: the torso frames read back from `images/objects/` with
/// their truth from `truth.csv` (one row per dot), scanned at the floor like those rendered in
/// memory; `objects.json` names every frame.
#[test]
fn written_objects_read_back() {
    let scenario = Scenario::paper();
    let dir = tempfile::tempdir().unwrap();
    let n = deltaz_host::simulate::objects::write_objects(&scenario, 5, dir.path()).unwrap();
    assert_eq!(n, 9);
    let out = dir.path().join("images/objects");
    let truth = std::fs::read_to_string(out.join("truth.csv")).unwrap();
    let objects: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("objects.json")).unwrap()).unwrap();
    let frames: Vec<_> = (0..3)
        .map(|k| {
            let name = format!("torso_{k}");
            assert_eq!(objects[&name]["kind"], "torso");
            let dots = truth
                .lines()
                .skip(1)
                .filter_map(|l| {
                    let f: Vec<&str> = l.split(',').collect();
                    let v = |i: usize| f[i].parse::<f64>().unwrap();
                    (f[0] == name).then(|| {
                        (
                            f[1].parse().unwrap(),
                            (v(2), v(3)),
                            Vector3::new(v(4), v(5), v(6)),
                        )
                    })
                })
                .collect::<Vec<_>>();
            let image = image::open(out.join(format!("{name}.png")))
                .unwrap()
                .to_luma8();
            (image, dots)
        })
        .collect();
    let rig = true_rig(&scenario);
    let depth = plate_depth(&scenario);
    let matched = scan_frames(&rig, &frames, (depth - 130.0, depth + 130.0), 0.7);
    let instrument = Instrument { rig, model: None };
    error_at_floor("torso from files", &instrument, &matched);
}
