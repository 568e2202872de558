//! The command line: `deltaz simulate --images`, then `deltaz measure` on the rendered images;
//! a bad image fails with its name and the problem, and writes nothing.

use deltaz_host::io::observations::read_observations;
use std::process::Command;

fn deltaz(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .args(args)
        .output()
        .expect("run deltaz")
}

#[test]
fn simulate_images_then_measure() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    let sim = deltaz(&[
        "simulate",
        "--scenario",
        "paper",
        "--out",
        out,
        "--images",
        "--sixteen-bit",
    ]);
    assert!(
        sim.status.success(),
        "{}",
        String::from_utf8_lossy(&sim.stderr)
    );
    let images = dir.path().join("images");
    let obs = dir.path().join("measured.csv");
    let s1 = images.join("s1.png");
    let measured = deltaz(&[
        "measure",
        s1.to_str().unwrap(),
        "--out",
        obs.to_str().unwrap(),
    ]);
    assert!(
        measured.status.success(),
        "{}",
        String::from_utf8_lossy(&measured.stderr)
    );
    let rows = read_observations(&obs).unwrap();
    let truth = read_observations(&images.join("centres.csv")).unwrap();
    let s1_truth: Vec<_> = truth.iter().filter(|o| o.image == "s1").collect();
    assert_eq!(rows.len(), s1_truth.len());
    for o in &rows {
        let miss = s1_truth
            .iter()
            .map(|t| (t.col - o.col).hypot(t.row - o.row))
            .fold(f64::INFINITY, f64::min);
        assert!(
            o.image == "s1" && miss < 0.05,
            "{} {}: {miss}",
            o.image,
            o.point
        );
    }

    let bad = dir.path().join("bad.png");
    std::fs::write(&bad, &std::fs::read(&s1).unwrap()[..500]).unwrap();
    let none = dir.path().join("none.csv");
    let failed = deltaz(&[
        "measure",
        s1.to_str().unwrap(),
        bad.to_str().unwrap(),
        "--out",
        none.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&failed.stderr);
    assert!(
        !failed.status.success() && err.contains("bad.png") && err.contains("corrupt or truncated"),
        "{err}"
    );
    assert!(!none.exists(), "no partial output");
}
