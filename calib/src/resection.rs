//! Space resection: the exterior orientation of one image from known control (section 5.2,
//! step 4, Table 2).
//!
//! 1. A closed-form start: the DLT (11 parameters, ≥ 6 non-coplanar points) or, for a planar set
//!    (≥ 4 points), the homography of the plane decomposed into rotation and translation.
//! 2. Gauss-Newton on κ, φ, ω, X0, Y0, Z0 with the residual of [`crate::residual`]
//!    (inner orientation known), control held fixed.
//! 3. σ of each parameter from σ0² (JᵀJ)⁻¹, σ0² = vᵀv / (2n − 6).

use crate::residual::{image_residual, POSE};
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::ExteriorOrientation;
use deltaz_shared::rotation::angles_from_matrix;
use nalgebra::{DMatrix, Matrix3, SMatrix, SVector, Vector2, Vector3};
use std::fmt;

/// Why a resection failed.
#[derive(Debug, Clone, PartialEq)]
pub enum ResectionError {
    /// Fewer points than the configuration needs.
    TooFewPoints {
        /// Points given.
        given: usize,
        /// Points needed.
        needed: usize,
    },
    /// The control points lie (nearly) on one line.
    Collinear,
    /// The control points lie behind the camera.
    BehindCamera,
    /// A coordinate is NaN or infinite.
    NotFinite,
    /// Gauss-Newton did not converge.
    NoConvergence,
}

impl fmt::Display for ResectionError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ResectionError::TooFewPoints { given, needed } => write!(
                f,
                "too few control points: {given} (need {needed}: 6 non-coplanar or 4 coplanar)"
            ),
            ResectionError::Collinear => f.write_str("the control points are collinear"),
            ResectionError::BehindCamera => f.write_str("the control points lie behind the camera"),
            ResectionError::NotFinite => f.write_str("a coordinate is NaN or infinite"),
            ResectionError::NoConvergence => f.write_str("the least-squares refinement diverged"),
        }
    }
}

impl std::error::Error for ResectionError {}

/// A resected exterior orientation with its precision.
#[derive(Debug, Clone, PartialEq)]
pub struct ResectionResult {
    /// κ, φ, ω, X0, Y0, Z0.
    pub exterior: ExteriorOrientation<f64>,
    /// σ of κ, φ, ω (rad), X0, Y0, Z0 (mm).
    pub sigma: [f64; POSE],
    /// A posteriori σ0 (mm in the image).
    pub sigma0: f64,
    /// Residual RMS (px).
    pub rms_px: f64,
    /// Gauss-Newton iterations.
    pub iterations: usize,
    /// Points used.
    pub points: usize,
}

/// Resects one image: `points` are (observed pixel (col, row), world coordinates) pairs.
pub fn resect(
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    points: &[(Vector2<f64>, Vector3<f64>)],
) -> Result<ResectionResult, ResectionError> {
    if points
        .iter()
        .any(|(p, x)| !p.iter().chain(x.iter()).all(|v| v.is_finite()))
    {
        return Err(ResectionError::NotFinite);
    }
    let observed: Vec<Vector2<f64>> = points
        .iter()
        .map(|(p, _)| grid.pixel_to_photo(p.x, p.y))
        .collect();
    let world: Vec<Vector3<f64>> = points.iter().map(|(_, x)| *x).collect();
    let start = closed_form(inner, &observed, &world)?;
    refine(grid, inner, &observed, &world, start)
}

/// Resects one image from an approximate pose (no closed-form start): Gauss-Newton from
/// `start` on (observed pixel, world) pairs; at least 4 points.
pub fn resect_from(
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    points: &[(Vector2<f64>, Vector3<f64>)],
    start: ExteriorOrientation<f64>,
) -> Result<ResectionResult, ResectionError> {
    if points.len() < 4 {
        return Err(ResectionError::TooFewPoints {
            given: points.len(),
            needed: 4,
        });
    }
    let observed: Vec<Vector2<f64>> = points
        .iter()
        .map(|(p, _)| grid.pixel_to_photo(p.x, p.y))
        .collect();
    let world: Vec<Vector3<f64>> = points.iter().map(|(_, x)| *x).collect();
    refine(grid, inner, &observed, &world, start)
}

/// The shape of a point set: its centroid, scale and principal axes (by decreasing spread).
struct Shape {
    centroid: Vector3<f64>,
    scale: f64,
    axes: Matrix3<f64>,
    spread: Vector3<f64>,
}

fn shape(world: &[Vector3<f64>]) -> Shape {
    let n = world.len() as f64;
    let centroid = world.iter().sum::<Vector3<f64>>() / n;
    let mut cov = Matrix3::zeros();
    for x in world {
        let d = x - centroid;
        cov += d * d.transpose();
    }
    let eig = cov.symmetric_eigen();
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let axes = Matrix3::from_columns(&order.map(|i| eig.eigenvectors.column(i).into_owned()));
    let spread = Vector3::from(order.map(|i| (eig.eigenvalues[i].max(0.0) / n).sqrt()));
    Shape {
        centroid,
        scale: spread.x.max(f64::MIN_POSITIVE),
        axes,
        spread,
    }
}

/// Normalised image coordinates (u, v) = (x_cam / z_cam, y_cam / z_cam) of observations.
fn normalised(inner: &InnerOrientation<f64>, observed: &[Vector2<f64>]) -> Vec<Vector2<f64>> {
    observed
        .iter()
        .map(|o| -inner.refine(*o) / inner.f)
        .collect()
}

/// The closed-form start: DLT or plane homography.
pub fn closed_form(
    inner: &InnerOrientation<f64>,
    observed: &[Vector2<f64>],
    world: &[Vector3<f64>],
) -> Result<ExteriorOrientation<f64>, ResectionError> {
    let n = world.len();
    if n < 4 {
        return Err(ResectionError::TooFewPoints {
            given: n,
            needed: 4,
        });
    }
    let s = shape(world);
    if s.spread.y < 1e-6 * s.spread.x {
        return Err(ResectionError::Collinear);
    }
    let uv = normalised(inner, observed);
    let planar = s.spread.z < 1e-3 * s.spread.x;
    let (r, centre) = if planar {
        homography_start(&s, &uv, world)?
    } else if n < 6 {
        return Err(ResectionError::TooFewPoints {
            given: n,
            needed: 6,
        });
    } else {
        dlt_start(&s, &uv, world)?
    };
    let behind = world
        .iter()
        .filter(|x| (r * (*x - centre)).z >= 0.0)
        .count();
    if behind * 2 > n {
        return Err(ResectionError::BehindCamera);
    }
    let (kappa, phi, omega) = angles_from_matrix(&r);
    Ok(ExteriorOrientation {
        kappa,
        phi,
        omega,
        centre,
    })
}

/// The null vector of a design matrix (right singular vector of the smallest singular value).
fn null_vector(a: DMatrix<f64>) -> Result<nalgebra::DVector<f64>, ResectionError> {
    let cols = a.ncols();
    // AᵀA is small (≤ 12 × 12): its eigenvector of the smallest eigenvalue.
    let eig = (a.transpose() * a).symmetric_eigen();
    let (k, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .ok_or(ResectionError::NotFinite)?;
    let v = eig.eigenvectors.column(k).into_owned();
    if v.len() != cols || !v.iter().all(|x| x.is_finite()) {
        return Err(ResectionError::NotFinite);
    }
    Ok(v)
}

/// The nearest rotation to a 3 × 3 matrix (scaled rotation), with its scale.
fn nearest_rotation(m: &Matrix3<f64>) -> (Matrix3<f64>, f64) {
    let svd = m.svd(true, true);
    let (u, vt) = (svd.u.unwrap(), svd.v_t.unwrap());
    let sign = m.determinant().signum();
    let mut r = u * vt * sign;
    if r.determinant() < 0.0 {
        // M was a reflection times a scale: flip the weakest axis.
        let mut u2 = u;
        u2.column_mut(2).neg_mut();
        r = u2 * vt;
    }
    (r, sign * svd.singular_values.mean())
}

/// DLT on normalised world coordinates: u = (p1·X̃ + p14) / (p3·X̃ + p34), likewise v.
fn dlt_start(
    s: &Shape,
    uv: &[Vector2<f64>],
    world: &[Vector3<f64>],
) -> Result<(Matrix3<f64>, Vector3<f64>), ResectionError> {
    let n = world.len();
    let mut a = DMatrix::zeros(2 * n, 12);
    for (i, (x, o)) in world.iter().zip(uv).enumerate() {
        let xn = (x - s.centroid) / s.scale;
        let h = [xn.x, xn.y, xn.z, 1.0];
        for k in 0..4 {
            a[(2 * i, k)] = h[k];
            a[(2 * i, 8 + k)] = -o.x * h[k];
            a[(2 * i + 1, 4 + k)] = h[k];
            a[(2 * i + 1, 8 + k)] = -o.y * h[k];
        }
    }
    let p = null_vector(a)?;
    let m = Matrix3::new(p[0], p[1], p[2], p[4], p[5], p[6], p[8], p[9], p[10]);
    let p4 = Vector3::new(p[3], p[7], p[11]);
    // x_cam ∝ M X̃ + p4 with X̃ = (X − c)/s: the centre is where M X̃ + p4 = 0.
    let xn0 = -m.try_inverse().ok_or(ResectionError::Collinear)? * p4;
    let (r, _) = nearest_rotation(&m);
    Ok((r, s.centroid + xn0 * s.scale))
}

/// Plane homography: x_cam ∝ [q1 q2 τ] (a, b, 1) for plane coordinates (a, b).
fn homography_start(
    s: &Shape,
    uv: &[Vector2<f64>],
    world: &[Vector3<f64>],
) -> Result<(Matrix3<f64>, Vector3<f64>), ResectionError> {
    let n = world.len();
    let (e1, e2) = (s.axes.column(0), s.axes.column(1));
    let mut a = DMatrix::zeros(2 * n, 9);
    for (i, (x, o)) in world.iter().zip(uv).enumerate() {
        let d = (x - s.centroid) / s.scale;
        let h = [d.dot(&e1), d.dot(&e2), 1.0];
        for k in 0..3 {
            a[(2 * i, k)] = h[k];
            a[(2 * i, 6 + k)] = -o.x * h[k];
            a[(2 * i + 1, 3 + k)] = h[k];
            a[(2 * i + 1, 6 + k)] = -o.y * h[k];
        }
    }
    let h = null_vector(a)?;
    let hm = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let (q1, q2, tau) = (hm.column(0), hm.column(1), hm.column(2));
    let mut lambda = (q1.norm() + q2.norm()) / 2.0;
    if tau.z / lambda > 0.0 {
        lambda = -lambda; // the plane's origin must be in front (z_cam < 0)
    }
    let (q1, q2, tau) = (q1 / lambda, q2 / lambda, tau / lambda);
    let q = Matrix3::from_columns(&[q1, q2, q1.cross(&q2)]);
    let (q, _) = nearest_rotation(&q);
    let plane = Matrix3::from_columns(&[e1.into_owned(), e2.into_owned(), e1.cross(&e2)]);
    let r = q * plane.transpose();
    Ok((r, s.centroid - r.transpose() * tau * s.scale))
}

/// Gauss-Newton on the six pose parameters.
fn refine(
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    observed: &[Vector2<f64>],
    world: &[Vector3<f64>],
    start: ExteriorOrientation<f64>,
) -> Result<ResectionResult, ResectionError> {
    let n = world.len();
    let mut pose = start;
    let mut iterations = 0;
    loop {
        let mut normal = SMatrix::<f64, POSE, POSE>::zeros();
        let mut rhs = SVector::<f64, POSE>::zeros();
        let mut vtv = 0.0;
        for (o, x) in observed.iter().zip(world) {
            let r = image_residual(inner, o, &pose, x);
            normal += r.d_pose.transpose() * r.d_pose;
            rhs -= r.d_pose.transpose() * r.value;
            vtv += r.value.norm_squared();
        }
        let cov_unit = normal.try_inverse().ok_or(ResectionError::Collinear)?;
        let step = cov_unit * rhs;
        if !step.iter().all(|s| s.is_finite()) || iterations > 50 {
            return Err(ResectionError::NoConvergence);
        }
        let converged =
            step.fixed_rows::<3>(0).amax() < 1e-12 && step.fixed_rows::<3>(3).amax() < 1e-9;
        if converged || iterations == 50 {
            if !converged {
                return Err(ResectionError::NoConvergence);
            }
            let dof = (2 * n).saturating_sub(POSE).max(1) as f64;
            let sigma0 = (vtv / dof).sqrt();
            let sigma = std::array::from_fn(|k| sigma0 * cov_unit[(k, k)].sqrt());
            let behind = world.iter().any(|x| pose.world_to_camera(x).z >= 0.0);
            if behind {
                return Err(ResectionError::BehindCamera);
            }
            return Ok(ResectionResult {
                exterior: pose,
                sigma,
                sigma0,
                rms_px: (vtv / (2 * n) as f64).sqrt() / grid.pixel_size,
                iterations,
                points: n,
            });
        }
        pose.kappa += step[0];
        pose.phi += step[1];
        pose.omega += step[2];
        pose.centre += step.fixed_rows::<3>(3);
        iterations += 1;
    }
}
