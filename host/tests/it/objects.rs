//! Objects never used in calibration, measured from their rendered images only (measure →
//! identify → reconstruct, [`crate::scan::scan_frames`]): a sphere's radius and form error, a
//! plane's flatness and the torso's error against its truth, each against the floor propagated
//! from the measured image noise.

use crate::scan::{error_at_floor, frame, propagated, scan_frames, Matched};
use deltaz_host::simulate::objects::{plate_depth, test_objects, Object};
use deltaz_host::simulate::{images::true_rig, Scenario};
use deltaz_host::system::SystemRig;
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

/// The two geometries: the paper's, and a second with the plates (hence the objects) 300 mm
/// nearer and the projector 60 mm further from the camera along X.
fn geometries() -> [(&'static str, Scenario); 2] {
    let mut second = Scenario::paper();
    for pose in &mut second.plate.images {
        pose.Z0 -= 300.0;
    }
    second.rig.projector_centre[0] += 60.0;
    [("paper", Scenario::paper()), ("second", second)]
}

/// The scans by `scenario`'s true rig of the test objects whose names start with `kind`: the
/// objects and their matched dots, frame by frame (identified over the plates' depth ± 130 mm).
fn scanned(scenario: &Scenario, kind: &str) -> (SystemRig, Vec<Object>, Vec<Vec<Matched>>) {
    let rig = true_rig(scenario);
    let depth = plate_depth(scenario);
    let objects: Vec<Object> = test_objects(depth)
        .into_iter()
        .filter(|(name, _)| name.starts_with(kind))
        .map(|(_, o)| o)
        .collect();
    let frames: Vec<_> = objects
        .iter()
        .enumerate()
        .map(|(k, o)| frame(&rig, o, 70 + k as u64))
        .collect();
    let matched = scan_frames(&rig, &frames, (depth - 130.0, depth + 130.0), 0.7);
    (rig, objects, matched)
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

/// The variance of each point along `normals` under its propagated covariance.
fn normal_variances(covariances: &[Matrix3<f64>], normals: &[Vector3<f64>]) -> Vec<f64> {
    covariances
        .iter()
        .zip(normals)
        .map(|(c, n)| (n.transpose() * c * n)[0])
        .collect()
}

/// The RMS of the residuals and their floor (the propagated normal variances less the `p`
/// fitted parameters' share), over all frames.
fn form_ratio(name: &str, fits: &[(DVector<f64>, Vec<f64>)], p: usize) -> (f64, f64, f64) {
    let n: usize = fits.iter().map(|(r, _)| r.len()).sum();
    let residual2 = fits.iter().map(|(r, _)| r.norm_squared()).sum::<f64>() / n as f64;
    let floor2 = fits
        .iter()
        .map(|(r, v)| v.iter().sum::<f64>() * (r.len() - p) as f64 / r.len() as f64)
        .sum::<f64>()
        / n as f64;
    let ratio = (residual2 / floor2).sqrt();
    println!(
        "{name}: {n} points, RMS {:.4} mm, floor {:.4} mm, ratio {ratio:.2}",
        residual2.sqrt(),
        floor2.sqrt()
    );
    assert!((0.8..=1.25).contains(&ratio), "{name}: RMS / floor {ratio}");
    (residual2.sqrt(), floor2.sqrt(), ratio)
}

/// A sphere of 300 mm radius in three frames, for each geometry: the fitted radius within 3 σ of the truth, σ
/// propagated from the image noise through the fit, and the form error (the RMS distance of
/// the points from the fitted sphere) at its floor.
#[test]
fn sphere_radius_and_form_from_images() {
    for (geometry, scenario) in geometries() {
        sphere(geometry, &scenario);
    }
}

fn sphere(geometry: &str, scenario: &Scenario) {
    let (rig, objects, matched) = scanned(scenario, "sphere");
    let (_, covariances) = propagated(&rig, &matched);
    let mut fits = Vec::new();
    for ((object, frame), covariances) in objects.iter().zip(&matched).zip(&covariances) {
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
        let v = normal_variances(covariances, &normals);
        // Sandwich covariance of the unweighted fit.
        let jtj_inv = (j.transpose() * &j).try_inverse().unwrap();
        let meat = j.transpose() * DMatrix::from_diagonal(&DVector::from_vec(v.clone())) * &j;
        let sigma_r = (&jtj_inv * meat * &jtj_inv)[(3, 3)].sqrt();
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
        assert!(sigma_r < 0.05, "radius σ {sigma_r} mm");
        fits.push((r, v));
    }
    form_ratio(&format!("{geometry} sphere form error"), &fits, 4);
}

/// A plane tilted 0.06-0.14 rad at the plates' depth ± 15 mm in three frames, for each geometry: its flatness
/// (the RMS distance of the points from the fitted plane) at its floor.
#[test]
fn plane_flatness_from_images() {
    for (geometry, scenario) in geometries() {
        flatness(geometry, &scenario);
    }
}

fn flatness(geometry: &str, scenario: &Scenario) {
    let (rig, objects, matched) = scanned(scenario, "plane");
    let (_, covariances) = propagated(&rig, &matched);
    let mut fits = Vec::new();
    for ((object, frame), covariances) in objects.iter().zip(&matched).zip(&covariances) {
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
        let v = normal_variances(covariances, &vec![normal; points.len()]);
        fits.push((r, v));
    }
    form_ratio(&format!("{geometry} plane flatness"), &fits, 3);
}

/// The torso in three frames, for each geometry: the points' error against the true surface points at the floor.
#[test]
fn torso_error_from_images() {
    for (geometry, scenario) in geometries() {
        let (rig, _, matched) = scanned(&scenario, "torso");
        error_at_floor(&format!("{geometry} torso"), &rig, &matched);
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
    error_at_floor("torso from files", &rig, &matched);
}
