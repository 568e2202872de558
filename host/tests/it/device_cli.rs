//! `deltaz device ...` through the binary: the in-process device, clear errors, and a stream whose
//! points agree with `deltaz reconstruct` on the same system.

use crate::cli::deltaz;
use deltaz_shared::protocol::PROTOCOL_VERSION;
use std::collections::HashMap;
use std::path::Path;

fn ok(args: &[&str]) -> String {
    let out = deltaz(args);
    assert!(
        out.status.success(),
        "deltaz {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr)
}

fn err(args: &[&str]) -> String {
    let out = deltaz(args);
    assert!(!out.status.success(), "deltaz {args:?} should fail");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// `image,point` → (X, Y, Z) of a points CSV.
fn points(path: &Path) -> HashMap<(String, String), [f64; 3]> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let xyz = [f[2], f[3], f[4]].map(|v| v.parse::<f64>().unwrap());
            ((f[0].to_owned(), f[1].to_owned()), xyz)
        })
        .collect()
}

#[test]
fn info_and_link_errors() {
    let info = ok(&["device", "info"]);
    assert!(
        info.contains(&format!("protocol {PROTOCOL_VERSION}")) && info.contains("no calibration"),
        "{info}"
    );
    let out = deltaz(&["device", "info", "--json"]);
    assert!(out.status.success());
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    assert_eq!(json["protocol"], PROTOCOL_VERSION);
    assert!(json["boot_error"].is_null(), "{json}");
    assert_eq!(json["ray_capacity"], deltaz_shared::protocol::MAX_RAYS);
    assert!(json["calibration"].is_null(), "{json}");
    let absent = err(&["device", "info", "--port", "/dev/deltaz-none"]);
    assert!(absent.contains("no device at /dev/deltaz-none"), "{absent}");
    let both = err(&["device", "info", "--port", "/dev/x", "--qemu=/x.elf"]);
    assert!(both.contains("exclude each other"), "{both}");
}

#[test]
fn stream_matches_reconstruct() {
    let dir = tempfile::tempdir().unwrap();
    let p = |name: &str| dir.path().join(name).display().to_string();
    ok(&["simulate", "--scenario", "paper", "--out", &p("")]);
    ok(&[
        "calibrate",
        "camera",
        "--init",
        &p("camera_init.json"),
        "--obs",
        &p("camera_obs.csv"),
        "--control",
        &p("camera_control.csv"),
        "--out",
        &p("camera.json"),
    ]);
    ok(&[
        "calibrate",
        "projector",
        "--camera",
        &p("camera.json"),
        "--control",
        &p("plate_control.csv"),
        "--obs",
        &p("plate_obs.csv"),
        "--out",
        &p("system.json"),
        // The 1st plate image's frame, where `stream --simulate` puts its plates.
        "--model",
        "paper",
    ]);
    let upload = ok(&["device", "upload", &p("system.json")]);
    assert!(upload.contains("read back, generation 1"), "{upload}");
    let stream = ok(&[
        "device",
        "stream",
        "--system",
        &p("system.json"),
        "--obs",
        &p("plate_obs.csv"),
        "--csv",
        &p("device.csv"),
        "--out",
        &p("device.ply"),
    ]);
    assert!(
        stream.contains("dots/s") && stream.contains(", 0 without a point ("),
        "{stream}"
    );
    // --json: one object on stdout with the stream's counts and the device's statistics.
    let out = deltaz(&[
        "device",
        "stream",
        "--system",
        &p("system.json"),
        "--simulate",
        "6",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    assert_eq!(json["frames"], 6);
    let n = json["points"].as_u64().unwrap() + json["without_point"].as_u64().unwrap();
    assert!(n > 1000, "{json}");
    assert_eq!(json["stats"]["points"].as_u64(), Some(n), "{json}");
    assert_eq!(json["stats"]["bad_frames"], 0);
    assert_eq!(
        json["stats"]["stack_peak_bytes"], 0,
        "the in-process device measures none"
    );
    assert_eq!(json["line"]["resent"], 0);
    ok(&[
        "reconstruct",
        "--system",
        &p("system.json"),
        "--obs",
        &p("plate_obs.csv"),
        "--out",
        &p("host.ply"),
        "--csv",
        &p("host.csv"),
    ]);
    let device = points(&dir.path().join("device.csv"));
    let host = points(&dir.path().join("host.csv"));
    assert_eq!(device.len(), host.len());
    assert!(device.len() >= 1000, "{} points", device.len());
    // The device sees centroids rounded to 1/64 pixel (≤ 1/128 px per axis): at 1.8 m with
    // f = 47 mm and 45 µm pixels one pixel spans about 1.8 mm, so ≤ 0.02 mm in X and Y, and
    // several times that in Z, the depth from a 490 mm baseline (0.06 mm measured).
    let worst = device
        .iter()
        .map(|(k, d)| {
            let h = host[k];
            (0..3).map(|i| (d[i] - h[i]).abs()).fold(0.0, f64::max)
        })
        .fold(0.0, f64::max);
    println!("device stream vs deltaz reconstruct: worst {worst:.4} mm per axis");
    assert!(worst < 0.1, "device vs reconstruct: {worst} mm");
    assert!(
        std::fs::metadata(dir.path().join("device.ply"))
            .unwrap()
            .len()
            > 1000
    );
    // Unlabelled: the device identifies the dots of the plate Z = 0 (about 1843 mm from the
    // camera) and gives every point the labelled stream gives, under the same ray id.
    let system = p("system.json");
    let stream = |extra: &[&str], csv: &str| {
        let mut args = vec!["device", "stream", "--system", &system];
        args.extend(["--simulate", "1", "--csv", csv]);
        args.extend(extra);
        ok(&args)
    };
    let identified = stream(
        &["--identify", "--near", "1780", "--far", "1900"],
        &p("identified.csv"),
    );
    assert!(
        identified.contains("440 dots: 440 points") && identified.contains(" 0 not identified"),
        "{identified}"
    );
    stream(&[], &p("labelled.csv"));
    assert_eq!(
        points(&dir.path().join("identified.csv")),
        points(&dir.path().join("labelled.csv"))
    );
    // A depth range wider than the plate's: some dots are ambiguous. Every dot sent is counted
    // once (points, not identified, without a point, each by reason), and the CSV and the PLY
    // hold the points.
    let counts = |extra: &[&str], csv: &str| {
        let mut args = vec!["device", "stream", "--system", &system, "--simulate", "3"];
        args.extend(["--json", "--csv", csv]);
        args.extend(extra);
        let out = deltaz(&args);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice::<serde_json::Value>(&out.stdout).expect("one JSON object")
    };
    let n = |v: &serde_json::Value| v.as_u64().unwrap();
    let labelled = counts(&[], &p("labelled3.csv"));
    let wide = counts(
        &[
            "--identify",
            "--near",
            "1600",
            "--far",
            "1900",
            "--out",
            &p("wide.ply"),
        ],
        &p("wide.csv"),
    );
    assert_eq!(wide["dots"], labelled["dots"], "{wide}");
    assert_eq!(n(&labelled["points"]), n(&labelled["dots"]), "{labelled}");
    let reasons = wide["reasons"].as_object().unwrap();
    let [unidentified, without] = [
        ["unassigned", "ambiguous", "conflict"].as_slice(),
        &["unknown_ray", "degenerate", "out_of_range", "off_sensor"],
    ]
    .map(|keys| keys.iter().map(|k| n(&reasons[*k])).sum::<u64>());
    assert_eq!(unidentified, n(&wide["unidentified"]), "{wide}");
    assert_eq!(without, n(&wide["without_point"]), "{wide}");
    assert!(unidentified > 0, "{wide}");
    assert_eq!(
        n(&wide["points"]) + unidentified + without,
        n(&wide["dots"]),
        "{wide}"
    );
    let rows = std::fs::read_to_string(dir.path().join("wide.csv")).unwrap();
    assert_eq!(rows.lines().count() as u64 - 2, n(&wide["points"]));
    let (comment, rows) = rows.split_once('\n').unwrap();
    assert!(comment.starts_with("# points in mm, the plate frame of image p1, calibration "));
    assert!(rows.starts_with("image,point,X,Y,Z,miss\n"));
    let ply = std::fs::read(dir.path().join("wide.ply")).unwrap();
    let header = String::from_utf8_lossy(&ply[..800]);
    assert!(
        header.contains(&format!("element vertex {}\n", n(&wide["points"])))
            && header.contains("comment calibration fingerprint: ")
            && header.contains("property uint frame\n"),
        "{header}"
    );
    let refused = err(&[
        "device",
        "stream",
        "--system",
        &p("system.json"),
        "--simulate",
        "1",
        "--identify",
    ]);
    assert!(refused.contains("no depth range"), "{refused}");
}
