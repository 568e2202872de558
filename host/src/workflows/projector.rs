//! Plates → projector (`deltaz calibrate projector`): every plate image resected on the plate
//! control (step 4), then the projector from the dots: by default (`joint`, `noncentral`) in
//! the whole-system adjustment of [`deltaz_calib::system_adjustment`] without the field images,
//! the camera of `camera.json` as a prior with its covariance, so that the camera's and the
//! plate poses' uncertainty reach the projector and every point's σ (the system in the camera
//! system, as `calibrate system` gives it); or (`paper`) the paper's steps 5-7 with camera and
//! poses taken as exact, the system in the plate frame of the 1st plate image.

use super::plates::{check_on_sensor, plate_images, plate_observations, resect_all};
use crate::io::camera_file::read_camera;
use crate::io::control::{read_control, ControlPoint};
use crate::io::observations::{read_observations, Observation};
use crate::io::system_file::{SystemContent, SystemRig, Warnings};
use crate::report::calibration_plots::{control_residuals, system_plots, PlateView, Plot};
use anyhow::Result;
use deltaz_calib::projector_calibration::{
    calibrate_projector as calibrate_from_plates, check_raised_control, DotObservation, Model,
};
use deltaz_calib::system_adjustment::{adjust_system, CameraSource, SystemInput};
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::ExteriorOrientation;
use std::path::Path;

/// A projector calibrated on plate images, with what it was calibrated from.
#[derive(Debug, Clone)]
pub struct ProjectorSystem {
    /// The system, with what was left out.
    pub content: SystemContent,
    /// The camera's raster.
    pub grid: PixelGrid<f64>,
    /// The camera's inner orientation the calibration ends with.
    pub inner: InnerOrientation<f64>,
    /// Each plate image: label, pose and dots.
    pub views: Vec<(String, ExteriorOrientation<f64>, Vec<DotObservation>)>,
    /// The plate observations.
    pub observations: Vec<Observation>,
    /// The plate control.
    pub control: Vec<ControlPoint>,
    /// What the user should know about the inputs (a camera file without its covariance).
    pub notes: Vec<String>,
}

/// Calibrates the projector from the plate observations `obs` (their `control` rows resect
/// each image, their `dot` rows calibrate the projector) on the plate control `control`, with
/// the camera of `camera` and `model`. `image_sigma_px` is the dots' image noise: `paper`
/// weights the plane points and gives the rays' covariances with it, `joint` and `noncentral`
/// start from it and estimate it. Images too poorly controlled to resect and rays seen on one
/// plate are left out (or, central models, determined through the centre) and listed in the
/// system's warnings.
pub fn calibrate_projector(
    camera: &Path,
    control: &Path,
    obs: &Path,
    model: Model,
    image_sigma_px: f64,
) -> Result<ProjectorSystem> {
    let camera_path = camera;
    let camera = read_camera(camera)?;
    let (grid, inner) = (camera.grid(), camera.inner());
    let control_points = read_control(control)?;
    let labelled: Vec<_> = control_points
        .iter()
        .map(|c| (c.point.clone(), c.xyz))
        .collect();
    check_raised_control(&labelled).map_err(|e| anyhow::anyhow!("{}: {e}", control.display()))?;
    let observations = read_observations(obs)?;
    check_on_sensor(obs, &grid, &observations)?;
    let resected = resect_all(obs, &grid, &inner, &observations, &control_points)?;
    let in_file = |e: &dyn std::fmt::Display| anyhow::anyhow!("{}: {e:#}", obs.display());
    let mut notes = Vec::new();
    let (content, inner, views) = if model == Model::Paper {
        let poses: Vec<_> = resected
            .results
            .iter()
            .map(|(image, r)| (image.clone(), r.exterior))
            .collect();
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
        let views = poses
            .into_iter()
            .zip(images)
            .map(|((image, exterior), i)| (image, exterior, i.dots));
        (content, inner, views.collect())
    } else {
        let prior = camera.prior();
        if prior.is_some() && camera.covariance.is_none() {
            notes.push(format!(
                "{}: no `covariance` (written by an older deltaz): the camera's prior takes its \
                 σ without their correlations; calibrate the camera again for the stated σ to \
                 hold",
                camera_path.display()
            ));
        }
        let noncentral = model == Model::Noncentral;
        let plates = plate_observations(&observations, &control_points, &resected.results)
            .map_err(|e| in_file(&e))?;
        let adjustment = adjust_system(&SystemInput {
            grid,
            inner,
            camera: prior.map_or(CameraSource::Fixed, CameraSource::Prior),
            control: &control_points,
            plates: plates.clone(),
            noncentral,
            image_sigma_px,
        })
        .map_err(|e| in_file(&format!("system adjustment: {e}")))?;
        let content =
            SystemContent::from_adjustment(grid, &adjustment, noncentral, resected.left_out);
        let views = plates
            .into_iter()
            .zip(&adjustment.poses)
            .map(|(p, exterior)| (p.image, *exterior, p.dots));
        (content, adjustment.model.inner, views.collect())
    };
    Ok(ProjectorSystem {
        content,
        grid,
        inner,
        views,
        observations,
        control: control_points,
        notes,
    })
}

impl ProjectorSystem {
    /// The calibration's plots ([`system_plots`]): the plate images' control residuals, the
    /// rays' miss distances and every plate reconstructed with `rig`.
    pub fn plots(&self, rig: &SystemRig) -> Result<Vec<Plot>> {
        let rays: Vec<_> = (self.content.projector.rays.iter())
            .map(|r| (r.id, (r.planes > 1).then_some((r.miss_rms, r.miss_max))))
            .collect();
        let poses: Vec<_> = (self.views.iter())
            .map(|(image, exterior, _)| (image.clone(), *exterior))
            .collect();
        let plates: Vec<_> = (self.views.iter())
            .map(|(image, exterior, dots)| PlateView {
                image,
                exterior: *exterior,
                dots,
            })
            .collect();
        let residuals = control_residuals(
            &self.grid,
            &self.inner,
            &poses,
            &self.observations,
            &self.control,
        );
        system_plots(&residuals, &self.grid, &rays, rig, &plates)
    }
}
