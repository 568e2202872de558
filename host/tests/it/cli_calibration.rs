//! End to end through the `deltaz` binary: simulate the paper rig, calibrate the camera, resect
//! the plate images with the result.

use crate::cli::{deltaz_in, deltaz_ok, words};
use std::path::Path;

/// The JSON file `name` in `dir`.
fn json(dir: &Path, name: &str) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join(name)).unwrap()).unwrap()
}

#[test]
fn simulate_calibrate_resect() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    deltaz_ok(d, &words("simulate --scenario paper --out sim --seed 3"));
    deltaz_ok(
        d,
        &words("calibrate camera --init sim/camera_init.json --obs sim/camera_obs.csv --control sim/camera_control.csv --out camera.json"),
    );
    let camera = json(d, "camera.json");
    let f = camera["inner"]["f"].as_f64().unwrap();
    let sf = camera["sigma"]["f"].as_f64().unwrap();
    assert!((f - 46.981).abs() < 3.0 * sf, "f {f} ± {sf}");
    assert_eq!(camera["format"], "deltaz.camera/1");

    deltaz_ok(
        d,
        &words("resect --camera camera.json --obs sim/plate_obs.csv --control sim/plate_control.csv --out poses.json"),
    );
    let poses = json(d, "poses.json");
    // Table 2's 1st plane: Z0 1842.675 mm (the calibrated camera's f error moves Z0 by
    // ~ Z0 · δf / f, a few mm, so a loose bound).
    let z0 = poses["stations"][0]["Z0"].as_f64().unwrap();
    assert!((z0 - 1842.675).abs() < 15.0, "Z0 {z0}");
    assert_eq!(poses["stations"].as_array().unwrap().len(), 3);

    // Without control: a free network, same f within 3σ.
    deltaz_ok(
        d,
        &words("calibrate camera --init sim/camera_init.json --obs sim/camera_obs.csv --out camera_free.json"),
    );
    let free = json(d, "camera_free.json");
    let f_free = free["inner"]["f"].as_f64().unwrap();
    assert!((f_free - 46.981).abs() < 3.0 * free["sigma"]["f"].as_f64().unwrap());

    // A bad control file: error naming it, and no output.
    std::fs::write(d.join("bad.csv"), "point,X,Y\nT01,1,2\n").unwrap();
    let out = deltaz_in(
        d,
        &words("calibrate camera --init sim/camera_init.json --obs sim/camera_obs.csv --control bad.csv --out camera2.json"),
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.csv:1: missing column `Z`"), "{err}");
    assert!(!d.join("camera2.json").exists());
}
