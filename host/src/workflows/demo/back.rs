//! The demo's back: a scoliotic back (a right thoracic curve, three frames standing, each
//! swayed by a few mm and about a degree) seen by the largest back rig the device holds
//! ([`device_back_scenario`]: the `back` scenario's rig cut to 22 × 23 = 506 dots, 26 mm apart
//! on the back; the device holds at most `MAX_RAYS` = 512 rays, fewer than the full rig's
//! 1,225), calibrated as `calibrate system` calibrates it from its simulated field and plates,
//! uploaded to the device, rendered (`out/images/back/`), scanned through the device, its points'
//! covariance from that calibration, and analysed: `report.html`, `analysis.json`, `back.ply`
//! and the rig's `back_system.json` in `out/`.

use super::super::back::{back_report, Calibration};
use super::super::back_scan::{scan_back, ScannedBack};
use super::super::scan::{identify_params, on_device};
use super::super::system::calibrate_simulation;
use crate::io::analysis_file::BackReport;
use crate::io::system_file::SystemFile;
use crate::link::{Device, Transport};
use crate::simulate::back::{BackModel, Deformity, Pose};
use crate::simulate::back_frames::render_backs;
use crate::simulate::images::{true_rig, ImageSpec};
use crate::simulate::{load_scenario, simulate, Scenario};
use anyhow::{Context, Result};
use deltaz_shared::identify::DepthRange;
use deltaz_shared::rig::Method;
use deltaz_surface::Options;
use nalgebra::Vector3;
use std::path::{Path, PathBuf};

/// The device-sized back rig's dot spacing on the back relative to the full rig's 20 mm.
const SPACING_SCALE: f64 = 1.3;
/// Its identification depth range (mm): the back at 1.5 m, arms and sway included.
const DEPTH_RANGE: [f64; 2] = [1400.0, 1650.0];
/// The identifier's lookup cell (px): 40 × 32 cells over the 1,280 × 1,024 sensor, within the
/// device's 2,048.
const LOOKUP_CELL_PX: f64 = 32.0;

/// The `back` scenario with its pattern cut to 22 × 23 dots (506 rays, what the device holds)
/// spread to 26 mm apart on the back, about the same centre and turned as the full rig's.
pub fn device_back_scenario() -> Result<Scenario> {
    let mut s = load_scenario("back")?;
    s.name = "back-device".into();
    let p = &mut s.rig.pattern;
    let (cols, rows) = (22u16, 23u16);
    let centre = |p: &crate::simulate::pattern::PatternSpec, k: usize| {
        p.origin[k]
            + p.col_step[k] * f64::from(p.cols - 1) / 2.0
            + p.row_step[k] * f64::from(p.rows - 1) / 2.0
    };
    let middle = [centre(p, 0), centre(p, 1)];
    p.col_step = p.col_step.map(|x| x * SPACING_SCALE);
    p.row_step = p.row_step.map(|x| x * SPACING_SCALE);
    (p.cols, p.rows) = (cols, rows);
    for (k, m) in middle.iter().enumerate() {
        p.origin[k] = m
            - p.col_step[k] * f64::from(cols - 1) / 2.0
            - p.row_step[k] * f64::from(rows - 1) / 2.0;
    }
    s.validate()?;
    Ok(s)
}

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
    /// The device-sized back rig's calibration (`back_system.json`).
    pub system: SystemFile,
}

/// Calibrate [`device_back_scenario`] (seeded by `seed`), upload it to `device` with the
/// identification over [`DEPTH_RANGE`], render [`subject`] through its true rig into
/// `images/back/`, scan it through the device and analyse it.
pub fn scan_demo_back<T: Transport>(
    images: &Path,
    (spec, seed): (&ImageSpec, u64),
    device: &mut Device<T>,
) -> Result<DemoBack> {
    let scenario = device_back_scenario()?;
    let calibrated = calibrate_simulation(&simulate(&scenario, seed))
        .context("calibrating the device-sized back rig")?;
    let rig = calibrated.content.rig()?;
    let system = SystemFile::new(calibrated.content)?;
    let [near, far] = DEPTH_RANGE;
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
    let labelled = subject(scenario.back.as_ref().map_or(1500.0, |b| b.distance));
    let skin = scenario.back.as_ref().map_or(*spec, |b| b.image_spec(spec));
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
        Some(&calibration),
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
