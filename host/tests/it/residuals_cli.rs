//! `calibrate camera` writes every observation's residual next to camera.json; their RMS is the
//! file's; against control flattened to Z = 0 (grossly inconsistent) it warns, naming the worst
//! images and points.

use deltaz_host::simulate::{simulate, write_simulation, Scenario};
use std::path::Path;
use std::process::Command;

fn calibrate(dir: &Path, control: &str) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .args("calibrate camera --init camera_init.json --obs camera_obs.csv".split(' '))
        .args([
            "--control",
            control,
            "--out",
            "camera.json",
            "--plots",
            "plots",
        ])
        .current_dir(dir)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{stderr}");
    stderr
}

/// RMS per coordinate of the residual CSV's adjusted rows, and the file's stated RMS.
fn rms(dir: &Path) -> (f64, f64) {
    let text = std::fs::read_to_string(dir.join("camera.residuals.csv")).unwrap();
    let (mut sum, mut n) = (0.0, 0.0);
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f[7] == "0" {
            sum += f[4].parse::<f64>().unwrap().powi(2) + f[5].parse::<f64>().unwrap().powi(2);
            n += 2.0;
        }
    }
    let camera: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("camera.json")).unwrap()).unwrap();
    ((sum / n).sqrt(), camera["rms_px"].as_f64().unwrap())
}

#[test]
fn residuals_written_and_inconsistent_control_warned() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_simulation(d, &simulate(&Scenario::paper(), 6)).unwrap();
    let calm = calibrate(d, "camera_control.csv");
    assert!(!calm.contains("warning"), "{calm}");
    let (ours, stated) = rms(d);
    assert!(
        (ours - stated).abs() < 2e-3 && (ours - 0.5).abs() < 0.1,
        "{ours} vs {stated}"
    );
    let vectors = std::fs::read_to_string(d.join("plots/residual_vectors.svg")).unwrap();
    assert!(
        vectors.contains("s9: RMS") && vectors.contains("col (px)") && vectors.contains("1 px")
    );
    let histogram = std::fs::read_to_string(d.join("plots/residual_histogram.svg")).unwrap();
    assert!(
        histogram.contains("Residuals: 840 coordinates") && histogram.contains("expected: normal")
    );

    let control = std::fs::read_to_string(d.join("camera_control.csv")).unwrap();
    let flat: String = control
        .lines()
        .enumerate()
        .map(|(i, l)| {
            let mut f: Vec<&str> = l.split(',').collect();
            if i > 0 {
                f[3] = "0";
            }
            f.join(",") + "\n"
        })
        .collect();
    std::fs::write(d.join("flat.csv"), flat).unwrap();
    let loud = calibrate(d, "flat.csv");
    assert!(
        loud.contains("warning: σ0 is")
            && loud.contains("Worst images: s")
            && loud.contains("Worst points: T"),
        "{loud}"
    );
    let (ours, stated) = rms(d);
    assert!(
        (ours - stated).abs() < 0.01 * stated && stated > 5.0,
        "{ours} vs {stated}"
    );
}

/// `--plots` of `calibrate projector` and `calibrate system`: residual vectors per image and
/// their histogram (the plate images' control targets, resp. the camera's field), the rays'
/// miss distances, and an accuracy map of every plate image with each of its dots.
#[test]
fn projector_and_system_plots() {
    use deltaz_host::io::camera_file::{write_camera, CameraFile};
    use deltaz_host::io::observations::{read_observations, PointKind};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scenario = Scenario::paper();
    write_simulation(d, &simulate(&scenario, 6)).unwrap();
    let (grid, inner) = deltaz_host::simulate::true_camera(&scenario);
    write_camera(&d.join("camera.json"), &CameraFile::init(&grid, inner)).unwrap();
    let run = |args: &str| {
        let out = Command::new(env!("CARGO_BIN_EXE_deltaz"))
            .args(args.split_whitespace())
            .current_dir(d)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(out.status.success(), "{args}: {stderr}");
        stderr
    };
    let said = run(
        "calibrate projector --camera camera.json --control plate_control.csv \
         --obs plate_obs.csv --out system.json --plots pp",
    );
    assert!(said.contains("6 plots -> pp"), "{said}");
    run(
        "calibrate system --init camera_init.json --camera-obs camera_obs.csv \
         --camera-control camera_control.csv --control plate_control.csv --obs plate_obs.csv \
         --out all.json --plots sp",
    );
    let plate = read_observations(&d.join("plate_obs.csv")).unwrap();
    let read = |dir: &str, name: &str| std::fs::read_to_string(d.join(dir).join(name)).unwrap();
    let targets = plate.iter().filter(|o| o.kind != PointKind::Dot).count();
    // Both draw the plate targets' residuals of their final adjustment (calibrate system's
    // no longer the field's of the bundle adjustment that started it).
    for (dir, coordinates, image) in [("pp", 2 * targets, "p3"), ("sp", 2 * targets, "p3")] {
        let vectors = read(dir, "residual_vectors.svg");
        assert!(vectors.contains(&format!("{image}: RMS")), "{dir}");
        assert!(!vectors.contains("s9: RMS"), "{dir}");
        let histogram = read(dir, "residual_histogram.svg");
        assert!(
            histogram.contains(&format!("Residuals: {coordinates} coordinates")),
            "{dir}: {coordinates}"
        );
        assert!(read(dir, "ray_misses.svg").contains("(440 rays)"), "{dir}");
        for p in ["p1", "p2", "p3"] {
            let dots = plate
                .iter()
                .filter(|o| o.image == p && o.kind == PointKind::Dot)
                .count();
            let map = read(dir, &format!("plate_{p}.svg"));
            assert!(
                map.contains(&format!(
                    "Plate image {p}, reconstructed, in its plate frame: {dots} points"
                )),
                "{dir} {p}: {dots}"
            );
            assert_eq!(map.matches(r#"r="4""#).count(), 2 * dots, "{dir} {p}");
        }
    }
}
