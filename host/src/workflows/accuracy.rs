//! Accuracy on simulated rigs: the experiments of section 6.2 (and beyond) run end to end on a
//! [`Simulation`]: resection of each plate image (step 4), projector calibration (steps 5-7),
//! reconstruction, and the errors against the paper's reference or against the truth, each beside
//! the image-noise floor (first-order propagation of the image noise through the intersection).
//!
//! All error figures are per axis `sqrt(Σ e² / (n − 1))`, the form of Table 7's "MSE" row, taken
//! about zero so that a bias counts. Against the truth they are in the camera system (x right,
//! y up, z backwards), which does not depend on how well the 1st image was resected.

use crate::io::system_file::{RayCovariances, SystemContent, SystemRig};
use crate::simulate::Simulation;
use crate::workflows::plates::plate_images;
use anyhow::{Context, Result};
use deltaz_calib::compare::{assess, sample_std_about};
use deltaz_calib::projector_calibration::{
    calibrate_projector, plane_points, Model, PlateImage, ProjectorCalibration,
};
use deltaz_calib::reconstruct::{calibration_covariance, covariance, reconstruct};
use deltaz_calib::system_adjustment::{
    adjust_system, CameraPrior, CameraSource, Frame, SystemAdjustment, SystemInput,
};
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::ExteriorOrientation;
use deltaz_shared::rig::Method;
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;

pub use crate::simulate::pattern::TABLE4_IDS;

/// Step 4 for every plate image: the camera pose in the plate frame, by space resection on the
/// plate's control points with the given inner orientation.
pub fn plate_poses(
    sim: &Simulation,
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
) -> Result<Vec<(String, ExteriorOrientation<f64>)>> {
    crate::workflows::plates::resect_images(
        std::path::Path::new("plate_obs.csv"),
        grid,
        inner,
        &sim.plate_obs,
        &sim.plate_control,
    )
    .map(|r| {
        r.into_iter()
            .map(|(image, res)| (image, res.exterior))
            .collect()
    })
}

/// A calibrated system and what went into it.
#[derive(Debug, Clone)]
pub struct Calibrated {
    /// The plate images (resected) of the whole simulation.
    pub images: Vec<PlateImage>,
    /// How many of them (the first ones) the calibration used.
    pub used: usize,
    /// The projector.
    pub projector: ProjectorCalibration,
    /// system.json content.
    pub content: SystemContent,
    /// The rig.
    pub rig: SystemRig,
}

/// Resects the plate images and calibrates the projector on the first `used` images, keeping
/// only the rays in `ids` (all when `None`).
pub fn calibrate_simulation(
    sim: &Simulation,
    inner: &InnerOrientation<f64>,
    model: Model,
    ids: Option<&[u16]>,
    used: usize,
) -> Result<Calibrated> {
    let grid = sim.camera_init.grid();
    let poses = plate_poses(sim, &grid, inner)?;
    let mut images = plate_images(&sim.plate_obs, &poses)?;
    if let Some(ids) = ids {
        for image in &mut images {
            image.dots.retain(|d| ids.contains(&d.id));
        }
    }
    let sigma_px = sim.truth.noise.image_sigma_px;
    let projector = calibrate_projector(&grid, inner, &images[..used], model, sigma_px)?;
    let content = SystemContent::new(grid, *inner, (&poses[0].0, images[0].exterior), &projector);
    let rig = content.rig()?;
    Ok(Calibrated {
        images,
        used,
        projector,
        content,
        rig,
    })
}

/// Per-axis figures of one experiment (mm).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Figures {
    /// sqrt(Σ e² / (n − 1)) per axis, no similarity fit.
    pub error: Vector3<f64>,
    /// The image-noise floor: RMS of the propagated σ per axis.
    pub floor: Vector3<f64>,
    /// Points compared.
    pub points: usize,
}

/// Section 6.2.3: the dots of calibration image `image` reconstructed and compared with their
/// plate coordinates from eq. (10) (the same image measurements), in the rig frame. Returns the
/// figures with no fit and the "MSE" after Table 6's similarity.
/// `sigma_px` is the image noise the floor is propagated from.
pub fn paper_experiment(
    cal: &Calibrated,
    image: usize,
    method: Method,
    sigma_px: f64,
) -> Result<(Figures, Vector3<f64>)> {
    let grid = *cal.rig.grid();
    let inner = *cal.rig.inner();
    let by_ray = plane_points(&grid, &inner, &cal.images[..cal.used], sigma_px)?;
    let dots = &cal.images[image].dots;
    let points = reconstruct(&cal.rig, dots, method, None, None)?;
    let mut reconstructed = Vec::new();
    let mut reference = Vec::new();
    let mut floors = Vec::new();
    for (dot, p) in dots.iter().zip(&points) {
        let on_plate = by_ray[&dot.id]
            .iter()
            .find(|pp| pp.plane == image)
            .context("the image's dot is missing from the plane points")?;
        reconstructed.push(p.point);
        reference.push(on_plate.point);
        floors.push(covariance(&cal.rig, dot, method, sigma_px)?.diagonal());
    }
    let errors: Vec<_> = reconstructed
        .iter()
        .zip(&reference)
        .map(|(a, b)| a - b)
        .collect();
    let fitted = assess(&reconstructed, &reference)?;
    Ok((
        Figures {
            error: sample_std_about(&errors, Vector3::zeros()),
            floor: rms_sigma(&floors),
            points: errors.len(),
        },
        fitted.mse,
    ))
}

/// Per-point results against the truth (camera system).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthComparison {
    /// Error vector (camera system, mm).
    pub error: Vector3<f64>,
    /// Propagated σ per camera axis from image noise alone: the floor (mm).
    pub floor: Vector3<f64>,
    /// Propagated σ per camera axis from image noise and calibration (mm).
    pub sigma: Vector3<f64>,
    /// The true point (camera system, mm).
    pub truth: Vector3<f64>,
}

/// The dots of plate image `image` reconstructed and compared with the true points where the
/// true rays meet the true plate, in the camera system; σ from the simulation's image noise,
/// alone (the floor) and with the calibration's share.
pub fn against_truth(
    sim: &Simulation,
    cal: &Calibrated,
    image: usize,
    method: Method,
) -> Result<Vec<TruthComparison>> {
    let sigma_px = sim.truth.noise.image_sigma_px;
    let pose: ExteriorOrientation<f64> = sim.truth.plate.images[image].camera.into();
    let r_k = pose.r_cam_world();
    // The plate Z = 0 in the camera system: n·x = d.
    let normal: Vector3<f64> = r_k.column(2).into();
    let d = -pose.centre.z;
    let projector = &sim.truth.projector;
    let centre = Vector3::from(projector.centre_camera);
    let r = *cal.rig.r_cam_world();
    let dots = &cal.images[image].dots;
    let points = reconstruct(&cal.rig, dots, method, None, None)?;
    let lines: RayCovariances = cal
        .projector
        .rays
        .iter()
        .map(|r| (r.id, r.line_cov))
        .collect();
    dots.iter()
        .zip(&points)
        .map(|(dot, p)| {
            let ray = projector
                .rays
                .iter()
                .find(|t| t.id == dot.id)
                .with_context(|| format!("ray {} not in the truth", dot.id))?;
            let start = centre + Vector3::from(ray.offset_camera);
            let dir = Vector3::from(ray.camera);
            let truth = start + dir * ((d - normal.dot(&start)) / normal.dot(&dir));
            let cam = r * (p.point - cal.rig.camera_centre());
            let image_cov = covariance(&cal.rig, dot, method, sigma_px)?;
            let line = lines.get(&dot.id).context("ray without covariance")?;
            let cal_cov = calibration_covariance(&cal.rig, dot, method, p.point, line)?;
            Ok(TruthComparison {
                error: cam - truth,
                floor: camera_axes(&r, &image_cov),
                sigma: camera_axes(&r, &(image_cov + cal_cov)),
                truth,
            })
        })
        .collect()
}

/// Figures of a truth comparison; with the honesty ratio RMS(e/σ) over all axes and points.
pub fn truth_figures(cmp: &[TruthComparison]) -> (Figures, f64) {
    let errors: Vec<_> = cmp.iter().map(|c| c.error).collect();
    let sigmas: Vec<_> = cmp
        .iter()
        .map(|c| c.floor.component_mul(&c.floor))
        .collect();
    let ratios: f64 = cmp
        .iter()
        .map(|c| c.error.component_div(&c.sigma).norm_squared())
        .sum();
    (
        Figures {
            error: sample_std_about(&errors, Vector3::zeros()),
            floor: rms_sigma(&sigmas),
            points: cmp.len(),
        },
        (ratios / (3 * cmp.len().max(1)) as f64).sqrt(),
    )
}

/// σ per camera axis of a rig-frame covariance: sqrt(diag(R Σ Rᵀ)).
fn camera_axes(r: &Matrix3<f64>, cov: &Matrix3<f64>) -> Vector3<f64> {
    (r * cov * r.transpose()).diagonal().map(f64::sqrt)
}

/// RMS of σ from per-point variances.
fn rms_sigma(variances: &[Vector3<f64>]) -> Vector3<f64> {
    let n = variances.len().max(1) as f64;
    (variances.iter().sum::<Vector3<f64>>() / n).map(f64::sqrt)
}

/// The bundle's options for simulated data: every observation kept (no data snooping).
pub fn no_snooping() -> deltaz_calib::bundle::CalibrationOptions {
    deltaz_calib::bundle::CalibrationOptions {
        snooping: false,
        ..Default::default()
    }
}

/// The camera calibrated on a simulation's target field (bundle adjustment with `options`).
pub fn bundle_camera(
    sim: &Simulation,
    options: &deltaz_calib::bundle::CalibrationOptions,
) -> Result<deltaz_calib::bundle::Calibration> {
    let init = &sim.camera_init;
    let problem = crate::workflows::camera::build_problem(
        std::path::Path::new("camera_obs.csv"),
        &init.grid(),
        &init.inner(),
        &sim.camera_obs,
        &sim.camera_control,
        options,
    )?;
    Ok(deltaz_calib::bundle::calibrate(problem, options)?)
}

/// [`bundle_camera`]'s inner orientation and the prior (free parameters and their covariance)
/// for the system.
pub fn calibrate_camera(sim: &Simulation) -> Result<(InnerOrientation<f64>, CameraPrior)> {
    let cal = bundle_camera(sim, &no_snooping())?;
    Ok((
        cal.problem.inner,
        crate::workflows::camera::camera_prior(&cal),
    ))
}

/// The whole-system adjustment on a simulation: every plate image but `held_out` resected with
/// `inner` (those that cannot be are left out and returned), then adjusted with the camera
/// `prior` (None: inner orientation fixed): sequentially.
pub fn adjust_simulation(
    sim: &Simulation,
    inner: &InnerOrientation<f64>,
    prior: Option<CameraPrior>,
    noncentral: bool,
    held_out: Option<usize>,
) -> Result<(SystemAdjustment, Vec<crate::io::system_file::LeftOut>)> {
    let camera = prior.map_or(CameraSource::Fixed, CameraSource::Prior);
    adjust_with(sim, inner, camera, noncentral, held_out)
}

/// As [`adjust_simulation`], jointly: the field images of `camera` (the bundle's calibration,
/// its values the start) in the same adjustment as the plates.
pub fn adjust_simulation_joint(
    sim: &Simulation,
    camera: &deltaz_calib::bundle::Calibration,
    noncentral: bool,
    held_out: Option<usize>,
) -> Result<(SystemAdjustment, Vec<crate::io::system_file::LeftOut>)> {
    let source = CameraSource::Field(&camera.problem);
    adjust_with(sim, &camera.problem.inner, source, noncentral, held_out)
}

fn adjust_with(
    sim: &Simulation,
    inner: &InnerOrientation<f64>,
    camera: CameraSource,
    noncentral: bool,
    held_out: Option<usize>,
) -> Result<(SystemAdjustment, Vec<crate::io::system_file::LeftOut>)> {
    let grid = sim.camera_init.grid();
    let path = std::path::Path::new("plate_obs.csv");
    let resected = crate::workflows::plates::resect_all(
        path,
        &grid,
        inner,
        &sim.plate_obs,
        &sim.plate_control,
    )?;
    let kept: Vec<(String, deltaz_calib::resection::ResectionResult)> = resected
        .results
        .iter()
        .filter(|(image, _)| held_out.is_none_or(|h| *image != format!("p{}", h + 1)))
        .cloned()
        .collect();
    let plates =
        crate::workflows::plates::plate_observations(&sim.plate_obs, &sim.plate_control, &kept)?;
    let input = SystemInput {
        grid,
        inner: *inner,
        camera,
        control: &sim.plate_control,
        plates,
        noncentral,
        image_sigma_px: 0.5,
    };
    let adjustment = adjust_system(&input)?;
    Ok((adjustment, resected.left_out))
}

/// A reconstructed point's error against the truth (camera system) and its covariance shares.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthPoint {
    /// Error (mm).
    pub error: Vector3<f64>,
    /// Covariance from the dot's image noise (mm²).
    pub image: Matrix3<f64>,
    /// Covariance from the calibration (mm²).
    pub calibration: Matrix3<f64>,
}

/// The dots of plate image `image` (not used in the adjustment) reconstructed in `frame` (the
/// camera system, or the plate frame of the model's datum image) and compared with the true
/// points: per dot the error and the covariance (image noise plus calibration).
pub fn system_against_truth(
    sim: &Simulation,
    adjustment: &SystemAdjustment,
    image: usize,
    method: Method,
    frame: Frame,
) -> Result<Vec<TruthPoint>> {
    let grid = sim.camera_init.grid();
    let pose: ExteriorOrientation<f64> = sim.truth.plate.images[image].camera.into();
    let normal: Vector3<f64> = pose.r_cam_world().column(2).into();
    let d = -pose.centre.z;
    let projector = &sim.truth.projector;
    let centre = Vector3::from(projector.centre_camera);
    let label = format!("p{}", image + 1);
    sim.plate_obs
        .iter()
        .filter(|o| o.image == label)
        .filter_map(|o| o.ray_id().map(|id| (id, o)))
        .filter(|(id, _)| adjustment.model.rays.iter().any(|r| r.id == *id))
        .map(|(id, o)| {
            let ray = projector
                .rays
                .iter()
                .find(|t| t.id == id)
                .with_context(|| format!("ray {id} not in the truth"))?;
            let start = centre + Vector3::from(ray.offset_camera);
            let dir = Vector3::from(ray.camera);
            let truth = start + dir * ((d - normal.dot(&start)) / normal.dot(&dir));
            let truth = match (frame, &adjustment.model.datum) {
                (Frame::Plate, Some(datum)) => {
                    let k: usize = datum.image.trim_start_matches('p').parse()?;
                    let pose: ExteriorOrientation<f64> =
                        sim.truth.plate.images[k - 1].camera.into();
                    pose.camera_to_world(&truth)
                }
                _ => truth,
            };
            let dot = deltaz_calib::projector_calibration::DotObservation {
                id,
                col: o.col,
                row: o.row,
            };
            let p = adjustment
                .model
                .reconstruct(&grid, &dot, method, frame)
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            Ok(TruthPoint {
                error: p.point - truth,
                image: p.image,
                calibration: p.calibration,
            })
        })
        .collect()
}
