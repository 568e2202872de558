//! The command line: `deltaz simulate --images`, then `deltaz measure` on the rendered images;
//! a bad image fails with its name and the problem, and writes nothing.

use crate::cli::deltaz;
use deltaz_host::io::observations::read_observations;

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

/// A batch with an image without targets: the others are measured and written, the bad one
/// reported with its rejections per reason and a polarity hint, and the exit code says so.
#[test]
fn batch_goes_on_past_an_image_without_targets() {
    use deltaz_measure::render::{Background, BitDepth, Scene, Spot};
    let dir = tempfile::tempdir().unwrap();
    let scene = |level: f64, amplitude: f64| Scene {
        width: 200,
        height: 150,
        spots: (1..=3)
            .flat_map(|i| {
                (1..=2).map(move |j| Spot::circle(50.0 * i as f64, 50.0 * j as f64, 6.0, amplitude))
            })
            .collect(),
        background: Background {
            level,
            slope_col: 0.0,
            slope_row: 0.0,
            ripple: 0.0,
            ripple_period: 100.0,
        },
        falloff: 0.0,
        blur_sigma: 1.0,
        noise_sigma: 2.0,
        seed: 5,
    };
    let bright = dir.path().join("bright.png");
    let dark = dir.path().join("dark.png");
    scene(40.0, 150.0)
        .render()
        .save_png(&bright, BitDepth::Eight)
        .unwrap();
    scene(200.0, -150.0)
        .render()
        .save_png(&dark, BitDepth::Eight)
        .unwrap();
    let out = dir.path().join("obs.csv");
    let run = deltaz(&[
        "measure",
        dark.to_str().unwrap(),
        bright.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success(), "{err}");
    assert!(
        err.contains("dark.png: no targets found")
            && err.contains("6 dark targets found with --dark")
            && err.contains("1 of 2 images not measured"),
        "{err}"
    );
    let rows = read_observations(&out).unwrap();
    assert_eq!(rows.len(), 6);
    assert!(rows.iter().all(|o| o.image == "bright"));
}

/// `measure --system`: one line per image whose counts add up (identified + not = the image's
/// dots, the reasons = not), the identified dots being the rows written; `--verbose` adds one
/// line per dot not identified and nothing else.
#[test]
fn measure_with_a_system_summarises_each_image() {
    use deltaz_host::io::camera_file::{write_camera, CameraFile};
    use deltaz_host::simulate::{images, simulate, true_camera, write_simulation, Scenario};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scenario = Scenario::paper();
    write_simulation(d, &simulate(&scenario, 2)).unwrap();
    images::write_images(&scenario, 2, &images::ImageSpec::default(), d).unwrap();
    let (grid, inner) = true_camera(&scenario);
    write_camera(&d.join("camera.json"), &CameraFile::init(&grid, inner)).unwrap();
    let path = |name: &str| d.join(name).to_str().unwrap().to_owned();
    let run = |args: &[&str]| {
        let out = deltaz(args);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).unwrap()
    };
    run(&[
        "calibrate",
        "projector",
        "--camera",
        &path("camera.json"),
        "--control",
        &path("plate_control.csv"),
        "--obs",
        &path("plate_obs.csv"),
        "--out",
        &path("system.json"),
    ]);
    let plates = ["p1", "p2", "p3"].map(|p| path(&format!("images/{p}.png")));
    let measure = |extra: &[&str]| {
        let mut args = vec!["measure"];
        args.extend(plates.iter().map(String::as_str));
        let (system, out) = (path("system.json"), path("dots.csv"));
        args.extend([
            "--out", &out, "--system", &system, "--near", "1500", "--far", "2100",
        ]);
        args.extend(extra);
        run(&args)
    };
    let text = measure(&[]);
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 4, "{text}");
    let numbers = |line: &str| -> Vec<usize> {
        line.split(|c: char| !c.is_ascii_digit())
            .filter_map(|w| w.parse().ok())
            .collect()
    };
    let (mut identified, mut not) = (0, 0);
    for (line, image) in lines.iter().zip(["p1", "p2", "p3"]) {
        // "p1: 431 dots: 341 identified, 90 not (85 ambiguous, 2 conflicts, 3 with ...)"
        assert!(line.starts_with(&format!("{image}: ")), "{line}");
        let n = numbers(line);
        assert_eq!(n[2] + n[3], n[1], "{line}");
        assert_eq!(n[4] + n[5] + n[6], n[3], "{line}");
        identified += n[2];
        not += n[3];
    }
    assert!(not > 0, "{text}");
    let rows = read_observations(&d.join("dots.csv")).unwrap();
    assert_eq!(rows.len(), identified);
    assert!(
        lines[3].starts_with(&format!(
            "{identified} observations in 3 images ({not} dots not identified"
        )),
        "{text}"
    );
    let verbose = measure(&["--verbose"]);
    let extra: Vec<&str> = verbose.lines().filter(|l| !lines.contains(l)).collect();
    assert_eq!(extra.len(), not + 1, "{verbose}");
    assert!(extra[..not]
        .iter()
        .all(|l| l.starts_with("not identified: p")));
}
