//! Accuracy on test objects against the floor: a sphere's radius and form error, a plane's
//! flatness, a surface's error against its truth, each beside what the image noise and the
//! calibration's covariance predict.
//!
//! A point's error is δc-common plus its own ([`PointShares`]): the calibration's core error δc
//! is one draw shared by all points, so a fit absorbs much of it; the floors here carry the joint
//! covariance of a frame's points through the fit, E[r rᵀ] = (I − H) Σ (I − H) with
//! H = J (JᵀJ)⁻¹ Jᵀ, and the fitted parameters' covariance by the sandwich (JᵀJ)⁻¹ Jᵀ Σ J (JᵀJ)⁻¹.

use deltaz_calib::system_adjustment::PointShares;
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// A scanned point on a test object: measured, true, and its covariance shares.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectPoint {
    /// The measured point (camera system, mm).
    pub point: Vector3<f64>,
    /// The true point.
    pub truth: Vector3<f64>,
    /// Its covariance shares.
    pub shares: PointShares,
}

/// An RMS beside its floor.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AtFloor {
    /// Points.
    pub points: usize,
    /// RMS (mm).
    pub rms_mm: f64,
    /// Its floor: what the image noise and the calibration predict (mm).
    pub floor_mm: f64,
    /// The floor's share independent from point to point (image noise and each ray's own
    /// error, mm); the rest is the calibration's error common to all points. None for a form
    /// error, whose floor already holds what the fit leaves of the common share.
    pub own_mm: Option<f64>,
}

impl AtFloor {
    /// RMS / floor.
    pub fn ratio(&self) -> f64 {
        self.rms_mm / self.floor_mm
    }
}

/// The 3D error of the points against their truth (RMS of |error| over all frames) and its
/// floor (the RMS of the covariances' traces).
pub fn error_against_truth(points: &[ObjectPoint], core: &DMatrix<f64>) -> AtFloor {
    let n = points.len().max(1) as f64;
    let mean = |f: &dyn Fn(&ObjectPoint) -> f64| (points.iter().map(f).sum::<f64>() / n).sqrt();
    AtFloor {
        points: points.len(),
        rms_mm: mean(&|p| (p.point - p.truth).norm_squared()),
        floor_mm: mean(&|p| (p.shares.image + p.shares.calibration(core)).trace()),
        own_mm: Some(mean(&|p| (p.shares.image + p.shares.ray).trace())),
    }
}

/// A least-squares surface fit to one frame's points: parameters, residuals (normal distances,
/// mm) and the expected sum of their squares.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceFit {
    /// The fitted parameters (sphere: centre, radius; plane: a point's offset along the normal
    /// and two tilts, about the points' mean).
    pub params: DVector<f64>,
    /// Their covariance (mm², rad²) propagated from the points'.
    pub covariance: DMatrix<f64>,
    /// Each point's distance from the fitted surface (mm).
    pub residuals: DVector<f64>,
    /// The expected sum of squared residuals (mm²).
    pub expected: f64,
}

/// The form error (RMS of the residuals) of fits over several frames, and its floor.
pub fn form(fits: &[SurfaceFit]) -> AtFloor {
    let n: usize = fits.iter().map(|f| f.residuals.len()).sum();
    let per = |x: f64| (x / n.max(1) as f64).sqrt();
    AtFloor {
        points: n,
        rms_mm: per(fits.iter().map(|f| f.residuals.norm_squared()).sum()),
        floor_mm: per(fits.iter().map(|f| f.expected).sum()),
        own_mm: None,
    }
}

/// Gauss-Newton on `residual(params, point) -> (distance, d distance / d params)`: the
/// parameters, the residuals and the Jacobian.
fn gauss_newton(
    start: DVector<f64>,
    points: &[Vector3<f64>],
    residual: impl Fn(&DVector<f64>, &Vector3<f64>) -> (f64, DVector<f64>),
) -> Option<(DVector<f64>, DVector<f64>, DMatrix<f64>)> {
    let eval = |x: &DVector<f64>| {
        let rows: Vec<_> = points.iter().map(|p| residual(x, p)).collect();
        let r = DVector::from_iterator(rows.len(), rows.iter().map(|(d, _)| *d));
        let j = DMatrix::from_fn(rows.len(), x.len(), |i, k| rows[i].1[k]);
        (r, j)
    };
    let mut x = start;
    for _ in 0..20 {
        let (r, j) = eval(&x);
        let step = (j.transpose() * &j).lu().solve(&(j.transpose() * r))?;
        x -= &step;
        if step.norm() < 1e-10 {
            break;
        }
    }
    let (r, j) = eval(&x);
    Some((x, r, j))
}

/// The covariance of the points' distances along `normals` (n × n): the calibration's common
/// share, each point's own on the diagonal.
fn normal_covariance(
    points: &[ObjectPoint],
    normals: &[Vector3<f64>],
    core: &DMatrix<f64>,
) -> DMatrix<f64> {
    let g = DMatrix::from_fn(points.len(), core.nrows(), |i, k| {
        points[i].shares.common.column(k).dot(&normals[i])
    });
    let own = DVector::from_iterator(
        points.len(),
        points.iter().zip(normals).map(|(p, n)| {
            let c: Matrix3<f64> = p.shares.image + p.shares.ray;
            (n.transpose() * c * n)[0]
        }),
    );
    &g * core * g.transpose() + DMatrix::from_diagonal(&own)
}

/// The fit's propagated parameter covariance and expected squared residuals (module docs).
fn propagate(
    params: DVector<f64>,
    residuals: DVector<f64>,
    j: &DMatrix<f64>,
    sigma: &DMatrix<f64>,
) -> Option<SurfaceFit> {
    let n = j.nrows();
    let jtj_inv = (j.transpose() * j).try_inverse()?;
    let projector = j * &jtj_inv * j.transpose();
    let m = DMatrix::identity(n, n) - projector;
    Some(SurfaceFit {
        params,
        covariance: &jtj_inv * j.transpose() * sigma * j * &jtj_inv,
        residuals,
        expected: (&m * sigma * &m).trace(),
    })
}

/// A sphere fitted to one frame's points (seen from the camera at the origin: the start is the
/// points' mean pushed 100 mm away from the camera); params (centre x, y, z, radius). None when
/// the fit fails (fewer than 5 points, or degenerate).
pub fn fit_sphere(points: &[ObjectPoint], core: &DMatrix<f64>) -> Option<SurfaceFit> {
    if points.len() < 5 {
        return None;
    }
    let xyz: Vec<_> = points.iter().map(|p| p.point).collect();
    let mean = xyz.iter().sum::<Vector3<f64>>() / xyz.len() as f64;
    let back = mean + mean.normalize() * 100.0;
    let start = DVector::from_vec(vec![back.x, back.y, back.z, 100.0]);
    let (x, r, j) = gauss_newton(start, &xyz, |x, p| {
        let d = p - Vector3::new(x[0], x[1], x[2]);
        let n = d.normalize();
        (
            d.norm() - x[3],
            DVector::from_vec(vec![-n.x, -n.y, -n.z, -1.0]),
        )
    })?;
    let c = Vector3::new(x[0], x[1], x[2]);
    let normals: Vec<_> = xyz.iter().map(|p| (p - c).normalize()).collect();
    propagate(x, r, &j, &normal_covariance(points, &normals, core))
}

/// A plane fitted to one frame's points (the smallest principal axis of their scatter):
/// params (offset along the normal, two tilts) about the mean, with the unit normal.
pub fn fit_plane(
    points: &[ObjectPoint],
    core: &DMatrix<f64>,
) -> Option<(SurfaceFit, Vector3<f64>)> {
    if points.len() < 4 {
        return None;
    }
    let xyz: Vec<_> = points.iter().map(|p| p.point).collect();
    let mean = xyz.iter().sum::<Vector3<f64>>() / xyz.len() as f64;
    let scatter: Matrix3<f64> = xyz
        .iter()
        .map(|p| (p - mean) * (p - mean).transpose())
        .sum();
    let eigen = scatter.symmetric_eigen();
    let k = eigen.eigenvalues.imin();
    let normal = eigen.eigenvectors.column(k).into_owned();
    let (u, w) = (
        eigen.eigenvectors.column((k + 1) % 3),
        eigen.eigenvectors.column((k + 2) % 3),
    );
    let r = DVector::from_iterator(xyz.len(), xyz.iter().map(|p| (p - mean).dot(&normal)));
    let j = DMatrix::from_fn(xyz.len(), 3, |i, c| match c {
        0 => 1.0,
        1 => (xyz[i] - mean).dot(&u),
        _ => (xyz[i] - mean).dot(&w),
    });
    let sigma = normal_covariance(points, &vec![normal; xyz.len()], core);
    let fit = propagate(DVector::zeros(3), r, &j, &sigma)?;
    Some((fit, normal))
}
