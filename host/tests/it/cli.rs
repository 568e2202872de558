//! The `deltaz` binary, run as a user runs it.

use deltaz_host::io::camera_file::{write_camera, CameraFile};
use deltaz_host::simulate::{simulate, true_camera, write_simulation, Scenario};
use std::path::Path;
use std::process::{Command, Output};

/// `deltaz ARGS` in the test's working directory.
pub fn deltaz(args: &[&str]) -> Output {
    deltaz_in(Path::new("."), args)
}

/// `deltaz ARGS` in `dir`.
pub fn deltaz_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run deltaz")
}

/// `deltaz ARGS` in `dir`, which must succeed (its stderr in the failure).
pub fn deltaz_ok(dir: &Path, args: &[&str]) -> Output {
    let out = deltaz_in(dir, args);
    assert!(
        out.status.success(),
        "deltaz {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// The words of a command line (no quoting).
pub fn words(line: &str) -> Vec<&str> {
    line.split_whitespace().collect()
}

/// A fresh folder `dir` with the paper rig simulated (its dots' image noise `image_sigma_px`,
/// draw `seed`) in sim/, the true camera in camera.json and the projector calibrated with it
/// into system.json (`deltaz calibrate projector` with `extra` arguments); the scenario.
pub fn paper_rig(dir: &Path, image_sigma_px: f64, seed: u64, extra: &[&str]) -> Scenario {
    let _ = std::fs::remove_dir_all(dir);
    std::fs::create_dir_all(dir).unwrap();
    let mut scenario = Scenario::paper();
    scenario.noise.image_sigma_px = image_sigma_px;
    write_simulation(&dir.join("sim"), &simulate(&scenario, seed)).unwrap();
    let (grid, inner) = true_camera(&scenario);
    write_camera(&dir.join("camera.json"), &CameraFile::init(&grid, inner)).unwrap();
    let calibrate = words(
        "calibrate projector --camera camera.json --control sim/plate_control.csv \
         --obs sim/plate_obs.csv --out system.json",
    );
    deltaz_ok(dir, &[&calibrate[..], extra].concat());
    scenario
}
