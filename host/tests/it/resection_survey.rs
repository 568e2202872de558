//! A survey of plate views on the desk rig ([`Scenario::desk`]): the camera near and far, turned
//! and tilted, so that each view holds from none to all six of the raised control points (and
//! as few as four points in all). Every view resects, with exact control (`resect`) and with
//! the control weighted by its σ (`resect_all`, what the calibrations use), its pose within 5σ
//! of the truth.

use deltaz_calib::resection::{resect, ResectionResult};
use deltaz_host::io::camera_file::PoseParams;
use deltaz_host::io::observations::PointKind;
use deltaz_host::simulate::{simulate, true_camera, Scenario, Simulation};
use deltaz_host::workflows::plates::resect_all;
use deltaz_shared::rotation::rotation_matrix;
use nalgebra::{Vector2, Vector3};
use std::path::Path;

/// 294 views: seven distances (260-1050 mm) × 7 × 6 aim points over the plate and its edges,
/// each with its own κ (±1.6 rad), φ and ω (±0.35 rad).
fn views() -> Vec<PoseParams> {
    let mut poses = Vec::new();
    for distance in [260.0, 330.0, 420.0, 540.0, 700.0, 880.0, 1050.0] {
        for x in [-30.0, 80.0, 190.0, 250.0, 310.0, 410.0, 520.0] {
            for y in [-30.0, 85.0, 160.0, 240.0, 315.0, 430.0] {
                let t = poses.len() as f64 + 1.0;
                let [kappa, phi, omega] = [
                    1.6 * (1.7 * t).sin(),
                    0.35 * (2.3 * t).sin(),
                    0.35 * (3.1 * t).cos(),
                ];
                let r = rotation_matrix(kappa, phi, omega);
                // The camera looks along its −z at the aim point.
                let c = Vector3::new(x, y, 0.0) + r.transpose().column(2) * distance;
                poses.push(PoseParams::from_array([kappa, phi, omega, c.x, c.y, c.z]));
            }
        }
    }
    poses
}

/// The control targets image `image` sees: (pixel, control coordinates, label).
fn sightings(sim: &Simulation, image: &str) -> Vec<(Vector2<f64>, Vector3<f64>, String)> {
    sim.plate_obs
        .iter()
        .filter(|o| o.image == image && o.kind == PointKind::Control)
        .map(|o| {
            let c = sim.plate_control.iter().find(|c| c.point == o.point);
            (Vector2::new(o.col, o.row), c.unwrap().xyz, o.point.clone())
        })
        .collect()
}

/// The largest |error| / σ of a resected pose against the truth, σ scaled from the resection's
/// own σ0 to the simulated image noise (`noise_mm`): with four or five points σ0 rests on two or
/// four degrees of freedom and would make the test a lottery.
fn worst_z(r: &ResectionResult, truth: &PoseParams, noise_mm: f64) -> f64 {
    let est = PoseParams::from(r.exterior).to_array();
    (0..6)
        .map(|k| (est[k] - truth.to_array()[k]).abs() / (r.sigma[k] / r.sigma0 * noise_mm))
        .fold(0.0, f64::max)
}

#[test]
fn every_plate_view_resects_whatever_its_raised_points() {
    let mut scenario = Scenario::desk();
    scenario.plate.images = views();
    let (grid, inner) = true_camera(&scenario);
    let noise_mm = scenario.noise.image_sigma_px * grid.pixel_size;
    let raised: Vec<String> = (scenario.plate.control.iter().enumerate())
        .filter(|(_, c)| c[2] > 0.0)
        .map(|(i, _)| format!("C{:02}", i + 1))
        .collect();
    let (mut by_raised, mut fewest, mut worst) = ([0usize; 7], usize::MAX, 0.0_f64);
    let mut failures = Vec::new();
    for seed in 1..=3 {
        let sim = simulate(&scenario, seed);
        let weighted = resect_all(
            Path::new("plate_obs.csv"),
            &grid,
            &inner,
            &sim.plate_obs,
            &sim.plate_control,
        )
        .unwrap();
        for (k, truth) in scenario.plate.images.iter().enumerate() {
            let image = format!("p{}", k + 1);
            let seen = sightings(&sim, &image);
            if seen.len() < 4 {
                continue;
            }
            let up = seen.iter().filter(|s| raised.contains(&s.2)).count();
            by_raised[up] += 1;
            fewest = fewest.min(seen.len());
            let pairs: Vec<_> = seen.iter().map(|s| (s.0, s.1)).collect();
            let exact = resect(&grid, &inner, &pairs).map_err(|e| e.to_string());
            let with_sigma = weighted
                .results
                .iter()
                .find(|(i, _)| *i == image)
                .map(|(_, r)| r.clone())
                .ok_or_else(|| {
                    let l = weighted.left_out.iter().find(|l| l.image == image);
                    l.map_or_else(String::new, |l| l.why.clone())
                });
            for (how, result) in [("resect", exact), ("resect_all", with_sigma)] {
                match result.map(|r| worst_z(&r, truth, noise_mm)) {
                    Ok(z) if z < 5.0 => worst = worst.max(z),
                    outcome => failures.push(format!(
                        "seed {seed} {image} ({} points, {up} raised), {how}: {outcome:?}",
                        seen.len()
                    )),
                }
            }
        }
    }
    eprintln!(
        "desk plate views by raised points in view (0-6): {by_raised:?}, at least {fewest} \
         points; worst pose error {worst:.2}σ; {} failures",
        failures.len()
    );
    assert!(failures.is_empty(), "{failures:#?}");
    assert!(by_raised.iter().all(|n| *n > 0), "{by_raised:?}");
}
