//! `--json` and `--quiet`: one JSON object on stdout with the figures, nothing on stderr when
//! quiet; the PLY of `reconstruct` read back by `compare`, its header naming units, frame and
//! the calibration's fingerprint, a `frame` property (the image's index) that tells merged images apart.

use crate::cli::{deltaz_in, words};
use deltaz_host::io::camera_file::{write_camera, CameraFile};
use deltaz_host::simulate::{simulate, true_camera, write_simulation, Scenario};
use serde_json::Value;
use std::path::Path;

/// Runs `deltaz ARGS --json --quiet` in `dir`: its JSON, after checking stderr is empty.
fn json(dir: &Path, command: &str) -> Value {
    let args = words(command);
    let out = deltaz_in(dir, &[&args[..], &["--json", "--quiet"]].concat());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && stderr.is_empty(),
        "{args:?}: {stderr}"
    );
    serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("{args:?}: {e}: {}", String::from_utf8_lossy(&out.stdout)))
}

#[test]
fn json_figures_and_ply_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut scenario = Scenario::paper();
    scenario.noise.image_sigma_px = 0.1;
    write_simulation(d, &simulate(&scenario, 3)).unwrap();
    let (grid, inner) = true_camera(&scenario);
    write_camera(&d.join("true.json"), &CameraFile::init(&grid, inner)).unwrap();

    let camera = json(
        d,
        "calibrate camera --init camera_init.json --obs camera_obs.csv --control camera_control.csv --out camera.json",
    );
    let f = camera["inner"]["f"].as_f64().unwrap();
    let sf = camera["sigma"]["f"].as_f64().unwrap();
    assert!((f - 46.981).abs() < 4.0 * sf, "f {f} ± {sf}");
    assert_eq!(camera["stations"].as_array().unwrap().len(), 9);

    let poses = json(
        d,
        "resect --camera true.json --obs plate_obs.csv --control plate_control.csv",
    );
    // Table 2's 1st plate image: Z0 1842.675 mm.
    let z0 = poses["stations"][0]["Z0"].as_f64().unwrap();
    assert!((z0 - 1842.675).abs() < 2.0, "{z0}");

    let system = json(
        d,
        "calibrate projector --camera true.json --control plate_control.csv --obs plate_obs.csv --out system.json --image-sigma-px 0.1",
    );
    assert_eq!(system["rays"], 440);
    let fingerprint = system["fingerprint"].as_str().unwrap().to_owned();

    // The device reads the fingerprint back: one object, nothing on stderr with --quiet.
    let upload = json(
        d,
        "device upload system.json --near 1600 --far 1900 --method paper",
    );
    assert_eq!(upload["fingerprint"], fingerprint.as_str(), "{upload}");
    assert_eq!(upload["rays"], 440);
    assert_eq!(upload["generation"], 1);
    assert_eq!(upload["method"], "paper");
    assert_eq!(upload["identification"]["far_mm"], 1900.0);
    assert_eq!(upload["persistent"], false);

    // The whole-system adjustment: its projector centre with σ, in the camera system (Table 3's
    // centre is about 500 mm to the side of the camera, in the direction −x).
    let all = json(
        d,
        "calibrate system --init camera_init.json --camera-obs camera_obs.csv \
         --camera-control camera_control.csv --control plate_control.csv --obs plate_obs.csv \
         --out all.json",
    );
    let x = all["centre_mm"][0].as_f64().unwrap();
    let sx = all["centre_sigma_mm"][0].as_f64().unwrap();
    assert!(x < -400.0 && sx > 0.0 && sx < 20.0, "{all}");
    assert_eq!(all["rays"], 440);

    // One image: labels are ray ids, as in the CSV; compare finds the identity.
    let plate = std::fs::read_to_string(d.join("plate_obs.csv")).unwrap();
    let p1: String = plate
        .lines()
        .filter(|l| l.starts_with("image") || (l.starts_with("p1,") && l.ends_with(",dot")))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(d.join("p1.csv"), p1).unwrap();
    let cloud = json(
        d,
        "reconstruct --system system.json --obs p1.csv --out p1.ply --csv p1_points.csv",
    );
    let points = cloud["points"].as_u64().unwrap();
    assert!(points > 400, "{points}");
    assert_eq!(cloud["fingerprint"], fingerprint.as_str());
    let ply = std::fs::read(d.join("p1.ply")).unwrap();
    let header = String::from_utf8_lossy(&ply[..600]);
    assert!(header.contains(&format!("comment calibration fingerprint: {fingerprint}\n")));
    assert!(
        header.contains(
            "comment frame: the camera system
"
        ) && header.contains("property uint frame")
    );
    let same = json(
        d,
        "compare --reconstructed p1.ply --reference p1_points.csv",
    );
    assert!(
        (same["lambda"].as_f64().unwrap() - 1.0).abs() < 1e-9,
        "{same}"
    );
    assert_eq!(
        same["residuals"].as_array().map_or(0, Vec::len) as u64,
        points
    );
    assert!(same["mse"]
        .as_array()
        .unwrap()
        .iter()
        .all(|v| v.as_f64().unwrap() < 1e-6));

    // Three images merged: a `frame` property tells them apart.
    json(
        d,
        "reconstruct --system system.json --obs plate_obs.csv --out all.ply --ascii",
    );
    let all = std::fs::read_to_string(d.join("all.ply")).unwrap();
    assert!(all.contains("property uint frame\n"));
    let frames: std::collections::BTreeSet<&str> = all
        .split("end_header\n")
        .nth(1)
        .unwrap()
        .lines()
        .map(|l| l.rsplit(' ').next().unwrap())
        .collect();
    assert_eq!(frames.into_iter().collect::<Vec<_>>(), ["0", "1", "2"]);
}
