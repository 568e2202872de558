//! Frames of a back through the whole image path, in memory (the Monte Carlo tests, the demo):
//! each frame's image measured, its dots identified and intersected on the host or by the
//! device ([`super::scan::scan`] with [`super::scan::on_host`] or [`super::scan::on_device`]),
//! the points as the cloud `deltaz scan` would write, each with its covariance from the
//! calibration ([`super::back::cloud_frames`]), and one subject's frames analysed together
//! ([`deltaz_surface::analyse`]).

use super::back::{cloud_frames, Calibration, PointSigma};
use super::scan::{scan, FramePoints, Identified};
use crate::io::ply::{Cloud, Vertex};
use crate::io::system_file::SystemFrame;
use anyhow::Result;
use deltaz_measure::{LoadedImage, MeasureParams};
use deltaz_surface::{analyse, BackAnalysis, Options};
use std::path::Path;

/// A back scanned and analysed.
#[derive(Debug, Clone)]
pub struct ScannedBack {
    /// Each frame's dots, identified, and points.
    pub frames: Vec<FramePoints>,
    /// All frames' points as one cloud (with the `frame` property).
    pub cloud: Cloud,
    /// The analysis of all frames.
    pub analysis: BackAnalysis,
}

/// The cloud of scanned `frames` as `deltaz scan` writes it: in the camera system, with the
/// calibration's fingerprint, each point's ray and frame, and the device's centroid step.
pub fn cloud_of(frames: &[FramePoints], fingerprint: &str, centroid_step_px: Option<f64>) -> Cloud {
    let vertices = frames
        .iter()
        .flat_map(|f| {
            f.found.points.iter().map(|p| Vertex {
                point: p.point,
                ray: Some(p.id),
                frame: Some(f.frame as u32),
                sigma: None,
            })
        })
        .collect();
    Cloud {
        frame: Some(SystemFrame::Camera.to_string()),
        fingerprint: Some(fingerprint.to_owned()),
        centroid_step_px,
        vertices,
    }
}

/// Scan the labelled `images` of one subject with `calibration` (`identify` on the host or the
/// device; the device's `centroid_step_px` for the points' covariance) and analyse them with
/// `options`; `name` names the subject in errors.
pub fn scan_back(
    name: &str,
    calibration: &Calibration,
    images: &[(String, image::GrayImage)],
    identify: impl FnMut(&[(f64, f64)]) -> Result<Identified>,
    centroid_step_px: Option<f64>,
    options: &Options,
) -> Result<ScannedBack> {
    let mut frames = Vec::with_capacity(images.len());
    let load = |i: usize| {
        let (label, image) = &images[i];
        Ok((label.clone(), LoadedImage::Eight(image.clone())))
    };
    scan(
        calibration.rig(),
        &MeasureParams::default(),
        images.len(),
        load,
        identify,
        |f| {
            frames.push(f.clone());
            Ok(())
        },
    )?;
    let cloud = cloud_of(&frames, calibration.fingerprint(), centroid_step_px);
    let surface = cloud_frames(
        Path::new(name),
        &cloud,
        PointSigma::Calibration(calibration),
    )?;
    let analysis = analyse(&surface, options).map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
    Ok(ScannedBack {
        frames,
        cloud,
        analysis,
    })
}
