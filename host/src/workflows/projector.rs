//! Plates → projector (`deltaz calibrate projector`): every plate image resected on the plate
//! control (step 4), then the projector calibrated from the dots (steps 5-7: the paper's ΔZ
//! method, or the joint or non-central models of [`deltaz_calib::projector_calibration`]), the
//! system in the plate frame of the 1st plate image.

use super::plates::{plate_images, resect_all};
use crate::io::camera_file::read_camera;
use crate::io::control::{read_control, ControlPoint};
use crate::io::observations::{read_observations, Observation};
use crate::io::system_file::{SystemContent, SystemRig, Warnings};
use crate::report::calibration_plots::{control_residuals, system_plots, PlateView, Plot};
use anyhow::Result;
use deltaz_calib::projector_calibration::{
    calibrate_projector as calibrate_from_plates, check_raised_control, Model, PlateImage,
    ProjectorCalibration,
};
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::ExteriorOrientation;
use std::path::Path;

/// A projector calibrated on plate images, with what it was calibrated from.
#[derive(Debug, Clone)]
pub struct ProjectorSystem {
    /// The system (plate frame of the 1st plate image, with what was left out).
    pub content: SystemContent,
    /// The projector calibration.
    pub projector: ProjectorCalibration,
    /// The camera's raster.
    pub grid: PixelGrid<f64>,
    /// The camera's inner orientation.
    pub inner: InnerOrientation<f64>,
    /// The resected plate images and their dots.
    pub images: Vec<PlateImage>,
    /// Their labels and poses.
    pub poses: Vec<(String, ExteriorOrientation<f64>)>,
    /// The plate observations.
    pub observations: Vec<Observation>,
    /// The plate control.
    pub control: Vec<ControlPoint>,
}

/// Calibrates the projector from the plate observations `obs` (their `control` rows resect
/// each image, their `dot` rows calibrate the projector) on the plate control `control`, with
/// the camera of `camera` and `model`; `image_sigma_px` weights the plane points and gives the
/// rays' covariances. Images too poorly controlled to resect and rays seen on one plate are left
/// out (or, central models, determined through the centre) and listed in the system's warnings.
pub fn calibrate_projector(
    camera: &Path,
    control: &Path,
    obs: &Path,
    model: Model,
    image_sigma_px: f64,
) -> Result<ProjectorSystem> {
    let camera = read_camera(camera)?;
    let (grid, inner) = (camera.grid(), camera.inner());
    let control_points = read_control(control)?;
    let labelled: Vec<_> = control_points
        .iter()
        .map(|c| (c.point.clone(), c.xyz))
        .collect();
    check_raised_control(&labelled).map_err(|e| anyhow::anyhow!("{}: {e}", control.display()))?;
    let observations = read_observations(obs)?;
    let resected = resect_all(obs, &grid, &inner, &observations, &control_points)?;
    let poses: Vec<_> = resected
        .results
        .iter()
        .map(|(image, r)| (image.clone(), r.exterior))
        .collect();
    let in_file = |e: &dyn std::fmt::Display| anyhow::anyhow!("{}: {e:#}", obs.display());
    let images = plate_images(&observations, &poses).map_err(|e| in_file(&e))?;
    let projector = calibrate_from_plates(&grid, &inner, &images, model, image_sigma_px)
        .map_err(|e| in_file(&e))?;
    // The rig frame is the 1st plate image's.
    let first = poses.first().map(|(image, pose)| (image.as_str(), *pose));
    let first = first.ok_or_else(|| in_file(&"no plate image could be resected"))?;
    let mut content = SystemContent::new(grid, inner, first, &projector);
    content.warnings = Warnings {
        left_out_images: resected.left_out,
        single_plane_rays: projector.single_plane.clone(),
        left_out_rays: projector.left_out.clone(),
    };
    Ok(ProjectorSystem {
        content,
        projector,
        grid,
        inner,
        images,
        poses,
        observations,
        control: control_points,
    })
}

impl ProjectorSystem {
    /// The calibration's plots ([`system_plots`]): the plate images' control residuals, the
    /// rays' miss distances and every plate reconstructed with `rig`.
    pub fn plots(&self, rig: &SystemRig) -> Result<Vec<Plot>> {
        let rays: Vec<_> = self
            .projector
            .rays
            .iter()
            .map(|r| (r.id, r.miss_rms, r.miss_max))
            .collect();
        let plates: Vec<_> = self
            .images
            .iter()
            .zip(&self.poses)
            .map(|(i, (image, _))| PlateView {
                image,
                exterior: i.exterior,
                dots: &i.dots,
            })
            .collect();
        let residuals = control_residuals(
            &self.grid,
            &self.inner,
            &self.poses,
            &self.observations,
            &self.control,
        );
        system_plots(&residuals, &self.grid, &rays, rig, &plates)
    }
}
