//! Space resection: the exterior orientation of one image from known control (section 5.2,
//! step 4, Table 2).
//!
//! 1. Closed-form starts for any configuration with a unique solution ([`closed_form_starts`]):
//!    the homography of the coplanar subset (the plane through three of the points that holds
//!    the most of them) decomposed into rotation and translation (all points in one plane, or a
//!    plane with a few raised points: ≥ 4 points in the plane), and the DLT
//!    (11 parameters, ≥ 6 points off one plane), and the perspective-three-point pose of three
//!    well-spread points (`p3p`) that best fits the others (any 4 points or more). Each is
//!    refined; the one with the smallest weighted residual wins, so a weak DLT (few raised
//!    points) cannot spoil a good planar start, nor a plane of three collinear points and one
//!    more a pose that the raised points decide.
//! 2. Gauss-Newton (with step halving) on κ, φ, ω, X0, Y0, Z0 with the residual of
//!    [`crate::residual`] (inner orientation known), control held fixed but weighted by its σ:
//!    an image point's variance is σ_image² + (f / depth)² σ_control².
//! 3. σ of each parameter from σ0² (JᵀPJ)⁻¹, σ0² = vᵀPv / (2n − 6) (P relative to the image
//!    noise, so σ0 is in mm in the image).

mod p3p;

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
    /// The best pose leaves residuals far above the image noise: the control does not fit the
    /// image (mislabelled points, or control mirrored through the camera).
    PoorFit {
        /// Residual RMS (px).
        rms_px: f64,
        /// The image noise expected (px).
        expected_px: f64,
    },
}

impl fmt::Display for ResectionError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ResectionError::TooFewPoints { given, needed } => write!(
                f,
                "too few control points: {given} (need {needed})"
            ),
            ResectionError::Collinear => f.write_str("the control points are collinear"),
            ResectionError::BehindCamera => f.write_str("the control points lie behind the camera"),
            ResectionError::NotFinite => f.write_str("a coordinate is NaN or infinite"),
            ResectionError::NoConvergence => f.write_str("the least-squares refinement diverged"),
            ResectionError::PoorFit {
                rms_px,
                expected_px,
            } => write!(
                f,
                "the control does not fit the image: residual RMS {rms_px:.2} px for {expected_px} px \
                 image noise (mislabelled points, or control on the wrong side of the camera?)"
            ),
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

/// A control point as seen in one image: the observed pixel (col, row), its coordinates and
/// their σ (mm per coordinate; 0 = exact).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sighting {
    /// Observed pixel (col, row).
    pub pixel: Vector2<f64>,
    /// Control coordinates (mm).
    pub xyz: Vector3<f64>,
    /// σ of each coordinate (mm).
    pub sigma: f64,
}

/// Pixel and control pairs as sightings of exact control (σ 0).
fn exact(points: &[(Vector2<f64>, Vector3<f64>)]) -> Vec<Sighting> {
    points
        .iter()
        .map(|&(pixel, xyz)| Sighting {
            pixel,
            xyz,
            sigma: 0.0,
        })
        .collect()
}

/// Resects one image: `points` are (observed pixel (col, row), world coordinates) pairs, the
/// control taken as exact.
pub fn resect(
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    points: &[(Vector2<f64>, Vector3<f64>)],
) -> Result<ResectionResult, ResectionError> {
    let sightings = exact(points);
    best_pose(grid, inner, &sightings, 1.0)
}

/// Resects one image from control with σ; `image_sigma_px` is the image noise the control's σ
/// is weighed against. Every closed-form start is refined, the smallest weighted residual wins;
/// a σ0 above 5 × the image noise is a [`ResectionError::PoorFit`].
pub fn resect_control(
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    points: &[Sighting],
    image_sigma_px: f64,
) -> Result<ResectionResult, ResectionError> {
    let result = best_pose(grid, inner, points, image_sigma_px)?;
    if result.sigma0 > 5.0 * image_sigma_px * grid.pixel_size {
        return Err(ResectionError::PoorFit {
            rms_px: result.rms_px,
            expected_px: image_sigma_px,
        });
    }
    Ok(result)
}

/// Every closed-form start refined; the smallest vᵀPv wins.
fn best_pose(
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    points: &[Sighting],
    image_sigma_px: f64,
) -> Result<ResectionResult, ResectionError> {
    if points
        .iter()
        .any(|p| !p.pixel.iter().chain(p.xyz.iter()).all(|v| v.is_finite()) || !p.sigma.is_finite())
    {
        return Err(ResectionError::NotFinite);
    }
    let obs = Observed::new(grid, points, image_sigma_px);
    let mut best: Option<(f64, ResectionResult)> = None;
    let mut failure = None;
    for start in closed_form_starts(inner, &obs.photo, &obs.world)? {
        match refine(grid, inner, &obs, start) {
            Ok((cost, r)) if best.as_ref().is_none_or(|b| cost < b.0) => best = Some((cost, r)),
            Ok(_) => {}
            Err(e) => failure = Some(e),
        }
    }
    best.map(|b| b.1)
        .ok_or(failure.unwrap_or(ResectionError::NoConvergence))
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
    let sightings = exact(points);
    let obs = Observed::new(grid, &sightings, 1.0);
    refine(grid, inner, &obs, start).map(|r| r.1)
}

/// Observations in photo coordinates with their control and σ.
struct Observed {
    photo: Vec<Vector2<f64>>,
    world: Vec<Vector3<f64>>,
    /// σ of the control coordinates relative to the image noise, in object space (mm / mm).
    relative_sigma: Vec<f64>,
}

impl Observed {
    fn new(grid: &PixelGrid<f64>, points: &[Sighting], image_sigma_px: f64) -> Self {
        let image_sigma = image_sigma_px * grid.pixel_size;
        Self {
            photo: points
                .iter()
                .map(|p| grid.pixel_to_photo(p.pixel.x, p.pixel.y))
                .collect(),
            world: points.iter().map(|p| p.xyz).collect(),
            relative_sigma: points
                .iter()
                .map(|p| {
                    if p.sigma > 0.0 {
                        p.sigma / image_sigma
                    } else {
                        0.0
                    }
                })
                .collect(),
        }
    }

    /// The weights at a pose: σ_image² / (σ_image² + (f / depth)² σ_control²) per point.
    fn weights(&self, f: f64, pose: &ExteriorOrientation<f64>) -> Vec<f64> {
        self.world
            .iter()
            .zip(&self.relative_sigma)
            .map(|(x, rel)| {
                let depth = pose.world_to_camera(x).z.abs().max(f64::MIN_POSITIVE);
                let scaled = rel * f / depth;
                1.0 / (1.0 + scaled * scaled)
            })
            .collect()
    }
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

/// At most this many point-to-plane tests in the search for the coplanar subset: every triple
/// of up to 30 points, a fixed sample of the triples beyond (RANSAC).
const PLANE_TESTS: usize = 200_000;

/// The coplanar subset: of the planes through three of the points, the one that holds the most
/// of them (within 1e-3 of the points' spread `scale`; the first found on a tie), every triple
/// tried for small sets and a fixed pseudo-random sample of them for large ones. A least-squares
/// plane would be tilted by the raised points and lose the plate; a plane through three points
/// is not. None when no plane holds 4 points that are not collinear.
fn coplanar_subset(world: &[Vector3<f64>], scale: f64) -> Option<Vec<usize>> {
    let n = world.len();
    let tolerance = 1e-3 * scale;
    let in_plane = |(a, b, c): (usize, usize, usize)| -> Option<Vec<usize>> {
        let normal = (world[b] - world[a]).cross(&(world[c] - world[a]));
        let norm = normal.norm();
        if norm <= 1e-6 * scale * scale {
            return None;
        }
        let normal = normal / norm;
        let held: Vec<usize> = (0..n)
            .filter(|&i| (world[i] - world[a]).dot(&normal).abs() <= tolerance)
            .collect();
        (held.len() >= 4).then_some(held)
    };
    let triples = n * n.saturating_sub(1) * n.saturating_sub(2) / 6;
    let sample = (PLANE_TESTS / n.max(1)).max(1);
    let candidates: Vec<(usize, usize, usize)> = if triples <= sample {
        (0..n)
            .flat_map(|a| (a + 1..n).flat_map(move |b| (b + 1..n).map(move |c| (a, b, c))))
            .collect()
    } else {
        let mut state = 0x853c_49e6_748f_ea9b_u64;
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 33) as usize % n
        };
        (0..sample).map(|_| (next(), next(), next())).collect()
    };
    let mut best: Option<Vec<usize>> = None;
    for held in candidates.into_iter().filter_map(in_plane) {
        if best.as_ref().is_none_or(|b| held.len() > b.len()) {
            let all = held.len() == n;
            best = Some(held);
            if all {
                break;
            }
        }
    }
    best.filter(|held| {
        let s = shape(&held.iter().map(|&i| world[i]).collect::<Vec<_>>());
        s.spread.y >= 1e-6 * s.spread.x
    })
}

/// The closed-form starts: the homography of the coplanar subset (≥ 4 points in one plane),
/// with ≥ 6 points off one plane the DLT, and the three-point pose. Starts that put most points
/// behind the camera are dropped; when none is left the error says why.
pub fn closed_form_starts(
    inner: &InnerOrientation<f64>,
    observed: &[Vector2<f64>],
    world: &[Vector3<f64>],
) -> Result<Vec<ExteriorOrientation<f64>>, ResectionError> {
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
    let mut candidates = Vec::new();
    if let Some(plane) = coplanar_subset(world, s.scale) {
        let (uv_p, world_p): (Vec<_>, Vec<_>) = plane.iter().map(|&i| (uv[i], world[i])).unzip();
        candidates.push(homography_start(&shape(&world_p), &uv_p, &world_p));
    }
    if !planar && n >= 6 {
        candidates.push(dlt_start(&s, &uv, world));
    }
    candidates.push(three_point_start(&uv, world));
    let mut error = ResectionError::BehindCamera;
    let mut starts = Vec::new();
    for candidate in candidates {
        match candidate {
            Ok((r, centre)) => {
                let behind = world
                    .iter()
                    .filter(|x| (r * (*x - centre)).z >= 0.0)
                    .count();
                if behind * 2 <= n {
                    let (kappa, phi, omega) = angles_from_matrix(&r);
                    starts.push(ExteriorOrientation {
                        kappa,
                        phi,
                        omega,
                        centre,
                    });
                }
            }
            Err(e) => error = e,
        }
    }
    if starts.is_empty() {
        return Err(error);
    }
    Ok(starts)
}

/// The three-point pose ([`p3p`]) of a well-spread triple (the point farthest from the
/// centroid, the one farthest from it, the one farthest from their line) that puts every point
/// in front of the camera with the smallest residual in normalised coordinates.
fn three_point_start(
    uv: &[Vector2<f64>],
    world: &[Vector3<f64>],
) -> Result<(Matrix3<f64>, Vector3<f64>), ResectionError> {
    let centroid = world.iter().sum::<Vector3<f64>>() / world.len() as f64;
    let farthest = |score: &dyn Fn(&Vector3<f64>) -> f64| {
        (0..world.len())
            .max_by(|&a, &b| score(&world[a]).total_cmp(&score(&world[b])))
            .unwrap_or(0)
    };
    let a = farthest(&|x| (x - centroid).norm_squared());
    let b = farthest(&|x| (x - world[a]).norm_squared());
    let edge = world[b] - world[a];
    let c = farthest(&|x| (x - world[a]).cross(&edge).norm_squared());
    let triple = [a, b, c];
    let bearings = triple.map(|i| -Vector3::new(uv[i].x, uv[i].y, 1.0).normalize());
    let misfit = |(r, centre): &(Matrix3<f64>, Vector3<f64>)| {
        world.iter().zip(uv).try_fold(0.0, |sum, (x, o)| {
            let p = r * (x - centre);
            (p.z < 0.0).then(|| sum + (Vector2::new(p.x / p.z, p.y / p.z) - o).norm_squared())
        })
    };
    p3p::p3p(&bearings, &triple.map(|i| world[i]))
        .into_iter()
        .filter_map(|pose| misfit(&pose).map(|m| (m, pose)))
        .min_by(|x, y| x.0.total_cmp(&y.0))
        .map(|(_, pose)| pose)
        .ok_or(ResectionError::BehindCamera)
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
    let rows = world.iter().map(|x| {
        let xn = (x - s.centroid) / s.scale;
        [xn.x, xn.y, xn.z, 1.0]
    });
    let p = null_vector(projective_design(rows, uv))?;
    let m = Matrix3::new(p[0], p[1], p[2], p[4], p[5], p[6], p[8], p[9], p[10]);
    let p4 = Vector3::new(p[3], p[7], p[11]);
    // x_cam ∝ M X̃ + p4 with X̃ = (X − c)/s: the centre is where M X̃ + p4 = 0.
    let xn0 = -m.try_inverse().ok_or(ResectionError::Collinear)? * p4;
    let (r, _) = nearest_rotation(&m);
    Ok((r, s.centroid + xn0 * s.scale))
}

/// The design matrix of a projective map P (3 × K, row-major) from homogeneous points h to image
/// points (u, v): per point the rows [hᵀ 0 −u hᵀ] and [0 hᵀ −v hᵀ], so that A vec(P) = 0.
fn projective_design<const K: usize>(
    points: impl Iterator<Item = [f64; K]>,
    uv: &[Vector2<f64>],
) -> DMatrix<f64> {
    let mut a = DMatrix::zeros(2 * uv.len(), 3 * K);
    for (i, (h, o)) in points.zip(uv).enumerate() {
        for k in 0..K {
            a[(2 * i, k)] = h[k];
            a[(2 * i, 2 * K + k)] = -o.x * h[k];
            a[(2 * i + 1, K + k)] = h[k];
            a[(2 * i + 1, 2 * K + k)] = -o.y * h[k];
        }
    }
    a
}

/// Plane homography: x_cam ∝ [q1 q2 τ] (a, b, 1) for plane coordinates (a, b).
fn homography_start(
    s: &Shape,
    uv: &[Vector2<f64>],
    world: &[Vector3<f64>],
) -> Result<(Matrix3<f64>, Vector3<f64>), ResectionError> {
    let (e1, e2) = (s.axes.column(0), s.axes.column(1));
    let rows = world.iter().map(|x| {
        let d = (x - s.centroid) / s.scale;
        [d.dot(&e1), d.dot(&e2), 1.0]
    });
    let h = null_vector(projective_design(rows, uv))?;
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

/// Gauss-Newton on the six pose parameters, weighted (see [`Observed::weights`], taken at the
/// current pose and renewed at convergence until they settle); a step that raises vᵀPv is
/// halved. Returns vᵀPv and the result.
fn refine(
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    obs: &Observed,
    start: ExteriorOrientation<f64>,
) -> Result<(f64, ResectionResult), ResectionError> {
    let n = obs.world.len();
    // vᵀPv, the normal matrix and the right-hand side at a pose (None if a point is behind).
    let system = |pose: &ExteriorOrientation<f64>, weights: &[f64]| {
        let mut normal = SMatrix::<f64, POSE, POSE>::zeros();
        let mut rhs = SVector::<f64, POSE>::zeros();
        let (mut vpv, mut vtv) = (0.0, 0.0);
        for (i, (o, x)) in obs.photo.iter().zip(&obs.world).enumerate() {
            let r = image_residual(inner, o, pose, x);
            let w = weights[i];
            normal += r.d_pose.transpose() * r.d_pose * w;
            rhs -= r.d_pose.transpose() * r.value * w;
            vpv += r.value.norm_squared() * w;
            vtv += r.value.norm_squared();
        }
        (vpv, vtv, normal, rhs)
    };
    let mut pose = start;
    let mut weights = obs.weights(inner.f, &pose);
    let mut current = system(&pose, &weights);
    for iterations in 0..=50 {
        let (vpv, vtv, normal, rhs) = current;
        let cov_unit = normal.try_inverse().ok_or(ResectionError::Collinear)?;
        let step = cov_unit * rhs;
        if !step.iter().all(|s| s.is_finite()) {
            return Err(ResectionError::NoConvergence);
        }
        let converged =
            step.fixed_rows::<3>(0).amax() < 1e-12 && step.fixed_rows::<3>(3).amax() < 1e-9;
        if converged {
            // The same rotation by its canonical angles (|φ| ≤ π/2, κ and ω in (−π, π]): a start
            // far off may converge to an equivalent set, κ + π, π − φ, ω + π.
            let (kappa, phi, omega) = angles_from_matrix(&pose.r_cam_world());
            let turned = [kappa - pose.kappa, phi - pose.phi, omega - pose.omega];
            if turned.iter().any(|d| d.abs() > 1e-9) {
                pose = ExteriorOrientation {
                    kappa,
                    phi,
                    omega,
                    ..pose
                };
                current = system(&pose, &weights);
                continue;
            }
            let renewed = obs.weights(inner.f, &pose);
            if renewed
                .iter()
                .zip(&weights)
                .any(|(a, b)| (a - b).abs() > 1e-9 * b)
            {
                weights = renewed;
                current = system(&pose, &weights);
                continue;
            }
            if obs.world.iter().any(|x| pose.world_to_camera(x).z >= 0.0) {
                return Err(ResectionError::BehindCamera);
            }
            let dof = (2 * n).saturating_sub(POSE).max(1) as f64;
            let sigma0 = (vpv / dof).sqrt();
            let sigma = std::array::from_fn(|k| sigma0 * cov_unit[(k, k)].sqrt());
            return Ok((
                vpv,
                ResectionResult {
                    exterior: pose,
                    sigma,
                    sigma0,
                    rms_px: (vtv / (2 * n) as f64).sqrt() / grid.pixel_size,
                    iterations,
                    points: n,
                },
            ));
        }
        let mut scale = 1.0;
        loop {
            let mut trial = pose;
            trial.kappa += step[0] * scale;
            trial.phi += step[1] * scale;
            trial.omega += step[2] * scale;
            trial.centre += step.fixed_rows::<3>(3) * scale;
            let next = system(&trial, &weights);
            if next.0 <= vpv * (1.0 + 1e-12) || scale < 1e-6 {
                pose = trial;
                current = next;
                break;
            }
            scale /= 2.0;
        }
    }
    Err(ResectionError::NoConvergence)
}
