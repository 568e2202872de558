//! What the analysis reads: each frame's points with their covariance, and the calibration's
//! share common to all of them.

use crate::mesh::Mesh;
use crate::{bounding_box, SurfaceError, MIN_POINTS};
use nalgebra::{DMatrix, Matrix3, Vector3};
use std::collections::HashMap;

/// A measured surface point (camera system: x right, y up, z toward the camera; mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanPoint {
    /// The point.
    pub position: Vector3<f64>,
    /// Its own covariance (mm²): the share independent from point to point.
    pub covariance: Matrix3<f64>,
    /// Its ray's node (column, row) in the projector's lattice: neighbouring nodes make the
    /// mesh's triangles. None for a point from elsewhere (a frame's points all have one or
    /// none): the mesh is then the Delaunay triangulation of the points' directions from the
    /// camera.
    pub ray: Option<[i32; 2]>,
}

/// The calibration's error common to all points of a frame (and to every frame measured with
/// the same calibration): point i's error is its own plus `G_i δ`, one δ for all.
#[derive(Debug, Clone, PartialEq)]
pub enum CommonShare {
    /// None (or not known).
    None,
    /// The same error δ ~ N(0, Σ) in every point (G_i = I): a common shift.
    Shift(Matrix3<f64>),
    /// δ ~ N(0, `covariance`) over the calibration's k core parameters; `sensitivity` (3n × k)
    /// stacks each point's G_i (rows 3i..3i+3 for point i).
    Core {
        /// Σ (k × k).
        covariance: DMatrix<f64>,
        /// G (3n × k).
        sensitivity: DMatrix<f64>,
    },
}

impl CommonShare {
    /// k, the size of δ.
    pub fn size(&self) -> usize {
        match self {
            CommonShare::None => 0,
            CommonShare::Shift(_) => 3,
            CommonShare::Core { covariance, .. } => covariance.nrows(),
        }
    }

    /// Σ, the covariance of δ.
    pub fn covariance(&self) -> DMatrix<f64> {
        match self {
            CommonShare::None => DMatrix::zeros(0, 0),
            CommonShare::Shift(c) => DMatrix::from_fn(3, 3, |i, j| c[(i, j)]),
            CommonShare::Core { covariance, .. } => covariance.clone(),
        }
    }

    /// G_i of point i (3 × k).
    pub fn sensitivity(&self, i: usize) -> DMatrix<f64> {
        match self {
            CommonShare::None => DMatrix::zeros(3, 0),
            CommonShare::Shift(_) => DMatrix::identity(3, 3),
            CommonShare::Core { sensitivity, .. } => sensitivity.rows(3 * i, 3).into_owned(),
        }
    }
}

/// One frame's points, as reconstructed with one calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// The points.
    pub points: Vec<ScanPoint>,
    /// The calibration's fingerprint (frames of one analysis must share it).
    pub calibration: Option<u64>,
    /// Its share common to all points.
    pub common: CommonShare,
}

impl Frame {
    /// A frame without a calibration's common share.
    pub fn new(points: Vec<ScanPoint>) -> Self {
        Self {
            points,
            calibration: None,
            common: CommonShare::None,
        }
    }

    /// The mesh over the frame's points: over the projector lattice when they carry their
    /// rays, else over the directions the camera sees them in.
    pub fn mesh(&self) -> Mesh {
        let positions: Vec<_> = self.points.iter().map(|p| p.position).collect();
        let rays: Option<Vec<_>> = self.points.iter().map(|p| p.ray).collect();
        match rays {
            Some(rays) => Mesh::over_lattice(&positions, &rays),
            None => Mesh::over_directions(&positions),
        }
    }

    /// The frame thinned to what a dot pattern `spacing` apart would give ([`thin`]): each
    /// cell's point nearest its centre, with the cell as its ray.
    pub fn thinned(&self, spacing: f64) -> Frame {
        let positions: Vec<Vector3<f64>> = self.points.iter().map(|p| p.position).collect();
        let kept = thin(&positions, spacing);
        let mut thinned = self.only(&kept.iter().map(|&(i, _)| i).collect::<Vec<_>>());
        for (p, &(_, node)) in thinned.points.iter_mut().zip(&kept) {
            p.ray = Some(node);
        }
        thinned
    }

    /// The frame's points `kept` (indices, in that order), the common share's rows following
    /// them.
    pub fn only(&self, kept: &[usize]) -> Frame {
        let common = match &self.common {
            CommonShare::Core {
                covariance,
                sensitivity,
            } => CommonShare::Core {
                covariance: covariance.clone(),
                sensitivity: DMatrix::from_fn(3 * kept.len(), sensitivity.ncols(), |r, c| {
                    sensitivity[(3 * kept[r / 3] + r % 3, c)]
                }),
            },
            other => other.clone(),
        };
        Frame {
            points: kept.iter().map(|&i| self.points[i]).collect(),
            calibration: self.calibration,
            common,
        }
    }

    /// Checks the frame's numbers: finite points in front of the camera, symmetric
    /// non-negative covariances, a common share of the right size, rays used once, and a span
    /// in mm (not metres); `index` names the frame in the error.
    pub fn validate(&self, index: usize) -> Result<(), SurfaceError> {
        let bad = |point: usize, problem: &str| SurfaceError::BadPoint {
            frame: index,
            point,
            problem: problem.to_string(),
        };
        for (i, p) in self.points.iter().enumerate() {
            if !p.position.iter().all(|x| x.is_finite()) {
                return Err(bad(i, "its coordinates are not finite"));
            }
            let c = &p.covariance;
            let symmetric = (c - c.transpose()).amax() <= 1e-9 * c.amax().max(1e-300);
            let eig = c.symmetric_eigenvalues();
            if !c.iter().all(|x| x.is_finite()) || !symmetric || eig.min() < -1e-12 * eig.max() {
                return Err(bad(i, "its covariance is not symmetric non-negative"));
            }
        }
        if let CommonShare::Core {
            covariance,
            sensitivity,
        } = &self.common
        {
            let k = covariance.nrows();
            if covariance.ncols() != k
                || sensitivity.ncols() != k
                || sensitivity.nrows() != 3 * self.points.len()
            {
                return Err(SurfaceError::BadCommonShare {
                    frame: index,
                    problem: format!(
                        "{k}×{} covariance and {}×{} sensitivity for {} points (needs k×k and 3n×k)",
                        covariance.ncols(),
                        sensitivity.nrows(),
                        sensitivity.ncols(),
                        self.points.len()
                    ),
                });
            }
        }
        let mut seen = HashMap::new();
        for (i, p) in self.points.iter().enumerate() {
            if p.position == Vector3::zeros() {
                return Err(bad(
                    i,
                    "it is (0, 0, 0), the camera's centre: some scanners write that for a point \
                     not measured; leave such points out",
                ));
            }
            if p.position.z >= 0.0 {
                return Err(bad(
                    i,
                    "it lies behind the camera (z ≥ 0; the camera system's z points toward the \
                     camera)",
                ));
            }
            if p.ray.is_some() != self.points[0].ray.is_some() {
                return Err(bad(i, "the frame mixes points with and without their rays"));
            }
            if let Some(first) = p.ray.and_then(|ray| seen.insert(ray, i)) {
                return Err(bad(
                    i,
                    &format!("its ray {:?} is point {first}'s too", p.ray),
                ));
            }
        }
        // A back spans hundreds of mm; one in metres, read as mm, spans a few.
        let (lo, hi) = bounding_box(self.points.iter().map(|p| p.position));
        let span = hi - lo;
        if self.points.len() >= MIN_POINTS && span.max() < 10.0 {
            return Err(SurfaceError::NoBack {
                frame: index,
                problem: format!(
                    "its points span {:.3} × {:.3} × {:.3} mm: are they in metres? The analysis \
                     reads mm",
                    span.x, span.y, span.z
                ),
            });
        }
        Ok(())
    }
}

/// Checks that all frames were measured with one calibration (the same fingerprint and the
/// same common covariance).
pub fn same_calibration(frames: &[Frame]) -> Result<(), SurfaceError> {
    let first = frames.first().ok_or(SurfaceError::NoFrames)?;
    for (k, f) in frames.iter().enumerate().skip(1) {
        let same_share = match (&first.common, &f.common) {
            (CommonShare::None, CommonShare::None) => true,
            (CommonShare::Shift(a), CommonShare::Shift(b)) => a == b,
            (CommonShare::Core { covariance: a, .. }, CommonShare::Core { covariance: b, .. }) => {
                a == b
            }
            _ => false,
        };
        if f.calibration != first.calibration || !same_share {
            return Err(SurfaceError::MixedCalibrations {
                frame: k,
                first: first.calibration,
                this: f.calibration,
            });
        }
    }
    Ok(())
}

/// Thins a dense cloud to what a dot pattern `spacing` apart would give: the point nearest the
/// centre of each square cell of the camera's x-y plane, with the cell as its lattice node.
/// Returns (index of the kept point, node).
pub fn thin(positions: &[Vector3<f64>], spacing: f64) -> Vec<(usize, [i32; 2])> {
    let mut best: HashMap<[i32; 2], (f64, usize)> = HashMap::new();
    for (i, p) in positions.iter().enumerate() {
        let (u, v) = (p.x / spacing, p.y / spacing);
        let node = [u.round() as i32, v.round() as i32];
        let d = (u - u.round()).powi(2) + (v - v.round()).powi(2);
        let entry = best.entry(node).or_insert((f64::INFINITY, i));
        if d < entry.0 {
            *entry = (d, i);
        }
    }
    let mut kept: Vec<_> = best.into_iter().map(|(node, (_, i))| (i, node)).collect();
    kept.sort_unstable();
    kept
}
