//! The back analysis: from one subject's frames to the indices a screening reads, each with
//! its σ.
//!
//! Levels are sections across the trunk's axis, one dot spacing apart, where the measured
//! trunk is at least [`MIN_WIDTH`] of its median width. At each, the symmetry point
//! ([`crate::symmetry`]) over a window of a quarter of the median width either side, and from
//! the surface there: the surface rotation atan(∂n/∂a) as the section's mirror symmetry gives
//! it (the tilt of its mirror axis from n: a section symmetric about that axis has the slope
//! tan θ at its symmetry point, and the window's points measure it, not the slope at one
//! point, which the lattice's sampling of the spinous groove would bias), the depth, the
//! sagittal slope
//! atan(∂n/∂v), the skin angle of two points 10 % of the line's length either side, and bent
//! forward the scoliometer's angle ([`crate::scoliometer`]) over a third of the median width
//! either side. Then along the line: its lateral deviation from the line through its ends, the
//! trunk imbalance (its top's offset from its bottom across the axis), the trunk inclination
//! (the angle of the line through its ends from the axis, in the sagittal plane, positive when
//! the top is nearer the camera), kyphosis and lordosis (standing: the thoraco-lumbar
//! inflection is where the sagittal slope is largest, the cervico-thoracic and lumbo-sacral
//! ones where it is least above and below it; kyphosis is the slope's change from the upper to
//! the middle one, lordosis from the lower). Every value is a function of the fitted surface;
//! its σ is its gradient carried through the fit's covariance ([`crate::fit`]).

use crate::fit::{fit, Fit, Sample};
use crate::input::{same_calibration, Frame};
use crate::mesh::Mesh;
use crate::scoliometer::resting_line;
use crate::spline::{Grid, D};
use crate::support::Support;
use crate::symmetry::{coarse, symmetry_at, Symmetry};
use crate::SurfaceError;
use nalgebra::{DMatrix, DVector, Matrix3, SymmetricEigen, Vector3};
use serde::{Deserialize, Serialize};

/// How the subject stood.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Posture {
    /// Upright, back to the camera.
    Standing,
    /// Bent forward (Adams): the trunk's axis lies across the image.
    ForwardBent,
}

/// What the analysis is told.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// Standing or bent forward.
    pub posture: Posture,
    /// Standing: the trunk's axis, the vertical (default +y).
    pub vertical: Option<Vector3<f64>>,
    /// Bent forward: the direction out of the back toward the camera (default +z).
    pub up: Option<Vector3<f64>>,
    /// Bent forward: the trunk's axis toward the head (default the back's longest direction
    /// across `up`, signed toward the image's −x).
    pub axis: Option<Vector3<f64>>,
    /// The surface's smoothing length, in dot spacings.
    pub smoothing: f64,
}

impl Options {
    /// A standing back, vertical +y.
    pub fn standing() -> Self {
        Self {
            posture: Posture::Standing,
            vertical: None,
            up: None,
            axis: None,
            smoothing: 0.4,
        }
    }

    /// A back bent forward, up +z.
    pub fn forward_bent() -> Self {
        Self {
            posture: Posture::ForwardBent,
            ..Self::standing()
        }
    }
}

/// The analysis frame in the camera system: a point X has the coordinates (a, v, n) =
/// (across·X, axis·X, up·X); across × axis = up.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Axes {
    /// Across the trunk (the subject's right standing).
    pub across: [f64; 3],
    /// Along the trunk's axis: the levels' coordinate.
    pub axis: [f64; 3],
    /// Toward the camera: the depth.
    pub up: [f64; 3],
}

impl Axes {
    fn matrix(&self) -> Matrix3<f64> {
        Matrix3::from_rows(&[
            Vector3::from(self.across).transpose(),
            Vector3::from(self.axis).transpose(),
            Vector3::from(self.up).transpose(),
        ])
    }
}

/// One level of the symmetry line (mm, degrees; `y` and `symmetry_x` are the level's v and
/// the symmetry point's a in [`Axes`], the camera's y and x standing with the default
/// vertical).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Level {
    /// The level.
    pub y: f64,
    /// The symmetry point across.
    pub symmetry_x: f64,
    /// Its σ.
    pub symmetry_x_sigma: f64,
    /// The surface's depth there.
    pub depth_mm: f64,
    /// Its σ.
    pub depth_sigma_mm: f64,
    /// Surface rotation atan(∂n/∂a) at the symmetry point, positive when the +a side is nearer.
    pub rotation_deg: f64,
    /// Its σ.
    pub rotation_sigma_deg: f64,
    /// The symmetry point's offset from the line through the ends of the symmetry line.
    pub lateral_deviation_mm: f64,
    /// Its σ.
    pub lateral_deviation_sigma_mm: f64,
    /// Sagittal slope atan(∂n/∂v) at the symmetry point, positive when the surface comes
    /// toward the camera going up the trunk.
    pub sagittal_slope_deg: f64,
    /// Its σ.
    pub sagittal_slope_sigma_deg: f64,
    /// Skin angle: of the line through the surface points [`BackAnalysis::skin_angle_distance_mm`]
    /// either side (None where they were not measured).
    pub skin_angle_deg: Option<f64>,
    /// Its σ.
    pub skin_angle_sigma_deg: Option<f64>,
    /// Bent forward: the virtual scoliometer's angle (ATR).
    pub atr_deg: Option<f64>,
    /// Its σ.
    pub atr_sigma_deg: Option<f64>,
    /// The window (a from, a to) the scoliometer rested on.
    pub atr_window: Option<[f64; 2]>,
}

/// A map over the analysis plane: `values[j * a.len() + i]` at (a[i], v[j]) (mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Map {
    /// Across.
    pub a: Vec<f64>,
    /// Along (the levels).
    pub v: Vec<f64>,
    /// The values (None off the measured surface).
    pub values: Vec<Option<f64>>,
    /// Their σ (None where not computed).
    pub sigmas: Vec<Option<f64>>,
}

/// A frame's sway relative to the first: the subject's rotation (about the first frame's
/// centre of points) and translation, in [`Axes`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sway {
    /// The frame (1, 2, …).
    pub frame: usize,
    /// Rotation vector (degrees) about across, axis, up.
    pub rotation_deg: [f64; 3],
    /// Its σ.
    pub rotation_sigma_deg: [f64; 3],
    /// Translation (mm).
    pub translation_mm: [f64; 3],
    /// Its σ.
    pub translation_sigma_mm: [f64; 3],
}

/// The measures of one back (mm, degrees; each with its σ).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BackAnalysis {
    /// How the subject stood.
    pub posture: Posture,
    /// Frames combined.
    pub frames: usize,
    /// Points on the back, all frames.
    pub points: usize,
    /// The calibration's fingerprint.
    pub calibration: Option<u64>,
    /// The dot spacing on the back.
    pub spacing_mm: f64,
    /// The analysis frame.
    pub axes: Axes,
    /// Half-width of the symmetry window.
    pub symmetry_window_mm: f64,
    /// The skin angle's distance either side of the symmetry line.
    pub skin_angle_distance_mm: f64,
    /// The normalised residuals' RMS of the surface fit (about 1 when the points' σ hold).
    pub fit_chi: f64,
    /// The symmetry line, level by level (bottom to top).
    pub levels: Vec<Level>,
    /// The largest surface rotation (the signed value of largest magnitude).
    pub rotation_max_deg: f64,
    /// Its σ.
    pub rotation_max_deg_sigma: f64,
    /// RMS of the surface rotation over the levels.
    pub rotation_rms_deg: f64,
    /// Its σ.
    pub rotation_rms_deg_sigma: f64,
    /// The largest lateral deviation (signed).
    pub lateral_deviation_max_mm: f64,
    /// Its σ.
    pub lateral_deviation_max_mm_sigma: f64,
    /// RMS of the lateral deviation.
    pub lateral_deviation_rms_mm: f64,
    /// Its σ.
    pub lateral_deviation_rms_mm_sigma: f64,
    /// The top of the symmetry line across from its bottom (+a: toward the subject's right).
    pub trunk_imbalance_mm: f64,
    /// Its σ.
    pub trunk_imbalance_mm_sigma: f64,
    /// The sagittal angle of the line through the ends from the axis.
    pub trunk_inclination_deg: f64,
    /// Its σ.
    pub trunk_inclination_deg_sigma: f64,
    /// Kyphosis (standing, when both inflections are in view).
    pub kyphosis_deg: Option<f64>,
    /// Its σ.
    pub kyphosis_deg_sigma: Option<f64>,
    /// Lordosis (standing, when both inflections are in view).
    pub lordosis_deg: Option<f64>,
    /// Its σ.
    pub lordosis_deg_sigma: Option<f64>,
    /// Bent forward: the largest scoliometer angle (signed).
    pub atr_max_deg: Option<f64>,
    /// Its σ.
    pub atr_max_deg_sigma: Option<f64>,
    /// Each later frame's sway relative to the first.
    pub sway: Vec<Sway>,
    /// The depth difference to the surface mirrored about the symmetry line, s(a) − s(2x − a).
    pub asymmetry: Map,
    /// The surface's depth.
    pub topography: Map,
}

/// Fewer points than this in a frame are not a back.
pub const MIN_POINTS: usize = 40;
/// A back departs from its best plane by tens of mm; a cloud within this RMS is a plane.
pub const PLANE_RMS_MM: f64 = 5.0;
/// Levels where the trunk is narrower than this share of its median width are left out.
pub const MIN_WIDTH: f64 = 0.6;
/// The most coefficients the surface has (its knots spread beyond the dot spacing then).
const MAX_COEFFICIENTS: usize = 1600;

/// A frame's back: its points in the analysis axes and the triangles of its largest piece.
struct Back {
    positions: Vec<Vector3<f64>>,
    kept: Vec<usize>,
    triangles: Vec<[usize; 3]>,
    spacing: f64,
}

/// A frame's back piece: its points, its triangles and the dot spacing.
type Piece = (Vec<usize>, Vec<[usize; 3]>, f64);

/// The back in a frame: the largest smooth piece of its lattice mesh.
fn find_back(frame: &Frame, index: usize) -> Result<Piece, SurfaceError> {
    if frame.points.len() < MIN_POINTS {
        return Err(SurfaceError::TooFewPoints {
            frame: index,
            points: frame.points.len(),
            needed: MIN_POINTS,
        });
    }
    let positions: Vec<_> = frame.points.iter().map(|p| p.position).collect();
    let rays: Vec<_> = frame.points.iter().map(|p| p.ray).collect();
    let mesh = Mesh::over_lattice(&positions, &rays);
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
    Ok((kept, triangles, mesh.spacing))
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
fn axes(options: &Options, back: &[Vector3<f64>]) -> Result<Axes, SurfaceError> {
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

/// Analyses one subject's frames (one calibration): registers them onto the first, fits one
/// surface to all, and measures it.
pub fn analyse(frames: &[Frame], options: &Options) -> Result<BackAnalysis, SurfaceError> {
    same_calibration(frames)?;
    for (k, f) in frames.iter().enumerate() {
        f.validate(k)?;
    }
    if !(options.smoothing > 0.0 && options.smoothing.is_finite()) {
        return Err(SurfaceError::BadOptions(format!(
            "the smoothing must be positive, got {}",
            options.smoothing
        )));
    }
    let found = frames
        .iter()
        .enumerate()
        .map(|(k, f)| find_back(f, k))
        .collect::<Result<Vec<_>, _>>()?;
    let first: Vec<Vector3<f64>> = found[0]
        .0
        .iter()
        .map(|&i| frames[0].points[i].position)
        .collect();
    let axes = axes(options, &first)?;
    let rot = axes.matrix();
    let rot_d = DMatrix::from_fn(3, 3, |r, c| rot[(r, c)]);
    let backs: Vec<Back> = frames
        .iter()
        .zip(found)
        .map(|(f, (kept, triangles, spacing))| Back {
            positions: f.points.iter().map(|p| rot * p.position).collect(),
            kept,
            triangles,
            spacing,
        })
        .collect();
    for (k, b) in backs.iter().enumerate() {
        check_shape(b, k)?;
    }
    let samples: Vec<Sample> = backs
        .iter()
        .zip(frames)
        .enumerate()
        .flat_map(|(k, (b, f))| {
            let rot_d = &rot_d;
            b.kept.iter().map(move |&i| Sample {
                p: b.positions[i],
                cov: rot * f.points[i].covariance * rot.transpose(),
                common: rot_d * f.common.sensitivity(i),
                frame: k,
            })
        })
        .collect();
    let spacing = backs[0].spacing;
    let (lo, hi) = bounds(&samples);
    let margin = 2.0 * spacing;
    let (lo, hi) = (
        [lo[0] - margin, lo[1] - margin],
        [hi[0] + margin, hi[1] + margin],
    );
    let area = (hi[0] - lo[0]) * (hi[1] - lo[1]);
    let step =
        (spacing / (frames.len() as f64).sqrt()).max((area / MAX_COEFFICIENTS as f64).sqrt() * 1.1);
    let grid = Grid::covering(lo, hi, step);
    let smoothing = options.smoothing * spacing;
    let lambda = (smoothing / step).powi(4) * (step / spacing).powi(2);
    let surface = fit(
        &samples,
        frames.len(),
        grid,
        lambda,
        frames[0].common.covariance(),
    )?;
    let mut support = Support::new(lo, hi, step / 4.0);
    for (k, b) in backs.iter().enumerate() {
        let pose = surface.poses[k];
        let moved = |i: usize| surface.centre + pose.r * (b.positions[i] - surface.centre) + pose.t;
        for t in &b.triangles {
            support.fill(t.map(moved));
        }
    }
    let measured = Measured {
        fit: &surface,
        support: &support,
        posture: options.posture,
    };
    let mut analysis = measured.analyse(spacing)?;
    analysis.frames = frames.len();
    analysis.points = samples.len();
    analysis.calibration = frames[0].calibration;
    analysis.axes = axes;
    analysis.sway = sway(&surface);
    Ok(analysis)
}

fn bounds(samples: &[Sample]) -> ([f64; 2], [f64; 2]) {
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

/// A back is wider and longer than a few dots and far from flat.
fn check_shape(b: &Back, frame: usize) -> Result<(), SurfaceError> {
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
        return Err(SurfaceError::Plane { frame, rms_mm: rms });
    }
    Ok(())
}

fn sway(fit: &Fit) -> Vec<Sway> {
    (1..fit.poses.len())
        .map(|k| {
            let grads: Vec<_> = (0..6).map(|j| fit.pose_gradient(k, j)).collect();
            let sigma: Vec<f64> = fit.variances(&grads).iter().map(|v| v.sqrt()).collect();
            // The pose maps frame k onto frame 0; the subject moved by its inverse.
            let inverse = fit.poses[k].r.inverse();
            let w = inverse.scaled_axis();
            let t = -(inverse * fit.poses[k].t);
            Sway {
                frame: k,
                rotation_deg: [w.x, w.y, w.z].map(f64::to_degrees),
                rotation_sigma_deg: [sigma[0], sigma[1], sigma[2]].map(f64::to_degrees),
                translation_mm: [t.x, t.y, t.z],
                translation_sigma_mm: [sigma[3], sigma[4], sigma[5]],
            }
        })
        .collect()
}

/// A level and the run (a from, a to) of measured surface along it.
type Run = (f64, (f64, f64));
/// A coarse candidate: position, misfit, slope.
type Candidate = (f64, f64, f64);

/// The fitted surface with where it was measured.
struct Measured<'a> {
    fit: &'a Fit,
    support: &'a Support,
    posture: Posture,
}

/// A value with its gradient over the fit's unknowns.
struct Var {
    value: f64,
    gradient: DVector<f64>,
}

impl Var {
    fn angle(slope: f64, gradient: DVector<f64>) -> Self {
        Self {
            value: slope.atan(),
            gradient: gradient / (1.0 + slope * slope),
        }
    }
}

/// One level's values.
struct LevelVars {
    v: f64,
    x: Var,
    depth: Var,
    rotation: Var,
    sagittal: Var,
    skin: Option<Var>,
    atr: Option<(Var, [f64; 2])>,
}

impl Measured<'_> {
    fn value(&self, a: f64, v: f64, d: D) -> f64 {
        self.fit.value(a, v, d).unwrap_or(f64::NAN)
    }

    /// ∇ of value d at (a(c), v) where a moves with gradient `ga`.
    fn moving(&self, a: f64, v: f64, d: D, slope: D, ga: &DVector<f64>) -> DVector<f64> {
        let mut g = ga * self.value(a, v, slope);
        self.fit.add(&mut g, a, v, d, 1.0);
        g
    }

    /// The levels: one dot spacing apart, where the trunk is at least MIN_WIDTH of its
    /// median width, with the run of measured surface at each.
    fn levels(&self, spacing: f64) -> Result<(Vec<Run>, f64), SurfaceError> {
        let (v0, v1) = self.support.rows().ok_or(SurfaceError::NoLevels)?;
        let count = ((v1 - v0) / spacing).floor() as usize;
        let runs: Vec<Run> = (1..count)
            .map(|k| v0 + k as f64 * spacing)
            .filter_map(|v| self.support.longest_run(v).map(|r| (v, r)))
            .collect();
        let mut widths: Vec<f64> = runs.iter().map(|(_, (lo, hi))| hi - lo).collect();
        widths.sort_by(f64::total_cmp);
        let median = *widths.get(widths.len() / 2).ok_or(SurfaceError::NoLevels)?;
        let wide = runs
            .into_iter()
            .filter(|(_, (lo, hi))| hi - lo >= MIN_WIDTH * median)
            .collect();
        Ok((wide, median))
    }

    fn analyse(&self, spacing: f64) -> Result<BackAnalysis, SurfaceError> {
        let (runs, width) = self.levels(spacing)?;
        let found = self.symmetry_line(&runs, width);
        if found.len() < 3 {
            return Err(SurfaceError::NoLevels);
        }
        let w = width / 4.0;
        let length = found.last().map_or(0.0, |l| l.0) - found[0].0;
        let skin_d = 0.1 * length;
        let atr_half = width / 3.0;
        let levels: Vec<LevelVars> = found
            .iter()
            .map(|(v, s, run)| self.level(*v, s, *run, skin_d, atr_half))
            .collect();
        Ok(self.summarise(levels, w, skin_d, spacing))
    }

    /// The symmetry line: each level's symmetry point over a window of a quarter of the median
    /// width either side, searched for within a quarter of the width from the run's middle.
    /// The levels are chained (a trunk's section is nearly circular, and an arc is mirror
    /// symmetric about any of its normals): the coarse candidates of all levels are joined by
    /// the path of least Σ ln(misfit) + Σ (Δx / Δv / [`LEAN`])², then each level is refined
    /// within a knot of its path.
    fn symmetry_line(
        &self,
        runs: &[(f64, (f64, f64))],
        width: f64,
    ) -> Vec<(f64, Symmetry, (f64, f64))> {
        let w = width / 4.0;
        let margin = self.fit.grid.step;
        let searched: Vec<_> = runs
            .iter()
            .filter_map(|&(v, (lo, hi))| {
                let mid = 0.5 * (lo + hi);
                let range = (
                    (mid - width / 4.0).max(lo + w + margin),
                    (mid + width / 4.0).min(hi - w - margin),
                );
                let candidates = coarse(self.fit, v, w, range, (lo + margin, hi - margin));
                (range.0 < range.1 && !candidates.is_empty()).then_some((v, (lo, hi), candidates))
            })
            .collect();
        let path = chain(
            &searched
                .iter()
                .map(|(v, _, c)| (*v, c.as_slice()))
                .collect::<Vec<_>>(),
        );
        searched
            .iter()
            .zip(path)
            .filter_map(|((v, run, candidates), x)| {
                let near = (x - margin, x + margin);
                let s = symmetry_at(self.fit, *v, w, candidates, near, near)?;
                self.support
                    .covers(s.a - w - margin, s.a + w + margin, *v)
                    .then_some((*v, s, *run))
            })
            .collect()
    }

    fn level(
        &self,
        v: f64,
        s: &Symmetry,
        (lo, hi): (f64, f64),
        skin_d: f64,
        atr_half: f64,
    ) -> LevelVars {
        let (a, ga) = (s.a, &s.gradient);
        let x = Var {
            value: a,
            gradient: ga.clone(),
        };
        let depth = Var {
            value: self.value(a, v, D::S),
            gradient: self.moving(a, v, D::S, D::A, ga),
        };
        let rotation = Var {
            value: s.theta,
            gradient: s.theta_gradient.clone(),
        };
        let sagittal = Var::angle(self.value(a, v, D::V), self.moving(a, v, D::V, D::AV, ga));
        let skin = self.support.covers(a - skin_d, a + skin_d, v).then(|| {
            let g = self.moving(a + skin_d, v, D::S, D::A, ga)
                - self.moving(a - skin_d, v, D::S, D::A, ga);
            let rise = self.value(a + skin_d, v, D::S) - self.value(a - skin_d, v, D::S);
            Var::angle(rise / (2.0 * skin_d), g / (2.0 * skin_d))
        });
        let atr = (self.posture == Posture::ForwardBent)
            .then(|| {
                let window = ((a - atr_half).max(lo), (a + atr_half).min(hi));
                let r = resting_line(self.fit, v, a, ga, window)?;
                Some((Var::angle(r.slope, r.gradient), [window.0, window.1]))
            })
            .flatten();
        LevelVars {
            v,
            x,
            depth,
            rotation,
            sagittal,
            skin,
            atr,
        }
    }

    fn summarise(
        &self,
        levels: Vec<LevelVars>,
        window: f64,
        skin_d: f64,
        spacing: f64,
    ) -> BackAnalysis {
        let n = levels.len();
        let (first, last) = (&levels[0], &levels[n - 1]);
        let span = last.v - first.v;
        let deviation: Vec<Var> = levels
            .iter()
            .map(|l| {
                let f = (l.v - first.v) / span;
                Var {
                    value: l.x.value - (1.0 - f) * first.x.value - f * last.x.value,
                    gradient: &l.x.gradient - &first.x.gradient * (1.0 - f) - &last.x.gradient * f,
                }
            })
            .collect();
        let rotations: Vec<&Var> = levels.iter().map(|l| &l.rotation).collect();
        let deviations: Vec<&Var> = deviation.iter().collect();
        let imbalance = Var {
            value: last.x.value - first.x.value,
            gradient: &last.x.gradient - &first.x.gradient,
        };
        let rise = last.depth.value - first.depth.value;
        let inclination = Var {
            value: rise.atan2(span),
            gradient: (&last.depth.gradient - &first.depth.gradient)
                * (span / (span * span + rise * rise)),
        };
        let (kyphosis, lordosis) = match self.posture {
            Posture::Standing => sagittal_angles(&levels),
            Posture::ForwardBent => (None, None),
        };
        let atrs: Vec<&Var> = levels
            .iter()
            .filter_map(|l| l.atr.as_ref().map(|a| &a.0))
            .collect();
        let atr_max = (!atrs.is_empty()).then(|| largest(&atrs));
        // Every σ in one propagation: per level x, depth, rotation, sagittal, deviation, skin, atr.
        let mut grads: Vec<DVector<f64>> = Vec::new();
        let mut slot = |g: &DVector<f64>| {
            grads.push(g.clone());
            grads.len() - 1
        };
        let per_level: Vec<[Option<usize>; 7]> = levels
            .iter()
            .zip(&deviation)
            .map(|(l, d)| {
                [
                    Some(slot(&l.x.gradient)),
                    Some(slot(&l.depth.gradient)),
                    Some(slot(&l.rotation.gradient)),
                    Some(slot(&l.sagittal.gradient)),
                    Some(slot(&d.gradient)),
                    l.skin.as_ref().map(|s| slot(&s.gradient)),
                    l.atr.as_ref().map(|a| slot(&a.0.gradient)),
                ]
            })
            .collect();
        let rot_max = largest(&rotations);
        let rot_rms = rms(&rotations);
        let dev_max = largest(&deviations);
        let dev_rms = rms(&deviations);
        let scalars = [
            Some(&rot_max),
            Some(&rot_rms),
            Some(&dev_max),
            Some(&dev_rms),
            Some(&imbalance),
            Some(&inclination),
            kyphosis.as_ref(),
            lordosis.as_ref(),
            atr_max.as_ref(),
        ];
        let scalar_slots: Vec<Option<usize>> = scalars
            .iter()
            .map(|s| s.map(|s| slot(&s.gradient)))
            .collect();
        let sigma: Vec<f64> = self
            .fit
            .variances(&grads)
            .iter()
            .map(|v| v.max(0.0).sqrt())
            .collect();
        let sd = |k: Option<usize>| k.map(|k| sigma[k]);
        let deg = f64::to_degrees;
        let out_levels = levels
            .iter()
            .zip(&deviation)
            .zip(&per_level)
            .map(|((l, d), k)| Level {
                y: l.v,
                symmetry_x: l.x.value,
                symmetry_x_sigma: sigma[k[0].unwrap_or(0)],
                depth_mm: l.depth.value,
                depth_sigma_mm: sigma[k[1].unwrap_or(0)],
                rotation_deg: deg(l.rotation.value),
                rotation_sigma_deg: deg(sigma[k[2].unwrap_or(0)]),
                sagittal_slope_deg: deg(l.sagittal.value),
                sagittal_slope_sigma_deg: deg(sigma[k[3].unwrap_or(0)]),
                lateral_deviation_mm: d.value,
                lateral_deviation_sigma_mm: sigma[k[4].unwrap_or(0)],
                skin_angle_deg: l.skin.as_ref().map(|s| deg(s.value)),
                skin_angle_sigma_deg: sd(k[5]).map(deg),
                atr_deg: l.atr.as_ref().map(|a| deg(a.0.value)),
                atr_sigma_deg: sd(k[6]).map(deg),
                atr_window: l.atr.as_ref().map(|a| a.1),
            })
            .collect();
        let s = |i: usize| sd(scalar_slots[i]).unwrap_or(f64::NAN);
        let (asymmetry, topography) = self.maps(&levels);
        BackAnalysis {
            posture: self.posture,
            frames: 1,
            points: 0,
            calibration: None,
            spacing_mm: spacing,
            axes: Axes {
                across: [1.0, 0.0, 0.0],
                axis: [0.0, 1.0, 0.0],
                up: [0.0, 0.0, 1.0],
            },
            symmetry_window_mm: window,
            skin_angle_distance_mm: skin_d,
            fit_chi: self.fit.chi(),
            levels: out_levels,
            rotation_max_deg: deg(rot_max.value),
            rotation_max_deg_sigma: deg(s(0)),
            rotation_rms_deg: deg(rot_rms.value),
            rotation_rms_deg_sigma: deg(s(1)),
            lateral_deviation_max_mm: dev_max.value,
            lateral_deviation_max_mm_sigma: s(2),
            lateral_deviation_rms_mm: dev_rms.value,
            lateral_deviation_rms_mm_sigma: s(3),
            trunk_imbalance_mm: imbalance.value,
            trunk_imbalance_mm_sigma: s(4),
            trunk_inclination_deg: deg(inclination.value),
            trunk_inclination_deg_sigma: deg(s(5)),
            kyphosis_deg: kyphosis.as_ref().map(|k| deg(k.value)),
            kyphosis_deg_sigma: sd(scalar_slots[6]).map(deg),
            lordosis_deg: lordosis.as_ref().map(|k| deg(k.value)),
            lordosis_deg_sigma: sd(scalar_slots[7]).map(deg),
            atr_max_deg: atr_max.as_ref().map(|a| deg(a.value)),
            atr_max_deg_sigma: sd(scalar_slots[8]).map(deg),
            sway: vec![],
            asymmetry,
            topography,
        }
    }

    /// The mirror-asymmetry map (with σ) and the topography, one dot spacing apart across, at
    /// the levels.
    fn maps(&self, levels: &[LevelVars]) -> (Map, Map) {
        let step = self.fit.grid.step;
        let (lo, hi) = levels
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), l| {
                let r = self
                    .support
                    .longest_run(l.v)
                    .unwrap_or((l.x.value, l.x.value));
                (lo.min(r.0), hi.max(r.1))
            });
        let a: Vec<f64> = (0..=((hi - lo) / step).floor() as usize)
            .map(|i| lo + i as f64 * step)
            .collect();
        let mut asym = Vec::new();
        let mut grads = Vec::new();
        let mut depth = Vec::new();
        for l in levels {
            for &x in &a {
                let on = self.support.contains(x, l.v);
                depth.push(on.then(|| self.value(x, l.v, D::S)));
                let mirror = 2.0 * l.x.value - x;
                if on && self.support.contains(mirror, l.v) {
                    let g = self.moving(x, l.v, D::S, D::A, &DVector::zeros(self.fit.unknowns()))
                        - self.moving(mirror, l.v, D::S, D::A, &(&l.x.gradient * 2.0));
                    asym.push(Some(
                        self.value(x, l.v, D::S) - self.value(mirror, l.v, D::S),
                    ));
                    grads.push(g);
                } else {
                    asym.push(None);
                }
            }
        }
        let mut sigma = self
            .fit
            .variances(&grads)
            .into_iter()
            .map(|v| v.max(0.0).sqrt());
        let sigmas = asym.iter().map(|x| x.and_then(|_| sigma.next())).collect();
        let v: Vec<f64> = levels.iter().map(|l| l.v).collect();
        let cells = depth.len();
        (
            Map {
                a: a.clone(),
                v: v.clone(),
                values: asym,
                sigmas,
            },
            Map {
                a,
                v,
                values: depth,
                sigmas: vec![None; cells],
            },
        )
    }
}

/// The symmetry line's usual lean from the axis (lateral mm per mm along): steeper steps
/// between levels cost as much as a misfit e times larger.
const LEAN: f64 = 0.25;

/// The path through each level's coarse candidates (x, misfit, _) of least
/// Σ ln(misfit) + Σ ((x_k − x_{k−1}) / (v_k − v_{k−1}) / LEAN)² (dynamic programming).
fn chain(levels: &[(f64, &[Candidate])]) -> Vec<f64> {
    let cost = |c: &Candidate| c.1.max(1e-300).ln();
    let mut total: Vec<Vec<f64>> = Vec::with_capacity(levels.len());
    let mut from: Vec<Vec<usize>> = Vec::with_capacity(levels.len());
    for (k, (v, candidates)) in levels.iter().enumerate() {
        let row: Vec<(f64, usize)> = candidates
            .iter()
            .map(|c| match k {
                0 => (cost(c), 0),
                _ => {
                    let (pv, prev) = levels[k - 1];
                    let step = |j: usize| {
                        let lean = (c.0 - prev[j].0) / (v - pv) / LEAN;
                        total[k - 1][j] + lean * lean
                    };
                    let best = (0..prev.len())
                        .min_by(|&i, &j| step(i).total_cmp(&step(j)))
                        .unwrap_or(0);
                    (cost(c) + step(best), best)
                }
            })
            .collect();
        total.push(row.iter().map(|r| r.0).collect());
        from.push(row.iter().map(|r| r.1).collect());
    }
    let Some(last) = total.last() else {
        return vec![];
    };
    let mut j = (0..last.len())
        .min_by(|&a, &b| last[a].total_cmp(&last[b]))
        .unwrap_or(0);
    let mut path = vec![0.0; levels.len()];
    for k in (0..levels.len()).rev() {
        path[k] = levels[k].1[j].0;
        j = from[k][j];
    }
    path
}

/// The value of largest magnitude (signed) with its gradient.
fn largest(vars: &[&Var]) -> Var {
    let best = vars
        .iter()
        .max_by(|p, q| p.value.abs().total_cmp(&q.value.abs()))
        .expect("at least one level");
    Var {
        value: best.value,
        gradient: best.gradient.clone(),
    }
}

/// The RMS with its gradient.
fn rms(vars: &[&Var]) -> Var {
    let n = vars.len() as f64;
    let value = (vars.iter().map(|v| v.value * v.value).sum::<f64>() / n).sqrt();
    let mut gradient = vars[0].gradient.clone() * 0.0;
    if value > 0.0 {
        for v in vars {
            gradient += &v.gradient * (v.value / (n * value));
        }
    }
    Var { value, gradient }
}

/// Kyphosis and lordosis from the sagittal slopes (module docs).
fn sagittal_angles(levels: &[LevelVars]) -> (Option<Var>, Option<Var>) {
    let slope = |i: usize| levels[i].sagittal.value;
    let Some(itl) = (0..levels.len()).max_by(|&i, &j| slope(i).total_cmp(&slope(j))) else {
        return (None, None);
    };
    let least =
        |range: std::ops::Range<usize>| range.min_by(|&i, &j| slope(i).total_cmp(&slope(j)));
    let angle = |other: Option<usize>| {
        other.map(|o| Var {
            value: slope(itl) - slope(o),
            gradient: &levels[itl].sagittal.gradient - &levels[o].sagittal.gradient,
        })
    };
    // Levels run bottom to top: the cervico-thoracic inflection is above the thoraco-lumbar.
    (angle(least(itl + 1..levels.len())), angle(least(0..itl)))
}
