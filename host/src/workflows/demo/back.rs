//! The demo's back: a scoliotic back (a right thoracic curve, three frames standing, each
//! swayed by a few mm and about a degree) seen by the `back` scenario's rig (1,225 dots, 20 mm
//! apart on the back, identified over its working depth of 1,250-1,750 mm), calibrated as
//! `calibrate system` calibrates it from its simulated field and plates,
//! uploaded to the device, rendered (`out/images/back/`), scanned through the device, its points'
//! covariance from that calibration, and analysed: `report.html`, `analysis.json`, `back.ply`
//! and the rig's `back_system.json` in `out/`.

use super::super::back::{back_report, Calibration, PointSigma};
use super::super::back_scan::{scan_back, ScannedBack};
use super::super::scan::{identify_params, on_device};
use super::super::system::calibrate_simulation;
use crate::io::analysis_file::BackReport;
use crate::io::system_file::SystemFile;
use crate::link::{Device, Transport};
use crate::simulate::back::{BackModel, Deformity, Pose};
use crate::simulate::back_frames::render_backs;
use crate::simulate::images::{true_rig, ImageSpec};
use crate::simulate::{load_scenario, simulate};
use anyhow::{Context, Result};
use deltaz_shared::identify::DepthRange;
use deltaz_shared::rig::Method;
use deltaz_surface::Options;
use nalgebra::Vector3;
use std::path::{Path, PathBuf};

/// The identifier's lookup cell (px) over the 1,280 × 1,024 sensor: the device's grid grows
/// from it until it fits.
const LOOKUP_CELL_PX: f64 = 32.0;

/// The demo's subject: the thoracic curve standing `distance` from the camera, three frames.
pub fn subject(distance: f64) -> Vec<(String, BackModel)> {
    let base = BackModel {
        distance,
        ..BackModel::standing(Deformity::thoracic())
    };
    let sway = |r: [f64; 3], t: [f64; 3]| Pose {
        rotation: Vector3::from(r).map(f64::to_radians),
        translation: Vector3::from(t),
    };
    [
        sway([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
        sway([0.4, -0.8, 0.3], [3.0, -2.0, 3.0]),
        sway([-0.5, 0.7, -0.4], [-2.0, 2.5, -3.0]),
    ]
    .into_iter()
    .enumerate()
    .map(|(k, pose)| (format!("back_{k}"), base.with_pose(pose)))
    .collect()
}

/// The back scanned, its report and the rig's calibration.
pub struct DemoBack {
    /// The scan and the analysis.
    pub scanned: ScannedBack,
    /// What `analysis.json` holds.
    pub report: BackReport,
    /// The subject's frames (the truth).
    pub models: Vec<BackModel>,
    /// The back rig's calibration (`back_system.json`).
    pub system: SystemFile,
}

/// Calibrate the `back` scenario (seeded by `seed`), upload it to `device` with the
/// identification over the scenario's working depth, render [`subject`] through its true rig into
/// `images/back/`, scan it through the device and analyse it.
pub fn scan_demo_back<T: Transport>(
    images: &Path,
    (spec, seed): (&ImageSpec, u64),
    device: &mut Device<T>,
) -> Result<DemoBack> {
    let scenario = load_scenario("back")?;
    let back = scenario
        .back
        .as_ref()
        .context("the `back` scenario has no [back] section")?;
    let calibrated =
        calibrate_simulation(&simulate(&scenario, seed)).context("calibrating the back rig")?;
    let rig = calibrated.content.rig()?;
    let system = SystemFile::new(calibrated.content)?;
    let [near, far] = back.depth_range;
    device
        .upload_identifying(
            &rig,
            system.fingerprint_u64()?,
            Method::ClosestApproach,
            Some(identify_params(
                DepthRange { near, far },
                1.0,
                LOOKUP_CELL_PX,
            )),
        )
        .map_err(|e| anyhow::anyhow!("uploading the back rig: {e}"))?;
    let labelled = subject(back.distance);
    let skin = back.image_spec(spec);
    let frames = render_backs(&true_rig(&scenario), &labelled, &skin, seed);
    let dir = images.join("back");
    std::fs::create_dir_all(&dir)?;
    let mut rendered = Vec::new();
    for f in &frames {
        f.image
            .save_png(&dir.join(format!("{}.png", f.label)), skin.depth)?;
        rendered.push((f.label.clone(), f.image.to_u8()));
    }
    let calibration = Calibration::new(system.clone(), rig.clone(), Path::new("back_system.json"))?;
    let grid = rig.grid();
    let step = crate::link::centroid_step_px(grid.width, grid.height);
    let scanned = scan_back(
        "the demo's back",
        &calibration,
        &rendered,
        on_device(&rig, device),
        Some(step),
        &Options::standing(),
    )?;
    let report = back_report(
        &[PathBuf::from("back.ply")],
        PointSigma::Calibration(&calibration),
        Some(system.fingerprint.clone()),
        scanned.analysis.clone(),
    );
    Ok(DemoBack {
        scanned,
        report,
        models: labelled.into_iter().map(|(_, m)| m).collect(),
        system,
    })
}
