//! Projector calibration by the ΔZ method (section 5.2, steps 5-7) and two models beyond the paper.
//!
//! Input: for each plate image, the camera's exterior orientation in the plate's frame (step 4,
//! space resection on the plate's control points), the plate surface as a plane in that frame, and
//! the observed pixel positions of the projected dots with their ray ids.
//!
//! | step | function | what |
//! |---|---|---|
//! | 5 | [`dot_on_plate`] | eq. (10) generalised to any plate plane: camera ray ∩ plate |
//! | — | [`RigFrame::to_rig`] | into the rig frame: the rays are fixed to the camera, so every image is carried into the frame of the 1st image (the paper's global frame) |
//! | 6 | [`centre_by_delta_z`] | the perspective centre by least squares of eqs (11)-(12) |
//! | 7 | [`direction_cosines`] | eqs (13)-(14) per plane (errata: A − P, normalised), averaged |
//! | beyond | [`joint_adjustment`] | centre and all rays at once, weighted by the propagated image noise, with σ |
//! | beyond | [`noncentral_lines`] | each ray a free line (absorbs projector distortion) |
//!
//! Because every image has its own resected pose, the planes need not be parallel and the
//! displacement between images need not be known.

use anyhow::{bail, Context, Result};
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::{Camera, ExteriorOrientation};
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// A plane n·X = d (n a unit normal) in a plate image's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Unit normal n.
    pub normal: Vector3<f64>,
    /// d = n·X for every point X on the plane (mm).
    pub offset: f64,
}

impl Plane {
    /// The plane Z = z, the paper's Z_plano of eq. (10).
    pub fn at_z(z: f64) -> Self {
        Self {
            normal: Vector3::z(),
            offset: z,
        }
    }
}

/// One observed projected dot: its ray id and pixel position.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DotObservation {
    /// The dot's ray id.
    pub id: u16,
    /// Pixel column.
    pub col: f64,
    /// Pixel row.
    pub row: f64,
}

/// One image of the calibration plate with the projected dots on it.
#[derive(Debug, Clone, PartialEq)]
pub struct PlateImage {
    /// The camera's exterior orientation in the plate's frame (step 4).
    pub exterior: ExteriorOrientation<f64>,
    /// The plate surface in that frame.
    pub plate: Plane,
    /// The projected dots seen in this image.
    pub dots: Vec<DotObservation>,
}

/// Which projector model to fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Model {
    /// Steps 6 and 7 of the paper: centre by eqs (11)-(12), cosines averaged over planes.
    Paper,
    /// Centre and all rays adjusted together, weighted by the propagated image noise.
    Joint,
    /// Every ray a free 3D line; the centre (from the joint adjustment) only anchors the offsets.
    Noncentral,
}

impl std::str::FromStr for Model {
    type Err = String;

    /// `paper`, `joint` or `noncentral`.
    fn from_str(text: &str) -> std::result::Result<Self, String> {
        match text {
            "paper" => Ok(Model::Paper),
            "joint" => Ok(Model::Joint),
            "noncentral" => Ok(Model::Noncentral),
            _ => Err(format!(
                "unknown projector model {text:?}: paper, joint or noncentral"
            )),
        }
    }
}

/// One calibrated ray with its fit residuals.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibratedRay {
    /// Ray id.
    pub id: u16,
    /// Direction cosines (l, m, n), from the projector towards the scene.
    pub direction: Vector3<f64>,
    /// The ray passes through centre + offset (zero for central models), mm.
    pub offset: Vector3<f64>,
    /// Number of planes the ray was seen on.
    pub planes: usize,
    /// RMS miss distance of its plane points from the fitted line (mm).
    pub miss_rms: f64,
    /// Largest miss distance (mm).
    pub miss_max: f64,
    /// The ray's lateral uncertainty from the image noise of its plane points, as a free line
    /// X(Z) = X(Z_p) + (Z − Z_p) a (likewise Y): [var X(Z_p), cov, var a] for X then for Y
    /// (mm², mm, 1). See [`LineCovariance`].
    pub line_cov: LineCovariance,
}

/// The covariance of a ray's lateral position as a free line fitted to its plane points:
/// per axis (X, Y) the 2 × 2 covariance of its value at the centre's Z and its slope dX/dZ,
/// stored as [var, cov, var_slope]. For the central models it is an upper bound (the centre
/// constraint only helps).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct LineCovariance(pub [[f64; 3]; 2]);

impl LineCovariance {
    /// The covariance multiplied by `factor` (a variance factor σ0²).
    pub fn scaled(&self, factor: f64) -> Self {
        Self(self.0.map(|row| row.map(|v| v * factor)))
    }

    /// The variance of the ray's X and Y at a height dz = Z − Z_p above the centre (mm²).
    pub fn lateral_variance(&self, dz: f64) -> [f64; 2] {
        self.0.map(|[v, c, s]| v + 2.0 * dz * c + dz * dz * s)
    }
}

/// The free-line covariance of a ray from its points (weights 1/σ²), see [`LineCovariance`].
pub fn line_covariance(centre_z: f64, points: &[PlanePoint]) -> LineCovariance {
    let (mut sw, mut sx, mut sxx) = (0.0, 0.0, 0.0);
    for p in points {
        let w = 1.0 / (p.sigma * p.sigma);
        let x = p.point.z - centre_z;
        sw += w;
        sx += w * x;
        sxx += w * x * x;
    }
    if points.len() == 1 {
        // The line through the (exact) centre and its one point: only the slope varies.
        return LineCovariance([[0.0, 0.0, 1.0 / (sw * sxx)]; 2]);
    }
    let det = sw * sxx - sx * sx;
    let one = [sxx / det, -sx / det, sw / det];
    LineCovariance([one, one])
}

/// The calibrated projector in the rig frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProjectorCalibration {
    /// The model fitted.
    pub model: Model,
    /// The perspective centre (X_p, Y_p, Z_p), mm.
    pub centre: Vector3<f64>,
    /// Its standard deviations (mm).
    pub centre_sigma: Vector3<f64>,
    /// The rays, sorted by id.
    pub rays: Vec<CalibratedRay>,
    /// Rays seen on one plate only, determined through the centre (central models).
    #[serde(default)]
    pub single_plane: Vec<u16>,
    /// Rays seen on one plate only and left out (the non-central model needs two).
    #[serde(default)]
    pub left_out: Vec<u16>,
}

/// The frame the rays are fixed in: the 1st image's camera pose carried to its plate frame.
#[derive(Debug, Clone, Copy)]
pub struct RigFrame {
    /// The camera pose in the rig (global) frame: the 1st image's exterior orientation.
    pub camera: ExteriorOrientation<f64>,
}

impl RigFrame {
    /// The rig frame of a set of images: that of the first.
    pub fn of(images: &[PlateImage]) -> Result<Self> {
        let first = images.first().context("no plate images")?;
        Ok(Self {
            camera: first.exterior,
        })
    }

    /// A point of image `pose`'s plate frame in the rig frame: into that image's camera system,
    /// x_cam = R_k (P − X0_k), then out through the 1st image's pose, R_1ᵀ x_cam + X0_1. With the
    /// paper's rig moved 100 mm towards a fixed plate, plate k lands at Z = 100 (k − 1).
    pub fn to_rig(&self, pose: &ExteriorOrientation<f64>, point: &Vector3<f64>) -> Vector3<f64> {
        self.camera.camera_to_world(&pose.world_to_camera(point))
    }
}

/// Step 5, eq. (10) generalised: the plate point of a dot seen at (col, row): the camera ray
/// X = X0 + λ (u, v, w) (eqs 6-7) meets the plane n·X = d at λ = (d − n·X0) / (n·(u, v, w)).
/// For the plane Z = Z_plano this is eq. (10): X = X0 + (Z − Z0) u / w, Y = Y0 + (Z − Z0) v / w.
pub fn dot_on_plate(
    camera: &Camera<f64>,
    plate: &Plane,
    col: f64,
    row: f64,
) -> Result<Vector3<f64>> {
    let direction = camera.pixel_to_ray_direction(col, row);
    let along = plate.normal.dot(&direction);
    let lambda = (plate.offset - plate.normal.dot(&camera.exterior.centre)) / along;
    if !(lambda.is_finite() && lambda > 0.0) {
        bail!("the camera ray through pixel ({col}, {row}) does not meet the plate in front of the camera");
    }
    Ok(camera.exterior.centre + direction * lambda)
}

/// The plate's control must not be coplanar: without raised points (more than 1 mm off the
/// best-fitting plane) the resection of each image leaves the plate's tilt and distance weakly
/// determined (section 3.2: 6 of the paper's 20 points stand 200 mm off the plate).
pub fn check_raised_control(control: &[(String, Vector3<f64>)]) -> Result<()> {
    let points: Vec<Vector3<f64>> = control.iter().map(|(_, p)| *p).collect();
    let mean = points.iter().sum::<Vector3<f64>>() / points.len().max(1) as f64;
    let centred: Vec<_> = points.iter().map(|p| p - mean).collect();
    let scatter: Matrix3<f64> = centred.iter().map(|v| v * v.transpose()).sum();
    let eigen = scatter.symmetric_eigen();
    let (k, _) = eigen.eigenvalues.argmin();
    let normal = eigen.eigenvectors.column(k);
    let off = centred
        .iter()
        .map(|v| v.dot(&normal).abs())
        .fold(0.0, f64::max);
    if points.len() < 4 || off < 1.0 {
        bail!(
            "the plate's control points are coplanar (largest distance from their plane {off:.3} mm): \
             add raised control points"
        );
    }
    Ok(())
}

/// One dot's point on one plane, in the rig frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanePoint {
    /// Index of the image (plane) it came from.
    pub plane: usize,
    /// The point (rig frame, mm).
    pub point: Vector3<f64>,
    /// Its standard deviation in the plate from image noise (mm, isotropic).
    pub sigma: f64,
}

/// Steps 5 and the frame change for every dot of every image: ray id → its points, one per plane
/// (a ray seen on one plate has one point).
/// `image_sigma_px` is the image noise (pixels) used to weight the points.
pub fn plane_points(
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    images: &[PlateImage],
    image_sigma_px: f64,
) -> Result<BTreeMap<u16, Vec<PlanePoint>>> {
    let frame = RigFrame::of(images)?;
    let mut by_ray: BTreeMap<u16, Vec<PlanePoint>> = BTreeMap::new();
    for (k, image) in images.iter().enumerate() {
        let camera = Camera {
            grid: *grid,
            inner: *inner,
            exterior: image.exterior,
        };
        for dot in &image.dots {
            let on_plate = dot_on_plate(&camera, &image.plate, dot.col, dot.row)
                .with_context(|| format!("image {}, ray {}", k + 1, dot.id))?;
            let points = by_ray.entry(dot.id).or_default();
            if points.iter().any(|p| p.plane == k) {
                bail!("image {}: ray {} is observed twice", k + 1, dot.id);
            }
            // Image noise σ (mm in the image) scaled by range / f onto the plate.
            let range = (on_plate - image.exterior.centre).norm();
            let sigma = image_sigma_px * grid.pixel_size * range / inner.f;
            points.push(PlanePoint {
                plane: k,
                point: frame.to_rig(&image.exterior, &on_plate),
                sigma,
            });
        }
    }
    Ok(by_ray)
}

/// Step 6: the projector centre by least squares of eq. (12), one pair of equations per ray and
/// pair of planes (a, b):
///
/// ```text
/// (Z_b − Z_a) X_p + (X_a − X_b) Z_p = X_a Z_b − X_b Z_a
/// (Z_b − Z_a) Y_p + (Y_a − Y_b) Z_p = Y_a Z_b − Y_b Z_a
/// ```
///
/// (eq. 11, the line through A and B passes through P, multiplied out). Returns the centre and
/// its σ from σ0² (AᵀA)⁻¹.
pub fn centre_by_delta_z(
    by_ray: &BTreeMap<u16, Vec<PlanePoint>>,
) -> Result<(Vector3<f64>, Vector3<f64>)> {
    let mut rows: Vec<([f64; 3], f64)> = Vec::new();
    for points in by_ray.values() {
        for (i, a) in points.iter().enumerate() {
            for b in &points[i + 1..] {
                let (a, b) = (a.point, b.point);
                let dz = b.z - a.z;
                rows.push(([dz, 0.0, a.x - b.x], a.x * b.z - b.x * a.z));
                rows.push(([0.0, dz, a.y - b.y], a.y * b.z - b.y * a.z));
            }
        }
    }
    let design = DMatrix::from_fn(rows.len(), 3, |r, c| rows[r].0[c]);
    let rhs = DVector::from_iterator(rows.len(), rows.iter().map(|r| r.1));
    let (centre, sigma) = least_squares(&design, &rhs)
        .context("the projector centre is undetermined: are the planes distinct in Z?")?;
    Ok((
        Vector3::new(centre[0], centre[1], centre[2]),
        sigma.fixed_rows::<3>(0).into(),
    ))
}

/// Step 7, eqs (13)-(14) as corrected in the errata: per plane the unit vector from the centre P
/// to the ray's point A, (A − P) / |A − P|, then the average over the planes (renormalised).
pub fn direction_cosines(centre: &Vector3<f64>, points: &[PlanePoint]) -> Vector3<f64> {
    points
        .iter()
        .map(|p| (p.point - centre).normalize())
        .sum::<Vector3<f64>>()
        .normalize()
}

/// Beyond the paper: the centre and every ray adjusted together. Each ray is the line
/// X(Z) = P + (Z − Z_p) (a, b, 1); a plane point A gives the residuals
/// A_x − X_p − a (A_z − Z_p) and A_y − Y_p − b (A_z − Z_p), weighted by 1/σ_A² (image noise
/// propagated onto the plate). Gauss-Newton, the ray slopes eliminated per ray (they enter only
/// their own ray's residuals). Starts from the paper's centre. Returns the centre, its σ
/// (σ0² N⁻¹, σ0 a posteriori) and the slopes per ray.
pub fn joint_adjustment(
    by_ray: &BTreeMap<u16, Vec<PlanePoint>>,
    start: Vector3<f64>,
) -> Result<JointFit> {
    let mut centre = start;
    let mut slopes = BTreeMap::new();
    let mut result = None;
    for _ in 0..20 {
        // Given the centre, each slope is a weighted 1-parameter fit; then reduce onto the centre.
        slopes = by_ray
            .iter()
            .map(|(id, pts)| (*id, best_slopes(&centre, pts)))
            .collect();
        let mut normal = Matrix3::<f64>::zeros();
        let mut gradient = Vector3::<f64>::zeros();
        let (mut chi2, mut observations) = (0.0, 0usize);
        for (id, pts) in by_ray {
            let s = slopes[id];
            for axis in 0..2 {
                // Residual r = A_axis − P_axis − s (A_z − Z_p); unknowns (P, s).
                // ∂r/∂P_axis = −1, ∂r/∂Z_p = s, ∂r/∂s = −(A_z − Z_p).
                let mut n_pp = Matrix3::zeros();
                let mut n_ps = Vector3::zeros();
                let (mut n_ss, mut g_p, mut g_s) = (0.0, Vector3::zeros(), 0.0);
                for p in pts {
                    let w = 1.0 / (p.sigma * p.sigma);
                    let dz = p.point.z - centre.z;
                    let r = p.point[axis] - centre[axis] - s[axis] * dz;
                    let mut j_p = Vector3::zeros();
                    j_p[axis] = -1.0;
                    j_p.z = s[axis];
                    let j_s = -dz;
                    n_pp += j_p * j_p.transpose() * w;
                    n_ps += j_p * j_s * w;
                    n_ss += j_s * j_s * w;
                    g_p += j_p * r * w;
                    g_s += j_s * r * w;
                    chi2 += r * r * w;
                    observations += 1;
                }
                normal += n_pp - n_ps * n_ps.transpose() / n_ss;
                gradient += g_p - n_ps * g_s / n_ss;
            }
        }
        let inverse = normal
            .try_inverse()
            .context("the joint adjustment is singular: planes not distinct?")?;
        let step = -(inverse * gradient);
        centre += step;
        let unknowns = 3 + 2 * by_ray.len();
        let redundancy = observations.saturating_sub(unknowns).max(1);
        let sigma0_sq = chi2 / redundancy as f64;
        result = Some((
            inverse.diagonal().map(|v| (v * sigma0_sq).sqrt()),
            sigma0_sq,
        ));
        if step.norm() < 1e-9 {
            break;
        }
    }
    let (centre_sigma, variance_factor) =
        result.context("no iteration of the joint adjustment ran")?;
    Ok(JointFit {
        centre,
        centre_sigma,
        slopes,
        variance_factor,
    })
}

/// The result of [`joint_adjustment`].
#[derive(Debug, Clone, PartialEq)]
pub struct JointFit {
    /// The projector centre (mm).
    pub centre: Vector3<f64>,
    /// Its σ (mm).
    pub centre_sigma: Vector3<f64>,
    /// The slopes (a, b) per ray: dX/dZ and dY/dZ.
    pub slopes: BTreeMap<u16, [f64; 2]>,
    /// σ0² relative to the a priori image noise: the image noise is σ0 × the one assumed.
    pub variance_factor: f64,
}

/// Per ray id: its unit direction and its offset from the centre.
pub type Lines = BTreeMap<u16, (Vector3<f64>, Vector3<f64>)>;

/// The weighted least-squares slopes (a, b) of a ray through `centre`, given its points.
fn best_slopes(centre: &Vector3<f64>, points: &[PlanePoint]) -> [f64; 2] {
    let mut out = [0.0; 2];
    for (axis, slope) in out.iter_mut().enumerate() {
        let (mut num, mut den) = (0.0, 0.0);
        for p in points {
            let w = 1.0 / (p.sigma * p.sigma);
            let dz = p.point.z - centre.z;
            num += w * dz * (p.point[axis] - centre[axis]);
            den += w * dz * dz;
        }
        *slope = num / den;
    }
    out
}

/// Beyond the paper: every ray a free line X(Z) = Q + (Z − Z_p)(a, b, 1), fitted to its own
/// points by weighted least squares; Q lies at the centre's Z and is stored as the offset
/// Q − P. Returns (direction, offset) per ray.
pub fn noncentral_lines(by_ray: &BTreeMap<u16, Vec<PlanePoint>>, centre: &Vector3<f64>) -> Lines {
    by_ray
        .iter()
        .map(|(id, pts)| {
            let mut offset = Vector3::zeros();
            let mut slope = [0.0; 2];
            for axis in 0..2 {
                // Weighted line fit of the axis coordinate against dz = Z − Z_p.
                let (mut sw, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for p in pts {
                    let w = 1.0 / (p.sigma * p.sigma);
                    let x = p.point.z - centre.z;
                    let y = p.point[axis] - centre[axis];
                    sw += w;
                    sx += w * x;
                    sy += w * y;
                    sxx += w * x * x;
                    sxy += w * x * y;
                }
                let det = sw * sxx - sx * sx;
                slope[axis] = (sw * sxy - sx * sy) / det;
                offset[axis] = (sxx * sy - sx * sxy) / det;
            }
            (*id, (slope_direction(slope), offset))
        })
        .collect()
}

/// The unit direction of slopes (a, b) per unit Z, pointing towards −Z (towards the scene).
fn slope_direction(slope: [f64; 2]) -> Vector3<f64> {
    -Vector3::new(slope[0], slope[1], 1.0).normalize()
}

/// Distance of a point from the line through `point` with unit `direction`.
pub fn miss_distance(line_point: &Vector3<f64>, direction: &Vector3<f64>, x: &Vector3<f64>) -> f64 {
    let d = x - line_point;
    (d - direction * d.dot(direction)).norm()
}

/// The whole projector calibration: steps 5-7 (and the models beyond), with per-ray miss
/// distances. The centre comes from the rays seen on two planes or more; a ray seen on one plate
/// is determined by the central models through the centre (listed in `single_plane`), and left
/// out by the non-central one (listed in `left_out`).
pub fn calibrate_projector(
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    images: &[PlateImage],
    model: Model,
    image_sigma_px: f64,
) -> Result<ProjectorCalibration> {
    if images.len() < 2 {
        bail!(
            "the ΔZ method needs at least two plate images, got {}",
            images.len()
        );
    }
    let all = plane_points(grid, inner, images, image_sigma_px)?;
    let (by_ray, single): (BTreeMap<_, _>, BTreeMap<_, _>) =
        all.into_iter().partition(|(_, pts)| pts.len() >= 2);
    if by_ray.is_empty() {
        bail!("no ray is seen on two planes: the projector centre is undetermined");
    }
    let (paper_centre, paper_sigma) = centre_by_delta_z(&by_ray)?;
    // The rays' covariances use the image noise the data show, not the one assumed.
    let joint = joint_adjustment(&by_ray, paper_centre)?;
    let factor = joint.variance_factor;
    let (centre, centre_sigma, lines): (_, _, Lines) = match model {
        Model::Paper => {
            let lines = by_ray
                .iter()
                .map(|(id, pts)| {
                    (
                        *id,
                        (direction_cosines(&paper_centre, pts), Vector3::zeros()),
                    )
                })
                .collect();
            (paper_centre, paper_sigma, lines)
        }
        Model::Joint => {
            let fit = joint.clone();
            let lines = fit
                .slopes
                .into_iter()
                .map(|(id, s)| (id, (slope_direction(s), Vector3::zeros())))
                .collect();
            (fit.centre, fit.centre_sigma, lines)
        }
        Model::Noncentral => (
            joint.centre,
            joint.centre_sigma,
            noncentral_lines(&by_ray, &joint.centre),
        ),
    };
    let (single_plane, left_out): (Vec<u16>, Vec<u16>) = match model {
        Model::Noncentral => (Vec::new(), single.keys().copied().collect()),
        _ => (single.keys().copied().collect(), Vec::new()),
    };
    let mut lines = lines;
    for id in &single_plane {
        let direction = direction_cosines(&centre, &single[id]);
        lines.insert(*id, (direction, Vector3::zeros()));
    }
    let mut determined = by_ray.clone();
    determined.extend(
        single
            .into_iter()
            .filter(|(id, _)| single_plane.contains(id)),
    );
    let rays = determined
        .iter()
        .map(|(id, pts)| {
            let (direction, offset) = lines[id];
            // A free line through two points always fits: its miss is that of the central fit.
            let (miss_point, miss_direction) = if model == Model::Noncentral && pts.len() < 3 {
                (joint.centre, slope_direction(joint.slopes[id]))
            } else {
                (centre + offset, direction)
            };
            let misses: Vec<f64> = pts
                .iter()
                .map(|p| miss_distance(&miss_point, &miss_direction, &p.point))
                .collect();
            let miss_rms = (misses.iter().map(|m| m * m).sum::<f64>() / misses.len() as f64).sqrt();
            CalibratedRay {
                id: *id,
                direction,
                offset,
                planes: pts.len(),
                miss_rms,
                miss_max: misses.iter().copied().fold(0.0, f64::max),
                line_cov: line_covariance(centre.z, pts).scaled(factor),
            }
        })
        .collect();
    Ok(ProjectorCalibration {
        model,
        centre,
        centre_sigma,
        rays,
        single_plane,
        left_out,
    })
}

/// Solves min |A x − b|² and returns x with σ(x) = sqrt(diag(σ0² (AᵀA)⁻¹)).
fn least_squares(
    design: &DMatrix<f64>,
    rhs: &DVector<f64>,
) -> Result<(DVector<f64>, DVector<f64>)> {
    let normal = design.transpose() * design;
    let inverse = normal
        .clone()
        .try_inverse()
        .context("the normal matrix is singular")?;
    let x = &inverse * design.transpose() * rhs;
    let residual = design * &x - rhs;
    let redundancy = (design.nrows() - design.ncols()).max(1);
    let sigma0_sq = residual.norm_squared() / redundancy as f64;
    Ok((x, inverse.diagonal().map(|v| (v * sigma0_sq).sqrt())))
}

#[cfg(test)]
mod tests {
    use super::*;
    use deltaz_shared::rotation::rotation_matrix;

    const GRID: PixelGrid<f64> = deltaz_shared::paper::DC40_GRID;

    fn inner() -> InnerOrientation<f64> {
        deltaz_shared::paper::TABLE1_INNER
    }

    /// Table 3's centre (global) and Table 4's nine rays.
    fn truth() -> (Vector3<f64>, Vec<(u16, Vector3<f64>)>) {
        use deltaz_shared::paper::{table4_direction, TABLE3_GLOBAL};
        const IDS: [u16; 9] = [101, 102, 103, 201, 202, 203, 301, 302, 303];
        let rays = (0..9).map(|k| (IDS[k], table4_direction(k))).collect();
        (Vector3::from(TABLE3_GLOBAL), rays)
    }

    /// Table 2's poses: the rig moves towards a fixed plate (Z = 0 of the plate frame), the
    /// projector fixed to the camera. Dots are exact projections, plus `noise` pixels.
    fn images(
        centre: Vector3<f64>,
        rays: &[(u16, Vector3<f64>)],
        poses: &[ExteriorOrientation<f64>],
        plate_z: &[f64],
    ) -> Vec<PlateImage> {
        let first = poses[0];
        poses
            .iter()
            .zip(plate_z)
            .map(|(pose, &z)| {
                let camera = Camera {
                    grid: GRID,
                    inner: inner(),
                    exterior: *pose,
                };
                // The projector in this image's plate frame: fixed to the camera.
                let to_plate = |x: &Vector3<f64>| pose.camera_to_world(&first.world_to_camera(x));
                let p = to_plate(&centre);
                let dots = rays
                    .iter()
                    .map(|(id, d)| {
                        let d_plate = pose.r_cam_world().transpose() * first.r_cam_world() * d;
                        let hit = p + d_plate * ((z - p.z) / d_plate.z);
                        let (col, row) = camera.world_to_pixel(&hit).unwrap();
                        DotObservation { id: *id, col, row }
                    })
                    .collect();
                PlateImage {
                    exterior: *pose,
                    plate: Plane::at_z(z),
                    dots,
                }
            })
            .collect()
    }

    fn table2() -> Vec<ExteriorOrientation<f64>> {
        [
            (0.01329, 0.01418, -0.02600, 375.121, 364.541, 1842.675),
            (0.01321, 0.00983, -0.02641, 369.765, 365.590, 1741.494),
            (0.01274, 0.01590, -0.02787, 382.264, 368.888, 1639.377),
        ]
        .iter()
        .map(|&(kappa, phi, omega, x, y, z)| ExteriorOrientation {
            kappa,
            phi,
            omega,
            centre: Vector3::new(x, y, z),
        })
        .collect()
    }

    #[test]
    fn eq10_is_the_plane_z_case() {
        let pose = table2()[0];
        let camera = Camera {
            grid: GRID,
            inner: inner(),
            exterior: pose,
        };
        let p = dot_on_plate(&camera, &Plane::at_z(0.0), 300.0, 200.0).unwrap();
        // Eq. (10) written out with refined image coordinates.
        let xy = camera.pixel_to_refined(300.0, 200.0);
        let r = rotation_matrix(pose.kappa, pose.phi, pose.omega);
        let f = inner().f;
        let den = r[(0, 2)] * xy.x + r[(1, 2)] * xy.y - r[(2, 2)] * f;
        let x = pose.centre.x
            + (0.0 - pose.centre.z) * (r[(0, 0)] * xy.x + r[(1, 0)] * xy.y - r[(2, 0)] * f) / den;
        let y = pose.centre.y
            + (0.0 - pose.centre.z) * (r[(0, 1)] * xy.x + r[(1, 1)] * xy.y - r[(2, 1)] * f) / den;
        assert!((p - Vector3::new(x, y, 0.0)).norm() < 1e-9, "{p}");
        // A tilted plane: the point lies on it and on the camera ray.
        let tilted = Plane {
            normal: Vector3::new(0.2, 0.0, 1.0).normalize(),
            offset: 30.0,
        };
        let q = dot_on_plate(&camera, &tilted, 300.0, 200.0).unwrap();
        assert!((tilted.normal.dot(&q) - 30.0).abs() < 1e-9);
        let back = camera.world_to_pixel(&q).unwrap();
        assert!((back.0 - 300.0).abs() < 1e-6 && (back.1 - 200.0).abs() < 1e-6);
    }

    /// Noise-free paper rig: every model recovers Table 3's centre and Table 4's rays exactly, and
    /// the plate of image k lies at Z = 100 (k − 1) in the rig frame (the errata's global frame)
    /// to within the poses' departures from a pure translation.
    #[test]
    fn exact_data_recovers_table3_and_table4() {
        let (centre, rays) = truth();
        let imgs = images(centre, &rays, &table2(), &[0.0; 3]);
        let pts = plane_points(&GRID, &inner(), &imgs, 0.5).unwrap();
        let mean_z: Vec<f64> = (0..3)
            .map(|k| {
                let z: Vec<f64> = pts.values().map(|p| p[k].point.z).collect();
                z.iter().sum::<f64>() / z.len() as f64
            })
            .collect();
        assert!(
            (mean_z[1] - 101.2).abs() < 3.0 && (mean_z[2] - 203.3).abs() < 6.0,
            "{mean_z:?}"
        );
        for model in [Model::Paper, Model::Joint, Model::Noncentral] {
            let cal = calibrate_projector(&GRID, &inner(), &imgs, model, 0.5).unwrap();
            assert!(
                (cal.centre - centre).norm() < 1e-6,
                "{model:?}: {}",
                cal.centre
            );
            for (ray, (id, d)) in cal.rays.iter().zip(&rays) {
                assert_eq!(ray.id, *id);
                assert!((ray.direction - d).norm() < 1e-9, "{model:?} ray {id}");
                assert!(ray.offset.norm() < 1e-6 && ray.miss_max < 1e-6);
                assert_eq!(ray.planes, 3);
            }
        }
    }

    /// Non-parallel plates, unknown displacements: the resected poses carry everything.
    #[test]
    fn tilted_plate_poses() {
        let (centre, rays) = truth();
        let mut poses = table2();
        poses[1].phi += 0.15;
        poses[1].centre.x += 250.0;
        poses[2].omega -= 0.1;
        poses[2].centre.y -= 160.0;
        let imgs = images(centre, &rays, &poses, &[0.0, 10.0, -5.0]);
        for model in [Model::Paper, Model::Joint, Model::Noncentral] {
            let cal = calibrate_projector(&GRID, &inner(), &imgs, model, 0.5).unwrap();
            assert!(
                (cal.centre - centre).norm() < 1e-6,
                "{model:?}: {}",
                cal.centre
            );
        }
    }

    /// A non-central ray on two planes fits any two points exactly: its miss is reported from
    /// the central fit, so a displaced dot shows instead of a miss of 0.
    #[test]
    fn two_plane_noncentral_rays_report_the_central_miss() {
        let (centre, rays) = truth();
        let mut imgs = images(centre, &rays, &table2(), &[0.0; 3]);
        let lost = rays[4].0;
        imgs[2].dots.retain(|d| d.id != lost);
        let dot = imgs[1].dots.iter_mut().find(|d| d.id == lost).unwrap();
        dot.col += 2.0;
        let cal = calibrate_projector(&GRID, &inner(), &imgs, Model::Noncentral, 0.5).unwrap();
        let ray = cal.rays.iter().find(|r| r.id == lost).unwrap();
        assert_eq!(ray.planes, 2);
        assert!(ray.miss_rms > 0.1, "miss {}", ray.miss_rms);
    }

    #[test]
    fn coplanar_control_is_an_error() {
        let mut control: Vec<(String, Vector3<f64>)> = (0..12)
            .map(|k| {
                (
                    format!("C{k}"),
                    Vector3::new(f64::from(k % 4) * 190.0, f64::from(k / 4) * 280.0, 0.0),
                )
            })
            .collect();
        let err = check_raised_control(&control).unwrap_err();
        assert!(err.to_string().contains("coplanar"), "{err}");
        control[5].1.z = 200.0;
        check_raised_control(&control).unwrap();
    }

    /// A ray seen on one plane: the central models determine it through the centre (exact
    /// data: its direction is the truth), the non-central model leaves it out; both list it.
    #[test]
    fn rays_on_one_plane_are_listed() {
        let (centre, rays) = truth();
        let (lost, half_lost) = (rays[4].0, rays[2].0);
        let mut imgs = images(centre, &rays, &table2(), &[0.0; 3]);
        imgs[1].dots.retain(|d| d.id != lost);
        imgs[2].dots.retain(|d| d.id != lost && d.id != half_lost);
        for model in [Model::Paper, Model::Joint] {
            let cal = calibrate_projector(&GRID, &inner(), &imgs, model, 0.5).unwrap();
            assert_eq!(
                (cal.single_plane.clone(), cal.left_out.clone()),
                (vec![lost], vec![])
            );
            let ray = cal.rays.iter().find(|r| r.id == lost).unwrap();
            assert_eq!(ray.planes, 1);
            let truth = rays[4].1;
            assert!(
                (ray.direction - truth).amax() < 1e-6,
                "{model:?}: {}",
                ray.direction
            );
            assert!(ray.line_cov.0[0].iter().all(|v| v.is_finite()));
        }
        let cal = calibrate_projector(&GRID, &inner(), &imgs, Model::Noncentral, 0.5).unwrap();
        assert_eq!((cal.single_plane, cal.left_out), (vec![], vec![lost]));
        assert_eq!(cal.rays.len(), rays.len() - 1);
        assert!(cal.rays.iter().all(|r| r.id != lost));
        let mut twice = images(centre, &rays, &table2(), &[0.0; 3]);
        let dup = twice[1].dots[0];
        twice[1].dots.push(dup);
        let err = calibrate_projector(&GRID, &inner(), &twice, Model::Paper, 0.5).unwrap_err();
        assert!(
            format!("{err:#}").contains(&format!("ray {} is observed twice", dup.id)),
            "{err:#}"
        );
    }
}
