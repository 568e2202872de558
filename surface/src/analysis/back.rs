//! Finding a frame's back (the largest piece of its mesh, checked for a back's shape)
//! and the analysis axes.

use super::{Axes, Options, Posture, MIN_POINTS, PLANE_RMS_MM, SCATTERED};
use crate::fit::Sample;
use crate::input::Frame;
use crate::SurfaceError;
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

/// A frame's back piece: its points, its triangles, the dot spacing and how irregularly the
/// points lie.
type Piece = (Vec<usize>, Vec<[usize; 3]>, f64, f64);

/// The back in a frame: the largest smooth piece of its mesh, of points not scattered at
/// random ([`SCATTERED`]).
pub(super) fn find_back(frame: &Frame, index: usize) -> Result<Piece, SurfaceError> {
    if frame.points.len() < MIN_POINTS {
        return Err(SurfaceError::TooFewPoints {
            frame: index,
            points: frame.points.len(),
            needed: MIN_POINTS,
        });
    }
    let mesh = frame.mesh();
    let (kept, triangles) = mesh.largest_piece();
    if kept.len() < MIN_POINTS {
        return Err(SurfaceError::NoBack {
            frame: index,
            problem: format!(
                "its largest connected surface has {} points (needs {MIN_POINTS})",
                kept.len()
            ),
        });
    }
    let irregularity = mesh.irregularity();
    if irregularity > SCATTERED {
        return Err(SurfaceError::Scattered {
            frame: index,
            irregularity,
        });
    }
    Ok((kept, triangles, mesh.spacing, irregularity))
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
pub(super) fn bounds(samples: &[Sample]) -> ([f64; 2], [f64; 2]) {
    let fold = |k: usize, f: fn(f64, f64) -> f64, start: f64| {
        samples.iter().map(|s| s.p[k]).fold(start, f)
    };
    (
        [
            fold(0, f64::min, f64::INFINITY),
            fold(1, f64::min, f64::INFINITY),
        ],
        [
            fold(0, f64::max, f64::NEG_INFINITY),
            fold(1, f64::max, f64::NEG_INFINITY),
        ],
    )
}

/// A back is wider and longer than a few dots (and than 10 mm: a cloud in metres is not a
/// back in mm) and far from flat.
pub(super) fn check_shape(b: &Back, frame: usize) -> Result<(), SurfaceError> {
    let points = b.kept.iter().map(|&i| b.positions[i]);
    let (_, rms) = principal(points.clone());
    let extent = |k: usize| {
        let (lo, hi) = points
            .clone()
            .map(|p| p[k])
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| {
                (l.min(x), h.max(x))
            });
        hi - lo
    };
    let (width, length) = (extent(0), extent(1));
    if width.max(length) < 10.0 {
        return Err(SurfaceError::NoBack {
            frame,
            problem: format!(
                "its surface spans {width:.3} × {length:.3} mm: are its points in metres? The \
                 analysis reads mm"
            ),
        });
    }
    if width < 8.0 * b.spacing || length < 8.0 * b.spacing {
        return Err(SurfaceError::NoBack {
            frame,
            problem: format!(
                "its surface spans {width:.0} × {length:.0} mm, under 8 dot spacings ({:.1} mm) either way",
                b.spacing
            ),
        });
    }
    if rms < PLANE_RMS_MM {
        return Err(SurfaceError::Plane {
            frame,
            rms_mm: rms,
            piece: b.kept.len(),
            points: b.positions.len(),
        });
    }
    Ok(())
}
