//! The frame a system knows and every output states: a `calibrate projector --model paper`
//! system is in the plate frame of its 1st plate image, a `calibrate projector` (joint) or
//! `calibrate system` one in the camera system; the PLY
//! header, the CSV's first line, the message and `--json` of `reconstruct` say which, and a frame
//! the system cannot give is refused.

use crate::cli::deltaz_in;
use crate::system::cli::calibrate_system;
use deltaz_host::io::system_file::{SystemFile, SystemFrame};
use deltaz_host::simulate::{simulate, write_simulation, Scenario};
use std::path::Path;
use std::process::Output;

fn ok(out: Output) -> String {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `reconstruct` of plate_obs.csv with `system` and `extra`: its JSON, the PLY's frame comment
/// and the CSV's first line.
fn reconstruct(dir: &Path, system: &str, extra: &[&str]) -> (serde_json::Value, String, String) {
    let mut args = vec![
        "reconstruct",
        "--system",
        system,
        "--obs",
        "plate_obs.csv",
        "--out",
        "cloud.ply",
        "--csv",
        "cloud.csv",
        "--json",
    ];
    args.extend_from_slice(extra);
    let json: serde_json::Value = serde_json::from_str(&ok(deltaz_in(dir, &args))).unwrap();
    let ply = std::fs::read(dir.join("cloud.ply")).unwrap();
    let end = ply.windows(10).position(|w| w == b"end_header").unwrap();
    let header = String::from_utf8_lossy(&ply[..end]).into_owned();
    let frame = header
        .lines()
        .find_map(|l| l.strip_prefix("comment frame: "))
        .unwrap_or_else(|| panic!("no frame comment in {header}"))
        .to_owned();
    let csv = std::fs::read_to_string(dir.join("cloud.csv")).unwrap();
    (json, frame, csv.lines().next().unwrap().to_owned())
}

#[test]
fn every_output_states_the_systems_frame() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_simulation(d, &simulate(&Scenario::desk(), 5)).unwrap();
    let camera = [
        "calibrate",
        "camera",
        "--init",
        "camera_init.json",
        "--obs",
        "camera_obs.csv",
        "--control",
        "camera_control.csv",
        "--out",
        "camera.json",
    ];
    ok(deltaz_in(d, &camera));
    let projector = [
        "calibrate",
        "projector",
        "--camera",
        "camera.json",
        "--control",
        "plate_control.csv",
        "--obs",
        "plate_obs.csv",
        "--out",
        "projector.json",
        "--model",
        "paper",
    ];
    let text = ok(deltaz_in(d, &projector));
    assert!(text.contains("in the plate frame of image p1"), "{text}");
    let (file, _) = SystemFile::load(&d.join("projector.json")).unwrap();
    let p1 = SystemFrame::Plate { image: "p1".into() };
    assert_eq!(file.content.frame, p1);
    let (json, ply, csv) = reconstruct(d, "projector.json", &[]);
    assert_eq!(json["frame"], "the plate frame of image p1");
    assert_eq!(ply, "the plate frame of image p1");
    assert_eq!(
        csv,
        format!(
            "# points in mm, the plate frame of image p1, calibration {}",
            file.fingerprint
        )
    );
    // Its points cannot be had in the camera system: refused, nothing written.
    std::fs::remove_file(d.join("cloud.ply")).unwrap();
    let refused = deltaz_in(
        d,
        &[
            "reconstruct",
            "--system",
            "projector.json",
            "--obs",
            "plate_obs.csv",
            "--out",
            "cloud.ply",
            "--frame",
            "camera",
        ],
    );
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success());
    assert!(
        err.contains("projector.json: the system is in the plate frame of image p1")
            && err.contains("cannot be given in the camera system"),
        "{err}"
    );
    assert!(!d.join("cloud.ply").exists());

    // The joint model (the default) calibrates in the camera system.
    let joint = &projector[..projector.len() - 2];
    let text = ok(deltaz_in(d, joint));
    assert!(text.contains("in the camera system"), "{text}");
    let (json, ply, _) = reconstruct(d, "projector.json", &[]);
    assert_eq!(
        (json["frame"].as_str(), ply.as_str()),
        (Some("the camera system"), "the camera system")
    );

    let json: serde_json::Value =
        serde_json::from_str(&ok(calibrate_system(d, &["--json"]))).unwrap();
    assert_eq!(json["frame"], "the camera system");
    let (file, _) = SystemFile::load(&d.join("system.json")).unwrap();
    assert_eq!(file.content.frame, SystemFrame::Camera);
    for extra in [&[][..], &["--frame", "camera"]] {
        let (json, ply, csv) = reconstruct(d, "system.json", extra);
        assert_eq!(json["frame"], "the camera system");
        assert_eq!(ply, "the camera system");
        assert!(
            csv.starts_with("# points in mm, the camera system,"),
            "{csv}"
        );
    }
    let datum = &file.content.projector.covariance.as_ref().unwrap();
    let datum = &datum.datum.as_ref().unwrap().image;
    let (json, ply, _) = reconstruct(d, "system.json", &["--frame", "plate"]);
    let plate = format!("the plate frame of image {datum} (the datum of `calibrate system`)");
    assert_eq!(json["frame"], plate.as_str());
    assert_eq!(ply, plate);
}

/// A system file of the format before frames were recorded is refused with what to do.
#[test]
fn a_system_without_its_frame_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("old.json");
    std::fs::write(
        &path,
        r#"{"format": "deltaz.system/1", "fingerprint": "0"}"#,
    )
    .unwrap();
    let err = SystemFile::load(&path).unwrap_err().to_string();
    assert!(
        err.contains("\"deltaz.system/1\" does not state its frame: calibrate again"),
        "{err}"
    );
}
