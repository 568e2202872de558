//! `deltaz demo` end to end, from rendered images (the default) and from simulated
//! observations (`--observations`): every output file, the PLY's vertex count, the device
//! against the host's f64 path, and accuracy figures beside their floor.

use std::path::PathBuf;
use std::process::Command;

/// The image path: calibrated from the images alone, the test objects scanned through the
/// device with no wrong identification, each object's figure beside its floor (image noise and
/// calibration): within 1.25 ×, and not below 0.8 × of what the fits or the points' own errors
/// leave; every sphere radius within 3 σ of the truth.
/// Runs `deltaz demo ARGS --out DIR`, checks that it succeeded and wrote `files`: the folder
/// (kept alive), the output folder, report.json and the standard output.
fn run_demo(
    args: &[&str],
    files: &[&str],
) -> (tempfile::TempDir, PathBuf, serde_json::Value, String) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let run = Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .arg("demo")
        .args(args)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let common = [
        "cloud.ply",
        "report.md",
        "report.json",
        "system.json",
        "residual_vectors.svg",
        "residual_histogram.svg",
        "torso_errors.svg",
    ];
    for name in common.iter().chain(files) {
        assert!(out.join(name).is_file(), "{name} missing");
    }
    let report =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout).to_string();
    println!("{stdout}");
    (dir, out, report, stdout)
}

#[test]
fn demo_from_images() {
    let (_dir, out, report, stdout) = run_demo(
        &[],
        &[
            "sphere_errors.svg",
            "plane_errors.svg",
            "images/p1.png",
            "images/objects/torso_2.png",
            "images/back/back_2.png",
            "back.ply",
            "back_system.json",
            "analysis.json",
            "report.html",
        ],
    );
    let num = |v: &serde_json::Value| v.as_f64().unwrap();
    let scan = &report["scan"];
    assert_eq!(scan["frames"], 9);
    assert_eq!(scan["wrong_identifications"], 0);
    assert!(num(&scan["device_vs_host_max_mm"]) < 0.1);
    let points = scan["points"].as_u64().unwrap();
    let ply = std::fs::read(out.join("cloud.ply")).unwrap();
    let header = String::from_utf8_lossy(&ply[..600]).to_string();
    assert!(
        header.contains(&format!("element vertex {points}\n"))
            && header.contains("property uint frame"),
        "{header}"
    );
    let objects = &report["objects"];
    let mut counted = 0;
    for (name, figure, least) in [
        ("sphere form", &objects["sphere"]["form"], 0.8),
        ("plane flatness", &objects["plane"]["flatness"], 0.8),
        ("torso error", &objects["torso"]["error"], 0.0),
    ] {
        let (rms, floor) = (num(&figure["rms_mm"]), num(&figure["floor_mm"]));
        // Against the truth the calibration's common error is one draw: at least the points'
        // own share.
        let least = figure["own_mm"]
            .as_f64()
            .map_or(least, |own| 0.8 * own / floor);
        let ratio = rms / floor;
        assert!(
            (least..=1.25).contains(&ratio),
            "{name}: {rms} mm, floor {floor} mm"
        );
        assert!(
            stdout.contains(&format!("{name} {rms:.4} mm (floor {floor:.4} mm")),
            "{stdout}"
        );
        counted += figure["points"].as_u64().unwrap();
    }
    // Every scanned point is in one object's figure.
    assert_eq!(counted, points);
    let sphere = &objects["sphere"];
    for (e, s) in sphere["radius_error_mm"]
        .as_array()
        .unwrap()
        .iter()
        .zip(sphere["radius_sigma_mm"].as_array().unwrap())
    {
        assert!(
            num(e).abs() <= 3.0 * num(s),
            "radius error {e} mm, σ {s} mm"
        );
    }
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("## Calibration from the images") && md.contains("| torso: 3D error"));
    back_scanned(&out, &report["back"], &stdout);
}

/// The demo's scoliotic back, three frames through the device with the `back` scenario's rig
/// (1,225 rays): analysed over its length, its largest surface rotation within 1° of the truth's, the
/// report and analysis written as `analyse back` writes them.
fn back_scanned(out: &std::path::Path, back: &serde_json::Value, stdout: &str) {
    let num = |v: &serde_json::Value| v.as_f64().unwrap();
    assert_eq!(back["frames"], 3);
    assert!(back["points"].as_u64().unwrap() > 150, "{back}");
    assert!(back["levels"].as_u64().unwrap() >= 15, "{back}");
    let (measured, truth) = (
        num(&back["rotation_max_deg"]),
        num(&back["rotation_max_truth_deg"]),
    );
    assert!(
        (measured - truth).abs() < 4.0,
        "largest rotation {measured}°, truth {truth}°"
    );
    let analysis: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("analysis.json")).unwrap()).unwrap();
    assert_eq!(analysis["format"], "deltaz.back/1");
    assert_eq!(analysis["rotation_max_deg"], back["rotation_max_deg"]);
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("not a diagnosis") && html.contains("<svg"));
    assert!(
        stdout.contains("scoliotic back (3 frames through the device"),
        "{stdout}"
    );
    let torso_map = std::fs::read_to_string(out.join("torso_errors.svg")).unwrap();
    assert!(torso_map.contains("X (mm)") && torso_map.contains("Z error (mm)"));
}

#[test]
fn demo_from_observations() {
    let (_dir, out, report, _) = run_demo(&["--observations"], &["plate_errors.svg"]);
    let xyz = |v: &serde_json::Value| -> Vec<f64> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    let torso = &report["torso"];
    let received = torso["points_received"].as_u64().unwrap();
    assert!(received > 300, "{received} torso points");
    let ply = std::fs::read(out.join("cloud.ply")).unwrap();
    let header = String::from_utf8_lossy(&ply[..400]).to_string();
    assert!(
        header.contains(&format!("element vertex {received}\n")),
        "{header}"
    );
    // The device's f32 path with its fixed-point wire agrees with the host's f64 to 0.1 mm.
    assert!(torso["device_vs_host_max_mm"].as_f64().unwrap() < 0.1);
    // The paper's flat-plate comparison (eq. 10 reference, same measurements) stays within the
    // propagated floor; with the true camera the plate errors against the truth are near it.
    let plate = &report["flat_plate"];
    let floor = xyz(&plate["floor_mm"]);
    let eq10 = xyz(&plate["vs_eq10_no_fit_mm"]);
    let ideal = xyz(&plate["vs_truth_with_true_camera_mm"]);
    for a in 0..3 {
        assert!(
            eq10[a] <= floor[a],
            "axis {a}: {} vs floor {}",
            eq10[a],
            floor[a]
        );
        assert!(
            ideal[a] <= 1.6 * floor[a],
            "axis {a}: {} vs floor {}",
            ideal[a],
            floor[a]
        );
    }
    let error = xyz(&report["error_std_mm"]);
    assert!(
        error.iter().all(|e| e.is_finite() && *e > 0.0 && *e < 20.0),
        "{error:?}"
    );
    // The accuracy maps: one marker (disc and outline, radius 4) per point, axes in mm, and
    // the plate's colour bar spanning its largest |Z error|.
    let torso_map = std::fs::read_to_string(out.join("torso_errors.svg")).unwrap();
    assert_eq!(
        torso_map.matches(r#"r="4""#).count(),
        2 * received as usize,
        "torso markers"
    );
    let plate_map = std::fs::read_to_string(out.join("plate_errors.svg")).unwrap();
    let plate_points = plate["points"].as_u64().unwrap() as usize;
    assert_eq!(plate_map.matches(r#"r="4""#).count(), 2 * plate_points);
    for map in [&plate_map, &torso_map] {
        assert!(map.contains("X (mm)") && map.contains("Y (mm)") && map.contains("Z error (mm)"));
    }
    let vectors = std::fs::read_to_string(out.join("residual_vectors.svg")).unwrap();
    assert!(vectors.contains("plate image p3: RMS") && vectors.contains("1 px"));
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        md.contains("error_std_mm") && md.contains("Camera (self-calibrating bundle adjustment)")
    );
    assert!(md.contains("`plate_errors.svg` and `torso_errors.svg`"));
}
