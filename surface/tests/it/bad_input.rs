//! Bad clouds get a clear error, never a panic.

use deltaz_surface::{analyse, CommonShare, Frame, Options, ScanPoint, SurfaceError};
use nalgebra::{DMatrix, Matrix3, Vector3};

fn grid(f: impl Fn(f64, f64) -> f64, n: i32) -> Frame {
    let points = (-n..=n)
        .flat_map(|j| (-n..=n).map(move |i| (i, j)))
        .map(|(i, j)| {
            let (x, y) = (20.0 * f64::from(i), 20.0 * f64::from(j));
            ScanPoint {
                position: Vector3::new(x, y, f(x, y)),
                covariance: Matrix3::identity() * 0.16,
                ray: Some([i, j]),
            }
        })
        .collect();
    Frame::new(points)
}

fn back(x: f64, _y: f64) -> f64 {
    -1500.0 + 90.0 * ((1.0 - (x / 200.0).powi(2)).max(0.0).sqrt() - 1.0)
}

#[test]
fn too_few_points() {
    let e = analyse(&[grid(back, 2)], &Options::standing()).unwrap_err();
    assert!(
        matches!(e, SurfaceError::TooFewPoints { points: 25, .. }),
        "{e}"
    );
}

#[test]
fn a_back_in_metres_is_named() {
    let mut f = grid(back, 12);
    for p in &mut f.points {
        p.position /= 1000.0;
    }
    let e = analyse(&[f], &Options::standing()).unwrap_err();
    assert!(matches!(e, SurfaceError::NoBack { .. }), "{e}");
    assert!(e.to_string().contains("metres"), "{e}");
}

#[test]
fn a_plane_is_not_a_back() {
    let plane = grid(|x, _| -1500.0 + 0.1 * x, 12);
    let e = analyse(std::slice::from_ref(&plane), &Options::standing()).unwrap_err();
    assert!(matches!(e, SurfaceError::Plane { .. }), "{e}");
    assert!(e.to_string().contains("(625 of its 625 points)"), "{e}");
    assert!(!e.to_string().contains("cut it"), "{e}");
    // With more points apart from it than on it, the message says what cuts a mesh apart.
    let mut cut = plane;
    let apart: Vec<ScanPoint> = (0..700)
        .map(|k| ScanPoint {
            ray: Some([100 + 3 * k as i32, 100]),
            ..cut.points[k % 625]
        })
        .collect();
    cut.points.extend(apart);
    let e = analyse(&[cut], &Options::standing()).unwrap_err();
    assert!(
        e.to_string().contains("(625 of its 1325 points)") && e.to_string().contains("cut it"),
        "{e}"
    );
}

#[test]
fn scattered_points_are_no_back() {
    let mut f = grid(back, 12);
    for (k, p) in f.points.iter_mut().enumerate() {
        p.ray = Some([3 * k as i32, 0]);
    }
    let e = analyse(&[f], &Options::standing()).unwrap_err();
    assert!(matches!(e, SurfaceError::NoBack { .. }), "{e}");
}

#[test]
fn mixed_calibrations() {
    let mut a = grid(back, 12);
    let mut b = a.clone();
    a.calibration = Some(1);
    b.calibration = Some(2);
    let e = analyse(&[a.clone(), b], &Options::standing()).unwrap_err();
    assert!(
        matches!(e, SurfaceError::MixedCalibrations { frame: 1, .. }),
        "{e}"
    );
    let mut c = a.clone();
    c.common = CommonShare::Shift(Matrix3::identity());
    assert!(matches!(
        analyse(&[a, c], &Options::standing()),
        Err(SurfaceError::MixedCalibrations { .. })
    ));
}

#[test]
fn bad_numbers() {
    let mut f = grid(back, 12);
    f.points[7].position.x = f64::NAN;
    let e = analyse(&[f], &Options::standing()).unwrap_err();
    assert!(matches!(e, SurfaceError::BadPoint { point: 7, .. }), "{e}");
    let mut f = grid(back, 12);
    f.common = CommonShare::Core {
        covariance: DMatrix::identity(2, 2),
        sensitivity: DMatrix::zeros(3, 2),
    };
    assert!(matches!(
        analyse(&[f], &Options::standing()),
        Err(SurfaceError::BadCommonShare { .. })
    ));
    assert_eq!(
        analyse(&[], &Options::standing()).unwrap_err(),
        SurfaceError::NoFrames
    );
    // A point behind the camera; a frame whose points have their rays but one.
    let mut f = grid(back, 12);
    f.points[5].position.z = 10.0;
    let e = analyse(&[f], &Options::standing()).unwrap_err();
    assert!(matches!(e, SurfaceError::BadPoint { point: 5, .. }), "{e}");
    assert!(e.to_string().contains("behind the camera"), "{e}");
    let mut f = grid(back, 12);
    f.points[9].ray = None;
    let e = analyse(&[f], &Options::standing()).unwrap_err();
    assert!(matches!(e, SurfaceError::BadPoint { point: 9, .. }), "{e}");
    assert!(e.to_string().contains("with and without their rays"), "{e}");
}
