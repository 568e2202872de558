//! Finding a frame's back (the largest piece of its mesh that is not a plane, checked for a
//! back's shape) and the analysis axes.

use super::{Axes, Options, PlaneLeftOut, Posture, PLANE_RMS_MM, SCATTERED};
use crate::input::Frame;
use crate::mesh::Piece;
use crate::{bounding_box, SurfaceError, MIN_POINTS};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use std::collections::BTreeSet;

/// A frame's back: its points in the analysis axes, those of its largest piece, the piece's
/// surface (its triangles and its gaps spanned) and the points on the surface's rim.
pub(super) struct Back {
    pub(super) positions: Vec<Vector3<f64>>,
    pub(super) kept: Vec<usize>,
    pub(super) surface: Vec<[usize; 3]>,
    pub(super) rim: BTreeSet<usize>,
    pub(super) spacing: f64,
    /// How irregularly its points lie ([`crate::mesh::Mesh::irregularity`]).
    pub(super) irregularity: f64,
}

/// What [`find_back`] finds in a frame: its back's points and triangles, their dot spacing,
/// how irregularly they lie, and the planes larger than the back left out.
pub(super) struct Found {
    pub(super) kept: Vec<usize>,
    pub(super) triangles: Vec<[usize; 3]>,
    pub(super) spacing: f64,
    pub(super) irregularity: f64,
    pub(super) planes: Vec<PlaneLeftOut>,
}

/// The back in a frame: the largest smooth piece of its mesh that is not a plane (a wall or
/// the floor in view is left out, and listed), of points not scattered at random
/// ([`SCATTERED`]).
pub(super) fn find_back(frame: &Frame, index: usize) -> Result<Found, SurfaceError> {
    if frame.points.len() < MIN_POINTS {
        return Err(SurfaceError::TooFewPoints {
            frame: index,
            points: frame.points.len(),
            needed: MIN_POINTS,
        });
    }
    let mesh = frame.mesh();
    let pieces = mesh.pieces();
    let largest = pieces.first().map_or(0, |p| p.points.len());
    if largest < MIN_POINTS {
        return Err(SurfaceError::NoBack {
            frame: index,
            problem: format!(
                "its largest connected surface has {largest} points (needs {MIN_POINTS})"
            ),
        });
    }
    let candidates: Vec<Piece> = pieces
        .into_iter()
        .take_while(|p| p.points.len() >= MIN_POINTS)
        .collect();
    let positions = |p: &Piece| p.points.iter().map(|&i| mesh.points[i]).collect::<Vec<_>>();
    let flatness = |p: &Piece| principal(positions(p).into_iter()).1;
    let Some(at) = candidates.iter().position(|p| flatness(p) >= PLANE_RMS_MM) else {
        return Err(SurfaceError::Plane {
            frame: index,
            rms_mm: flatness(&candidates[0]),
            piece: largest,
            points: frame.points.len(),
        });
    };
    let back = &candidates[at];
    // The spacing and irregularity are those of the frame without the planes left out (of
    // the whole frame where there are none, as the analysis was made with them).
    let planar: BTreeSet<usize> = candidates[..at]
        .iter()
        .flat_map(|p| p.points.iter().copied())
        .collect();
    let rest: Vec<usize> = (0..mesh.points.len())
        .filter(|i| !planar.contains(i))
        .collect();
    let rest_triangles: Vec<[usize; 3]> = mesh
        .triangles
        .iter()
        .filter(|t| t.iter().all(|i| !planar.contains(i)))
        .copied()
        .collect();
    let irregularity = mesh.irregularity(&rest_triangles);
    if irregularity > SCATTERED {
        return Err(SurfaceError::Scattered {
            frame: index,
            irregularity,
        });
    }
    let centre = |p: &Piece| positions(p).iter().sum::<Vector3<f64>>() / p.points.len() as f64;
    let back_distance = centre(back).norm();
    let planes = candidates[..at]
        .iter()
        .map(|p| {
            let c = centre(p);
            PlaneLeftOut {
                frame: index,
                points: p.points.len(),
                centre: c.into(),
                beyond_mm: c.norm() - back_distance,
            }
        })
        .collect();
    Ok(Found {
        kept: back.points.clone(),
        triangles: back.triangles.clone(),
        spacing: mesh.spacing_over(&rest),
        irregularity,
        planes,
    })
}

/// The principal directions of points (largest spread first) and their RMS distance from
/// their best plane.
fn principal(points: impl Iterator<Item = Vector3<f64>> + Clone) -> (Matrix3<f64>, f64) {
    let n = points.clone().count() as f64;
    let mean = points.clone().sum::<Vector3<f64>>() / n;
    let cov = points
        .map(|p| (p - mean) * (p - mean).transpose())
        .sum::<Matrix3<f64>>()
        / n;
    let e = SymmetricEigen::new(cov);
    let mut order = [0, 1, 2];
    order.sort_by(|&i, &j| e.eigenvalues[j].total_cmp(&e.eigenvalues[i]));
    let dirs = Matrix3::from_columns(&order.map(|k| e.eigenvectors.column(k).into_owned()));
    (dirs, e.eigenvalues[order[2]].max(0.0).sqrt())
}

fn unit(v: Vector3<f64>, what: &str) -> Result<Vector3<f64>, SurfaceError> {
    v.try_normalize(1e-12)
        .ok_or_else(|| SurfaceError::BadOptions(format!("the {what} is a zero vector")))
}

/// The analysis axes from the options and the first frame's back.
pub(super) fn axes(options: &Options, back: &[Vector3<f64>]) -> Result<Axes, SurfaceError> {
    let (axis, up) = match options.posture {
        Posture::Standing => {
            let axis = unit(options.vertical.unwrap_or(Vector3::y()), "vertical")?;
            (axis, Vector3::z())
        }
        Posture::ForwardBent => {
            let up = unit(options.up.unwrap_or(Vector3::z()), "up direction")?;
            let axis = match options.axis {
                Some(a) => unit(a, "trunk axis")?,
                None => {
                    let across_up = back.iter().map(|p| p - up * up.dot(p));
                    let d: Vector3<f64> = principal(across_up).0.column(0).into();
                    if d.x > 0.0 {
                        -d
                    } else {
                        d
                    }
                }
            };
            (axis, up)
        }
    };
    let up = unit(up - axis * axis.dot(&up), "up direction across the axis")?;
    let across = axis.cross(&up);
    Ok(Axes {
        across: across.into(),
        axis: axis.into(),
        up: up.into(),
    })
}

/// A back is wider and longer than a few dots.
pub(super) fn check_shape(b: &Back, frame: usize) -> Result<(), SurfaceError> {
    let (lo, hi) = bounding_box(b.kept.iter().map(|&i| b.positions[i]));
    let (width, length) = (hi.x - lo.x, hi.y - lo.y);
    if width < 8.0 * b.spacing || length < 8.0 * b.spacing {
        return Err(SurfaceError::NoBack {
            frame,
            problem: format!(
                "its surface spans {width:.0} × {length:.0} mm, under 8 dot spacings ({:.1} mm) either way",
                b.spacing
            ),
        });
    }
    Ok(())
}
