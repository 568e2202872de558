//! The back model's dots as a scan gives them: each dot's own noise (σ mostly along the
//! camera's line of sight) and the calibration's error common to all points of a scan.

use crate::honesty::assert_honest;
use deltaz_host::simulate::back::{Axes, BackModel, Deformity, Lattice, LatticeDot, Pose};
use deltaz_surface::{analyse, BackAnalysis, CommonShare, Frame, Options, ScanPoint, SurfaceError};
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// The noise of a scan (mm, rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Noise {
    /// σ along the camera's line of sight.
    pub depth: f64,
    /// σ across it.
    pub lateral: f64,
    /// σ of the common shift (each axis).
    pub common_shift: f64,
    /// σ of the common rotation about the camera's y axis through the back's centre.
    pub common_tilt: f64,
}

impl Noise {
    /// The issue's: 0.4 mm in depth, and a common share.
    pub fn issue() -> Self {
        Self {
            depth: 0.4,
            lateral: 0.1,
            common_shift: 0.3,
            common_tilt: 0.1f64.to_radians(),
        }
    }
}

/// The back's centre, which the common rotation turns about.
const CENTRE: Vector3<f64> = Vector3::new(0.0, 0.0, -1500.0);

/// Three frames of one standing back with a thoracic curve, swayed between them by a few mm
/// and about a degree ([`swayed`]).
pub fn swayed_thoracic() -> [BackModel; 3] {
    swayed(BackModel::standing(Deformity::thoracic()))
}

/// Three frames of `base`, swayed between them by a few mm and about a degree.
pub fn swayed(base: BackModel) -> [BackModel; 3] {
    let sway = |r: [f64; 3], t: [f64; 3]| Pose {
        rotation: Vector3::from(r).map(f64::to_radians),
        translation: Vector3::from(t),
    };
    [
        base.clone(),
        base.with_pose(sway([0.3, -1.0, 0.5], [3.0, -2.0, 4.0])),
        base.with_pose(sway([-0.5, 0.8, -0.6], [-2.5, 3.0, -3.0])),
    ]
}

/// A point's common-share sensitivity: a shift, and a rotation about y through the centre.
fn sensitivity(p: &Vector3<f64>) -> DMatrix<f64> {
    let turn = Vector3::y().cross(&(p - CENTRE));
    DMatrix::from_fn(3, 4, |r, c| if c < 3 { f64::from(r == c) } else { turn[r] })
}

/// The common share's covariance.
fn common_covariance(noise: &Noise) -> DMatrix<f64> {
    let s = noise.common_shift.powi(2);
    DMatrix::from_diagonal(&DVector::from_vec(vec![s, s, s, noise.common_tilt.powi(2)]))
}

/// A draw of the common error δ of one scan.
pub fn common_draw(noise: &Noise, rng: &mut ChaCha8Rng) -> DVector<f64> {
    let sd = common_covariance(noise).map_diagonal(f64::sqrt);
    sd.map(|s| s * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, rng))
}

/// The dots on the back (the arms too) measured: true point + own noise + G δ; `calibration`
/// is the fingerprint.
pub fn frame(
    dots: &[LatticeDot],
    noise: &Noise,
    delta: &DVector<f64>,
    rng: &mut ChaCha8Rng,
) -> Frame {
    let mut g_all = DMatrix::zeros(3 * dots.len(), 4);
    let points = dots
        .iter()
        .enumerate()
        .map(|(i, d)| {
            let p = d.hit.point;
            let sight = p.normalize();
            let along = sight * sight.transpose();
            let cov =
                along * noise.depth.powi(2) + (Matrix3::identity() - along) * noise.lateral.powi(2);
            let own = cov.cholesky().unwrap().l()
                * Vector3::from_fn(|_, _| {
                    <StandardNormal as Distribution<f64>>::sample(&StandardNormal, rng)
                });
            let g = sensitivity(&p);
            g_all.rows_mut(3 * i, 3).copy_from(&g);
            let common = &g * delta;
            ScanPoint {
                position: p + own + Vector3::new(common[0], common[1], common[2]),
                covariance: cov,
                ray: Some(d.ray),
            }
        })
        .collect();
    Frame {
        points,
        calibration: Some(0x00de_17a2),
        common: CommonShare::Core {
            covariance: common_covariance(noise),
            sensitivity: g_all,
        },
    }
}

/// A seeded generator for draw `k` of a test.
pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// The dots a projector lattice `spacing` apart puts on `model`, the back's only.
pub fn back_dots(model: &BackModel, spacing: f64) -> Vec<LatticeDot> {
    model.sample(&Lattice::beside_camera(spacing))
}

/// The points another scanner gives of `model`: where its camera (at the origin) looks, on a
/// grid of directions `spacing` apart at 1.5 m, each jittered by up to `jitter` of it (either
/// way; `seed`). Each keeps its grid node as its ray, for a caller that drops them.
pub fn scanner_dots(model: &BackModel, spacing: f64, jitter: f64, seed: u64) -> Vec<LatticeDot> {
    let mut r = rng(seed);
    let jitter = rand_distr::Uniform::new(-jitter * spacing, jitter * spacing).unwrap();
    let n = (450.0 / spacing).floor() as i32;
    let grid = (-n..=n).flat_map(|j| (-n..=n).map(move |i| [i, j]));
    let directions: Vec<_> = grid
        .map(|node| {
            (
                node,
                node.map(|k| f64::from(k) * spacing + jitter.sample(&mut r)),
            )
        })
        .collect();
    looked_at(model, directions)
}

/// The points of `model` where a camera looks in directions scattered at random, as many as
/// [`scanner_dots`]'s grid holds, each uniform over its field (`seed`): a back model's mesh
/// sampled uniformly, as clouds are made of them.
pub fn scattered_dots(model: &BackModel, spacing: f64, seed: u64) -> Vec<LatticeDot> {
    let mut r = rng(seed);
    let n = (450.0 / spacing).floor() as i32;
    let half = f64::from(n) * spacing;
    let field = rand_distr::Uniform::new(-half, half).unwrap();
    let directions: Vec<_> = (0..(2 * n + 1).pow(2))
        .map(|k| ([k, 0], [0; 2].map(|_| field.sample(&mut r))))
        .collect();
    looked_at(model, directions)
}

/// Where a camera at the origin looking in `directions` (x, y at 1.5 m, each with a key) sees
/// `model`: the lines of sight that meet the surface within 80° of its normal, each point with
/// its key as its ray.
fn looked_at(model: &BackModel, directions: Vec<([i32; 2], [f64; 2])>) -> Vec<LatticeDot> {
    let seen = |(ray, [x, y]): ([i32; 2], [f64; 2])| {
        let sight = Vector3::new(x, y, -1500.0).normalize();
        let hit = model.hit(&Vector3::zeros(), &sight)?;
        (-hit.normal.dot(&sight) > 80f64.to_radians().cos()).then_some(LatticeDot { ray, hit })
    };
    directions.into_iter().filter_map(seen).collect()
}

/// Error and error/σ of an index over draws.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Errors {
    sum: f64,
    sq: f64,
    z2: f64,
    n: usize,
}

impl Errors {
    /// Adds an error with its σ.
    pub fn push(&mut self, error: f64, sigma: f64) {
        self.sum += error;
        self.sq += error * error;
        self.z2 += (error / sigma).powi(2);
        self.n += 1;
    }

    /// Mean error.
    pub fn mean(&self) -> f64 {
        self.sum / self.n.max(1) as f64
    }

    /// RMS error.
    pub fn rms(&self) -> f64 {
        (self.sq / self.n.max(1) as f64).sqrt()
    }

    /// RMS of error / σ.
    pub fn z(&self) -> f64 {
        (self.z2 / self.n.max(1) as f64).sqrt()
    }

    /// How many errors.
    pub fn count(&self) -> usize {
        self.n
    }

    /// Asserts that the σ were honest: the RMS of error/σ within 0.8-1.25 (the issue's bar).
    pub fn assert_honest(&self, what: &str) {
        assert_honest(self.z(), what);
    }
}

/// Errors with their σ, collected.
impl FromIterator<(f64, f64)> for Errors {
    fn from_iter<I: IntoIterator<Item = (f64, f64)>>(errors: I) -> Self {
        let mut collected = Errors::default();
        for (error, sigma) in errors {
            collected.push(error, sigma);
        }
        collected
    }
}

/// The analysis frame of an analysis, for the model's truth.
pub fn axes_of(a: &BackAnalysis) -> Axes {
    Axes {
        across: Vector3::from(a.axes.across),
        axis: Vector3::from(a.axes.axis),
        up: Vector3::from(a.axes.up),
    }
}

/// Each index's errors against the model's truth.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct IndexErrors {
    /// Symmetry line, per level (mm).
    pub symmetry_x: Errors,
    /// Surface rotation, per level (°).
    pub rotation: Errors,
    /// Skin angle, per level (°).
    pub skin_angle: Errors,
    /// Scoliometer, per level (°).
    pub atr: Errors,
    /// Largest rotation (°).
    pub rotation_max: Errors,
    /// Largest lateral deviation (mm).
    pub lateral_deviation_max: Errors,
    /// RMS of the rotation over the levels (°).
    pub rotation_rms: Errors,
    /// RMS of the lateral deviation (mm).
    pub lateral_deviation_rms: Errors,
    /// Trunk imbalance (mm).
    pub trunk_imbalance: Errors,
    /// Trunk inclination (°).
    pub trunk_inclination: Errors,
    /// Largest scoliometer angle (°).
    pub atr_max: Errors,
    /// Kyphosis (°).
    pub kyphosis: Errors,
    /// Lordosis (°).
    pub lordosis: Errors,
    /// The mirror-asymmetry map, at every third level (mm).
    pub asymmetry: Errors,
    /// Its largest value (mm).
    pub asymmetry_max: Errors,
    /// The largest |rotation| of each draw (°).
    pub largest_rotation: Vec<f64>,
    /// The levels where the symmetry line was not found, all draws.
    pub left_out: usize,
    /// The draws whose line is mostly lost (`BackAnalysis::line_mostly_lost`).
    pub lines_lost: usize,
    /// The draws whose profile reads as a back seen upside down
    /// (`BackAnalysis::looks_upside_down`).
    pub upside_down: usize,
    /// The draws bent forward whose line rests on faint features (`BackAnalysis::line_faint`).
    pub faint: usize,
    /// Each standing draw's sagittal mid-height excess (°).
    pub mid_excess: Vec<f64>,
    /// Each draw's asymmetry over the noise (`BackAnalysis::asymmetry_over_noise`).
    pub asymmetry_over_noise: Vec<f64>,
    /// The points left out of the fit as wild, all draws.
    pub wild: usize,
    /// The planes larger than the back left out (a wall in view), all draws.
    pub planes: usize,
}

/// The signed value of largest magnitude.
fn largest(values: impl Iterator<Item = f64>) -> f64 {
    values.fold(0.0, |m: f64, x| if x.abs() > m.abs() { x } else { m })
}

/// The least and the greatest of `values` (None if there are none).
fn range(values: &[f64]) -> Option<(f64, f64)> {
    let first = *values.first()?;
    Some(
        values
            .iter()
            .fold((first, first), |(lo, hi), &x| (lo.min(x), hi.max(x))),
    )
}

/// The root mean square of `values`.
fn rms(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = values.fold((0.0, 0.0), |(s, n), x| (s + x * x, n + 1.0));
    (sum / n).sqrt()
}

impl IndexErrors {
    /// The range of the standing draws' sagittal mid-height excess, as printed.
    pub fn mid_excess_range(&self) -> String {
        range(&self.mid_excess).map_or("none (bent forward)".into(), |(lo, hi)| {
            format!("{lo:+.1} to {hi:+.1}°")
        })
    }

    /// The range of the draws' asymmetry over the noise, as printed.
    pub fn asymmetry_over_noise_range(&self) -> String {
        range(&self.asymmetry_over_noise)
            .map_or("none".into(), |(lo, hi)| format!("{lo:.0}-{hi:.0}"))
    }

    /// Adds an analysis of `model` (the frame 0 model of a scan) to the errors.
    pub fn add(&mut self, model: &BackModel, a: &BackAnalysis) {
        let axes = axes_of(a);
        self.left_out += a.levels_left_out.len();
        self.lines_lost += usize::from(a.line_mostly_lost());
        self.upside_down += usize::from(a.looks_upside_down());
        self.faint += usize::from(a.line_faint());
        self.mid_excess.extend(a.sagittal_mid_excess_deg());
        self.asymmetry_over_noise.push(a.asymmetry_over_noise);
        self.wild += a.wild.len();
        self.planes += a.planes_left_out.len();
        let mut truth = Vec::new();
        for l in &a.levels {
            let (x, n) = model
                .symmetry_point(&axes, l.y)
                .expect("truth at the level");
            let rotation = model
                .rotation(&axes, l.y)
                .expect("truth at the level")
                .to_degrees();
            self.symmetry_x.push(l.symmetry_x - x, l.symmetry_x_sigma);
            self.rotation
                .push(l.rotation_deg - rotation, l.rotation_sigma_deg);
            if let (Some(s), Some(sd)) = (l.skin_angle_deg, l.skin_angle_sigma_deg) {
                let t = model
                    .skin_angle(&axes, l.y, a.skin_angle_distance_mm)
                    .unwrap();
                self.skin_angle.push(s - t.to_degrees(), sd);
            }
            let atr = l.atr_window.map(|w| {
                model
                    .scoliometer(&axes, l.y, (w[0], w[1]))
                    .unwrap()
                    .to_degrees()
            });
            if let (Some(t), Some(e), Some(sd)) = (atr, l.atr_deg, l.atr_sigma_deg) {
                self.atr.push(e - t, sd);
            }
            truth.push((l.y, x, n, rotation, atr));
        }
        let (first, last) = (truth[0], truth[truth.len() - 1]);
        let deviation: Vec<f64> = truth
            .iter()
            .map(|t| {
                let f = (t.0 - first.0) / (last.0 - first.0);
                t.1 - (1.0 - f) * first.1 - f * last.1
            })
            .collect();
        self.rotation_rms.push(
            a.rotation_rms_deg - rms(truth.iter().map(|t| t.3)),
            a.rotation_rms_deg_sigma,
        );
        self.lateral_deviation_rms.push(
            a.lateral_deviation_rms_mm - rms(deviation.iter().copied()),
            a.lateral_deviation_rms_mm_sigma,
        );
        // The largest values as magnitudes: their sign is chance where two levels of opposite
        // sign are within the noise (deltaz_surface::compare).
        let magnitude = |measured: f64, truth: f64| measured.abs() - truth.abs();
        self.rotation_max.push(
            magnitude(a.rotation_max_deg, largest(truth.iter().map(|t| t.3))),
            a.rotation_max_deg_sigma,
        );
        self.lateral_deviation_max.push(
            magnitude(a.lateral_deviation_max_mm, largest(deviation.into_iter())),
            a.lateral_deviation_max_mm_sigma,
        );
        self.trunk_imbalance.push(
            a.trunk_imbalance_mm - (last.1 - first.1),
            a.trunk_imbalance_mm_sigma,
        );
        let inclination = (last.2 - first.2).atan2(last.0 - first.0).to_degrees();
        self.trunk_inclination.push(
            a.trunk_inclination_deg - inclination,
            a.trunk_inclination_deg_sigma,
        );
        if let (Some(m), Some(sd)) = (a.atr_max_deg, a.atr_max_deg_sigma) {
            self.atr_max
                .push(magnitude(m, largest(truth.iter().filter_map(|t| t.4))), sd);
        }
        self.largest_rotation.push(a.rotation_max_deg.abs());
        self.add_sagittal(model, a, &axes);
        self.add_asymmetry(model, a, &axes);
    }

    /// Kyphosis and lordosis against the truth's, by the analysis' definition over the true
    /// sagittal slopes at the same levels.
    fn add_sagittal(&mut self, model: &BackModel, a: &BackAnalysis, axes: &Axes) {
        let slopes: Vec<f64> = a
            .levels
            .iter()
            .map(|l| model.sagittal_slope(axes, l.y).unwrap().to_degrees())
            .collect();
        let Some(itl) = (0..slopes.len()).max_by(|&i, &j| slopes[i].total_cmp(&slopes[j])) else {
            return;
        };
        let least = |r: std::ops::Range<usize>| r.map(|i| slopes[i]).fold(f64::INFINITY, f64::min);
        let truth = [least(itl + 1..slopes.len()), least(0..itl)];
        let measured = [
            (a.kyphosis_deg, a.kyphosis_deg_sigma),
            (a.lordosis_deg, a.lordosis_deg_sigma),
        ];
        for ((m, t), errors) in measured
            .into_iter()
            .zip(truth)
            .zip([&mut self.kyphosis, &mut self.lordosis])
        {
            if let ((Some(m), Some(sd)), true) = (m, t.is_finite()) {
                errors.push(m - (slopes[itl] - t), sd);
            }
        }
    }

    /// The asymmetry map against the truth's, s(a) − s(2x − a) about the true symmetry point,
    /// at every third level and at its largest value's cell.
    fn add_asymmetry(&mut self, model: &BackModel, a: &BackAnalysis, axes: &Axes) {
        let map = &a.asymmetry;
        let truth = |across: f64, v: f64| {
            let (x, _) = model.symmetry_point(axes, v)?;
            let depth = |u: f64| model.depth(axes, u, v);
            Some(depth(across)? - depth(2.0 * x - across)?)
        };
        for (j, &v) in map.v.iter().enumerate().step_by(3) {
            for (i, &across) in map.a.iter().enumerate() {
                let k = j * map.a.len() + i;
                if let (Some(value), Some(sd), Some(t)) =
                    (map.values[k], map.sigmas[k], truth(across, v))
                {
                    self.asymmetry.push(value - t, sd);
                }
            }
        }
        if let (Some(m), Some(sd), Some([across, v])) = (
            a.asymmetry_max_mm,
            a.asymmetry_max_mm_sigma,
            a.asymmetry_max_at,
        ) {
            self.asymmetry_max.push(m - truth(across, v).unwrap(), sd);
        }
    }
}

/// The issue's bars for the symmetry line and the surface rotation: at least 15 levels a draw
/// over 30 draws, rotation ≤ 0.5° RMS per level, symmetry line ≤ 2 mm RMS, both with an RMS of
/// error/σ within 0.8-1.25.
pub fn check_line_and_rotation(what: &str, e: &IndexErrors) {
    assert!(
        e.symmetry_x.count() >= 30 * 15,
        "{what}: {} levels",
        e.symmetry_x.count()
    );
    check_accuracy(what, e);
    e.symmetry_x
        .assert_honest(&format!("{what}: symmetry line"));
}

/// The issue's accuracy bars (rotation ≤ 0.5° RMS, its error/σ within 0.8-1.25; symmetry line
/// ≤ 2 mm RMS), the line's error/σ left to the caller, no draw's line mostly lost and no
/// draw read as upside down or as resting on faint features.
pub fn check_accuracy(what: &str, e: &IndexErrors) {
    assert_eq!(e.lines_lost, 0, "{what}: lines mostly lost");
    assert_eq!(e.upside_down, 0, "{what}: read as upside down");
    assert_eq!(e.faint, 0, "{what}: read as resting on faint features");
    assert!(
        e.rotation.rms() <= 0.5,
        "{what}: rotation RMS {:.3}°",
        e.rotation.rms()
    );
    assert!(
        e.symmetry_x.rms() <= 2.0,
        "{what}: symmetry line RMS {:.2} mm",
        e.symmetry_x.rms()
    );
    e.rotation.assert_honest(&format!("{what}: rotation"));
}

/// `draws` scans of `models` (one frame each, the same subject swayed; frame 0's truth), their
/// dots falling where `dots` says, each scan with its own noise and common error, its points
/// `given` as it says, analysed with `options`.
pub fn scans(
    models: &[BackModel],
    dots: Dots,
    given: Given,
    draws: u64,
    seed: u64,
    options: &Options,
) -> IndexErrors {
    let mut errors = IndexErrors::default();
    for k in 0..draws {
        let (models, dots) = match dots {
            Dots::Placed(spacing) => {
                let models = placed(models, spacing, seed + k);
                let dots = models.iter().map(|m| back_dots(m, spacing)).collect();
                (models, dots)
            }
            Dots::Fixed(dots) => (models.to_vec(), dots.to_vec()),
        };
        let a = scanned(&dots, given, &Noise::issue(), seed + k, options)
            .unwrap_or_else(|e| panic!("{}, draw {k}: {e}", models[0].deformity.name));
        errors.add(&models[0], &a);
    }
    errors
}

/// Where a draw's dots fall on the subject.
#[derive(Clone, Copy)]
pub enum Dots<'a> {
    /// The lattice this far apart (mm), [`placed`] anew on the subject each draw.
    Placed(f64),
    /// These on each model, every draw.
    Fixed(&'a [Vec<LatticeDot>]),
}

/// `models` shifted together across the camera by a draw (`seed`) uniform over a dot cell
/// `spacing` wide: where the lattice falls on the subject.
pub fn placed(models: &[BackModel], spacing: f64, seed: u64) -> Vec<BackModel> {
    let mut r = rng(seed ^ 0x9e37_79b9);
    let cell = rand_distr::Uniform::new(-0.5 * spacing, 0.5 * spacing).unwrap();
    shifted(models, [cell.sample(&mut r), cell.sample(&mut r)])
}

/// `models` shifted together across the camera by `[x, y]` (mm).
pub fn shifted(models: &[BackModel], [x, y]: [f64; 2]) -> Vec<BackModel> {
    models
        .iter()
        .map(|m| {
            m.with_pose(Pose {
                translation: m.pose.translation + Vector3::new(x, y, 0.0),
                ..m.pose
            })
        })
        .collect()
}

/// How a draw's points reach the analysis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Given {
    /// With their rays: meshed over the lattice.
    WithRays,
    /// Without (a cloud from elsewhere): meshed over what the camera sees.
    WithoutRays,
    /// Without, thinned to what a dot pattern this far apart (mm) would give, as `deltaz
    /// analyse back` thins a dense cloud.
    Thinned(f64),
    /// With their rays, each dot missed with this probability (the draw's own).
    Missing(f64),
    /// With their rays, each dot's point off with this probability: moved along the camera's
    /// line of sight by 5-30 mm either way (a centroid pulled by a neighbour, a highlight).
    Wrong(f64),
}

/// One draw (`seed`): a frame of each of `dots` with its own noise and the common error, its
/// points `given` as it says, all analysed together with `options`.
pub fn scanned(
    dots: &[Vec<LatticeDot>],
    given: Given,
    noise: &Noise,
    seed: u64,
    options: &Options,
) -> Result<BackAnalysis, SurfaceError> {
    let mut r = rng(seed);
    let delta = common_draw(noise, &mut r);
    let mut frames: Vec<Frame> = dots
        .iter()
        .map(|d| frame(d, noise, &delta, &mut r))
        .collect();
    for f in &mut frames {
        match given {
            Given::WithRays => {}
            Given::WithoutRays | Given::Thinned(_) => {
                f.points.iter_mut().for_each(|p| p.ray = None)
            }
            Given::Missing(p) => {
                let seen = rand_distr::Bernoulli::new(1.0 - p).unwrap();
                let kept: Vec<usize> = (0..f.points.len())
                    .filter(|_| seen.sample(&mut r))
                    .collect();
                *f = f.only(&kept);
            }
            Given::Wrong(p) => {
                let wrong = rand_distr::Bernoulli::new(p).unwrap();
                let by = rand_distr::Uniform::new(5.0, 30.0).unwrap();
                let away = rand_distr::Bernoulli::new(0.5).unwrap();
                for q in &mut f.points {
                    if wrong.sample(&mut r) {
                        let sign = if away.sample(&mut r) { 1.0 } else { -1.0 };
                        q.position += q.position.normalize() * sign * by.sample(&mut r);
                    }
                }
            }
        }
        if let Given::Thinned(spacing) = given {
            *f = f.thinned(spacing);
        }
    }
    analyse(&frames, options)
}
