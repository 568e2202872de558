//! `system.json` ("deltaz.system/2"): the calibrated camera-projector system, what the device
//! receives.
//!
//! Holds the frame its coordinates are in ([`SystemFrame`]: the camera system of `calibrate
//! system`, or the plate frame of one plate image for `calibrate projector`), the camera's raster
//! and inner orientation, its pose in that frame, the
//! projector centre with σ, every ray (id, l, m, n, offset) with its fit residuals, and a
//! `fingerprint`: FNV-1a 64 over the canonical JSON of everything else (struct field order, serde_json's
//! shortest round-trip floats), written as 16 hex digits. The device echoes it, so the host knows
//! which calibration measured a frame. Loading checks the format, the fingerprint, finite numbers,
//! unit direction cosines and unique ray ids, and builds a [`SystemRig`].

use anyhow::{bail, Context, Result};
use deltaz_calib::projector_calibration::{
    CalibratedRay, LineCovariance, Model, ProjectorCalibration,
};
use deltaz_calib::residual::INNER_NAMES;
use deltaz_calib::system_adjustment::{AdjustedRay, Datum, SystemAdjustment, SystemModel};
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::ExteriorOrientation;
use deltaz_shared::projector::{Projector, ProjectorRay};
use deltaz_shared::rig::Rig;
use nalgebra::{DMatrix, Vector3};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The format tag of `system.json`.
pub const FORMAT: &str = "deltaz.system/2";

/// The frame a system's coordinates (its camera pose, projector centre and rays, and so the
/// points reconstructed with it) are in.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum SystemFrame {
    /// The camera system: x right, y up, z toward the viewer, the origin the perspective centre
    /// (the instrument's own frame; `calibrate system`).
    Camera,
    /// The plate (control) frame of one plate image: the plate surface Z = 0 as it stood in
    /// that image (`calibrate projector`: its 1st plate image).
    Plate {
        /// The plate image's label.
        image: String,
    },
}

impl std::fmt::Display for SystemFrame {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SystemFrame::Camera => write!(f, "the camera system"),
            SystemFrame::Plate { image } => write!(f, "the plate frame of image {image}"),
        }
    }
}

pub use deltaz_calib::reconstruct::{RayCovariances, SystemRig};

/// The camera pose in the rig frame (eq. 3): κ, φ, ω (rad) and X0, Y0, Z0 (mm).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// κ (rad).
    pub kappa: f64,
    /// φ (rad).
    pub phi: f64,
    /// ω (rad).
    pub omega: f64,
    /// Perspective centre (X0, Y0, Z0), mm.
    pub centre: [f64; 3],
}

impl From<ExteriorOrientation<f64>> for Pose {
    fn from(e: ExteriorOrientation<f64>) -> Self {
        Self {
            kappa: e.kappa,
            phi: e.phi,
            omega: e.omega,
            centre: e.centre.into(),
        }
    }
}

impl From<Pose> for ExteriorOrientation<f64> {
    fn from(p: Pose) -> Self {
        Self {
            kappa: p.kappa,
            phi: p.phi,
            omega: p.omega,
            centre: Vector3::from(p.centre),
        }
    }
}

/// The camera part of the system.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SystemCamera {
    /// Pixel ↔ photo coordinates.
    pub grid: PixelGrid<f64>,
    /// Inner orientation (mm).
    pub inner: InnerOrientation<f64>,
    /// Pose in the rig frame.
    pub pose: Pose,
}

/// One ray as stored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SystemRay {
    /// Ray id.
    pub id: u16,
    /// Direction cosine l.
    pub l: f64,
    /// Direction cosine m.
    pub m: f64,
    /// Direction cosine n.
    pub n: f64,
    /// The ray's point minus the centre (mm), absent for central models.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offset: Option<[f64; 3]>,
    /// Planes the ray was calibrated on.
    pub planes: usize,
    /// RMS miss distance of its plane points (mm).
    pub miss_rms: f64,
    /// Largest miss distance (mm).
    pub miss_max: f64,
    /// The ray's lateral covariance from calibration (for σ of reconstructed points).
    #[serde(default)]
    pub line_cov: LineCovariance,
    /// From the whole-system adjustment: the ray's parameters and covariances.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adjusted: Option<RayCovariance>,
}

/// A ray of the whole-system adjustment: x(z) = P + o + (z − P_z)(a, b, 1) in the camera system.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RayCovariance {
    /// a, b and (non-central) q_x, q_y of o = (q_x, q_y, 0).
    pub params: Vec<f64>,
    /// Their covariance, row by row.
    pub covariance: Vec<Vec<f64>>,
    /// Their covariance with the core [free inner | P], row by row (one row per parameter).
    pub cross: Vec<Vec<f64>>,
}

/// The calibration's covariance from the whole-system adjustment: what a point's σ needs
/// besides each ray's own block.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SystemCovariance {
    /// The adjusted inner parameters by name: the core's first entries, then X_p, Y_p, Z_p.
    pub inner_free: Vec<String>,
    /// Covariance of the core, row by row (mm², rad² where it applies).
    pub core: Vec<Vec<f64>>,
    /// The image noise of the dots, estimated (px).
    pub dot_sigma_px: f64,
    /// The image noise of the plate targets, estimated (px).
    pub target_sigma_px: f64,
    /// The image noise of the field targets, estimated (px), when the camera's field images
    /// were in the same adjustment.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub field_sigma_px: Option<f64>,
    /// The plate frame offered as the points' frame: the camera's pose in it, its parameters
    /// (κ, φ, ω, X0, Y0, Z0) the core's last six.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub datum: Option<StoredDatum>,
}

/// The datum image and the camera's pose in its plate frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StoredDatum {
    /// The plate image's label.
    pub image: String,
    /// The camera's pose in that plate frame.
    pub pose: Pose,
}

/// An image left out of a calibration, and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LeftOut {
    /// The image's label.
    pub image: String,
    /// What is wrong with it.
    pub why: String,
}

/// What the calibration left out or could determine only without redundancy.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Warnings {
    /// Plate images that could not be resected, with the reason.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub left_out_images: Vec<LeftOut>,
    /// Rays seen on one plate: determined by the central model through the centre.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub single_plane_rays: Vec<u16>,
    /// Rays left out (seen on one plate, non-central model).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub left_out_rays: Vec<u16>,
}

impl Warnings {
    /// Nothing to report.
    pub fn is_empty(&self) -> bool {
        self.left_out_images.is_empty()
            && self.single_plane_rays.is_empty()
            && self.left_out_rays.is_empty()
    }

    /// With `--strict`: an error naming every warning (of the calibration from `origin`), or
    /// nothing to report.
    pub fn strict(&self, origin: &Path) -> Result<()> {
        if !self.is_empty() {
            bail!(
                "{}: --strict: {}",
                origin.display(),
                self.lines().join("; ")
            );
        }
        Ok(())
    }

    /// One line per warning.
    pub fn lines(&self) -> Vec<String> {
        let ids = |v: &[u16]| v.iter().map(u16::to_string).collect::<Vec<_>>().join(", ");
        let mut out: Vec<String> = self
            .left_out_images
            .iter()
            .map(|l| format!("image {:?} left out: {}", l.image, l.why))
            .collect();
        if !self.single_plane_rays.is_empty() {
            out.push(format!(
                "{} rays seen on one plate only, determined through the centre without redundancy: {}",
                self.single_plane_rays.len(),
                ids(&self.single_plane_rays)
            ));
        }
        if !self.left_out_rays.is_empty() {
            out.push(format!(
                "{} rays seen on one plate only left out (the non-central model needs two): {}",
                self.left_out_rays.len(),
                ids(&self.left_out_rays)
            ));
        }
        out
    }
}

/// The projector part of the system.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SystemProjector {
    /// The model fitted.
    pub model: Model,
    /// Centre (X_p, Y_p, Z_p) in the rig frame (mm).
    pub centre: [f64; 3],
    /// σ of the centre (mm).
    pub centre_sigma: [f64; 3],
    /// The rays, sorted by id.
    pub rays: Vec<SystemRay>,
    /// The covariance of the whole-system adjustment, if it made this calibration.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub covariance: Option<SystemCovariance>,
}

/// Everything the fingerprint covers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SystemContent {
    /// The frame of every coordinate below.
    pub frame: SystemFrame,
    /// The camera.
    pub camera: SystemCamera,
    /// The projector.
    pub projector: SystemProjector,
    /// What was left out or determined without redundancy.
    #[serde(default, skip_serializing_if = "Warnings::is_empty")]
    pub warnings: Warnings,
}

/// `system.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SystemFile {
    /// "deltaz.system/1".
    pub format: String,
    /// FNV-1a 64 of the canonical JSON of `content`, 16 hex digits.
    pub fingerprint: String,
    /// The calibration.
    #[serde(flatten)]
    pub content: SystemContent,
}

/// FNV-1a, 64 bit.
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

impl SystemContent {
    /// The content's fingerprint: FNV-1a 64 of its canonical (compact) JSON.
    pub fn fingerprint(&self) -> Result<u64> {
        Ok(fnv1a64(&serde_json::to_vec(self)?))
    }

    /// The system of a calibrated camera and projector, in the plate frame of plate image
    /// `image`, where the camera stood at `pose`.
    pub fn new(
        grid: PixelGrid<f64>,
        inner: InnerOrientation<f64>,
        (image, pose): (&str, ExteriorOrientation<f64>),
        projector: &ProjectorCalibration,
    ) -> Self {
        let rays = projector.rays.iter().map(SystemRay::from).collect();
        Self {
            frame: SystemFrame::Plate {
                image: image.to_owned(),
            },
            camera: SystemCamera {
                grid,
                inner,
                pose: pose.into(),
            },
            projector: SystemProjector {
                model: projector.model,
                centre: projector.centre.into(),
                centre_sigma: projector.centre_sigma.into(),
                rays,
                covariance: None,
            },
            warnings: Warnings::default(),
        }
    }

    /// The system of a whole-system adjustment, in the camera system (the camera's pose is the
    /// identity): the instrument's own frame. Its warnings: the plate images `left_out_images`
    /// and the adjustment's rays seen on one plate (determined through the centre, or left out
    /// by the non-central model).
    pub fn from_adjustment(
        grid: PixelGrid<f64>,
        adjustment: &SystemAdjustment,
        noncentral: bool,
        left_out_images: Vec<LeftOut>,
    ) -> Self {
        let warnings = Warnings {
            left_out_images,
            single_plane_rays: if noncentral {
                Vec::new()
            } else {
                adjustment.single_plane.clone()
            },
            left_out_rays: adjustment.left_out.clone(),
        };
        let m = &adjustment.model;
        let rows = |c: &DMatrix<f64>| -> Vec<Vec<f64>> {
            c.row_iter().map(|r| r.iter().copied().collect()).collect()
        };
        let rays = m
            .rays
            .iter()
            .map(|r| {
                let (direction, offset) = r.line();
                SystemRay {
                    id: r.id,
                    l: direction.x,
                    m: direction.y,
                    n: direction.z,
                    offset: noncentral.then(|| offset.into()),
                    planes: r.planes,
                    miss_rms: r.miss_rms,
                    miss_max: r.miss_max,
                    line_cov: LineCovariance::default(),
                    adjusted: Some(RayCovariance {
                        params: r.params.clone(),
                        covariance: rows(&r.covariance),
                        cross: rows(&r.cross),
                    }),
                }
            })
            .collect();
        Self {
            frame: SystemFrame::Camera,
            camera: SystemCamera {
                grid,
                inner: m.inner,
                pose: Pose {
                    kappa: 0.0,
                    phi: 0.0,
                    omega: 0.0,
                    centre: [0.0; 3],
                },
            },
            projector: SystemProjector {
                model: if noncentral {
                    Model::Noncentral
                } else {
                    Model::Joint
                },
                centre: m.centre.into(),
                centre_sigma: m.centre_sigma().into(),
                rays,
                covariance: Some(SystemCovariance {
                    inner_free: m
                        .inner_free
                        .iter()
                        .map(|&k| INNER_NAMES[k].to_owned())
                        .collect(),
                    core: rows(&m.core_covariance),
                    dot_sigma_px: m.sigma_dots_px,
                    target_sigma_px: adjustment.sigma_targets_px,
                    field_sigma_px: adjustment.sigma_field_px,
                    datum: m.datum.as_ref().map(|d| StoredDatum {
                        image: d.image.clone(),
                        pose: d.pose.into(),
                    }),
                }),
            },
            warnings,
        }
    }

    /// The model a point's σ is computed from, when the whole-system adjustment made this
    /// calibration (None otherwise).
    pub fn model(&self) -> Result<Option<SystemModel>> {
        let Some(cov) = &self.projector.covariance else {
            return Ok(None);
        };
        let matrix = |rows: &[Vec<f64>], what: &str| -> Result<DMatrix<f64>> {
            let n = rows.first().map_or(0, Vec::len);
            if rows.iter().any(|r| r.len() != n) {
                bail!("{what}: rows of unequal length");
            }
            Ok(DMatrix::from_fn(rows.len(), n, |a, b| rows[a][b]))
        };
        let inner_free = cov
            .inner_free
            .iter()
            .map(|name| {
                INNER_NAMES
                    .iter()
                    .position(|n| n == name)
                    .with_context(|| format!("unknown inner parameter {name:?}"))
            })
            .collect::<Result<Vec<_>>>()?;
        let core = matrix(&cov.core, "covariance.core")?;
        let k = inner_free.len() + if cov.datum.is_some() { 9 } else { 3 };
        if core.shape() != (k, k) {
            bail!("covariance.core is {:?}, expected {k} × {k}", core.shape());
        }
        let rays = self
            .projector
            .rays
            .iter()
            .map(|r| {
                let a = r
                    .adjusted
                    .as_ref()
                    .with_context(|| format!("ray {}: no adjusted parameters", r.id))?;
                let covariance = matrix(&a.covariance, "ray covariance")?;
                let cross = matrix(&a.cross, "ray cross covariance")?;
                let p = a.params.len();
                if !(p == 2 || p == 4) || covariance.shape() != (p, p) || cross.shape() != (p, k) {
                    bail!("ray {}: covariance of the wrong size", r.id);
                }
                Ok(AdjustedRay {
                    id: r.id,
                    params: a.params.clone(),
                    planes: r.planes,
                    covariance,
                    cross,
                    rms_px: 0.0,
                    miss_rms: r.miss_rms,
                    miss_max: r.miss_max,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Some(SystemModel {
            inner: self.camera.inner,
            inner_free,
            centre: Vector3::from(self.projector.centre),
            rays,
            core_covariance: core,
            sigma_dots_px: cov.dot_sigma_px,
            datum: cov.datum.as_ref().map(|d| Datum {
                image: d.image.clone(),
                pose: d.pose.into(),
            }),
        }))
    }

    /// Validates and builds the rig (world = the rig frame).
    pub fn rig(&self) -> Result<SystemRig> {
        let inner = &self.camera.inner;
        let grid = &self.camera.grid;
        let pose = &self.camera.pose;
        let mut rays = Vec::with_capacity(self.projector.rays.len());
        for r in &self.projector.rays {
            let direction = Vector3::new(r.l, r.m, r.n);
            let offset = Vector3::from(r.offset.unwrap_or([0.0; 3]));
            if !direction.iter().chain(offset.iter()).all(|v| v.is_finite()) {
                bail!(
                    "ray {}: a direction cosine or offset is NaN or infinite",
                    r.id
                );
            }
            let norm = direction.norm();
            if (norm - 1.0).abs() > deltaz_shared::projector::UNIT_TOLERANCE {
                bail!(
                    "ray {}: direction cosines are not a unit vector (|(l, m, n)| = {norm})",
                    r.id
                );
            }
            rays.push(ProjectorRay {
                id: r.id,
                direction,
                offset,
            });
        }
        rays.sort_by_key(|r| r.id);
        if let Some(w) = rays.windows(2).find(|w| w[0].id == w[1].id) {
            bail!("ray {} appears more than once", w[0].id);
        }
        let projector = Projector::new(Vector3::from(self.projector.centre), rays)
            .map_err(|e| anyhow::anyhow!("projector: {e}"))?;
        let rig = Rig::new(*grid, *inner, &(*pose).into(), projector);
        rig.validate().map_err(|e| anyhow::anyhow!("system: {e}"))?;
        Ok(rig)
    }
}

impl From<&CalibratedRay> for SystemRay {
    fn from(r: &CalibratedRay) -> Self {
        Self {
            id: r.id,
            l: r.direction.x,
            m: r.direction.y,
            n: r.direction.z,
            offset: (r.offset != Vector3::zeros()).then(|| r.offset.into()),
            planes: r.planes,
            miss_rms: r.miss_rms,
            miss_max: r.miss_max,
            line_cov: r.line_cov,
            adjusted: None,
        }
    }
}

impl SystemFile {
    /// Wraps content with its format tag and fingerprint.
    pub fn new(content: SystemContent) -> Result<Self> {
        Ok(Self {
            format: FORMAT.to_string(),
            fingerprint: format!("{:016x}", content.fingerprint()?),
            content,
        })
    }

    /// The fingerprint as a number.
    pub fn fingerprint_u64(&self) -> Result<u64> {
        u64::from_str_radix(&self.fingerprint, 16)
            .with_context(|| format!("fingerprint {:?} is not 16 hex digits", self.fingerprint))
    }

    /// Parses and validates `system.json` text (format, fingerprint, rig); `origin` names the
    /// source in errors.
    pub fn parse(text: &str, origin: &str) -> Result<(Self, SystemRig)> {
        match crate::io::format_tag(text).as_deref() {
            Some(FORMAT) => {}
            Some("deltaz.system/1") => bail!(
                "{origin}: format \"deltaz.system/1\" does not state its frame: calibrate again \
                 (this deltaz reads {FORMAT:?})"
            ),
            Some(other) => bail!("{origin}: format {other:?}, expected {FORMAT:?}"),
            None => {}
        }
        let file: Self = serde_json::from_str(text)
            .with_context(|| format!("{origin}: not a valid system.json"))?;
        let rig = file
            .content
            .rig()
            .with_context(|| format!("{origin}: invalid calibration"))?;
        let stated = file.fingerprint_u64().with_context(|| origin.to_string())?;
        let actual = file.content.fingerprint()?;
        if stated != actual {
            bail!("{origin}: fingerprint {stated:016x} does not match the content ({actual:016x}): edited by hand?");
        }
        Ok((file, rig))
    }

    /// Reads and validates a `system.json`.
    pub fn load(path: &Path) -> Result<(Self, SystemRig)> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Each ray's calibration covariance by id, for [`deltaz_calib::reconstruct`].
    pub fn line_covariances(&self) -> RayCovariances {
        self.content
            .projector
            .rays
            .iter()
            .map(|r| (r.id, r.line_cov))
            .collect()
    }

    /// Pretty JSON text.
    pub fn to_json(&self) -> Result<String> {
        Ok(serde_json::to_string_pretty(self)? + "\n")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> SystemFile {
        let grid = PixelGrid {
            pixel_size: 0.045,
            width: 768,
            height: 512,
            origin_col: 378.0,
            origin_row: 252.0,
        };
        let ray = |id, l: f64, m: f64| CalibratedRay {
            id,
            direction: Vector3::new(l, m, -(1.0 - l * l - m * m).sqrt()),
            offset: Vector3::zeros(),
            planes: 3,
            miss_rms: 0.1,
            miss_max: 0.2,
            line_cov: LineCovariance([[0.1, -1e-4, 1e-7]; 2]),
        };
        let projector = ProjectorCalibration {
            model: Model::Paper,
            centre: Vector3::new(-114.601, 383.502, 1905.981),
            centre_sigma: Vector3::new(0.5, 0.5, 2.0),
            rays: vec![ray(1, 0.09159, -0.17179), ray(2, 0.24040, -0.16860)],
            single_plane: Vec::new(),
            left_out: Vec::new(),
        };
        let pose = ExteriorOrientation {
            kappa: 0.01329,
            phi: 0.01418,
            omega: -0.026,
            centre: Vector3::new(375.121, 364.541, 1842.675),
        };
        SystemFile::new(SystemContent::new(
            grid,
            InnerOrientation::ideal(46.981),
            ("p1", pose),
            &projector,
        ))
        .unwrap()
    }

    #[test]
    fn round_trip_and_stable_fingerprint() {
        let file = sample();
        let text = file.to_json().unwrap();
        let (back, rig) = SystemFile::parse(&text, "mem").unwrap();
        assert_eq!(back, file);
        assert_eq!(
            back.fingerprint,
            sample().fingerprint,
            "stable across builds"
        );
        assert_eq!(file.fingerprint.len(), 16);
        // Pinned: the fingerprint must not change between builds or runs for the same content.
        assert_eq!(file.fingerprint, "6d3f03951d1a1ab1");
        assert_eq!(rig.projector_centred().rays().len(), 2);
        // FNV-1a 64 reference values.
        assert_eq!(fnv1a64(b""), 0xcbf29ce484222325);
        assert_eq!(fnv1a64(b"a"), 0xaf63dc4c8601ec8c);
    }

    fn rejects(edit: impl Fn(&mut SystemFile), needle: &str) {
        let mut file = sample();
        edit(&mut file);
        file.fingerprint = format!("{:016x}", file.content.fingerprint().unwrap());
        let err = SystemFile::parse(&file.to_json().unwrap(), "system.json").unwrap_err();
        assert!(format!("{err:#}").contains(needle), "{err:#}");
    }

    #[test]
    fn bad_systems_are_errors() {
        rejects(
            |f| f.content.projector.rays[1].l = 0.5,
            "ray 2: direction cosines are not a unit vector",
        );
        rejects(
            |f| f.content.projector.rays[0].m = f64::NAN,
            "not a valid system.json",
        );
        rejects(
            |f| f.content.projector.rays[1].id = 1,
            "ray 1 appears more than once",
        );
        rejects(
            |f| f.format = "deltaz.system/0".into(),
            "expected \"deltaz.system/2\"",
        );
        let mut f = sample();
        f.content.projector.centre[0] += 1.0;
        let err = SystemFile::parse(&f.to_json().unwrap(), "s.json").unwrap_err();
        assert!(
            err.to_string().contains("does not match the content"),
            "{err}"
        );
    }
}
