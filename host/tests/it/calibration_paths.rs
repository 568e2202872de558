//! The two ways a user calibrates, run as commands on the desk rig ([`Scenario::desk`], not the
//! paper's): `calibrate camera` then `calibrate projector --camera camera.json` (sequential),
//! and `calibrate system` (joint), each on the same 50 noise draws with one plate image held
//! out. The stated σ of the projector centre and of the held-out plate's points (`reconstruct`'s
//! σ, camera system) is honest on both paths: RMS of error / σ per axis within 0.8-1.25. The
//! sequential path is honest only if camera.json carries the camera's covariance and the
//! projector calibration takes it, with the plate poses, into its σ.

use crate::cli::deltaz_ok;
use crate::honesty::assert_honest;
use deltaz_host::io::observations::write_observations;
use deltaz_host::simulate::{simulate, write_simulation, Scenario, Simulation};
use nalgebra::Vector3;
use std::path::Path;

/// Runs `deltaz ARGS --quiet` in `dir`; panics with its stderr when it fails.
fn deltaz(dir: &Path, args: &[&str]) {
    deltaz_ok(dir, &[args, &["--quiet"]].concat());
}

/// Where the true ray `id` meets the plate of image `image` (camera system, mm).
fn truth_point(sim: &Simulation, image: usize, id: u16) -> Vector3<f64> {
    let pose: deltaz_shared::collinearity::ExteriorOrientation<f64> =
        sim.truth.plate.images[image].camera.into();
    let normal: Vector3<f64> = pose.r_cam_world().column(2).into();
    let projector = &sim.truth.projector;
    let ray = projector.rays.iter().find(|r| r.id == id).unwrap();
    let start = Vector3::from(projector.centre_camera) + Vector3::from(ray.offset_camera);
    let direction = Vector3::from(ray.camera);
    start + direction * ((-pose.centre.z - normal.dot(&start)) / normal.dot(&direction))
}

/// Sums of squared error / σ per axis.
#[derive(Default)]
struct Ratios {
    sum: Vector3<f64>,
    n: f64,
}

impl Ratios {
    fn add(&mut self, error: Vector3<f64>, sigma: Vector3<f64>) {
        self.sum += error.component_div(&sigma).map(|v| v * v);
        self.n += 1.0;
    }

    fn rms(&self) -> Vector3<f64> {
        (self.sum / self.n).map(f64::sqrt)
    }
}

/// One path's system.json against the truth: its projector centre, and the held-out image's
/// dots reconstructed through it (`held.csv`) with their σ.
fn assess(dir: &Path, sim: &Simulation, held_out: usize, system: &str) -> (Ratios, Ratios) {
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join(system)).unwrap()).unwrap();
    let projector = &file["projector"];
    let vector = |v: &serde_json::Value| Vector3::from_fn(|a, _| v[a].as_f64().unwrap());
    let mut centre = Ratios::default();
    centre.add(
        vector(&projector["centre"]) - Vector3::from(sim.truth.projector.centre_camera),
        vector(&projector["centre_sigma"]),
    );
    let rays: Vec<u16> = (projector["rays"].as_array().unwrap().iter())
        .map(|r| r["id"].as_u64().unwrap() as u16)
        .collect();
    let label = format!("p{}", held_out + 1);
    let held: Vec<_> = (sim.plate_obs.iter())
        .filter(|o| o.image == label && o.ray_id().is_some_and(|id| rays.contains(&id)))
        .cloned()
        .collect();
    write_observations(&dir.join("held.csv"), &held).unwrap();
    let csv = format!("{system}.csv");
    let ply = format!("{system}.ply");
    let args = ["reconstruct", "--system", system, "--obs", "held.csv"];
    deltaz(dir, &[&args[..], &["--out", &ply, "--csv", &csv]].concat());
    let mut points = Ratios::default();
    let text = std::fs::read_to_string(dir.join(&csv)).unwrap();
    for line in text.lines().skip(2) {
        let f: Vec<&str> = line.split(',').collect();
        let v: Vec<f64> = f[2..].iter().map(|x| x.parse().unwrap()).collect();
        let truth = truth_point(sim, held_out, f[1].parse().unwrap());
        points.add(
            Vector3::new(v[0], v[1], v[2]) - truth,
            Vector3::new(v[4], v[5], v[6]),
        );
    }
    assert!(points.n as usize >= 300, "{} points", points.n);
    (centre, points)
}

#[test]
fn both_calibration_paths_state_honest_sigma_on_the_desk_rig() {
    let scenario = Scenario::desk();
    let held_out = Scenario::DESK_HELD_OUT;
    let paths = ["sequential.json", "joint.json"];
    let mut tallies: Vec<(Ratios, Ratios)> = paths
        .iter()
        .map(|_| (Ratios::default(), Ratios::default()))
        .collect();
    for seed in 0..100 {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let sim = simulate(&scenario, 3000 + seed);
        write_simulation(d, &sim).unwrap();
        let plates: Vec<_> = (sim.plate_obs.iter())
            .filter(|o| o.image != format!("p{}", held_out + 1))
            .cloned()
            .collect();
        write_observations(&d.join("plates.csv"), &plates).unwrap();
        let field = [
            "--camera-obs",
            "camera_obs.csv",
            "--camera-control",
            "camera_control.csv",
        ];
        let plate = ["--control", "plate_control.csv", "--obs", "plates.csv"];
        deltaz(
            d,
            &[
                &["calibrate", "camera", "--init", "camera_init.json"][..],
                &["--obs", "camera_obs.csv", "--control", "camera_control.csv"],
                &["--out", "camera.json"],
            ]
            .concat(),
        );
        deltaz(
            d,
            &[
                &["calibrate", "projector", "--camera", "camera.json"][..],
                &plate,
                &["--out", paths[0]],
            ]
            .concat(),
        );
        deltaz(
            d,
            &[
                &["calibrate", "system", "--init", "camera_init.json"][..],
                &field,
                &plate,
                &["--out", paths[1]],
            ]
            .concat(),
        );
        for (tally, path) in tallies.iter_mut().zip(paths) {
            let (centre, points) = assess(d, &sim, held_out, path);
            tally.0.sum += centre.sum;
            tally.0.n += centre.n;
            tally.1.sum += points.sum;
            tally.1.n += points.n;
        }
    }
    for ((centre, points), path) in tallies.iter().zip(paths) {
        let (c, p) = (centre.rms(), points.rms());
        println!(
            "desk, {path}: RMS(error/σ) camera system, projector centre {:.2?}, held-out points \
             {:.2?} ({} draws, {} points)",
            c.as_slice(),
            p.as_slice(),
            centre.n,
            points.n
        );
    }
    for ((centre, points), path) in tallies.iter().zip(paths) {
        let (c, p) = (centre.rms(), points.rms());
        for a in 0..3 {
            assert_honest(c[a], format_args!("{path}: centre axis {a}"));
            assert_honest(p[a], format_args!("{path}: points axis {a}"));
        }
    }
}
