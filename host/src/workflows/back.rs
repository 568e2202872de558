//! Clouds → the back analysis (`deltaz analyse back`, the station's captures): each cloud's
//! points (one frame per cloud, or per `frame` property) with their covariance, then
//! [`deltaz_surface::analyse`] over all frames of the subject.
//!
//! A point's covariance comes from the calibration when `system.json` (of `calibrate system`,
//! with its covariance) is given: the point is projected back to its dot's pixel, and
//! [`SystemModel::reconstruct_shares`] splits its covariance into the share of its own (image
//! noise, with the wire's centroid quantisation for device clouds, and its ray's own error) and
//! the calibration's error common to every point ([`CommonShare::Core`]). Without a system, a
//! cloud's own `sigma_*` properties give each point's covariance, or for a cloud from elsewhere
//! one σ given for all its points (no common share either way); a cloud with none of these
//! cannot be analysed honestly and is refused. A cloud from elsewhere may lack the rays (its
//! surface is then meshed over what the camera sees) and the header's frame (its points are
//! then taken in the camera system, as the analysis' conventions state, and the report says so).

use crate::io::analysis_file::{BackReport, ANALYSIS_FORMAT};
use crate::io::ply::{read_cloud, Cloud};
use crate::io::system_file::{SystemFile, SystemFrame, SystemRig};
use crate::simulate::pattern::ID_STRIDE;
use anyhow::{bail, Context, Result};
use deltaz_calib::projector_calibration::DotObservation;
use deltaz_calib::system_adjustment::{Frame as ModelFrame, PointShares, SystemModel};
use deltaz_shared::rig::Method;
use deltaz_surface::{analyse, BackAnalysis, CommonShare, Frame, Options, ScanPoint};
use nalgebra::{DMatrix, Matrix3, Vector3};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Where the points' covariance comes from.
#[derive(Clone, Copy)]
pub enum PointSigma<'a> {
    /// The calibration the clouds were measured with (`--system`), its common share included.
    Calibration(&'a Calibration),
    /// The clouds' own `sigma_*` properties.
    Own,
    /// One σ (mm) on each axis for every point of clouds that carry none (`--sigma`).
    Given(f64),
}

/// The calibration a cloud's covariance comes from.
pub struct Calibration {
    file: SystemFile,
    rig: SystemRig,
    model: SystemModel,
    split: deltaz_calib::system_adjustment::CoreSplit,
}

impl Calibration {
    /// `system.json`, which must be in the camera system with the covariance of `calibrate
    /// system` (or of `calibrate projector`'s joint model).
    pub fn load(path: &Path) -> Result<Self> {
        let (file, rig) = SystemFile::load(path)?;
        Self::new(file, rig, path)
    }

    /// [`Calibration::load`] of a system in memory; `path` names it in errors.
    pub fn new(file: SystemFile, rig: SystemRig, path: &Path) -> Result<Self> {
        if file.content.frame != SystemFrame::Camera {
            bail!(
                "{}: the system is in {}: the back analysis needs the camera system",
                path.display(),
                file.content.frame
            );
        }
        let model = file
            .content
            .model()
            .with_context(|| path.display().to_string())?
            .with_context(|| {
                format!(
                    "{}: no covariance (a `calibrate projector --model paper` system): the points' \
                     σ needs `calibrate system`",
                    path.display()
                )
            })?;
        let split = model
            .core_split()
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        Ok(Self {
            file,
            rig,
            model,
            split,
        })
    }

    /// Its rig.
    pub fn rig(&self) -> &SystemRig {
        &self.rig
    }

    /// The fingerprint (16 hex digits).
    pub fn fingerprint(&self) -> &str {
        &self.file.fingerprint
    }

    /// The calibration file.
    pub fn file(&self) -> &SystemFile {
        &self.file
    }

    /// The covariance of the calibration's core parameters (the share common to all points).
    pub fn core_covariance(&self) -> &DMatrix<f64> {
        &self.model.core_covariance
    }

    /// The covariance shares of the point the device gave at `point` (camera system) for ray
    /// `id`: the point projected back to its dot's pixel, then [`SystemModel::reconstruct_shares`].
    pub fn shares(&self, id: u16, point: &Vector3<f64>) -> Result<PointShares> {
        let (col, row) = self
            .rig
            .pixel_of_centred(&(point - self.rig.camera_centre()))
            .map_err(|e| anyhow::anyhow!("ray {id}: {e}"))?;
        let dot = DotObservation { id, col, row };
        self.model
            .reconstruct_shares(
                &self.split,
                self.rig.grid(),
                &dot,
                Method::ClosestApproach,
                ModelFrame::Camera,
            )
            .map_err(|e| anyhow::anyhow!("ray {id}: {e}"))
    }
}

/// A ray's node (column, row) in the projector's lattice (ids are row · [`ID_STRIDE`] + col).
fn lattice_node(id: u16) -> [i32; 2] {
    [i32::from(id % ID_STRIDE), i32::from(id / ID_STRIDE)]
}

/// The clouds of one analysis, read.
pub struct Clouds {
    /// Their frames, each point with its covariance.
    pub frames: Vec<Frame>,
    /// What was assumed of them (a cloud that does not say its frame).
    pub notes: Vec<String>,
    /// The calibration they name, if any (one for all).
    pub fingerprint: Option<String>,
}

/// The clouds at `paths`, each point with its covariance from `sigma`.
pub fn frames(paths: &[PathBuf], sigma: PointSigma) -> Result<Clouds> {
    let mut frames = Vec::new();
    let mut notes = Vec::new();
    let mut fingerprint: Option<(String, &Path)> = None;
    for path in paths {
        let cloud = read_cloud(path)?;
        notes.extend(check_frame(path, &cloud)?);
        if let Some(f) = &cloud.fingerprint {
            match &fingerprint {
                Some((first, at)) if first != f => bail!(
                    "{}: measured with calibration {f}, but {} with {first}: frames of one \
                     analysis need one calibration",
                    path.display(),
                    at.display()
                ),
                _ => fingerprint = Some((f.clone(), path)),
            }
        }
        if let (PointSigma::Calibration(c), Some(f)) = (sigma, &cloud.fingerprint) {
            if c.fingerprint() != f {
                bail!(
                    "{}: measured with calibration {f}, not the system's {}",
                    path.display(),
                    c.fingerprint()
                );
            }
        }
        frames.extend(cloud_frames(path, &cloud, sigma)?);
    }
    Ok(Clouds {
        frames,
        notes,
        fingerprint: fingerprint.map(|(f, _)| f),
    })
}

/// The frames of one cloud (`path` names it): one per `frame` value (the whole cloud without
/// it), in the order of the values, each point with its covariance from `sigma`.
pub fn cloud_frames(path: &Path, cloud: &Cloud, sigma: PointSigma) -> Result<Vec<Frame>> {
    let mut split: BTreeMap<u32, Vec<_>> = BTreeMap::new();
    for v in &cloud.vertices {
        split.entry(v.frame.unwrap_or(0)).or_default().push(*v);
    }
    split
        .into_values()
        .map(|vertices| match sigma {
            PointSigma::Calibration(c) => with_calibration(&vertices, cloud.centroid_step_px, c)
                .with_context(|| path.display().to_string()),
            PointSigma::Own => with_sigma(path, &vertices, None),
            PointSigma::Given(s) => with_sigma(path, &vertices, Some(s)),
        })
        .collect()
}

/// A cloud's points must be in the camera system: a cloud that names another frame is refused;
/// one that names none (a cloud from elsewhere) is taken in it, and the note returned says so.
fn check_frame(path: &Path, cloud: &Cloud) -> Result<Option<String>> {
    let camera = SystemFrame::Camera.to_string();
    match cloud.frame.as_deref() {
        Some(frame) if frame == camera => Ok(None),
        Some(frame) => bail!(
            "{}: its points are in {frame}: the back analysis needs {camera} (x right, y up, z \
             toward the camera)",
            path.display()
        ),
        None => Ok(Some(format!(
            "{} does not say its frame (a deltaz cloud's header does): its points are taken in \
             {camera} (mm; x right, y up, z toward the camera, which is at the origin)",
            path.display()
        ))),
    }
}

/// A frame of `vertices` with each point's own σ, or `given` for points without one.
fn with_sigma(
    path: &Path,
    vertices: &[crate::io::ply::Vertex],
    given: Option<f64>,
) -> Result<Frame> {
    let points = vertices
        .iter()
        .map(|v| {
            let sigma = match (v.sigma, given) {
                (Some(own), None) => own,
                (None, Some(s)) => Vector3::repeat(s),
                (Some(_), Some(_)) => bail!(
                    "{}: the points carry their own σ (sigma_x, sigma_y, sigma_z): --sigma is \
                     for clouds without",
                    path.display()
                ),
                (None, None) => bail!(
                    "{}: the points carry no σ: give --system system.json (of `calibrate \
                     system`) for their covariance, or for a cloud from elsewhere --sigma MM, \
                     its points' σ",
                    path.display()
                ),
            };
            Ok(ScanPoint {
                position: v.point,
                covariance: Matrix3::from_diagonal(&sigma.component_mul(&sigma)),
                ray: v.ray.map(lattice_node),
            })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Frame::new(points))
}

/// A frame of `vertices` (camera system, each with its ray) with each point's covariance from
/// the calibration `c`; `centroid_step_px`: the step the device quantised the centroids to.
pub fn with_calibration(
    vertices: &[crate::io::ply::Vertex],
    centroid_step_px: Option<f64>,
    c: &Calibration,
) -> Result<Frame> {
    // Device clouds: each centroid was quantised to a step q on the wire (variance q²/12).
    let s2 = c.model.sigma_dots_px.powi(2);
    let quantised = centroid_step_px.map_or(1.0, |q| (s2 + q * q / 12.0) / s2);
    let k = c.model.core_covariance.nrows();
    let mut sensitivity = DMatrix::zeros(3 * vertices.len(), k);
    let mut points = Vec::with_capacity(vertices.len());
    for (i, v) in vertices.iter().enumerate() {
        let id = v.ray.context(
            "the points carry no `ray_id`: the calibration gives a point's covariance through \
             its ray",
        )?;
        let shares = c.shares(id, &v.point)?;
        sensitivity
            .view_mut((3 * i, 0), (3, k))
            .copy_from(&shares.common);
        points.push(ScanPoint {
            position: v.point,
            covariance: shares.image * quantised + shares.ray,
            ray: Some(lattice_node(id)),
        });
    }
    let fingerprint = u64::from_str_radix(c.fingerprint(), 16).ok();
    Ok(Frame {
        points,
        calibration: fingerprint,
        common: CommonShare::Core {
            covariance: c.model.core_covariance.clone(),
            sensitivity,
        },
    })
}

/// A cloud whose points lie closer than this (mm) is denser than any dot pattern the σ were
/// tested at (10-40 mm), and is thinned unless --thin says otherwise ...
const DENSE_MM: f64 = 8.0;
/// ... to this spacing (mm), or three times its own if more: a scanner's points need not lie
/// on a grid, and scattered at random they leave a cell of three times their spacing empty
/// once in 8,000 (a cell of twice, once in 50: a hole in the mesh).
const THIN_MM: f64 = 10.0;
/// Points lying more irregularly than this ([`deltaz_surface::mesh::Mesh::irregularity`]) get
/// a note: on the back model the σ held at 0.13 and understated the errors 1.6 times at 0.21,
/// 2-3 times at 0.40 (the analysis refuses points scattered at random,
/// [`deltaz_surface::analysis::SCATTERED`]).
const IRREGULAR: f64 = 0.2;

/// `deltaz analyse back`: the clouds at `paths` analysed with `options`, their points'
/// covariance from `system` (its path) or one σ `given` for all (or else their own), each
/// cloud thinned to what a dot pattern `thin` mm apart would give if asked.
pub fn analyse_clouds(
    paths: &[PathBuf],
    system: Option<&Path>,
    given: Option<f64>,
    thin: Option<f64>,
    options: &Options,
) -> Result<BackReport> {
    if let Some(s) = thin.filter(|s| !(*s > 0.0 && s.is_finite())) {
        bail!("--thin {s}: a dot spacing is a positive number of mm");
    }
    let calibration = system.map(Calibration::load).transpose()?;
    let sigma = match (&calibration, given) {
        (Some(c), None) => PointSigma::Calibration(c),
        (None, Some(s)) if s > 0.0 && s.is_finite() => PointSigma::Given(s),
        (None, Some(s)) => bail!("--sigma {s}: a point's σ is a positive number of mm"),
        (None, None) => PointSigma::Own,
        (Some(_), Some(_)) => bail!("give --system or --sigma, not both"),
    };
    analyse_with(paths, sigma, thin, options)
}

/// [`analyse_clouds`] with the points' covariance from `sigma`. Clouds denser than a dot
/// pattern (`DENSE_MM`) are thinned even if `thin` is not given, and a note says so.
pub fn analyse_with(
    paths: &[PathBuf],
    sigma: PointSigma,
    thin: Option<f64>,
    options: &Options,
) -> Result<BackReport> {
    if paths.is_empty() {
        bail!("give at least one --cloud");
    }
    let Clouds {
        mut frames,
        mut notes,
        fingerprint,
    } = frames(paths, sigma)?;
    let names: Vec<String> = paths.iter().map(|p| p.display().to_string()).collect();
    let mut names = names.join(", ");
    // Before thinning: a cloud in metres thinned is a point or two, its scale lost.
    for (k, f) in frames.iter().enumerate() {
        f.validate(k).map_err(|e| anyhow::anyhow!("{names}: {e}"))?;
    }
    let dense = || {
        let spacing = frames.first()?.mesh().spacing;
        (spacing < DENSE_MM).then(|| {
            let s = (3.0 * spacing).max(THIN_MM).round();
            notes.push(format!(
                "the points lie {spacing:.1} mm apart, denser than the dot patterns (10-40 mm) \
                 the σ were tested at: thinned to {s} mm (--thin MM for another spacing)"
            ));
            s
        })
    };
    let thinned = thin.or_else(dense);
    if let Some(s) = thinned {
        frames = frames.iter().map(|f| f.thinned(s)).collect();
        notes.push(format!(
            "thinned to what a dot pattern {s} mm apart would give: of each {s} mm square of the \
             camera's x-y plane, the point nearest its centre"
        ));
    }
    if let Some(s) = thinned {
        names += &format!(" (thinned to {s} mm)");
    }
    let analysis = analyse(&frames, options).map_err(|e| anyhow::anyhow!("{names}: {e}"))?;
    let frame_names: Vec<String> = (0..frames.len()).map(|k| format!("frame {k}")).collect();
    notes.extend(fit_notes(&analysis, &frames, &frame_names));
    let fingerprint = match sigma {
        PointSigma::Calibration(c) => Some(c.fingerprint().to_owned()),
        _ => fingerprint,
    };
    Ok(BackReport {
        notes,
        ..back_report(paths, sigma, fingerprint, analysis)
    })
}

/// What the reader must know of the points the analysis of `frames` (each called by its
/// `names`) set aside or found wanting: points lying irregularly, points left out of the
/// surface fit as wild (where they lie), planes larger than the back left out. `deltaz
/// analyse back`, its report and the station's surface say it alike.
pub fn fit_notes(analysis: &BackAnalysis, frames: &[Frame], names: &[String]) -> Vec<String> {
    let mut notes = Vec::new();
    if analysis.irregularity > IRREGULAR {
        notes.push(format!(
            "the points lie irregularly (their nearest neighbours' distances spread by {:.0} % of \
             their mean, a grid's by 5 %): the σ were tested on samplings within 13 %; at 21 % \
             they understated the errors 1.6 times on the back model, at 40 % 2-3 times",
            100.0 * analysis.irregularity
        ));
    }
    if !analysis.wild.is_empty() {
        let listed: Vec<String> = analysis
            .wild
            .iter()
            .map(|w| {
                let p = frames[w.frame].points[w.point].position;
                format!(
                    "{} at ({:.1}, {:.1}, {:.1}) {:+.1} mm off",
                    names[w.frame], p.x, p.y, p.z, w.residual_mm
                )
            })
            .collect();
        notes.push(format!(
            "{} points left out of the surface fit as wild (each off the surface by over 5 times \
             the residuals' spread where its neighbours' were not: a dot misidentified, a \
             highlight; crosses on the topography), in the camera system (mm; off: in depth, \
             + nearer the camera): {}",
            listed.len(),
            listed.join(", ")
        ));
    }
    for p in &analysis.planes_left_out {
        let [x, y, z] = p.centre;
        notes.push(format!(
            "{}: a plane larger than the back left out (a wall or the floor in view): {} points \
             about ({x:.0}, {y:.0}, {z:.0}) in the camera system, {:.0} mm beyond the back; the \
             back is the largest surface that is not a plane",
            names[p.frame], p.points, p.beyond_mm
        ));
    }
    notes
}

/// The report of an analysis of the clouds at `paths` (what `analysis.json` holds), with where
/// the points' covariance came from (`sigma`).
pub fn back_report(
    paths: &[PathBuf],
    sigma: PointSigma,
    fingerprint: Option<String>,
    analysis: deltaz_surface::BackAnalysis,
) -> BackReport {
    let no_common = "no share common to all points: give --system for it";
    let covariance = match sigma {
        PointSigma::Calibration(c) => format!(
            "the calibration's covariance (system {}): image noise, each ray's own error and \
             the share common to all points",
            c.fingerprint()
        ),
        PointSigma::Own => format!("the clouds' own σ per axis ({no_common})"),
        PointSigma::Given(s) => {
            format!("σ {s} mm on each axis for every point, as given ({no_common})")
        }
    };
    BackReport {
        format: ANALYSIS_FORMAT.to_owned(),
        clouds: paths.to_vec(),
        fingerprint,
        covariance,
        notes: Vec::new(),
        analysis,
    }
}
