//! What `--plots DIR` of the calibration commands draws (with [`super::plots`]): the image
//! residual vectors per image and their histogram against the normal distribution, the
//! projector rays' miss distances, and an accuracy map of every plate image: its dots
//! reconstructed with the calibrated system (eqs 8-9 or the closest approach) and expressed in
//! that plate's frame, where the plate surface is Z = 0, so that their Z is the distance off the
//! plate.

use super::console::Output;
use super::plots;
use super::residuals::Residual;
use crate::io::control::ControlPoint;
use crate::io::observations::{Observation, PointKind};
use crate::io::system_file::SystemRig;
use anyhow::Result;
use deltaz_calib::projector_calibration::DotObservation;
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::{Camera, ExteriorOrientation};
use deltaz_shared::rig::Method;
use std::collections::HashMap;

/// A plot: its file name and SVG.
pub type Plot = (String, String);

/// Writes `files` and, with `dir`, the plots `make` draws into it, all or nothing, and says on
/// stderr how many plots went where.
pub fn write_with_plots(
    files: &[(&std::path::Path, &[u8])],
    dir: Option<&std::path::Path>,
    make: impl FnOnce() -> Result<Vec<Plot>>,
    output: Output,
) -> Result<()> {
    let made = match dir {
        Some(_) => make()?,
        None => Vec::new(),
    };
    plots::write_with_plots(files, dir, &made)?;
    report_plots(dir, &made, output);
    Ok(())
}

/// Says on stderr how many plots went into `dir`, if plots were asked for.
pub fn report_plots(dir: Option<&std::path::Path>, plots: &[Plot], output: Output) {
    if let Some(dir) = dir {
        output.status(format!("{} plots -> {}", plots.len(), dir.display()));
    }
}

/// `residual_vectors.svg` and `residual_histogram.svg` of image residuals on a `width` ×
/// `height` px sensor.
pub fn residual_plots(residuals: &[Residual], width: u32, height: u32) -> Result<Vec<Plot>> {
    let (histogram, _) = plots::residual_histogram(residuals)?;
    Ok(vec![
        (
            "residual_vectors.svg".to_owned(),
            plots::residual_vectors(residuals, width, height)?,
        ),
        ("residual_histogram.svg".to_owned(), histogram),
    ])
}

/// The plots of a projector or system calibration: [`residual_plots`] of `residuals` on the
/// sensor of `grid`, `ray_misses.svg` of each ray's RMS and largest distance from its plate
/// points (mm; `None` for a ray seen on one plate) and `plate_maps` of the plates
/// reconstructed with `rig`.
pub fn system_plots(
    residuals: &[Residual],
    grid: &PixelGrid<f64>,
    rays: &[plots::RayMiss],
    rig: &SystemRig,
    plates: &[PlateView],
) -> Result<Vec<Plot>> {
    let mut made = residual_plots(residuals, grid.width, grid.height)?;
    made.push(("ray_misses.svg".to_owned(), plots::ray_misses(rays)?));
    made.extend(plate_maps(rig, plates, Method::ClosestApproach)?);
    Ok(made)
}

/// The residuals of a resected image's control targets: observed − projected through the pose
/// (px); the image's dots are skipped, as are targets without control.
pub fn control_residuals(
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    poses: &[(String, ExteriorOrientation<f64>)],
    observations: &[Observation],
    control: &[ControlPoint],
) -> Vec<Residual> {
    let known: HashMap<&str, &ControlPoint> =
        control.iter().map(|c| (c.point.as_str(), c)).collect();
    let known = &known;
    poses
        .iter()
        .flat_map(|(image, exterior)| {
            let camera = Camera {
                grid: *grid,
                inner: *inner,
                exterior: *exterior,
            };
            observations
                .iter()
                .filter(move |o| o.image == *image && o.kind != PointKind::Dot)
                .filter_map(move |o| {
                    let c = known.get(o.point.as_str())?;
                    let (col, row) = camera.world_to_pixel(&c.xyz).ok()?;
                    Some(Residual {
                        image: o.image.clone(),
                        point: o.point.clone(),
                        observed: [o.col, o.row],
                        v: [o.col - col, o.row - row],
                        rejected: false,
                    })
                })
        })
        .collect()
}

/// One plate image for its accuracy map.
#[derive(Debug, Clone, Copy)]
pub struct PlateView<'a> {
    /// The image's label.
    pub image: &'a str,
    /// The camera's pose in the plate's frame (plate surface Z = 0).
    pub exterior: ExteriorOrientation<f64>,
    /// The dots seen in the image.
    pub dots: &'a [DotObservation],
}

/// The plate image's dots reconstructed with `rig` and carried into the plate's frame through
/// the camera system: (X, Y, Z) in mm, Z the distance off the plate surface. Dots of rays the
/// rig does not hold (left out of the calibration) are skipped.
pub fn plate_points(rig: &SystemRig, plate: &PlateView, method: Method) -> Vec<(f64, f64, f64)> {
    let r = rig.r_cam_world();
    plate
        .dots
        .iter()
        .filter_map(|d| rig.reconstruct(d.id, d.col, d.row, method).ok())
        .map(|hit| {
            let camera = r * (hit.point - rig.camera_centre());
            let p = plate.exterior.camera_to_world(&camera);
            (p.x, p.y, p.z)
        })
        .collect()
}

/// `plate_<image>.svg` for every plate image: the accuracy map of its reconstructed dots off the
/// plate surface.
fn plate_maps(rig: &SystemRig, plates: &[PlateView], method: Method) -> Result<Vec<Plot>> {
    plates
        .iter()
        .map(|plate| {
            let points = plate_points(rig, plate, method);
            let title = format!(
                "Plate image {}, reconstructed, in its plate frame",
                plate.image
            );
            let svg = plots::accuracy_map(&title, "Z off the plate", &points)?;
            Ok((format!("plate_{}.svg", plate.image), svg))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate::{images::true_rig, simulate, Scenario};

    /// With the true rig, noise-free dots and exact plate control, every reconstructed plate
    /// point lies on its plate (Z = 0) within rounding; the accuracy map marks each of them.
    #[test]
    fn true_rig_puts_the_dots_on_their_plates() {
        let mut scenario = Scenario::paper();
        scenario.noise.image_sigma_px = 0.0;
        scenario.plate.control_sigma = 0.0;
        let sim = simulate(&scenario, 1);
        let rig = true_rig(&scenario);
        let grid = sim.camera_init.grid();
        let (_, inner) = crate::simulate::true_camera(&scenario);
        let poses = crate::workflows::accuracy::plate_poses(&sim, &grid, &inner).unwrap();
        let images = crate::workflows::plates::plate_images(&sim.plate_obs, &poses).unwrap();
        let views: Vec<PlateView> = images
            .iter()
            .zip(&poses)
            .map(|(i, (label, _))| PlateView {
                image: label,
                exterior: i.exterior,
                dots: &i.dots,
            })
            .collect();
        for view in &views {
            let points = plate_points(&rig, view, Method::ClosestApproach);
            assert_eq!(points.len(), view.dots.len());
            let worst = points.iter().map(|p| p.2.abs()).fold(0.0, f64::max);
            assert!(worst < 1e-3, "{}: {worst} mm off the plate", view.image);
        }
        let maps = plate_maps(&rig, &views, Method::ClosestApproach).unwrap();
        assert_eq!(maps.len(), 3);
        assert_eq!(maps[0].0, "plate_p1.svg");
        assert_eq!(
            maps[0].1.matches(r#"r="4""#).count(),
            2 * views[0].dots.len()
        );
        let residuals =
            control_residuals(&grid, &inner, &poses, &sim.plate_obs, &sim.plate_control);
        let worst = residuals.iter().map(Residual::norm).fold(0.0, f64::max);
        assert!(!residuals.is_empty() && worst < 1e-3, "{worst} px");
    }
}
