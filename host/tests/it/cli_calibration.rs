//! End to end through the `deltaz` binary: simulate the paper rig, calibrate the camera, resect
//! the plate images with the result.

use crate::cli::deltaz;
use std::path::Path;

fn path(dir: &Path, name: &str) -> String {
    dir.join(name).to_string_lossy().into_owned()
}

#[test]
fn simulate_calibrate_resect() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = deltaz(&[
        "simulate",
        "--scenario",
        "paper",
        "--out",
        &path(d, "sim"),
        "--seed",
        "3",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let sim = d.join("sim");
    let out = deltaz(&[
        "calibrate",
        "camera",
        "--init",
        &path(&sim, "camera_init.json"),
        "--obs",
        &path(&sim, "camera_obs.csv"),
        "--control",
        &path(&sim, "camera_control.csv"),
        "--out",
        &path(d, "camera.json"),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let camera: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("camera.json")).unwrap()).unwrap();
    let f = camera["inner"]["f"].as_f64().unwrap();
    let sf = camera["sigma"]["f"].as_f64().unwrap();
    assert!((f - 46.981).abs() < 3.0 * sf, "f {f} ± {sf}");
    assert_eq!(camera["format"], "deltaz.camera/1");

    let out = deltaz(&[
        "resect",
        "--camera",
        &path(d, "camera.json"),
        "--obs",
        &path(&sim, "plate_obs.csv"),
        "--control",
        &path(&sim, "plate_control.csv"),
        "--out",
        &path(d, "poses.json"),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let poses: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("poses.json")).unwrap()).unwrap();
    // Table 2's 1st plane: Z0 1842.675 mm (the calibrated camera's f error moves Z0 by
    // ~ Z0 · δf / f, a few mm, so a loose bound).
    let z0 = poses["stations"][0]["Z0"].as_f64().unwrap();
    assert!((z0 - 1842.675).abs() < 15.0, "Z0 {z0}");
    assert_eq!(poses["stations"].as_array().unwrap().len(), 3);

    // Without control: a free network, same f within 3σ.
    let out = deltaz(&[
        "calibrate",
        "camera",
        "--init",
        &path(&sim, "camera_init.json"),
        "--obs",
        &path(&sim, "camera_obs.csv"),
        "--out",
        &path(d, "camera_free.json"),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let free: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("camera_free.json")).unwrap())
            .unwrap();
    let f_free = free["inner"]["f"].as_f64().unwrap();
    assert!((f_free - 46.981).abs() < 3.0 * free["sigma"]["f"].as_f64().unwrap());

    // A bad control file: error naming it, and no output.
    std::fs::write(d.join("bad.csv"), "point,X,Y\nT01,1,2\n").unwrap();
    let out = deltaz(&[
        "calibrate",
        "camera",
        "--init",
        &path(&sim, "camera_init.json"),
        "--obs",
        &path(&sim, "camera_obs.csv"),
        "--control",
        &path(d, "bad.csv"),
        "--out",
        &path(d, "camera2.json"),
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.csv:1: missing column `Z`"), "{err}");
    assert!(!d.join("camera2.json").exists());
}
