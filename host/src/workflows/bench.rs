//! Timings (`deltaz bench`, `deltaz bench-measure`): the camera's bundle adjustment and the
//! whole-system adjustment of the paper scenario and of a large network, the dot identification
//! and the scan pipeline.

use super::accuracy::{adjust_simulation_joint, bundle_camera, no_snooping};
use super::camera::camera_file;
use super::scan::{identify_params, on_device, on_host, scan, ScanStats};
use crate::report::console::Output;
use crate::simulate::objects::{object_dots, object_frame, Object};
use crate::simulate::{images::true_rig, simulate, Scenario};
use anyhow::Result;
use deltaz_calib::bundle::CalibrationOptions;
use deltaz_measure::{host_identifier, LoadedImage, MeasureParams};
use deltaz_shared::identify::{Assignment, DepthRange, Identifier};
use deltaz_shared::rig::Method;
use std::time::Instant;

/// `deltaz bench`: the camera calibration (bundle adjustment) and the whole-system adjustment of
/// the paper scenario and of a large network of `images` field images with about `targets`
/// targets; the report's text and one JSON record per run.
pub fn calibration(
    images: u32,
    targets: u32,
    output: Output,
) -> Result<(String, Vec<serde_json::Value>)> {
    let mut text = String::new();
    let mut runs = Vec::new();
    for scenario in [Scenario::paper(), Scenario::large(images, targets)] {
        let progress = output.progress(format!("calibrating {}", scenario.name));
        let sim = simulate(&scenario, 1);
        let start = Instant::now();
        let cal = bundle_camera(&sim, &CalibrationOptions::default())?;
        let seconds = start.elapsed().as_secs_f64();
        progress.finish_and_clear();
        let file = camera_file(&cal, &sim.camera_obs);
        text += &format!(
            "{}: {} images, {} targets, {} observations: {:.3} s, {} LM iterations, σ0 {:.4} mm, {} correlations > 0.9\n",
            scenario.name,
            cal.problem.images.len(),
            cal.problem.xyz.len(),
            sim.camera_obs.len(),
            seconds,
            cal.iterations,
            cal.solution.sigma0,
            file.correlations.len()
        );
        runs.push(serde_json::json!({
            "scenario": scenario.name,
            "images": cal.problem.images.len(),
            "targets": cal.problem.xyz.len(),
            "observations": sim.camera_obs.len(),
            "seconds": seconds,
            "iterations": cal.iterations,
            "sigma0_mm": cal.solution.sigma0,
            "correlations": file.correlations.len(),
        }));
    }
    let progress = output.progress("adjusting the whole systems".into());
    let (system_text, system_runs) = system(images, targets)?;
    progress.finish_and_clear();
    text += &system_text;
    runs.extend(system_runs);
    Ok((text, runs))
}

/// Timings of the whole-system adjustment: the paper scenario, and a large network (the paper's
/// rig with `images` field images of about `targets` targets and the five plates of
/// [`Scenario::paper_five_plates`], 440 dots each), each simulated once. The camera's bundle
/// adjustment (the start) and the joint adjustment of field images, plates and projector (with
/// the plates' resection) are timed apart. The report's text lines and one JSON record per
/// scenario.
pub fn system(images: u32, targets: u32) -> Result<(String, Vec<serde_json::Value>)> {
    let mut large = Scenario::large(images, targets);
    large.plate.images = Scenario::paper_five_plates().plate.images;
    large.plate.images.truncate(5);
    let mut text = String::new();
    let mut runs = Vec::new();
    for scenario in [Scenario::paper(), large] {
        let sim = simulate(&scenario, 1);
        let start = Instant::now();
        let camera = bundle_camera(&sim, &no_snooping())?;
        let bundle = start.elapsed().as_secs_f64();
        let start = Instant::now();
        let (adj, _) = adjust_simulation_joint(&sim, &camera, false, None)?;
        let joint = start.elapsed().as_secs_f64();
        let dots = sim
            .plate_obs
            .iter()
            .filter(|o| o.ray_id().is_some())
            .count();
        let sigma_field = adj.sigma_field_px.unwrap_or(f64::NAN);
        text += &format!(
            "{} system: {} field images × {} targets, {} plates, {} dots: bundle (start) {:.3} s, \
             joint adjustment {:.3} s, {} iterations, σ0 field targets {:.3} px, plate targets \
             {:.3} px, dots {:.3} px\n",
            scenario.name,
            camera.problem.images.len(),
            camera.problem.xyz.len(),
            adj.poses.len(),
            dots,
            bundle,
            joint,
            adj.iterations,
            sigma_field,
            adj.sigma_targets_px,
            adj.model.sigma_dots_px
        );
        runs.push(serde_json::json!({
            "scenario": format!("{} system", scenario.name),
            "images": camera.problem.images.len(),
            "targets": camera.problem.xyz.len(),
            "plates": adj.poses.len(),
            "dots": dots,
            "bundle_seconds": bundle,
            "seconds": joint,
            "iterations": adj.iterations,
            "sigma0_px": {
                "field_targets": sigma_field,
                "plate_targets": adj.sigma_targets_px,
                "dots": adj.model.sigma_dots_px,
            },
        }));
    }
    Ok((text, runs))
}

/// Scan timings (`deltaz bench-measure`): 60 frames of the paper rig's dots rendered on planes
/// 1690-1780 mm away, tilted up to 0.1 rad (768 × 512, radius 4 px, blur 1 px, noise 2 DN),
/// scanned in process on the host and through the in-process device.
pub fn scans() -> Result<String> {
    let rig = true_rig(&Scenario::paper());
    let frames: Vec<_> = [
        (1690.0, 0.0),
        (1720.0, 0.05),
        (1750.0, -0.05),
        (1780.0, 0.1),
    ]
    .iter()
    .enumerate()
    .map(|(k, &(depth, tilt))| {
        let dots = object_dots(&rig, &Object::Plane { depth, tilt });
        object_frame(&rig, &dots, k as u64)
    })
    .collect();
    let depth = DepthRange {
        near: 1600.0,
        far: 1860.0,
    };
    let identifier = host_identifier(&rig, depth, 1.0, 16.0)?;
    let count = 60;
    let load = |i: usize| {
        Ok((
            format!("f{i}"),
            LoadedImage::Eight(frames[i % frames.len()].clone()),
        ))
    };
    let params = MeasureParams::default();
    let method = Method::ClosestApproach;
    let host = scan(
        &rig,
        &params,
        count,
        load,
        on_host(&rig, &identifier, method),
        |_| Ok(()),
    )?;
    let mut device = crate::link::Device::in_process();
    device.upload_identifying(&rig, 1, method, Some(identify_params(depth, 1.0, 16.0)))?;
    let through = scan(
        &rig,
        &params,
        count,
        load,
        on_device(&rig, &mut device),
        |_| Ok(()),
    )?;
    let line = |what: &str, stats: &ScanStats| {
        format!(
            "scan ({what}, 768 x 512, {} dots per frame): {} frames in {:.2} s, {:.1} frames/s, latency {:.1} ms, {} points\n",
            stats.points / stats.frames.max(1),
            stats.frames,
            stats.elapsed.as_secs_f64(),
            stats.frames_per_second(),
            stats.mean_latency.as_secs_f64() * 1e3,
            stats.points
        )
    };
    Ok(line("in process, host", &host) + &line("through the in-process device", &through))
}

/// Time the epipolar identification of the paper's 440 dots on a plane 1740 mm away: building
/// the lookup (once per calibration) and identifying a frame.
pub fn identification() -> String {
    let rig = true_rig(&Scenario::paper());
    let plane = Object::Plane {
        depth: 1740.0,
        tilt: 0.0,
    };
    let dots: Vec<(f64, f64)> = object_dots(&rig, &plane).iter().map(|d| d.1).collect();
    let depth = DepthRange {
        near: 1680.0,
        far: 1800.0,
    };
    let start = Instant::now();
    let ident = Identifier::<f64, 512, 2048, 8192>::new(&rig, depth, 1.0, 16.0)
        .expect("the paper rig fits");
    let build = start.elapsed().as_secs_f64();
    let mut out = vec![Assignment::Unassigned; dots.len()];
    let rounds = 200;
    let start = Instant::now();
    let mut identified = 0;
    for _ in 0..rounds {
        identified = ident.identify_frame(&dots, &mut out);
    }
    let per_frame = start.elapsed().as_secs_f64() / f64::from(rounds);
    format!(
        "identification (paper rig, 1680-1800 mm, 1 px): lookup built in {:.2} ms ({} entries); {identified} of {} dots in {:.1} µs per frame ({:.2} µs per dot)\n",
        build * 1e3,
        ident.entries(),
        dots.len(),
        per_frame * 1e6,
        per_frame * 1e6 / dots.len() as f64
    )
}
