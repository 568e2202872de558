//! The Calibration panel: what the calibration is (fingerprint, date, the σ0 of each
//! observation group of its adjustment, its warnings) and whether it still holds: a flat board
//! scanned, a plane fitted to its points, its flatness (RMS of the points' distances from the
//! plane) set beside its floor, what the calibration's covariance and the image noise predict
//! for that fit ([`fit_plane`], [`form`]), and a plain verdict.

use super::sessions::utc_stamp;
use super::state::KeptFrame;
use crate::report::object_accuracy::{fit_plane, form, AtFloor, ObjectPoint};
use crate::workflows::back::Calibration;
use anyhow::{bail, Result};
use serde::Serialize;
use std::path::Path;

/// The flatness a board may show, as a multiple of its floor, before the calibration is called
/// into question. For a flat board RMS²/floor² follows χ²_ν/ν with ν = n − 3 degrees of
/// freedom: with n ≥ [`PLANE_MIN_POINTS`] its standard deviation is at most √(2/27) = 0.27,
/// so a ratio of 1.5 (RMS² 2.25 × the floor's) lies more than 4.6 σ out: a good calibration
/// does not fail the check, a calibration whose errors bend a plane by half the floor again
/// does.
pub const PLANE_RATIO_LIMIT: f64 = 1.5;

/// The fewest points on the board for a verdict.
pub const PLANE_MIN_POINTS: usize = 30;

/// The panel's facts about the calibration.
pub fn calibration_facts(c: &Calibration, system: &Path) -> serde_json::Value {
    let file = c.file();
    let date = std::fs::metadata(system)
        .and_then(|m| m.modified())
        .map(utc_stamp)
        .ok();
    let cov = file.content.projector.covariance.as_ref();
    let mut warnings = file.content.warnings.lines();
    if cov.is_some_and(|c| c.dot_sigma_px > 1.0) {
        warnings.push(
            "the dots' image noise σ0 exceeds 1 px: the dot images are poor (focus, exposure)"
                .to_owned(),
        );
    }
    serde_json::json!({
        "system": system,
        "fingerprint": c.fingerprint(),
        "date": date,
        "frame": file.content.frame.to_string(),
        "model": format!("{:?}", file.content.projector.model).to_lowercase(),
        "rays": file.content.projector.rays.len(),
        "sigma0_px": {
            "dots": cov.map(|c| c.dot_sigma_px),
            "plate targets": cov.map(|c| c.target_sigma_px),
            "field targets": cov.and_then(|c| c.field_sigma_px),
        },
        "warnings": warnings,
    })
}

/// A plane check's result.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlaneCheck {
    /// Frames fitted.
    pub frames: usize,
    /// Flatness and its floor.
    pub flatness: AtFloor,
    /// flatness / floor.
    pub ratio: f64,
    /// The ratio stays within [`PLANE_RATIO_LIMIT`].
    pub holds: bool,
    /// In words.
    pub verdict: String,
}

/// The plane check on the frames with points of `frames` (a flat board in view).
pub fn plane_check(frames: &[KeptFrame], c: &Calibration) -> Result<PlaneCheck> {
    let core = c.core_covariance();
    let mut fits = Vec::new();
    for f in frames
        .iter()
        .filter(|f| f.found.points.len() >= PLANE_MIN_POINTS)
    {
        // The fit reads each point and its covariance shares (the truth is not known here).
        let points = f
            .found
            .points
            .iter()
            .map(|p| {
                Ok(ObjectPoint {
                    point: p.point,
                    truth: p.point,
                    shares: c.shares(p.id, &p.point)?,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        if let Some((fit, _)) = fit_plane(&points, core) {
            fits.push(fit);
        }
    }
    if fits.is_empty() {
        bail!(
            "no frame with {PLANE_MIN_POINTS} points or more on a plane: put the flat board \
             in front of the camera, filling the view"
        );
    }
    let flatness = form(&fits);
    let ratio = flatness.ratio();
    let holds = ratio <= PLANE_RATIO_LIMIT;
    let verdict = if holds {
        format!(
            "the calibration holds: the board is flat to {:.3} mm RMS, {ratio:.2} × what the \
             calibration predicts ({:.3} mm)",
            flatness.rms_mm, flatness.floor_mm
        )
    } else {
        format!(
            "calibrate again: the board looks bent by {:.3} mm RMS, {ratio:.2} × what the \
             calibration predicts ({:.3} mm; a flat board and a sound calibration stay within \
             {PLANE_RATIO_LIMIT} ×)",
            flatness.rms_mm, flatness.floor_mm
        )
    };
    Ok(PlaneCheck {
        frames: fits.len(),
        flatness,
        ratio,
        holds,
        verdict,
    })
}
