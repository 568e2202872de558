//! Timings of the whole-system adjustment (part of `deltaz bench`): the paper scenario, and a
//! large network (the paper's rig with `images` field images of about `targets` targets and the
//! five plates of [`Scenario::paper_five_plates`], 440 dots each), each simulated once. The
//! camera's bundle adjustment (the start) and the joint adjustment of field images, plates and
//! projector (with the plates' resection) are timed apart.

use crate::accuracy::{adjust_simulation_joint, bundle_camera, no_snooping};
use crate::simulate::{simulate, Scenario};
use anyhow::Result;
use std::time::Instant;

/// The report's text lines and one JSON record per scenario.
pub fn run(images: u32, targets: u32) -> Result<(String, Vec<serde_json::Value>)> {
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
