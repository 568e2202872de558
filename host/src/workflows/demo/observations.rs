//! `deltaz demo --observations`: the whole system on the simulated paper rig, from simulated
//! image observations (0.5 px noise) rather than images.
//!
//! 1. Simulate the paper's rig (Tables 1-4 geometry, 0.5 px image noise): the target field for
//!    the camera, three plate images with control and projected dots.
//! 2. Calibrate the camera by self-calibrating bundle adjustment (section 6.2.1).
//! 3. Calibrate the projector by the ΔZ method (resection per plate image, steps 5-7).
//! 4. Upload the calibration to the device and send one frame of dot centroids seen on a
//!    torso-like surface; receive the 3D points ([`measure`]).
//! 5. Write `cloud.ply`, `report.md`, `report.json` and the plots: `residual_vectors.svg`,
//!    `residual_histogram.svg`, `plate_errors.svg` and `torso_errors.svg`.

use super::{bar, slashed, v3, write_results};
use crate::io::ply::{encode_with, CloudInfo, Encoding};
use crate::io::system_file::{SystemFile, SystemRig};
use crate::link::Device;
use crate::report::calibration_plots::residual_plots;
use crate::report::plots;
use crate::report::residuals::Residual;
use crate::simulate::objects::torso_height;
use crate::simulate::{simulate, Scenario, Simulation};
use crate::workflows::accuracy::{
    against_truth, bundle_camera, calibrate_simulation, paper_experiment, truth_figures,
};
use crate::workflows::camera::camera_file;
use anyhow::{bail, Context, Result};
use deltaz_calib::bundle::CalibrationOptions;
use deltaz_calib::compare::sample_std_about;
use deltaz_calib::projector_calibration::{Model, Plane, PlateImage};
use deltaz_calib::reconstruct::{covariance, reconstruct, ReconstructedPoint};
use deltaz_shared::collinearity::{Camera, ExteriorOrientation};
use deltaz_shared::rig::Method;
use nalgebra::Vector3;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use serde_json::json;
use std::path::Path;

/// One frame of identified dot centroids: (ray id, col, row).
pub type Frame = Vec<(u16, f64, f64)>;

/// The device step: upload the rig (verified by its fingerprint) to the device and compute one
/// frame. Runs the firmware's logic in this process ([`Device::in_process`]) over the same
/// framing as a real device; a centroid the device cannot intersect is dropped with its index.
pub fn measure(
    rig: &SystemRig,
    fingerprint: u64,
    frame: &[(u16, f64, f64)],
) -> Result<Vec<(usize, Vector3<f64>)>> {
    let mut device = Device::in_process();
    device
        .upload(rig, fingerprint)
        .map_err(|e| anyhow::anyhow!("upload: {e}"))?;
    let points = device
        .compute(frame)
        .map_err(|e| anyhow::anyhow!("compute: {e}"))?;
    Ok(points
        .into_iter()
        .enumerate()
        .filter_map(|(i, p)| p.ok().map(|w| (i, w.point)))
        .collect())
}

/// Where a true ray (global frame) meets the torso, by bisection on its parameter.
fn hit_torso(start: &Vector3<f64>, dir: &Vector3<f64>) -> Option<Vector3<f64>> {
    let above = |t: f64| {
        let p = start + dir * t;
        p.z - torso_height(p.x, p.y)
    };
    // From the projector (Z ≈ 1900) down to below the plane Z = 150.
    let (mut lo, mut hi) = (0.0, (150.0 - start.z) / dir.z);
    if hi.is_nan() || hi <= 0.0 || above(lo) <= 0.0 || above(hi) >= 0.0 {
        return None;
    }
    for _ in 0..80 {
        let mid = 0.5 * (lo + hi);
        if above(mid) > 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some(start + dir * (0.5 * (lo + hi)))
}

/// The frame the camera sees of the torso: the true rays on the true surface, imaged by the true
/// camera at its 1st plate pose, with the simulation's image noise. Returns the frame and the
/// true points (camera system).
fn torso_frame(sim: &Simulation, seed: u64) -> Result<(Frame, Vec<Vector3<f64>>)> {
    let truth = &sim.truth;
    let pose: ExteriorOrientation<f64> = truth.projector.camera_global.into();
    let camera = Camera {
        grid: sim.camera_init.grid(),
        inner: truth.camera.inner.into(),
        exterior: pose,
    };
    let centre = Vector3::from(truth.projector.centre_global);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let sigma = truth.noise.image_sigma_px;
    let mut frame = Vec::new();
    let mut points = Vec::new();
    for ray in &truth.projector.rays {
        let start = centre + Vector3::from(ray.offset_global);
        let Some(x) = hit_torso(&start, &Vector3::from(ray.global)) else {
            continue;
        };
        let Ok((col, row)) = camera.world_to_pixel(&x) else {
            continue;
        };
        if !camera.grid.contains(col, row) {
            continue;
        }
        let (dc, dr): (f64, f64) = (
            StandardNormal.sample(&mut rng),
            StandardNormal.sample(&mut rng),
        );
        frame.push((ray.id, col + sigma * dc, row + sigma * dr));
        points.push(pose.world_to_camera(&x));
    }
    if frame.is_empty() {
        bail!("no projected dot lands on the torso in view");
    }
    Ok((frame, points))
}

/// Per plate image: observed dot minus where the calibrated ray meets that plate, in pixels.
fn dot_residuals(
    rig: &SystemRig,
    images: &[PlateImage],
    labels: &[String],
) -> Result<Vec<Residual>> {
    let first = images.first().context("no plate images")?.exterior;
    let camera = Camera {
        grid: *rig.grid(),
        inner: *rig.inner(),
        exterior: first,
    };
    let projector = rig.projector_centred();
    images
        .iter()
        .zip(labels)
        .map(|(image, label)| {
            // The plate Z = 0 of image k, carried into the rig frame: through k's camera system.
            let r_k = image.exterior.r_cam_world();
            let r_1 = first.r_cam_world();
            let normal = r_1.transpose() * r_k * Plane::at_z(0.0).normal;
            let on_plate =
                first.camera_to_world(&image.exterior.world_to_camera(&Vector3::zeros()));
            image
                .dots
                .iter()
                .map(|dot| {
                    let ray = projector.ray(dot.id).map_err(|e| anyhow::anyhow!("{e}"))?;
                    let start = ray.point + rig.camera_centre();
                    let t = normal.dot(&(on_plate - start)) / normal.dot(&ray.direction);
                    let predicted = camera
                        .world_to_pixel(&(start + ray.direction * t))
                        .map_err(|e| anyhow::anyhow!("ray {}: {e}", dot.id))?;
                    Ok(Residual {
                        image: format!("plate image {label}"),
                        point: dot.id.to_string(),
                        observed: [dot.col, dot.row],
                        v: [dot.col - predicted.0, dot.row - predicted.1],
                        rejected: false,
                    })
                })
                .collect::<Result<Vec<_>>>()
        })
        .collect::<Result<Vec<_>>>()
        .map(|images| images.concat())
}

/// Runs the demo and writes its files into `out` (created if needed). Everything is computed
/// before the first file is written.
pub fn run(out: &Path, seed: u64) -> Result<serde_json::Value> {
    let steps = bar(5, "demo");
    let scenario = Scenario::paper();
    steps.set_message("simulating the paper rig");
    let sim = simulate(&scenario, seed);
    steps.inc(1);

    steps.set_message("camera bundle adjustment");
    let bundle = bundle_camera(&sim, &CalibrationOptions::default())?;
    let camera_file = camera_file(&bundle, &sim.camera_obs);
    let inner = camera_file.inner();
    steps.inc(1);

    steps.set_message("projector calibration");
    let cal = calibrate_simulation(&sim, &inner, Model::Paper, None, 3)?;
    let system = SystemFile::new(cal.content.clone())?;
    let fingerprint = system.fingerprint_u64()?;
    let sigma_px = sim.truth.noise.image_sigma_px;
    let (plate_fig, plate_fit_mse) = paper_experiment(&cal, 2, Method::ClosestApproach, sigma_px)?;
    let plate_truth = against_truth(&sim, &cal, 2, Method::ClosestApproach)?;
    let (plate_truth_fig, honesty) = truth_figures(&plate_truth);
    // The same with the simulator's true inner orientation: what the camera calibration costs.
    let true_inner = sim.truth.camera.inner.into();
    let ideal = calibrate_simulation(&sim, &true_inner, Model::Paper, None, 3)?;
    let (ideal_fig, _) = truth_figures(&against_truth(&sim, &ideal, 2, Method::ClosestApproach)?);
    steps.inc(1);

    steps.set_message("measuring the torso");
    let (frame, truth_points) = torso_frame(&sim, seed ^ 0x70_72_73_6f)?;
    let measured = measure(&cal.rig, fingerprint, &frame)?;
    let dots: Vec<_> = measured
        .iter()
        .map(
            |(i, _)| deltaz_calib::projector_calibration::DotObservation {
                id: frame[*i].0,
                col: frame[*i].1,
                row: frame[*i].2,
            },
        )
        .collect();
    let calibration = system.line_covariances();
    let host_points = reconstruct(
        &cal.rig,
        &dots,
        Method::ClosestApproach,
        Some(sigma_px),
        Some(&calibration),
    )?;
    let r = *cal.rig.r_cam_world();
    let mut errors = Vec::new();
    let mut device_vs_host = 0.0_f64;
    let cloud: Vec<ReconstructedPoint> = measured
        .iter()
        .zip(&host_points)
        .map(|((i, p), host)| {
            errors.push(r * (p - cal.rig.camera_centre()) - truth_points[*i]);
            device_vs_host = device_vs_host.max((p - host.point).norm());
            ReconstructedPoint { point: *p, ..*host }
        })
        .collect();
    let torso_error = sample_std_about(&errors, Vector3::zeros());
    // The same frame through the system calibrated with the true inner orientation.
    let ideal_points = reconstruct(&ideal.rig, &dots, Method::ClosestApproach, None, None)?;
    let r_ideal = *ideal.rig.r_cam_world();
    let ideal_errors: Vec<_> = measured
        .iter()
        .zip(&ideal_points)
        .map(|((i, _), p)| r_ideal * (p.point - ideal.rig.camera_centre()) - truth_points[*i])
        .collect();
    let torso_ideal = sample_std_about(&ideal_errors, Vector3::zeros());
    // The floor: image noise alone, per camera axis.
    let mut floor_var = Vector3::zeros();
    for dot in &dots {
        let cov = covariance(&cal.rig, dot, Method::ClosestApproach, sigma_px)?;
        floor_var += (r * cov * r.transpose()).diagonal();
    }
    let torso_floor = (floor_var / dots.len().max(1) as f64).map(f64::sqrt);
    steps.inc(1);

    steps.set_message("plots and report");
    let labels: Vec<String> = sim
        .truth
        .plate
        .images
        .iter()
        .map(|i| i.image.clone())
        .collect();
    let residuals = dot_residuals(&cal.rig, &cal.images, &labels)?;
    let grid = cal.rig.grid();
    let mut plot_files = residual_plots(&residuals, grid.width, grid.height)?;
    plot_files.extend([
        (
            "plate_errors.svg".to_owned(),
            plots::accuracy_map(
                "Flat plate (image p3) against truth, camera system",
                "Z error",
                &plate_truth
                    .iter()
                    .map(|c| (c.truth.x, c.truth.y, c.error.z))
                    .collect::<Vec<_>>(),
            )?,
        ),
        (
            "torso_errors.svg".to_owned(),
            plots::accuracy_map(
                "Torso (one device frame) against truth, camera system",
                "Z error",
                &measured
                    .iter()
                    .zip(&errors)
                    .map(|((i, _), e)| (truth_points[*i].x, truth_points[*i].y, e.z))
                    .collect::<Vec<_>>(),
            )?,
        ),
    ]);
    let truth_centre = Vector3::from(sim.truth.projector.centre_camera);
    let centre_cam = r * (cal.projector.centre - cal.rig.camera_centre());
    let inner_truth = sim.truth.camera.inner;
    let report = json!({
        "format": "deltaz.demo/1",
        "scenario": scenario.name,
        "seed": seed,
        "image_sigma_px": sigma_px,
        "fingerprint": system.fingerprint,
        "camera": {
            "f": inner.f, "cx": inner.cx, "cy": inner.cy, "k1": inner.k1,
            "sigma": {"f": camera_file.sigma.f, "cx": camera_file.sigma.cx, "cy": camera_file.sigma.cy, "k1": camera_file.sigma.k1},
            "truth": {"f": inner_truth.f, "cx": inner_truth.cx, "cy": inner_truth.cy, "k1": inner_truth.k1},
            "rms_px": camera_file.rms_px,
        },
        "projector": {
            "model": "paper",
            "centre_camera_mm": v3(&centre_cam),
            "centre_sigma_mm": v3(&cal.projector.centre_sigma),
            "centre_truth_camera_mm": v3(&truth_centre),
            "rays": cal.projector.rays.len(),
        },
        "flat_plate": {
            "points": plate_fig.points,
            "vs_eq10_no_fit_mm": v3(&plate_fig.error),
            "vs_eq10_after_similarity_mm": v3(&plate_fit_mse),
            "vs_truth_mm": v3(&plate_truth_fig.error),
            "vs_truth_with_true_camera_mm": v3(&ideal_fig.error),
            "floor_mm": v3(&plate_truth_fig.floor),
            "sigma_honesty_rms": honesty,
        },
        "error_std_mm": v3(&torso_error),
        "torso": {
            "dots_sent": frame.len(),
            "points_received": cloud.len(),
            "floor_mm": v3(&torso_floor),
            "error_std_with_true_camera_mm": v3(&torso_ideal),
            "device_vs_host_max_mm": device_vs_host,
        },
    });
    let md = report_markdown(&report);
    let info = CloudInfo {
        frame: system.content.frame.to_string(),
        fingerprint: Some(system.fingerprint.clone()),
        frames: None,
        centroid_step_px: Some(crate::link::centroid_step_px(
            cal.rig.grid().width,
            cal.rig.grid().height,
        )),
    };
    let ply = encode_with(&cloud, Encoding::BinaryLittleEndian, &info);
    steps.inc(1);
    steps.finish_and_clear();

    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    write_results(out, &ply, &system, &plot_files, (&report, &md), &[])?;
    Ok(report)
}

/// The summary `deltaz demo --observations` prints (mm, X / Y / Z).
pub fn summary(report: &serde_json::Value) -> String {
    format!(
        "torso error std {} mm (floor {} mm), flat plate vs truth {} mm (X / Y / Z)",
        slashed(&report["error_std_mm"]),
        slashed(&report["torso"]["floor_mm"]),
        slashed(&report["flat_plate"]["vs_truth_mm"])
    )
}

fn report_markdown(r: &serde_json::Value) -> String {
    let f = |v: &serde_json::Value| -> String {
        match v.as_f64() {
            Some(x) => format!("{x:.4}"),
            None => slashed(v),
        }
    };
    let c = &r["camera"];
    let p = &r["projector"];
    let plate = &r["flat_plate"];
    let torso = &r["torso"];
    format!(
        "# deltaz demo: the paper rig, simulated\n\n\
         Scenario `{}`, seed {}, image noise {} px. Calibration fingerprint `{}`.\n\n\
         ## Camera (self-calibrating bundle adjustment)\n\n\
         | | f (mm) | cx (mm) | cy (mm) | k1 |\n|---|---|---|---|---|\n\
         | estimated | {} | {} | {} | {:.3e} |\n| σ | {} | {} | {} | {:.1e} |\n| truth | {} | {} | {} | {:.3e} |\n\n\
         ## Projector (ΔZ method, paper model, {} rays on 3 plates)\n\n\
         Centre in the camera system: {} mm (σ {} mm); truth {} mm.\n\n\
         ## Flat plate (image p3, {} dots; the paper's section 6.2.3)\n\n\
         | per axis X / Y / Z (mm) | |\n|---|---|\n\
         | against eq. (10) plate coordinates, no fit | {} |\n\
         | against eq. (10), after Table 6's similarity (Table 7's MSE) | {} |\n\
         | against the truth (camera system), no fit | {} |\n\
         | the same with the true inner orientation (no camera calibration error) | {} |\n\
         | image-noise floor (propagated) | {} |\n\n\
         RMS of error/σ against the truth: {} (σ from image noise and the projector calibration;\n\
         the camera calibration's own uncertainty is not propagated, hence the excess). Plots: `residual_vectors.svg` (observed dot − calibrated\n\
         ray on each plate, px, magnified), `residual_histogram.svg` (against the normal distribution),\n\
         `plate_errors.svg` and `torso_errors.svg` (Z error against truth over X, Y, mm).\n\n\
         ## Torso (one frame through the device)\n\n\
         {} dots sent, {} points received (`cloud.ply`). Error against truth (camera system, no fit):\n\
         **{} mm** (`error_std_mm`); with the true inner orientation {} mm; image-noise floor {} mm. Device (f32, fixed-point wire) vs host f64:\n\
         at most {} mm.\n",
        r["scenario"].as_str().unwrap_or(""),
        r["seed"],
        r["image_sigma_px"],
        r["fingerprint"].as_str().unwrap_or(""),
        f(&c["f"]), f(&c["cx"]), f(&c["cy"]), c["k1"].as_f64().unwrap_or(f64::NAN),
        f(&c["sigma"]["f"]), f(&c["sigma"]["cx"]), f(&c["sigma"]["cy"]), c["sigma"]["k1"].as_f64().unwrap_or(f64::NAN),
        f(&c["truth"]["f"]), f(&c["truth"]["cx"]), f(&c["truth"]["cy"]), c["truth"]["k1"].as_f64().unwrap_or(f64::NAN),
        p["rays"],
        f(&p["centre_camera_mm"]), f(&p["centre_sigma_mm"]), f(&p["centre_truth_camera_mm"]),
        plate["points"],
        f(&plate["vs_eq10_no_fit_mm"]), f(&plate["vs_eq10_after_similarity_mm"]),
        f(&plate["vs_truth_mm"]), f(&plate["vs_truth_with_true_camera_mm"]), f(&plate["floor_mm"]), f(&plate["sigma_honesty_rms"]),
        torso["dots_sent"], torso["points_received"],
        f(&r["error_std_mm"]), f(&torso["error_std_with_true_camera_mm"]), f(&torso["floor_mm"]), f(&torso["device_vs_host_max_mm"]),
    )
}
