//! `system.json` ("deltaz.system/1"): the calibrated camera-projector system, what the device
//! receives.
//!
//! Holds the camera's raster and inner orientation, its pose in the rig (global) frame, the
//! projector centre with σ, every ray (id, l, m, n, offset) with its fit residuals, and a
//! `fingerprint`: FNV-1a 64 over the canonical JSON of everything else (struct field order, serde_json's
//! shortest round-trip floats), written as 16 hex digits. The device echoes it, so the host knows
//! which calibration measured a frame. Loading checks the format, the fingerprint, finite numbers,
//! unit direction cosines and unique ray ids, and builds a [`SystemRig`].

use crate::projector_calibration::{CalibratedRay, LineCovariance, Model, ProjectorCalibration};
use anyhow::{bail, Context, Result};
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::ExteriorOrientation;
use deltaz_shared::projector::{Projector, ProjectorRay};
use deltaz_shared::rig::Rig;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The format tag of `system.json`.
pub const FORMAT: &str = "deltaz.system/1";

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
}

/// Everything the fingerprint covers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SystemContent {
    /// The camera.
    pub camera: SystemCamera,
    /// The projector.
    pub projector: SystemProjector,
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

    /// The system of a calibrated camera and projector.
    pub fn new(
        grid: PixelGrid<f64>,
        inner: InnerOrientation<f64>,
        pose: ExteriorOrientation<f64>,
        projector: &ProjectorCalibration,
    ) -> Self {
        let rays = projector.rays.iter().map(SystemRay::from).collect();
        Self {
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
            },
        }
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
        let file: Self = serde_json::from_str(text)
            .with_context(|| format!("{origin}: not a valid system.json"))?;
        if file.format != FORMAT {
            bail!("{origin}: format {:?}, expected {FORMAT:?}", file.format);
        }
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

    /// Each ray's calibration covariance by id, for [`crate::reconstruct`].
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
            pose,
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
        assert_eq!(file.fingerprint, "dcf81c9e1c2eb81c");
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
            "expected \"deltaz.system/1\"",
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
