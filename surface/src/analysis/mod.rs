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
//! its σ is its gradient carried through the fit's covariance (`crate::fit`).

mod back;
mod indices;
mod levels;
mod selection;

use crate::fit::{fit, Fit, Pose, Sample};
use crate::input::{same_calibration, Frame};
use crate::mesh::Mesh;
use crate::spline::Grid;
use crate::support::Support;
use crate::{bounding_box, SurfaceError};
use back::{axes, check_shape, find_back, Back};
use levels::Measured;
use nalgebra::{DMatrix, Matrix3, Vector3};
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
    /// Where the symmetry line is ambiguous here (a second mirror axis more than a knot away
    /// that the chain of levels cannot tell from this one): that axis' symmetry point across.
    /// Every value measured at the line then carries the half-difference of its two readings
    /// in its σ (None where the line is unambiguous; absent in files of older versions).
    #[serde(default)]
    pub symmetry_x_rival: Option<f64>,
}

/// A map over the analysis plane: `values[j * a.len() + i]` at `(a[i], v[j])` (mm).
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

/// A point left out of the surface fit as wild ([`BackAnalysis::wild`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WildPoint {
    /// Its frame.
    pub frame: usize,
    /// Its index in the frame.
    pub point: usize,
    /// Where it lies, (a, v) in [`Axes`] (registered onto the first frame).
    pub at: [f64; 2],
    /// How far it lay off the surface fitted with it, in depth (mm; positive: nearer the
    /// camera).
    pub residual_mm: f64,
}

/// A plane larger than the back, left out of a frame ([`BackAnalysis::planes_left_out`]): a
/// wall or the floor in view.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlaneLeftOut {
    /// Its frame.
    pub frame: usize,
    /// Its points.
    pub points: usize,
    /// Their centre, in the frame's camera system (mm).
    pub centre: [f64; 3],
    /// How much further from the camera its centre lies than the back's (mm).
    pub beyond_mm: f64,
}

/// A frame's sway relative to the first: the subject's rotation (about the first frame's
/// centre of points) and translation, in [`Axes`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sway {
    /// The frame (1, 2, …).
    pub frame: usize,
    /// Rotation vector (degrees) about across, axis, up.
    pub rotation_deg: [f64; 3],
    /// Its σ: the points' noise, and about the axis the detail between the dots, which each
    /// frame samples elsewhere (a trunk trades that turn for a shift across).
    pub rotation_sigma_deg: [f64; 3],
    /// Translation (mm).
    pub translation_mm: [f64; 3],
    /// Its σ: the points' noise, and across the detail between the dots. Toward the camera it
    /// errs several times its σ (the lattice samples the detail differently in each frame).
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
    /// How irregularly the first frame's points lie, a plane left out aside
    /// ([`crate::mesh::Mesh::irregularity`]: a lattice's 0.05; at most [`SCATTERED`]).
    #[serde(default)]
    pub irregularity: f64,
    /// The points left out of the surface fit as wild: each lay off the surface fitted with it
    /// by more than 5 times the residuals' robust spread, where its neighbours' did not (a dot
    /// misidentified, a centroid pulled by a highlight), in frame and point order.
    #[serde(default)]
    pub wild: Vec<WildPoint>,
    /// The planes larger than the back in view (a wall, the floor), left out: the back is the
    /// largest smooth surface that is not a plane ([`PLANE_RMS_MM`]).
    #[serde(default)]
    pub planes_left_out: Vec<PlaneLeftOut>,
    /// The points apart from the back, all frames, left out: in pieces of the mesh the back's
    /// does not join that are not planes larger than it (the arms standing, anything beside
    /// the subject, a wall in pieces smaller than the back). With the back's, wild points
    /// included, and the planes', they are every point of the frames.
    #[serde(default)]
    pub points_apart: usize,
    /// The analysis frame.
    pub axes: Axes,
    /// Half-width of the symmetry window.
    pub symmetry_window_mm: f64,
    /// The skin angle's distance either side of the symmetry line.
    pub skin_angle_distance_mm: f64,
    /// The normalised residuals' RMS of the surface fit (about 1 when the points' σ hold).
    pub fit_chi: f64,
    /// The surface's misfit along the symmetry line (`crate::fit::Fit::misfit` within the
    /// symmetry window, of the first frame's points alone): detail between the dots, which the
    /// sampling terms of the symmetry line's and the rotation's σ scale with.
    pub misfit_mm: f64,
    /// What makes the symmetry line a back's: how far from mirror symmetric the sections are
    /// about the positions searched, against the points' noise (at the median level, the
    /// median over the positions of the odd part's misfit over the symmetry window, over what
    /// the noise alone makes it). A back's trunk is asymmetric away from its spine: the ten
    /// real backs at 15 mm read 17 or more standing and 5 or more bent forward over five
    /// lattice placements, the back model 84-282 (a body broad and flat, its groove 1 mm deep,
    /// 17-28). A surface without a back's features is about as symmetric about one position as
    /// another, asymmetric by its noise alone: about 1, and the analysis is refused under
    /// [`LINE_UNDETERMINED`].
    #[serde(default)]
    pub asymmetry_over_noise: f64,
    /// The symmetry line, level by level (bottom to top).
    pub levels: Vec<Level>,
    /// The levels (their y, bottom to top) where the back is measured across but the symmetry
    /// line was not found: no symmetry point in the searched range with the window measured
    /// either side, or none that holds to the line. The profiles and every measure leave them
    /// out, so nothing there is measured: a largest value may lie among them. On the real
    /// backs standing square to the camera, 0 to 12 of 23-29 levels over five lattice placements
    /// (at the line's ends, and at waists where the measured surface ends within a window and a
    /// knot of the spine even with the window narrowed; on the back models none, or the one
    /// beyond the line's top end). See [`Self::line_mostly_lost`].
    #[serde(default)]
    pub levels_left_out: Vec<f64>,
    /// The largest surface rotation (the signed value of largest magnitude). Its σ is its
    /// level's with what choosing it among levels within the noise of it adds (the analysis'
    /// `selection`), and describes its magnitude: where levels of opposite sign are within the
    /// noise of each other, which one is the largest, and so the sign, is chance
    /// ([`crate::compare()`] compares magnitudes). Where the line is ambiguous it holds, in
    /// place of its level's rival, half the range of the largest magnitude with each
    /// ambiguous level at its own reading or its rival's ([`Level::symmetry_x_rival`]).
    pub rotation_max_deg: f64,
    /// Its σ.
    pub rotation_max_deg_sigma: f64,
    /// RMS of the surface rotation over the levels. The noise adds to it: its σ holds what it
    /// adds, which where the profile is mostly noise (a straight back) is most of the value.
    pub rotation_rms_deg: f64,
    /// Its σ.
    pub rotation_rms_deg_sigma: f64,
    /// The largest lateral deviation (signed; as the largest rotation, its σ describes its
    /// magnitude).
    pub lateral_deviation_max_mm: f64,
    /// Its σ.
    pub lateral_deviation_max_mm_sigma: f64,
    /// RMS of the lateral deviation (its σ holding what the noise adds, as the RMS rotation's).
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
    /// Bent forward: the largest scoliometer angle (signed; as the largest rotation, its σ
    /// describes its magnitude).
    pub atr_max_deg: Option<f64>,
    /// Its σ.
    pub atr_max_deg_sigma: Option<f64>,
    /// The asymmetry map's value of largest magnitude on the +a side of the symmetry line
    /// (standing, the subject's right), where it and its mirror image lie a grid step or more
    /// inside the measured surface (None when no cell does): positive where that side is nearer
    /// the camera than its mirror image (the map is odd about the line, so its other side holds
    /// the same values negated, and the side fixes the sign). Its σ is its cell's with what
    /// choosing it among the cells adds: the largest of many cells leans away from zero with
    /// their noise where the map is nearly flat (the analysis' `selection`).
    pub asymmetry_max_mm: Option<f64>,
    /// Its σ.
    pub asymmetry_max_mm_sigma: Option<f64>,
    /// Where it is, (a, v) in [`Axes`].
    pub asymmetry_max_at: Option<[f64; 2]>,
    /// Each later frame's sway relative to the first.
    pub sway: Vec<Sway>,
    /// The depth difference to the surface mirrored about the symmetry line, s(a) − s(2x − a).
    pub asymmetry: Map,
    /// The surface's depth.
    pub topography: Map,
}

impl BackAnalysis {
    /// Whether the symmetry line holds at fewer than half the levels where the back is
    /// measured ([`Self::levels_left_out`]): its measures then describe a small part of the
    /// back, perhaps along a false axis. On the real backs standing square to the camera it held
    /// at 54 % of them or more on every lattice placement. A symptom, not a proof: turned by 5°
    /// from the camera, one of them held a false axis at 20 of its 26 levels, so the subject
    /// must still face the camera.
    pub fn line_mostly_lost(&self) -> bool {
        self.levels.len() < self.levels_left_out.len()
    }

    /// Standing: the mean sagittal slope of the middle third of the levels less that of the
    /// outer two thirds (None bent forward, or under six levels). A back standing is steepest
    /// at mid height (the thoraco-lumbar inflection, between the lordosis below and the
    /// kyphosis above) and least toward both ends; seen upside down the profile is reversed.
    /// See [`Self::looks_upside_down`].
    pub fn sagittal_mid_excess_deg(&self) -> Option<f64> {
        let n = self.levels.len();
        if self.posture != Posture::Standing || n < 6 {
            return None;
        }
        let sum = |levels: &[Level]| levels.iter().map(|l| l.sagittal_slope_deg).sum::<f64>();
        let middle = &self.levels[n / 3..n - n / 3];
        let (all, mid) = (sum(&self.levels), sum(middle));
        let outer = n - middle.len();
        Some(mid / middle.len() as f64 - (all - mid) / outer as f64)
    }

    /// Whether the sagittal profile is that of a back seen upside down (its mid-height excess,
    /// [`Self::sagittal_mid_excess_deg`], below −[`UPSIDE_DOWN_EXCESS_DEG`]): a cloud whose +y
    /// points to the feet (a camera mounted upside down, a scanner writing y down) gives every
    /// profile reversed and the rotation's sign turned, which nothing else in the analysis
    /// shows. On the ten real backs (15 mm) the excess measured +7 to +23° standing and −6 to
    /// −22° turned upside down, their lower two thirds alone +6 to +21° and −5 to −19°. Their
    /// upper two thirds alone read −3 to +5° standing (not flagged) and −4 to +5° upside down:
    /// so short a part of a back says little of the view.
    pub fn looks_upside_down(&self) -> bool {
        self.sagittal_mid_excess_deg()
            .is_some_and(|e| e < -UPSIDE_DOWN_EXCESS_DEG)
    }

    /// Whether the analysis, bent forward, rests on faint features: its sections' asymmetry
    /// under [`FAINT`] times their noise, where the σ may understate the errors several times.
    /// Standing, such a line kept its σ on the model trunk, and is not flagged.
    pub fn line_faint(&self) -> bool {
        self.posture == Posture::ForwardBent && self.asymmetry_over_noise < FAINT
    }
}

/// A surface whose sections are less asymmetric than this about the positions searched,
/// against the points' noise ([`BackAnalysis::asymmetry_over_noise`]), has no back's symmetry
/// line, and its analysis is refused ([`SurfaceError::LineUndetermined`]): each section is
/// about as symmetric about any point (a surface of even curvature: a paraboloid, a cylinder),
/// and the line would settle on the noise, 15-56 mm off at σ 5-10 mm (a paraboloid with 0.4 mm
/// noise), its rotations of 1.5-3° at σ 0.3-0.6° where there is none. Such surfaces (three
/// paraboloids, a cylinder) read 0.7 on average and 1.9 at most over 474 analyses 15 and 20 mm
/// apart with their points' σ stated as they scatter, (scatter/σ)² times that with it
/// misstated: the test relies on the σ given. The real backs read at least 5 (bent forward;
/// standing 17). It is the whole analysis' test, not each level's: a level past a back's
/// features (its groove faded out) may read under it, and is kept, its σ holding through the
/// line chained to the levels about it (several times the grooved levels').
pub const LINE_UNDETERMINED: f64 = 3.0;

/// Bent forward, a symmetry line whose sections are asymmetric less than this many times their
/// noise ([`BackAnalysis::asymmetry_over_noise`]) rests on faint features, and its σ may
/// understate its errors ([`BackAnalysis::line_faint`]). On the library's model trunk with a
/// 1 mm spinous groove (reading 3.3-6.0) the rotation's RMS error/σ was 2.9-6.8 bent forward and
/// 1.1 standing, with a 2 mm groove (10-20) 1.04-1.06 either way. Of the real backs bent
/// forward, the two mildest read 5.3-8.1 on every lattice placement and a third under 10 on
/// one of five, the others 13 or more; among the three are the two whose largest scoliometer
/// reading moved between placements far beyond its σ (−5.6 ± 0.8° to +1.9 ± 1.6°, −9.7 ± 0.7°
/// to +15.2 ± 4.7°).
pub const FAINT: f64 = 10.0;

/// A standing back's sagittal mid-height excess below minus this is read as upside down
/// ([`BackAnalysis::looks_upside_down`]).
pub const UPSIDE_DOWN_EXCESS_DEG: f64 = 4.0;

/// A back departs from its best plane by tens of mm; a cloud within this RMS is a plane.
pub const PLANE_RMS_MM: f64 = 5.0;
/// Levels where the trunk is narrower than this share of its median width are left out.
pub const MIN_WIDTH: f64 = 0.6;
/// Points lying more irregularly than this ([`crate::mesh::Mesh::irregularity`]) are scattered
/// at random (0.55): on the back model such a cloud put the symmetry line 5-20 mm off 20 mm
/// apart, 23-29 mm off 5 mm apart. A grid whose points stray by up to half its spacing reads
/// 0.40 (its σ understated the errors 2-3 times), by up to 0.15 0.13 (its σ held).
pub const SCATTERED: f64 = 0.45;
/// A point's neighbours, whose residuals say whether its own is wild, lie within this many
/// dot spacings ([`crate::fit::Fit::wild`]).
const WILD_RADIUS: f64 = 2.5;
/// The most coefficients the surface has (its knots spread beyond the dot spacing then).
const MAX_COEFFICIENTS: usize = 1600;
/// Analyses one subject's frames (one calibration): registers them onto the first, fits one
/// surface to all, and measures it. Points the fit finds wild ([`BackAnalysis::wild`]) are left
/// out of it, and it is made again, until none is; they stay in the mesh, which says where the
/// back was measured.
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
        .kept
        .iter()
        .map(|&i| frames[0].points[i].position)
        .collect();
    let axes = axes(options, &first)?;
    let rot = axes.matrix();
    let planes_left_out: Vec<PlaneLeftOut> = found.iter().flat_map(|f| f.planes.clone()).collect();
    let in_planes: usize = planes_left_out.iter().map(|p| p.points).sum();
    let on_backs: usize = found.iter().map(|f| f.kept.len()).sum();
    let in_frames: usize = frames.iter().map(|f| f.points.len()).sum();
    let points_apart = in_frames - on_backs - in_planes;
    let backs: Vec<Back> = frames
        .iter()
        .zip(found)
        .map(|(f, found)| {
            let gaps = Mesh::gaps(&found.triangles);
            let surface = [found.triangles, gaps].concat();
            Back {
                positions: f.points.iter().map(|p| rot * p.position).collect(),
                kept: found.kept,
                rim: Mesh::rim(&surface),
                surface,
                spacing: found.spacing,
                irregularity: found.irregularity,
            }
        })
        .collect();
    for (k, b) in backs.iter().enumerate() {
        check_shape(b, k)?;
    }
    let mut wild: Vec<WildPoint> = Vec::new();
    loop {
        match measure(frames, &backs, axes, options, &wild)? {
            Round::Wild(found) => wild.extend(found),
            Round::Measured(mut analysis) => {
                let asymmetry = analysis.asymmetry_over_noise;
                // NaN: no asymmetry where the points state no noise.
                if asymmetry.is_nan() || asymmetry < LINE_UNDETERMINED {
                    let chi = analysis.fit_chi;
                    return Err(SurfaceError::LineUndetermined { asymmetry, chi });
                }
                wild.sort_by_key(|w| (w.frame, w.point));
                analysis.wild = wild;
                analysis.planes_left_out = planes_left_out;
                analysis.points_apart = points_apart;
                return Ok(*analysis);
            }
        }
    }
}

/// What one round of [`measure`] came to.
enum Round {
    /// Points wild among those fitted: the round is repeated without them.
    Wild(Vec<WildPoint>),
    /// None wild: the analysis.
    Measured(Box<BackAnalysis>),
}

/// The surface of the `backs` found in `frames`, in `axes`, fitted without the points `wild`;
/// the points wild among the rest if there are any, else its analysis.
fn measure(
    frames: &[Frame],
    backs: &[Back],
    axes: Axes,
    options: &Options,
    wild: &[WildPoint],
) -> Result<Round, SurfaceError> {
    let rot = axes.matrix();
    let rot_d = DMatrix::from_fn(3, 3, |r, c| rot[(r, c)]);
    let origin: Vec<[usize; 2]> = backs
        .iter()
        .enumerate()
        .flat_map(|(k, b)| b.kept.iter().map(move |&i| [k, i]))
        .filter(|&[k, i]| !wild.iter().any(|w| w.frame == k && w.point == i))
        .collect();
    let samples: Vec<Sample> = origin
        .iter()
        .map(|&[k, i]| Sample {
            p: backs[k].positions[i],
            cov: rot * frames[k].points[i].covariance * rot.transpose(),
            common: &rot_d * frames[k].common.sensitivity(i),
            frame: k,
        })
        .collect();
    let spacing = backs[0].spacing;
    let (lo, hi) = bounding_box(samples.iter().map(|s| s.p));
    let margin = 2.0 * spacing;
    let (lo, hi) = (
        [lo[0] - margin, lo[1] - margin],
        [hi[0] + margin, hi[1] + margin],
    );
    let area = (hi[0] - lo[0]) * (hi[1] - lo[1]);
    let step_of = |frames: usize| {
        (spacing / (frames as f64).sqrt()).max((area / MAX_COEFFICIENTS as f64).sqrt() * 1.1)
    };
    let fit_on = |samples: &[Sample], poses: Vec<Pose>| {
        let step = step_of(poses.len());
        let smoothing = options.smoothing * spacing;
        let lambda = (smoothing / step).powi(4) * (step / spacing).powi(2);
        let grid = Grid::covering(lo, hi, step);
        fit(samples, poses, grid, lambda, frames[0].common.covariance())
    };
    let step = step_of(frames.len());
    // Several frames: frame 0 alone on its own grid, the others registered on it where it
    // measured the surface, then all together on a finer grid. The sampling terms are frame
    // 0's alone (`sampled`): the frames of a scan sample the back where the first does (a
    // subject sways by a few mm, a fraction of a dot cell), and the detail between the dots
    // moves each alike (levels.rs' `Sampling`).
    let (first, joint) = match frames.len() {
        1 => (fit_on(&samples, vec![Pose::identity()])?, None),
        n => {
            let own: Vec<Sample> = samples.iter().filter(|s| s.frame == 0).cloned().collect();
            let first = fit_on(&own, vec![Pose::identity()])?;
            let mut first_measured = Support::new(lo, hi, step / 4.0);
            for t in &backs[0].surface {
                first_measured.fill(t.map(|i| backs[0].positions[i]));
            }
            let mut poses = vec![Pose::identity()];
            for k in 1..n {
                poses.push(first.register(&samples, k, &first_measured)?);
            }
            let joint = fit_on(&samples, poses)?;
            (first, Some(joint))
        }
    };
    let surface = joint.as_ref().unwrap_or(&first);
    // Wild points within the surface: along its rim the surface turns away from its fit (on a
    // real back, each point of a flank found wild once the last was left out), and a point
    // there has neighbours on one side only.
    let wild = surface
        .wild(WILD_RADIUS * spacing)
        .into_iter()
        .map(|(sample, at, residual_mm)| {
            let [frame, point] = origin[sample];
            WildPoint {
                frame,
                point,
                at,
                residual_mm,
            }
        })
        .filter(|w| !backs[w.frame].rim.contains(&w.point))
        .collect::<Vec<_>>();
    if !wild.is_empty() {
        return Ok(Round::Wild(wild));
    }
    let mut support = Support::new(lo, hi, step / 4.0);
    for (k, b) in backs.iter().enumerate() {
        let pose = surface.poses[k];
        let moved = |i: usize| surface.centre + pose.r * (b.positions[i] - surface.centre) + pose.t;
        for t in &b.surface {
            support.fill(t.map(moved));
        }
    }
    // The trunk's radius about its axis, for the registration's sampling terms: half its width.
    let (left, right) = bounding_box(samples.iter().filter(|s| s.frame == 0).map(|s| s.p));
    let radius = 0.5 * (right[0] - left[0]);
    let measured = Measured {
        fit: surface,
        sampled: &first,
        support: &support,
        posture: options.posture,
        radius,
    };
    let mut analysis = measured.analyse(spacing)?;
    analysis.frames = frames.len();
    analysis.points = samples.len();
    analysis.irregularity = backs[0].irregularity;
    analysis.calibration = frames[0].calibration;
    analysis.axes = axes;
    if let Some(joint) = &joint {
        analysis.sway = sway(joint, analysis.misfit_mm, radius);
    }
    Ok(Round::Measured(Box::new(analysis)))
}
/// The sway's shift toward the camera errs by this times the misfit along the symmetry line.
/// Calibrated on two bodies' three swayed frames at 16 placements of the lattice each (the
/// thoracic curve and the second trunk's double curve), where it erred 0.25 and 0.21 mm RMS,
/// 8.3 and 6.1 times the noise's σ; with the term 1.10 and 0.85 (0.3 from the first alone left
/// the second at 0.77).
const SWAY_DEPTH: f64 = 0.27;

/// The frames' sway from the poses of `fit`, with sampling terms for its turn about the
/// trunk's axis and its shift across: the frames sample the detail between the dots at other
/// places, and a trunk, nearly a cylinder about its axis (about its `radius` behind the
/// surface), trades a turn for a shift. By `misfit`, that of frame 0's surface alone along
/// the symmetry line (`misfit_mm`), the turn errs by misfit / radius (rad) and the shift by
/// the misfit (mm). On three swayed frames at 16 placements of the lattice, the
/// turn erred by 0.28° RMS at a σ of 0.04° from the noise (error/σ 6.9, with its term 1.13),
/// the shift by 0.89 mm at 0.14 mm (6.9, with its term 1.05); on a second body 1.09 and 0.99.
/// The shift toward the camera errs by [`SWAY_DEPTH`] × misfit: the dots fall on the groove's
/// bottom or beside it alike along the trunk. The other components' σ are the noise's: there
/// they erred 1.7-2.8 σ (turns about across and toward the camera, the shift along).
fn sway(fit: &Fit, misfit: f64, radius: f64) -> Vec<Sway> {
    (1..fit.poses.len())
        .map(|k| {
            let grads: Vec<_> = (0..6).map(|j| fit.pose_gradient(k, j)).collect();
            let mut sigma: Vec<f64> = fit.variances(&grads).iter().map(|v| v.sqrt()).collect();
            sigma[1] = sigma[1].hypot(misfit / radius);
            sigma[3] = sigma[3].hypot(misfit);
            sigma[5] = sigma[5].hypot(SWAY_DEPTH * misfit);
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
