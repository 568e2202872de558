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
