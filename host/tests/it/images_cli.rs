//! `deltaz calibrate camera --images` and `deltaz calibrate projector --images` after
//! `deltaz simulate --images`: no observation file given by hand; the measured observations
//! are written next to the outputs. A folder without images is an error and writes nothing.

use crate::cli::deltaz_in;
use deltaz_host::io::observations::{read_observations, PointKind};
use std::process::Output;

/// The status lines (stderr) of a successful run.
fn ok(out: &Output) -> String {
    let status = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{status}");
    status
}

#[test]
fn calibrations_from_image_folders() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok(&deltaz_in(
        d,
        &["simulate", "--scenario", "paper", "--out", ".", "--images"],
    ));
    let run = deltaz_in(
        d,
        &[
            "calibrate",
            "camera",
            "--init",
            "camera_init.json",
            "--images",
            "images",
            "--only",
            "s",
            "--control",
            "camera_control.csv",
            "--out",
            "camera.json",
            "--json",
        ],
    );
    let camera = ok(&run);
    // One status line per image on stderr; stdout holds the result alone, one JSON object.
    assert!(
        camera.contains("s9: ") && camera.contains("control targets identified"),
        "{camera}"
    );
    let json: serde_json::Value = serde_json::from_slice(&run.stdout).expect("one JSON object");
    assert_eq!(json["stations"].as_array().map(Vec::len), Some(9), "{json}");
    let field = read_observations(&d.join("camera.obs.csv")).unwrap();
    assert!(field.len() >= 380, "{}", field.len());
    assert!(field.iter().all(|o| o.point.starts_with('T')));

    let projector = ok(&deltaz_in(
        d,
        &[
            "calibrate",
            "projector",
            "--camera",
            "camera.json",
            "--control",
            "plate_control.csv",
            "--images",
            "images",
            "--only",
            "p",
            "--out",
            "system.json",
        ],
    ));
    println!("{projector}");
    let plate = read_observations(&d.join("system.obs.csv")).unwrap();
    let dots = plate.iter().filter(|o| o.kind == PointKind::Dot).count();
    let control = plate.len() - dots;
    assert!(dots >= 1250, "{dots} dots");
    assert_eq!(control, 45);
    assert!(d.join("system.json").is_file());

    // An empty folder: an error naming it, nothing written.
    std::fs::create_dir(d.join("empty")).unwrap();
    let out = deltaz_in(
        d,
        &[
            "calibrate",
            "camera",
            "--init",
            "camera_init.json",
            "--images",
            "empty",
            "--control",
            "camera_control.csv",
            "--out",
            "again.json",
        ],
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("empty: no PNG, TIFF or JPEG images"), "{err}");
    assert!(!d.join("again.json").exists() && !d.join("again.obs.csv").exists());
}
