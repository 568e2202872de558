//! Camera and projector calibrated from images alone, as a user of the rig would: the field
//! images' targets identified by the known layout and the camera calibrated from them
//! (self-calibrating bundle adjustment), the plate images' control targets and projected dots
//! identified, then field images, plates and projector in one whole-system adjustment started
//! from the bundle's solution (`deltaz calibrate system`). The system is in the camera system, and
//! every point reconstructed with it carries the calibration's covariance besides the image
//! noise's ([`deltaz_calib::system_adjustment::SystemModel::reconstruct`]).

use crate::bundle::{calibrate, CalibrationOptions};
use crate::camera_calibration::{build_problem, camera_file};
use crate::io::camera_file::CameraFile;
use crate::io::control::ControlPoint;
use crate::measure::identify_images::{identify_images, image_files, DotGrid, IdentifiedImages};
use crate::measure::layout::Layout;
use crate::measure::MeasureParams;
use crate::plates::{plate_observations, resect_all};
use crate::residuals::{residuals, Residual};
use crate::simulate::images::ImageSpec;
use crate::simulate::{simulate, Scenario};
use crate::system::{SystemContent, SystemRig, Warnings};
use anyhow::{Context, Result};
use deltaz_calib::system_adjustment::{adjust_system, CameraSource, SystemAdjustment, SystemInput};
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use nalgebra::Vector2;
use std::path::Path;

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
    /// The whole-system adjustment.
    pub adjustment: SystemAdjustment,
    /// The system (camera system, with its covariance), as `system.json` holds it.
    pub content: SystemContent,
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
    let problem = build_problem(
        &field_path,
        &known.grid,
        &known.start,
        &field.observations,
        &known.field_control,
        &options,
    )?;
    let bundle = calibrate(problem, &options)
        .map_err(|e| anyhow::anyhow!("{}: bundle adjustment: {e}", field_path.display()))?;
    let inner = bundle.problem.inner;

    // Rays labelled on one plate only are kept: the central model determines them through the
    // centre, and a dot of a ray the system lacked would be taken for a neighbour's in a scan.
    let plates = identify_images(
        &image_files(dir, "p")?,
        &params,
        &layout(&known.plate_control, "plate")?,
        &known.grid,
        &inner,
        LAYOUT_TOLERANCE_PX,
        Some(&known.dots),
    )?;
    let plate_path = dir.join("p*");
    let resected = resect_all(
        &plate_path,
        &known.grid,
        &inner,
        &plates.observations,
        &known.plate_control,
    )?;
    let adjustment = adjust_system(&SystemInput {
        grid: known.grid,
        inner,
        camera: CameraSource::Field(&bundle.problem),
        control: &known.plate_control,
        plates: plate_observations(
            &plates.observations,
            &known.plate_control,
            &resected.results,
        )?,
        noncentral: false,
        image_sigma_px: TARGET_SIGMA_PX,
    })
    .map_err(|e| anyhow::anyhow!("{}: system adjustment: {e}", plate_path.display()))?;
    let warnings = Warnings {
        left_out_images: resected.left_out,
        single_plane_rays: adjustment.single_plane.clone(),
        left_out_rays: adjustment.left_out.clone(),
    };
    let content = SystemContent::from_adjustment(known.grid, &adjustment, false, warnings);
    let rig = content
        .rig()
        .context("the system calibrated from the images")?;
    Ok(ImageCalibration {
        camera: camera_file(&bundle, &field.observations),
        residuals: residuals(&bundle, &field.observations),
        field,
        plates,
        adjustment,
        content,
        rig,
    })
}
