//! Reconstruction (section 2): identified dots (ray id, pixel) → 3D points through the shared
//! crate's rig (f64), with the miss distance of the two rays and, on request, σ by first-order
//! propagation of the image noise: Σ_X = σ² J Jᵀ with J = ∂X/∂(col, row) (central differences).
//! With the calibration taken as exact this σ is the *image-noise floor* of each point: what one
//! measurement carries however good the calibration is. The calibration's share comes from each
//! ray's line covariance (see [`calibration_covariance`]).

use crate::projector_calibration::DotObservation;
use crate::projector_calibration::LineCovariance;
use anyhow::{Context, Result};
use deltaz_shared::intersection::{closest_approach, intersect_paper};
use deltaz_shared::projector::ProjectorRay;
use deltaz_shared::rig::Method;
use deltaz_shared::rig::Rig;
use nalgebra::{Matrix3, Matrix3x2, Vector3};

/// The calibrated rig in f64 with its rays in a `Vec` (what `system.json` describes).
pub type SystemRig = Rig<f64, Vec<ProjectorRay<f64>>>;

/// Calibration covariances of the rays by id.
pub type RayCovariances = std::collections::BTreeMap<u16, LineCovariance>;

/// One reconstructed dot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReconstructedPoint {
    /// Ray id.
    pub id: u16,
    /// The point (rig frame, mm).
    pub point: Vector3<f64>,
    /// How far the camera ray and the projector ray miss each other (mm).
    pub miss: f64,
    /// Per-axis σ from image noise (mm), when asked for.
    pub sigma: Option<Vector3<f64>>,
}

/// Reconstructs every observation with [`reconstruct_dot`]; an unknown ray or a degenerate
/// intersection names the observation (its 1-based index, ray and pixel).
pub fn reconstruct(
    rig: &SystemRig,
    dots: &[DotObservation],
    method: Method,
    image_sigma_px: Option<f64>,
    calibration: Option<&RayCovariances>,
) -> Result<Vec<ReconstructedPoint>> {
    dots.iter()
        .enumerate()
        .map(|(k, dot)| {
            reconstruct_dot(rig, dot, method, image_sigma_px, calibration).with_context(|| {
                format!(
                    "observation {} (ray {} at {}, {})",
                    k + 1,
                    dot.id,
                    dot.col,
                    dot.row
                )
            })
        })
        .collect()
}

/// One dot: the intersection of eqs (6)-(9) and its miss distance; `image_sigma_px` (pixels)
/// turns on the σ propagation, to which `calibration` (the rays' line covariances) adds the
/// calibration's share. Allocates nothing unless it fails, so a stream of dots costs the same
/// per dot however many there are.
pub fn reconstruct_dot(
    rig: &SystemRig,
    dot: &DotObservation,
    method: Method,
    image_sigma_px: Option<f64>,
    calibration: Option<&RayCovariances>,
) -> Result<ReconstructedPoint> {
    let hit = rig
        .reconstruct(dot.id, dot.col, dot.row, method)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let sigma = match image_sigma_px {
        Some(s) => {
            let mut cov = covariance(rig, dot, method, s)?;
            if let Some(line) = calibration.and_then(|c| c.get(&dot.id)) {
                cov += calibration_covariance(rig, dot, method, hit.point, line)?;
            }
            Some(cov.diagonal().map(f64::sqrt))
        }
        None => None,
    };
    Ok(ReconstructedPoint {
        id: dot.id,
        point: hit.point,
        miss: hit.miss,
        sigma,
    })
}

/// ∂X/∂(col, row) of one dot by central differences (0.01 px steps).
pub fn jacobian(rig: &SystemRig, dot: &DotObservation, method: Method) -> Result<Matrix3x2<f64>> {
    let h = 0.01;
    let at = |dc: f64, dr: f64| {
        rig.reconstruct(dot.id, dot.col + dc, dot.row + dr, method)
            .map(|hit| hit.point)
            .map_err(|e| anyhow::anyhow!("ray {}: {e}", dot.id))
    };
    let d_col = (at(h, 0.0)? - at(-h, 0.0)?) / (2.0 * h);
    let d_row = (at(0.0, h)? - at(0.0, -h)?) / (2.0 * h);
    Ok(Matrix3x2::from_columns(&[d_col, d_row]))
}

/// The calibration's share of a point's covariance: the projector ray shifted sideways (X, Y of
/// the rig frame) by its [`LineCovariance`] at the point's height, J_r diag(var X, var Y) J_rᵀ with
/// J_r = ∂point/∂shift by central differences (0.01 mm).
pub fn calibration_covariance(
    rig: &SystemRig,
    dot: &DotObservation,
    method: Method,
    point: Vector3<f64>,
    line: &LineCovariance,
) -> Result<Matrix3<f64>> {
    let projector = rig
        .projector_centred()
        .ray(dot.id)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let camera = rig.camera_ray(dot.col, dot.row);
    let centre_z = rig.projector_centred().centre().z + rig.camera_centre().z;
    let variance = line.lateral_variance(point.z - centre_z);
    let h = 0.01;
    let mut cov = Matrix3::zeros();
    for (axis, var) in variance.iter().enumerate() {
        let at = |shift: f64| -> Result<Vector3<f64>> {
            let mut ray = projector;
            ray.point[axis] += shift;
            let hit = match method {
                Method::Paper => intersect_paper(&camera, &ray),
                Method::ClosestApproach => closest_approach(&camera, &ray),
            };
            hit.map(|h| h.point)
                .map_err(|e| anyhow::anyhow!("ray {}: {e}", dot.id))
        };
        let column = (at(h)? - at(-h)?) / (2.0 * h);
        cov += column * column.transpose() * *var;
    }
    Ok(cov)
}

/// Σ_X = σ² J Jᵀ for isotropic image noise σ (pixels).
pub fn covariance(
    rig: &SystemRig,
    dot: &DotObservation,
    method: Method,
    image_sigma_px: f64,
) -> Result<Matrix3<f64>> {
    let j = jacobian(rig, dot, method)?;
    Ok(j * j.transpose() * (image_sigma_px * image_sigma_px))
}

#[cfg(test)]
mod tests {
    use super::*;
    use deltaz_shared::collinearity::{Camera, ExteriorOrientation};
    use deltaz_shared::paper::{DC40_GRID, TABLE1_INNER, TABLE3_GLOBAL};
    use deltaz_shared::projector::{Projector, ProjectorRay};
    use deltaz_shared::rig::Rig;

    /// The paper rig in the 1st plane's frame (Tables 1-4), rays 102 and 203.
    fn paper_rig() -> (SystemRig, Camera<f64>) {
        let camera = Camera {
            grid: DC40_GRID,
            inner: TABLE1_INNER,
            exterior: ExteriorOrientation {
                kappa: 0.01329,
                phi: 0.01418,
                omega: -0.026,
                centre: Vector3::new(375.121, 364.541, 1842.675),
            },
        };
        let ray = |id, l: f64, m: f64| ProjectorRay {
            id,
            direction: Vector3::new(l, m, -(1.0 - l * l - m * m).sqrt()),
            offset: Vector3::zeros(),
        };
        let rays = vec![ray(102, 0.23928, -0.01954), ray(203, 0.37689, 0.13301)];
        let projector = Projector::new(Vector3::from(TABLE3_GLOBAL), rays).unwrap();
        let rig = Rig::new(camera.grid, camera.inner, &camera.exterior, projector);
        (rig, camera)
    }

    /// Exact dots come back exactly; the image-noise floor at the plate of the 3rd image
    /// (Z = 200, 1640 mm from the camera) is σZ ≈ Z²σ/(B f) ≈ 2.6 mm at 0.5 px, σXY far smaller.
    #[test]
    fn exact_points_and_the_noise_floor() {
        let (rig, camera) = paper_rig();
        let centre = rig.projector_centred().centre() + rig.camera_centre();
        let mut dots = Vec::new();
        let mut truth = Vec::new();
        for r in rig.projector_centred().rays() {
            let x = centre + r.direction * ((200.0 - centre.z) / r.direction.z);
            let (col, row) = camera.world_to_pixel(&x).unwrap();
            dots.push(DotObservation { id: r.id, col, row });
            truth.push(x);
        }
        for method in [Method::Paper, Method::ClosestApproach] {
            let pts = reconstruct(&rig, &dots, method, Some(0.5), None).unwrap();
            for (p, x) in pts.iter().zip(&truth) {
                assert!((p.point - x).norm() < 1e-6 && p.miss < 1e-6);
                let s = p.sigma.unwrap();
                assert!(s.z > 2.0 && s.z < 3.3, "σZ {s}");
                assert!(s.x < 0.6 * s.z && s.y < 0.3 * s.z, "σ {s}");
            }
        }
        let z = camera.exterior.centre.z - 200.0;
        let formula = z * z * 0.5 * 0.045 / (490.0 * 46.981);
        assert!((formula - 2.63).abs() < 0.01);
        let unknown = [DotObservation {
            id: 7,
            col: 1.0,
            row: 2.0,
        }];
        let err = reconstruct(&rig, &unknown, Method::Paper, None, None).unwrap_err();
        assert!(
            format!("{err:#}").contains("observation 1 (ray 7"),
            "{err:#}"
        );
        assert!(format!("{err:#}").contains("no ray 7"), "{err:#}");
    }
}
