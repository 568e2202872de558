//! Plate images from files: the resection of every image on the control file (step 4) and the
//! projected dots of each resected image.

use crate::io::control::ControlPoint;
use crate::io::observations::{image_labels, off_sensor, Observation, PointKind};
use crate::io::system_file::LeftOut;
use crate::io::FileError;
use anyhow::{bail, Context, Result};
use deltaz_calib::projector_calibration::{DotObservation, Plane, PlateImage};
use deltaz_calib::resection::{resect, resect_control, ResectionResult, Sighting};
use deltaz_calib::system_adjustment::PlateObservations;
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::ExteriorOrientation;
use nalgebra::Vector2;
use std::collections::HashMap;
use std::path::Path;

/// The plate images of an observation file: for each resected image (in the given order) its
/// `dot` observations, the plate surface at Z = 0 of the plate frame. A dot label that is not a
/// ray id names its line; an image without dots is an error.
pub fn plate_images(
    observations: &[Observation],
    poses: &[(String, ExteriorOrientation<f64>)],
) -> Result<Vec<PlateImage>> {
    poses
        .iter()
        .map(|(image, exterior)| {
            let dots = observations
                .iter()
                .filter(|o| &o.image == image && o.kind == PointKind::Dot)
                .map(|o| {
                    let id = o.ray_id().with_context(|| {
                        format!("line {}: dot label {:?} is not a ray id", o.line, o.point)
                    })?;
                    Ok(DotObservation {
                        id,
                        col: o.col,
                        row: o.row,
                    })
                })
                .collect::<Result<Vec<_>>>()?;
            if dots.is_empty() {
                bail!("image {image:?} has no projected dots");
            }
            Ok(PlateImage {
                exterior: *exterior,
                plate: Plane::at_z(0.0),
                dots,
            })
        })
        .collect()
}

/// The images of an observation file resected on the control, and those that could not be.
#[derive(Debug, Clone)]
pub struct Resected {
    /// (image, result) in the file's order.
    pub results: Vec<(String, ResectionResult)>,
    /// Images too poorly controlled to resect, with the reason.
    pub left_out: Vec<LeftOut>,
}

/// Checks that every observation of the file `obs_path` (target or dot) lies on the camera's
/// sensor: one off it is an error naming its line, as `reconstruct` gives it (the observations
/// of another camera, or of resized images). For the files a user gives; simulated
/// observations may run past the sensor's edge.
pub fn check_on_sensor(
    obs_path: &Path,
    grid: &PixelGrid<f64>,
    observations: &[Observation],
) -> Result<()> {
    let sensor = (grid.width, grid.height);
    let off = observations
        .iter()
        .find_map(|o| off_sensor(obs_path, o.line, (o.col, o.row), sensor));
    match off {
        Some(e) => Err(e.into()),
        None => Ok(()),
    }
}

/// Resects every image of an observation file on the control file, the control weighted by its
/// σ against the image noise (estimated: the median σ0 of a first pass with exact control).
/// Dots are skipped; a target that is not in the control file is an error naming the
/// observation's line; an image that cannot be resected is left out with the reason.
pub fn resect_all(
    obs_path: &Path,
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    observations: &[Observation],
    control: &[ControlPoint],
) -> anyhow::Result<Resected> {
    let known: HashMap<&str, &ControlPoint> =
        control.iter().map(|c| (c.point.as_str(), c)).collect();
    let mut images = Vec::new();
    for image in image_labels(observations) {
        let mut points = Vec::new();
        for o in observations.iter().filter(|o| o.image == image) {
            if o.kind == PointKind::Dot {
                continue;
            }
            let c = known.get(o.point.as_str()).ok_or_else(|| {
                FileError::at(
                    obs_path,
                    o.line,
                    format!("unknown point {:?}: not in the control file", o.point),
                )
            })?;
            points.push(Sighting {
                pixel: Vector2::new(o.col, o.row),
                xyz: c.xyz,
                sigma: c.sigma,
            });
        }
        images.push((image, points));
    }
    let mut first: Vec<f64> = images
        .iter()
        .filter_map(|(_, pts)| {
            let exact: Vec<_> = pts.iter().map(|p| (p.pixel, p.xyz)).collect();
            resect(grid, inner, &exact).ok().map(|r| r.sigma0)
        })
        .collect();
    first.sort_by(f64::total_cmp);
    let noise_px = first
        .get(first.len() / 2)
        .map_or(0.5, |s0| s0 / grid.pixel_size)
        .max(1e-3);
    let mut resected = Resected {
        results: Vec::new(),
        left_out: Vec::new(),
    };
    for (image, points) in images {
        match resect_control(grid, inner, &points, noise_px) {
            Ok(r) => resected.results.push((image, r)),
            Err(e) => resected.left_out.push(LeftOut {
                image,
                why: e.to_string(),
            }),
        }
    }
    Ok(resected)
}

/// [`resect_all`] where an image that cannot be resected is an error naming it.
pub fn resect_images(
    obs_path: &Path,
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    observations: &[Observation],
    control: &[ControlPoint],
) -> anyhow::Result<Vec<(String, ResectionResult)>> {
    let resected = resect_all(obs_path, grid, inner, observations, control)?;
    if let Some(l) = resected.left_out.first() {
        bail!("image {:?}: cannot resect: {}", l.image, l.why);
    }
    Ok(resected.results)
}

/// The whole-system adjustment's plate images: for each resected image its targets (indices
/// into `control`) and its dots. A dot label that is not a ray id names its line.
pub fn plate_observations(
    observations: &[Observation],
    control: &[ControlPoint],
    resected: &[(String, ResectionResult)],
) -> Result<Vec<PlateObservations>> {
    let index: HashMap<&str, usize> = control
        .iter()
        .enumerate()
        .map(|(j, c)| (c.point.as_str(), j))
        .collect();
    let poses: Vec<(String, ExteriorOrientation<f64>)> = resected
        .iter()
        .map(|(image, r)| (image.clone(), r.exterior))
        .collect();
    let images = plate_images(observations, &poses)?;
    Ok(resected
        .iter()
        .zip(images)
        .map(|((image, r), plate)| PlateObservations {
            image: image.clone(),
            start: r.exterior,
            targets: observations
                .iter()
                .filter(|o| &o.image == image && o.kind == PointKind::Control)
                .filter_map(|o| {
                    index
                        .get(o.point.as_str())
                        .map(|j| (Vector2::new(o.col, o.row), *j))
                })
                .collect(),
            dots: plate.dots,
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::camera_file::PoseParams;
    use crate::simulate::{simulate, true_camera, Scenario};
    use deltaz_calib::resection::{closed_form_starts, ResectionError};
    use nalgebra::Vector3;

    fn plate_points(
        sim: &crate::simulate::Simulation,
        image: &str,
        truth_control: bool,
    ) -> Vec<(Vector2<f64>, Vector3<f64>)> {
        sim.plate_obs
            .iter()
            .filter(|o| o.image == image && o.kind == PointKind::Control)
            .map(|o| {
                let xyz = if truth_control {
                    sim.truth.point(&o.point).unwrap()
                } else {
                    sim.plate_control
                        .iter()
                        .find(|c| c.point == o.point)
                        .unwrap()
                        .xyz
                };
                (Vector2::new(o.col, o.row), xyz)
            })
            .collect()
    }

    /// The paper's three plate images (0.5 px noise, noisy control as written to the files)
    /// recover Table 2's poses within 3σ, and σ0 is near the simulated 0.5 px.
    #[test]
    fn paper_plate_images_recover_table2_within_3_sigma() {
        let scenario = Scenario::paper();
        let (grid, inner) = true_camera(&scenario);
        for seed in 1..=5 {
            let sim = simulate(&scenario, seed);
            for (k, truth) in scenario.plate.images.iter().enumerate() {
                let image = format!("p{}", k + 1);
                let res = resect(&grid, &inner, &plate_points(&sim, &image, false)).unwrap();
                let est = PoseParams::from(res.exterior).to_array();
                for (j, (e, t)) in est.iter().zip(truth.to_array()).enumerate() {
                    let z = (e - t) / res.sigma[j];
                    assert!(
                        z.abs() < 3.0,
                        "seed {seed} {image} param {j}: {e} vs {t}, {z:.2}σ"
                    );
                }
                let s0_px = res.sigma0 / grid.pixel_size;
                assert!((0.25..0.8).contains(&s0_px), "σ0 {s0_px} px");
            }
        }
    }

    /// Without noise every closed-form start is exact: the DLT, the homography of the plate's
    /// plane and the three-point pose for the whole control, the homography and the three-point
    /// pose for the points in the plane.
    #[test]
    fn closed_form_is_exact_without_noise() {
        let mut scenario = Scenario::paper();
        scenario.noise.image_sigma_px = 0.0;
        let (grid, inner) = true_camera(&scenario);
        let sim = simulate(&scenario, 1);
        let pts = plate_points(&sim, "p1", true);
        let truth: ExteriorOrientation<f64> = scenario.plate.images[0].into();
        let check = |pts: &[(Vector2<f64>, Vector3<f64>)], candidates: usize| {
            let obs: Vec<_> = pts
                .iter()
                .map(|(p, _)| grid.pixel_to_photo(p.x, p.y))
                .collect();
            let world: Vec<_> = pts.iter().map(|(_, x)| *x).collect();
            let starts = closed_form_starts(&inner, &obs, &world).unwrap();
            assert_eq!(starts.len(), candidates);
            for start in starts {
                assert!(
                    (start.centre - truth.centre).amax() < 1e-6,
                    "{}",
                    start.centre
                );
                assert!((start.r_cam_world() - truth.r_cam_world()).amax() < 1e-9);
            }
        };
        check(&pts, 3);
        let flat: Vec<_> = pts.iter().copied().filter(|(_, x)| x.z == 0.0).collect();
        assert!(flat.len() >= 4);
        check(&flat, 2);
        let res = resect(&grid, &inner, &flat).unwrap();
        assert!((res.exterior.centre - truth.centre).amax() < 1e-6);
    }

    #[test]
    fn unsolvable_configurations_say_why() {
        let scenario = Scenario::paper();
        let (grid, inner) = true_camera(&scenario);
        let sim = simulate(&scenario, 1);
        let pts = plate_points(&sim, "p1", true);
        assert_eq!(
            resect(&grid, &inner, &pts[..3]),
            Err(ResectionError::TooFewPoints {
                given: 3,
                needed: 4
            })
        );
        let line: Vec<_> = pts.iter().copied().filter(|(_, x)| x.y == -40.0).collect();
        assert!(line.len() >= 4);
        assert_eq!(resect(&grid, &inner, &line), Err(ResectionError::Collinear));
        // Mirror the control through the camera: the DLT puts every point behind it, the
        // plane alone fits a camera turned round, which the raised points contradict by ~10 px.
        let c = Vector3::from(
            scenario.plate.images[0].to_array()[3..]
                .try_into()
                .unwrap_or([0.0; 3]),
        );
        let behind: Vec<_> = pts
            .iter()
            .map(|(p, x)| Sighting {
                pixel: *p,
                xyz: 2.0 * c - x,
                sigma: 0.1,
            })
            .collect();
        let e = resect_control(&grid, &inner, &behind, 0.5).unwrap_err();
        assert!(
            matches!(e, ResectionError::PoorFit { rms_px, .. } if rms_px > 5.0),
            "{e:?}"
        );
        let mut nan = pts.clone();
        nan[0].1.x = f64::NAN;
        assert_eq!(resect(&grid, &inner, &nan), Err(ResectionError::NotFinite));
    }

    #[test]
    fn resect_images_names_unknown_points_and_images() {
        let scenario = Scenario::paper();
        let (grid, inner) = true_camera(&scenario);
        let sim = simulate(&scenario, 1);
        let path = Path::new("plate_obs.csv");
        let all = resect_images(path, &grid, &inner, &sim.plate_obs, &sim.plate_control).unwrap();
        assert_eq!(all.len(), 3);
        let mut obs = sim.plate_obs.clone();
        obs[1].point = "C99".into();
        obs[1].line = 3;
        let e = resect_images(path, &grid, &inner, &obs, &sim.plate_control).unwrap_err();
        assert!(
            e.to_string()
                .contains("plate_obs.csv:3: unknown point \"C99\""),
            "{e}"
        );
        let few: Vec<_> = sim
            .plate_obs
            .iter()
            .filter(|o| o.image != "p2" || o.point.as_str() < "C05")
            .cloned()
            .collect();
        let e = resect_images(path, &grid, &inner, &few, &sim.plate_control).unwrap_err();
        assert!(e.to_string().contains("image \"p2\": cannot resect"), "{e}");
    }
}
