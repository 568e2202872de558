//! Camera and projector calibrated together (`deltaz calibrate system`, the image calibration,
//! the demo): the one chain
//!
//! 1. field → camera: the self-calibrating bundle adjustment of the field images
//!    ([`super::camera::bundle_field`]), the start;
//! 2. plates → resection of every plate image on the plate control ([`resect_all`]), the plate
//!    images' targets and dots ([`plate_observations`]);
//! 3. both → the whole-system adjustment ([`adjust_system`]): the camera's inner orientation,
//!    every field and plate pose, both controls and the projector in one problem with a variance
//!    component per group, and the system in the camera system ([`SystemContent`], with the
//!    covariance a point's σ needs; [`deltaz_calib::system_adjustment::SystemModel::reconstruct`]).
//!
//! [`calibrate_system`] runs it on observation files; [`calibrate_from_images`] on a folder of
//! images, where the plate images are identified with the bundle's inner orientation between
//! steps 1 and 2.

use super::camera::{bundle_field, camera_file, Targets};
use super::observations::{identify_images, image_files, DotGrid, IdentifiedImages};
use super::plates::{plate_observations, resect_all};
use crate::io::camera_file::CameraFile;
use crate::io::control::ControlPoint;
use crate::io::system_file::{SystemContent, SystemFile, SystemRig};
use crate::report::residuals::{residuals, Residual};
use crate::simulate::images::ImageSpec;
use crate::simulate::{simulate, Scenario, Simulation};
use anyhow::{Context, Result};
use deltaz_calib::bundle::{Calibration, CalibrationOptions};
use deltaz_calib::system_adjustment::{
    adjust_system, CameraSource, PlateObservations, SystemAdjustment, SystemInput,
};
use deltaz_measure::layout::Layout;
use deltaz_measure::MeasureParams;
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use nalgebra::Vector2;
use std::path::Path;

/// A system calibrated from field and plate observations, with what each step found.
#[derive(Debug, Clone)]
pub struct SystemCalibration {
    /// The camera from the bundle adjustment of the field (the start).
    pub bundle: Calibration,
    /// The plate images as the whole-system adjustment took them.
    pub plates: Vec<PlateObservations>,
    /// The whole-system adjustment.
    pub adjustment: SystemAdjustment,
    /// The system (camera system, with its covariance and what was left out), as `system.json`
    /// holds it.
    pub content: SystemContent,
}

/// Steps 2-3 of the chain after the field's bundle adjustment: the plate images of `plates`
/// resected, then field, plates and projector adjusted together; every ray a free line with
/// `noncentral`. `image_sigma_px` is the a-priori σ of the plate targets.
pub fn adjust(
    grid: PixelGrid<f64>,
    bundle: Calibration,
    plates: Targets,
    noncentral: bool,
    image_sigma_px: f64,
) -> Result<SystemCalibration> {
    let inner = bundle.problem.inner;
    let in_file = |e: &dyn std::fmt::Display| anyhow::anyhow!("{}: {e:#}", plates.path.display());
    let resected = resect_all(
        plates.path,
        &grid,
        &inner,
        plates.observations,
        plates.control,
    )?;
    let observations = plate_observations(plates.observations, plates.control, &resected.results)
        .map_err(|e| in_file(&e))?;
    let adjustment = adjust_system(&SystemInput {
        grid,
        inner,
        camera: CameraSource::Field(&bundle.problem),
        control: plates.control,
        plates: observations.clone(),
        noncentral,
        image_sigma_px,
    })
    .map_err(|e| in_file(&format!("system adjustment: {e}")))?;
    let content = SystemContent::from_adjustment(grid, &adjustment, noncentral, resected.left_out);
    Ok(SystemCalibration {
        bundle,
        plates: observations,
        adjustment,
        content,
    })
}

/// The whole chain on observations: the field's bundle adjustment (started from `start`, with
/// `options`), then [`adjust`].
pub fn calibrate_system(
    grid: PixelGrid<f64>,
    start: &InnerOrientation<f64>,
    field: Targets,
    plates: Targets,
    options: &CalibrationOptions,
    noncentral: bool,
) -> Result<SystemCalibration> {
    let bundle = bundle_field(&grid, start, field, options)?;
    adjust(grid, bundle, plates, noncentral, options.image_sigma_px)
}

/// The whole chain ([`calibrate_system`]) on a simulation's observations, as `deltaz calibrate
/// system` runs it on the files `deltaz simulate` writes (default options, central rays).
pub fn calibrate_simulation(sim: &Simulation) -> Result<SystemCalibration> {
    calibrate_system(
        sim.camera_init.grid(),
        &sim.camera_init.inner(),
        Targets {
            path: Path::new("camera_obs.csv"),
            observations: &sim.camera_obs,
            control: &sim.camera_control,
        },
        Targets {
            path: Path::new("plate_obs.csv"),
            observations: &sim.plate_obs,
            control: &sim.plate_control,
        },
        &CalibrationOptions::default(),
        false,
    )
}

/// The text of `system.json` of [`calibrate_simulation`].
pub fn simulated_system(sim: &Simulation) -> Result<String> {
    SystemFile::new(calibrate_simulation(sim)?.content)?.to_json()
}

/// What a user knows besides the images: the sensor and a start for its inner orientation, the
/// control of the field and of the plate, and the projected pattern.
#[derive(Debug, Clone, PartialEq)]
pub struct Known {
    /// The sensor's raster.
    pub grid: PixelGrid<f64>,
    /// Start values of the inner orientation (approximate f).
    pub start: InnerOrientation<f64>,
    /// The target field's control (mm, with σ).
    pub field_control: Vec<ControlPoint>,
    /// The plate's control.
    pub plate_control: Vec<ControlPoint>,
    /// The projected pattern, its marker and its directions in the image.
    pub dots: DotGrid,
}

impl Known {
    /// What the user of a simulated rig knows ([`simulate`] with `seed`: the sensor's start
    /// values and the surveyed control, with its errors) when its images are rendered by `spec`
    /// ([`crate::simulate::images::write_images`]: the pattern's column index grows to the
    /// right in the image, its row index upwards).
    pub fn simulated(scenario: &Scenario, spec: &ImageSpec, seed: u64) -> Result<Self> {
        let sim = simulate(scenario, seed);
        Ok(Self {
            grid: sim.camera_init.grid(),
            start: sim.camera_init.inner(),
            field_control: sim.camera_control,
            plate_control: sim.plate_control,
            dots: DotGrid {
                pattern: scenario.rig.pattern.clone(),
                marker: spec
                    .marker_node
                    .context("the images have no marker dot to start the grid walk from")?,
                col_dir: Vector2::new(1.0, 0.0),
                row_dir: Vector2::new(0.0, -1.0),
            },
        })
    }
}

/// A system calibrated from images, with what each step found.
#[derive(Debug, Clone)]
pub struct ImageCalibration {
    /// The field images' identified targets and their reports.
    pub field: IdentifiedImages,
    /// The camera from the bundle adjustment on the field.
    pub camera: CameraFile,
    /// The field targets' residuals in that adjustment.
    pub residuals: Vec<Residual>,
    /// The plate images' identified control and dots.
    pub plates: IdentifiedImages,
    /// The calibration.
    pub system: SystemCalibration,
    /// Its rig.
    pub rig: SystemRig,
}

/// The tolerance (px) of the layout match.
const LAYOUT_TOLERANCE_PX: f64 = 8.0;

/// A priori σ of the measured target centres (px), weighting the field's control against the
/// images (template-fit centroids are a few hundredths of a pixel).
const TARGET_SIGMA_PX: f64 = 0.05;

/// Calibrate camera and projector from the images in `dir`: the field images named `s*`, the
/// plate images `p*` (each with its projector-off sibling `p*_control`, [`identify_images`]).
pub fn calibrate_from_images(dir: &Path, known: &Known) -> Result<ImageCalibration> {
    let params = MeasureParams::default();
    let layout = |control: &[ControlPoint], what: &str| {
        Layout::with_default_distinct(control.iter().map(|c| (c.point.clone(), c.xyz)).collect())
            .map_err(|e| anyhow::anyhow!("{what} control: {e}"))
    };
    let field = identify_images(
        &image_files(dir, "s")?,
        &params,
        &layout(&known.field_control, "field")?,
        &known.grid,
        &known.start,
        LAYOUT_TOLERANCE_PX,
        None,
    )?;
    let options = CalibrationOptions {
        image_sigma_px: TARGET_SIGMA_PX,
        ..Default::default()
    };
    let field_path = dir.join("s*");
    let field_targets = Targets {
        path: &field_path,
        observations: &field.observations,
        control: &known.field_control,
    };
    let bundle = bundle_field(&known.grid, &known.start, field_targets, &options)?;

    // Rays labelled on one plate only are kept: the central model determines them through the
    // centre, and a dot of a ray the system lacked would be taken for a neighbour's in a scan.
    let plates = identify_images(
        &image_files(dir, "p")?,
        &params,
        &layout(&known.plate_control, "plate")?,
        &known.grid,
        &bundle.problem.inner,
        LAYOUT_TOLERANCE_PX,
        Some(&known.dots),
    )?;
    let camera = camera_file(&bundle, &field.observations);
    let residuals = residuals(&bundle, &field.observations);
    let plate_targets = Targets {
        path: &dir.join("p*"),
        observations: &plates.observations,
        control: &known.plate_control,
    };
    let system = adjust(known.grid, bundle, plate_targets, false, TARGET_SIGMA_PX)?;
    let rig = system
        .content
        .rig()
        .context("the system calibrated from the images")?;
    Ok(ImageCalibration {
        camera,
        residuals,
        field,
        plates,
        system,
        rig,
    })
}
