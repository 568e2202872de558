//! `deltaz demo` end to end: every output file, the PLY's vertex count, the device against the
//! host's f64 path, and accuracy figures beside their image-noise floor.

use std::process::Command;

#[test]
fn demo_writes_its_report() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let run = Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .args(["demo", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    for name in [
        "cloud.ply",
        "report.md",
        "report.json",
        "system.json",
        "residual_vectors.svg",
        "residual_histogram.svg",
        "plate_errors.svg",
        "torso_errors.svg",
    ] {
        assert!(out.join(name).is_file(), "{name} missing");
    }
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
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
