//! Points reconstructed with the adjusted system: a dot's point in the camera system or the plate
//! frame with its covariance, split into the shares common to all points and its own.

use super::{pose_array, pose_from, Frame, SystemError, SystemModel};
use crate::projector_calibration::DotObservation;
use crate::residual::{inner_from_array, inner_to_array};
use deltaz_shared::camera::PixelGrid;
use deltaz_shared::intersection::{closest_approach, intersect_paper};
use deltaz_shared::projector::Ray;
use deltaz_shared::rig::Method;
use nalgebra::{DMatrix, Matrix3, Vector3};

/// A point reconstructed in the camera system with its covariance in two shares.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SystemPoint {
    /// The point (camera system, mm).
    pub point: Vector3<f64>,
    /// Covariance from the dot's image noise (mm²).
    pub image: Matrix3<f64>,
    /// Covariance from the calibration (mm²).
    pub calibration: Matrix3<f64>,
}

/// A reconstructed point's covariance split by what is shared between points: its error is
/// `common` δc + its own error, δc the error of the core parameters (inner orientation, centre,
/// datum pose; covariance [`SystemModel::core_covariance`]) common to every point, and the own
/// error (the dot's image noise and its ray's parameters given the core) independent from
/// point to point but for points of the same ray.
///
/// A ray's parameters r depend on the core through their cross covariance: r = A δc + u with
/// A = Σ_rc Σ_c⁻¹ and u independent of the core and of the other rays (the rays are eliminated
/// one by one in the Schur complement), Σ_u = Σ_r − A Σ_cr.
#[derive(Debug, Clone, PartialEq)]
pub struct PointShares {
    /// The point.
    pub point: Vector3<f64>,
    /// Covariance from the dot's image noise (mm²).
    pub image: Matrix3<f64>,
    /// Covariance from the ray's own parameter error u (mm²).
    pub ray: Matrix3<f64>,
    /// The point's sensitivity to the core parameters (3 × core), ray's share A included.
    pub common: DMatrix<f64>,
}

impl PointShares {
    /// The calibration's whole covariance of the point: common G Σ_c Gᵀ plus the ray's own.
    pub fn calibration(&self, core_covariance: &DMatrix<f64>) -> Matrix3<f64> {
        let c = &self.common * core_covariance * self.common.transpose();
        Matrix3::from_fn(|a, b| c[(a, b)]) + self.ray
    }

    /// The covariance between this point and `other`, a point of another ray: the share of the
    /// common core error.
    pub fn cross(&self, other: &PointShares, core_covariance: &DMatrix<f64>) -> Matrix3<f64> {
        let c = &self.common * core_covariance * other.common.transpose();
        Matrix3::from_fn(|a, b| c[(a, b)])
    }
}

impl SystemModel {
    /// A dot reconstructed in `frame` with its covariance: from the image noise of the dot (the
    /// estimated σ of the dots) and from the calibration (inner orientation, centre, the ray's
    /// parameters and, in the plate frame, the datum pose, with all their correlations),
    /// first-order by central differences.
    pub fn reconstruct(
        &self,
        grid: &PixelGrid<f64>,
        dot: &DotObservation,
        method: Method,
        frame: Frame,
    ) -> Result<SystemPoint, SystemError> {
        let l = self.linearise(grid, dot, method, frame)?;
        let cov = &l.jacobian * self.ray_parameter_covariance(l.ray) * l.jacobian.transpose();
        Ok(SystemPoint {
            point: l.point,
            image: l.image,
            calibration: Matrix3::from_fn(|a, b| cov[(a, b)]),
        })
    }

    /// The pseudo-inverse of the core covariance that [`Self::reconstruct_shares`] splits the
    /// rays' parameters with, computed once for all dots: a core parameter held fixed (a zero
    /// row and column, and zero cross covariance) splits off nothing.
    pub fn core_split(&self) -> Result<CoreSplit, SystemError> {
        let c = &self.core_covariance;
        c.clone()
            .pseudo_inverse(c.amax() * 1e-14)
            .map(CoreSplit)
            .map_err(|_| SystemError::Singular)
    }

    /// [`Self::reconstruct`] with the calibration's covariance split into the share common to
    /// every point and the ray's own ([`PointShares`]), for the covariance between points;
    /// `split` is this model's [`Self::core_split`].
    pub fn reconstruct_shares(
        &self,
        split: &CoreSplit,
        grid: &PixelGrid<f64>,
        dot: &DotObservation,
        method: Method,
        frame: Frame,
    ) -> Result<PointShares, SystemError> {
        let l = self.linearise(grid, dot, method, frame)?;
        let ray = &self.rays[l.ray];
        // Split the ray's parameters r = A δc + u (see [`PointShares`]).
        let core = self.core_covariance.nrows();
        let a = &ray.cross * &split.0;
        let own = &ray.covariance - &a * ray.cross.transpose();
        let j_core = l.jacobian.columns(0, core);
        let j_ray = l.jacobian.columns(core, ray.params.len());
        let common = j_core + j_ray * a;
        let ray_cov = j_ray * own * j_ray.transpose();
        Ok(PointShares {
            point: l.point,
            image: l.image,
            ray: Matrix3::from_fn(|a, b| ray_cov[(a, b)]),
            common,
        })
    }

    /// A dot's point in `frame`, its image-noise covariance, and its Jacobian with respect to
    /// the core parameters and then its ray's (central differences).
    fn linearise(
        &self,
        grid: &PixelGrid<f64>,
        dot: &DotObservation,
        method: Method,
        frame: Frame,
    ) -> Result<Linearised, SystemError> {
        let datum = match (frame, &self.datum) {
            (Frame::Plate, None) => {
                return Err(SystemError::Geometry(
                    "the calibration has no plate datum: points are in the camera system only"
                        .into(),
                ))
            }
            (_, datum) => datum.as_ref().map(|d| d.pose),
        };
        let index = self
            .rays
            .binary_search_by_key(&dot.id, |r| r.id)
            .map_err(|_| SystemError::Geometry(format!("no ray {}", dot.id)))?;
        let ray = &self.rays[index];
        let k = self.inner_free.len();
        let mut theta: Vec<f64> = self
            .inner_free
            .iter()
            .map(|&i| inner_to_array(&self.inner)[i])
            .collect();
        theta.extend(self.centre.iter());
        let ray_at = k + 3 + if datum.is_some() { 6 } else { 0 };
        if let Some(pose) = &datum {
            theta.extend(pose_array(pose));
        }
        theta.extend(&ray.params);
        let point = |theta: &[f64], col: f64, row: f64| -> Result<Vector3<f64>, SystemError> {
            let mut a = inner_to_array(&self.inner);
            for (slot, &i) in self.inner_free.iter().enumerate() {
                a[i] = theta[slot];
            }
            let inner = inner_from_array(a);
            let refined = inner.refine(grid.pixel_to_photo(col, row));
            let camera = Ray {
                point: Vector3::zeros(),
                direction: Vector3::new(refined.x, refined.y, -inner.f),
            };
            let centre = Vector3::new(theta[k], theta[k + 1], theta[k + 2]);
            let p = &theta[ray_at..];
            let offset = match p.len() {
                4 => Vector3::new(p[2], p[3], 0.0),
                _ => Vector3::zeros(),
            };
            let projector = Ray {
                point: centre + offset,
                direction: -Vector3::new(p[0], p[1], 1.0),
            };
            let hit = match method {
                Method::Paper => intersect_paper(&camera, &projector),
                Method::ClosestApproach => closest_approach(&camera, &projector),
            };
            let x = hit
                .map(|h| h.point)
                .map_err(|e| SystemError::Geometry(format!("ray {}: {e}", dot.id)))?;
            Ok(match frame {
                Frame::Camera => x,
                Frame::Plate => {
                    let pose: [f64; 6] = theta[k + 3..k + 9].try_into().unwrap_or([0.0; 6]);
                    pose_from(pose).camera_to_world(&x)
                }
            })
        };
        let x = point(&theta, dot.col, dot.row)?;
        let h_px = 0.01;
        let d_col = (point(&theta, dot.col + h_px, dot.row)?
            - point(&theta, dot.col - h_px, dot.row)?)
            / (2.0 * h_px);
        let d_row = (point(&theta, dot.col, dot.row + h_px)?
            - point(&theta, dot.col, dot.row - h_px)?)
            / (2.0 * h_px);
        let s2 = self.sigma_dots_px * self.sigma_dots_px;
        let image = (d_col * d_col.transpose() + d_row * d_row.transpose()) * s2;
        let mut jac = DMatrix::zeros(3, theta.len());
        for i in 0..theta.len() {
            let h = 1e-6 * theta[i].abs().max(1e-3);
            let (mut up, mut down) = (theta.clone(), theta.clone());
            up[i] += h;
            down[i] -= h;
            let d = (point(&up, dot.col, dot.row)? - point(&down, dot.col, dot.row)?) / (2.0 * h);
            jac.set_column(i, &d);
        }
        Ok(Linearised {
            point: x,
            image,
            jacobian: jac,
            ray: index,
        })
    }
}

/// The pseudo-inverse of a model's core covariance ([`SystemModel::core_split`]).
#[derive(Debug, Clone)]
pub struct CoreSplit(DMatrix<f64>);

/// [`SystemModel::linearise`]'s result.
struct Linearised {
    point: Vector3<f64>,
    image: Matrix3<f64>,
    /// 3 × (core + the ray's parameters).
    jacobian: DMatrix<f64>,
    /// The ray's index in [`SystemModel::rays`].
    ray: usize,
}
