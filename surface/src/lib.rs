//! deltaz-surface: back-surface topography from structured-light points, the measures a
//! scoliosis screening reads, each with its σ.
//!
//! From each frame's points ([`Frame`]: positions in the camera system, each point's
//! covariance, the calibration's common share), a mesh over the projector lattice (or, for
//! points without their rays, over what the camera sees: [`mesh`]) finds the back (the
//! largest connected piece; occlusions and depth jumps leave holes), one smooth
//! surface is fitted to all frames of a subject with the frames registered onto the first
//! (`fit`), and [`analyse`] measures it: the symmetry line ([`symmetry`]), the surface
//! rotation along it, its lateral deviation, trunk imbalance and inclination, skin angles,
//! the sagittal profile (kyphosis, lordosis), the virtual scoliometer on a forward-bent scan
//! ([`scoliometer`]) and a mirror-asymmetry map ([`BackAnalysis`]). [`compare()`] tells which
//! changes between two analyses exceed measurement noise.
//!
//! Conventions: mm and degrees in the output; the camera system x right, y up, z toward the
//! camera, the subject's back to the camera (the subject's right is +x); vertical +y unless
//! given; `rotation_deg` is atan(∂z/∂x) of the surface at the symmetry line, positive when the
//! +x side comes toward the camera.
#![deny(missing_docs)]

pub mod analysis;
pub mod compare;
mod fit;
pub mod input;
pub mod mesh;
pub mod scoliometer;
mod spline;
mod support;
pub mod symmetry;

pub use analysis::{
    analyse, Axes, BackAnalysis, Level, Map, Options, PlaneLeftOut, Posture, Sway, WildPoint,
};
pub use compare::{compare, Change, Comparison};
pub use input::{thin, CommonShare, Frame, ScanPoint};

use nalgebra::Vector3;

/// Fewer points than this in a frame are not a back.
pub const MIN_POINTS: usize = 40;

/// The least and greatest coordinates of `points` (infinite without any).
pub(crate) fn bounding_box(
    points: impl IntoIterator<Item = Vector3<f64>>,
) -> (Vector3<f64>, Vector3<f64>) {
    points.into_iter().fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(lo, hi), p| (lo.inf(&p), hi.sup(&p)),
    )
}

/// The median of `values` (the upper one of an even count; 0 without any).
pub(crate) fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied().unwrap_or(0.0)
}

/// Why a cloud could not be analysed.
#[derive(Debug, Clone, PartialEq)]
pub enum SurfaceError {
    /// No frame was given.
    NoFrames,
    /// A point's numbers are unusable.
    BadPoint {
        /// The frame (0-based).
        frame: usize,
        /// The point (0-based).
        point: usize,
        /// What is wrong.
        problem: String,
    },
    /// The common share's matrices do not fit the frame.
    BadCommonShare {
        /// The frame.
        frame: usize,
        /// What is wrong.
        problem: String,
    },
    /// A frame was measured with another calibration than the first.
    MixedCalibrations {
        /// The frame.
        frame: usize,
        /// The first frame's fingerprint.
        first: Option<u64>,
        /// This frame's.
        this: Option<u64>,
    },
    /// Too few points to be a back.
    TooFewPoints {
        /// The frame.
        frame: usize,
        /// Its points.
        points: usize,
        /// How many are needed.
        needed: usize,
    },
    /// No back in view.
    NoBack {
        /// The frame.
        frame: usize,
        /// Why not.
        problem: String,
    },
    /// Every surface in the frame is a plane: no back.
    Plane {
        /// The frame.
        frame: usize,
        /// Its RMS distance from its best plane (mm).
        rms_mm: f64,
        /// The points of the largest smooth piece of its mesh, which was measured.
        piece: usize,
        /// The frame's points.
        points: usize,
    },
    /// The points are scattered at random ([`analysis::SCATTERED`]), too irregularly for a
    /// back's detail.
    Scattered {
        /// The frame (0-based).
        frame: usize,
        /// How irregularly its points lie ([`mesh::Mesh::irregularity`]).
        irregularity: f64,
    },
    /// The surface fit's normal equations are singular.
    Singular,
    /// No level across the back where a symmetry line could be found.
    NoLevels,
    /// The symmetry line is undetermined: the sections are about as symmetric about any
    /// position, their asymmetry under [`analysis::LINE_UNDETERMINED`] times the noise's (a
    /// surface without a back's features).
    LineUndetermined {
        /// [`analysis::BackAnalysis::asymmetry_over_noise`].
        asymmetry: f64,
        /// The surface fit's χ ([`analysis::BackAnalysis::fit_chi`]): well under 1, the
        /// points' σ is overstated, and their noise taken for more than it is.
        chi: f64,
    },
    /// The options are unusable.
    BadOptions(String),
}

impl std::fmt::Display for SurfaceError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SurfaceError::NoFrames => f.write_str("no frame to analyse"),
            SurfaceError::BadPoint {
                frame,
                point,
                problem,
            } => write!(f, "frame {frame}, point {point}: {problem}"),
            SurfaceError::BadCommonShare { frame, problem } => {
                write!(
                    f,
                    "frame {frame}: the calibration's common share does not fit: {problem}"
                )
            }
            SurfaceError::MixedCalibrations { frame, first, this } => {
                let name = |c: &Option<u64>| c.map_or("none".to_string(), |c| format!("{c:016x}"));
                write!(
                    f,
                    "frame {frame} was measured with calibration {} but frame 0 with {}: \
                     frames of one analysis need one calibration",
                    name(this),
                    name(first)
                )
            }
            SurfaceError::TooFewPoints {
                frame,
                points,
                needed,
            } => write!(
                f,
                "frame {frame} has {points} points, a back needs at least {needed}"
            ),
            SurfaceError::LineUndetermined { asymmetry, chi } => write!(
                f,
                "no back's symmetry line: the surface is about as symmetric about any position \
                 across it, its asymmetry {asymmetry:.1} times what the points' noise makes \
                 (under {}), as a surface of even curvature is: it lacks a back's features (the \
                 spinous groove, the muscles beside it), or its points' σ is overstated (they \
                 scatter about the surface {chi:.2} times their σ, about 1 where it holds)",
                analysis::LINE_UNDETERMINED
            ),
            SurfaceError::NoBack { frame, problem } => {
                write!(f, "frame {frame}: no back in view: {problem}")
            }
            SurfaceError::Plane {
                frame,
                rms_mm,
                piece,
                points,
            } => {
                write!(
                    f,
                    "frame {frame} is a plane, not a back: every smooth piece of its mesh of {} \
                     points or more is one, and the largest ({piece} of its {points} points) lies \
                     within {rms_mm:.2} mm RMS of its best plane (a back departs by more than {} \
                     mm)",
                    MIN_POINTS,
                    analysis::PLANE_RMS_MM
                )?;
                if 2 * piece < *points {
                    f.write_str(
                        "; depth jumps, folds or a noise as large as the dots' spacing cut it \
                         from the rest",
                    )?;
                }
                Ok(())
            }
            SurfaceError::Scattered {
                frame,
                irregularity,
            } => write!(
                f,
                "frame {frame}: the points are scattered at random (their nearest neighbours' \
                 distances spread by {:.0} % of their mean, a grid's by 5 %), too irregularly to \
                 resolve a back: sampled so, the back model's symmetry line came out 5-30 mm \
                 off. A dense scan thinned evenly (to three times its spacing), or a dot \
                 pattern, samples evenly",
                100.0 * irregularity
            ),
            SurfaceError::Singular => {
                f.write_str("the surface fit is singular (too few points spread over the back)")
            }
            SurfaceError::NoLevels => f.write_str(
                "no level across the back where the symmetry line could be found \
                 (is the back's middle in view?)",
            ),
            SurfaceError::BadOptions(why) => write!(f, "bad options: {why}"),
        }
    }
}

impl std::error::Error for SurfaceError {}
