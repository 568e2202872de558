//! `deltaz calibrate projector` and `deltaz reconstruct` on simulated files, and their bad
//! input: rays seen on one plane, coplanar plate control, an unknown ray, an edited system.json.
//! Nothing is written when they fail.

use crate::cli::deltaz_in;
use deltaz_host::io::camera_file::{write_camera, CameraFile};
use deltaz_host::simulate::{simulate, true_camera, write_simulation, Scenario};
use std::path::Path;
use std::process::Output;

/// A simulated paper rig at 0.1 px with the true camera as camera.json.
fn setup(dir: &Path) {
    let mut scenario = Scenario::paper();
    scenario.noise.image_sigma_px = 0.1;
    let sim = simulate(&scenario, 2);
    write_simulation(dir, &sim).unwrap();
    let (grid, inner) = true_camera(&scenario);
    write_camera(&dir.join("camera.json"), &CameraFile::init(&grid, inner)).unwrap();
}

fn calibrate(dir: &Path, control: &str, obs: &str, model: &str) -> Output {
    calibrate_with(dir, control, obs, model, &[])
}

fn calibrate_with(dir: &Path, control: &str, obs: &str, model: &str, extra: &[&str]) -> Output {
    let mut args = vec![
        "calibrate",
        "projector",
        "--camera",
        "camera.json",
        "--control",
        control,
        "--obs",
        obs,
        "--out",
        "system.json",
        "--model",
        model,
        "--image-sigma-px",
        "0.1",
    ];
    args.extend_from_slice(extra);
    deltaz_in(dir, &args)
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn calibrate_then_reconstruct() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    setup(d);
    // The default (`joint`) last: its system, in the camera system, reconstructs below.
    for model in ["paper", "noncentral", "joint"] {
        let out = calibrate(d, "plate_control.csv", "plate_obs.csv", model);
        assert!(out.status.success(), "{model}: {}", stderr(&out));
        let system: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(d.join("system.json")).unwrap()).unwrap();
        assert_eq!(system["format"], "deltaz.system/2");
        let frame = match model {
            "paper" => serde_json::json!({"kind": "plate", "image": "p1"}),
            _ => serde_json::json!({"kind": "camera"}),
        };
        assert_eq!(system["frame"], frame, "{model}");
        assert_eq!(system["projector"]["rays"].as_array().unwrap().len(), 440);
        assert_eq!(system["fingerprint"].as_str().unwrap().len(), 16);
    }
    // The 3rd image's dots through the system: back on the 3rd plate, 1639 mm in front of the
    // camera (Table 2's Z0).
    let obs = std::fs::read_to_string(d.join("plate_obs.csv")).unwrap();
    let mut dots = String::from("image,point,col,row,kind\n");
    for line in obs
        .lines()
        .filter(|l| l.starts_with("p3,") && l.ends_with(",dot"))
    {
        dots += line;
        dots.push('\n');
    }
    std::fs::write(d.join("dots.csv"), dots).unwrap();
    let out = deltaz_in(
        d,
        &[
            "reconstruct",
            "--system",
            "system.json",
            "--obs",
            "dots.csv",
            "--out",
            "cloud.ply",
            "--csv",
            "cloud.csv",
            "--sigma-px",
            "0.1",
            "--ascii",
        ],
    );
    assert!(out.status.success(), "{}", stderr(&out));
    let csv = std::fs::read_to_string(d.join("cloud.csv")).unwrap();
    let rows: Vec<Vec<f64>> = csv
        .lines()
        .skip(2)
        .map(|l| l.split(',').skip(1).map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 440);
    let mean_z = rows.iter().map(|r| r[3]).sum::<f64>() / rows.len() as f64;
    assert!((mean_z + 1639.4).abs() < 2.0, "mean Z {mean_z}");
    let worst = rows.iter().map(|r| r[7]).fold(0.0, f64::max);
    assert!(
        rows.iter().all(|r| r[7] > 0.3) && worst < 2.0,
        "σZ up to {worst}"
    );
    let ply = std::fs::read_to_string(d.join("cloud.ply")).unwrap();
    assert!(ply.contains("element vertex 440\n") && ply.contains("property double sigma_z\n"));
}

#[test]
fn bad_input_is_named_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    setup(d);
    // Coplanar control: every point flattened onto the plate.
    let control = std::fs::read_to_string(d.join("plate_control.csv")).unwrap();
    let flat: String = control
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if i == 0 {
                format!("{l}\n")
            } else {
                let mut f: Vec<&str> = l.split(',').collect();
                f[3] = "0";
                f.join(",") + "\n"
            }
        })
        .collect();
    std::fs::write(d.join("flat.csv"), flat).unwrap();
    let out = calibrate(d, "flat.csv", "plate_obs.csv", "paper");
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains("flat.csv: the plate's control points are coplanar"),
        "{}",
        stderr(&out)
    );
    assert!(!d.join("system.json").exists());

    // Ray 305 seen on the 1st plate only.
    let obs = std::fs::read_to_string(d.join("plate_obs.csv")).unwrap();
    let lonely: String = obs
        .lines()
        .filter(|l| !(l.starts_with("p2,305,") || l.starts_with("p3,305,")))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(d.join("lonely.csv"), lonely).unwrap();
    let out = calibrate(d, "plate_control.csv", "lonely.csv", "joint");
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("warning: 1 rays seen on one plate only, determined through the centre without redundancy: 305"),
        "{}",
        stderr(&out)
    );

    // A good system, then an unknown ray and a hand-edited system.
    assert!(calibrate(d, "plate_control.csv", "plate_obs.csv", "paper")
        .status
        .success());
    std::fs::write(
        d.join("unknown.csv"),
        "image,point,col,row\nf1,305,300,200\nf1,2121,310,210\n",
    )
    .unwrap();
    let out = deltaz_in(
        d,
        &[
            "reconstruct",
            "--system",
            "system.json",
            "--obs",
            "unknown.csv",
            "--out",
            "u.ply",
        ],
    );
    assert!(!out.status.success());
    assert!(
        stderr(&out)
            .contains("unknown.csv:3: ray 2121 at (310, 210): the projector has no ray 2121"),
        "{}",
        stderr(&out)
    );
    assert!(!d.join("u.ply").exists());
    let text = std::fs::read_to_string(d.join("system.json")).unwrap();
    let mut system: serde_json::Value = serde_json::from_str(&text).unwrap();
    system["projector"]["rays"][3]["n"] = serde_json::json!(-0.5);
    std::fs::write(
        d.join("edited.json"),
        serde_json::to_string(&system).unwrap(),
    )
    .unwrap();
    let out = deltaz_in(
        d,
        &[
            "reconstruct",
            "--system",
            "edited.json",
            "--obs",
            "unknown.csv",
            "--out",
            "u.ply",
        ],
    );
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains("direction cosines are not a unit vector"),
        "{}",
        stderr(&out)
    );
    assert!(!d.join("u.ply").exists());
}

/// Reconstruction streams in batches of 65,536 rows: 70,000 dots (the 3rd plate's, over many
/// frames) give the same points as the library one by one, at the batch boundary too; a bad row
/// after the first batch fails naming its line and leaves no output and no temporary file.
#[test]
fn reconstruct_streams_across_batches() {
    use deltaz_calib::projector_calibration::DotObservation;
    use deltaz_calib::reconstruct::reconstruct;
    use deltaz_host::io::system_file::SystemFile;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    setup(d);
    assert!(calibrate(d, "plate_control.csv", "plate_obs.csv", "paper")
        .status
        .success());
    let obs = std::fs::read_to_string(d.join("plate_obs.csv")).unwrap();
    let plate: Vec<(u16, f64, f64)> = obs
        .lines()
        .filter(|l| l.starts_with("p3,") && l.ends_with(",dot"))
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (
                f[1].parse().unwrap(),
                f[2].parse().unwrap(),
                f[3].parse().unwrap(),
            )
        })
        .collect();
    let total = 70_000;
    let mut text = String::from("image,point,col,row,kind\n");
    let mut dots = Vec::new();
    for k in 0..total {
        let (id, col, row) = plate[k % plate.len()];
        // Each frame shifts its dots a little, so that frames differ.
        let frame = k / plate.len();
        let (col, row) = (col + 0.01 * frame as f64, row);
        text += &format!("f{frame},{id},{col},{row},dot\n");
        dots.push(DotObservation { id, col, row });
    }
    std::fs::write(d.join("many.csv"), &text).unwrap();
    let args = [
        "reconstruct",
        "--system",
        "system.json",
        "--obs",
        "many.csv",
        "--out",
        "many.ply",
        "--csv",
        "many.csv.out",
    ];
    let out = deltaz_in(d, &args);
    assert!(out.status.success(), "{}", stderr(&out));
    let ply = std::fs::read(d.join("many.ply")).unwrap();
    let head = b"element vertex 70000\n";
    assert!(ply.windows(head.len()).any(|w| w == head));
    let body = ply.len() - (ply.windows(11).position(|w| w == b"end_header\n").unwrap() + 11);
    // x y z, ray_id, miss, frame (the image's index).
    assert_eq!(body, total * (3 * 8 + 2 + 8 + 4));
    let csv = std::fs::read_to_string(d.join("many.csv.out")).unwrap();
    assert!(
        csv.starts_with("# points in mm, the plate frame of image "),
        "{csv:.80}"
    );
    let lines: Vec<&str> = csv.lines().skip(2).collect();
    assert_eq!(lines.len(), total);
    let (_, rig) = SystemFile::load(&d.join("system.json")).unwrap();
    let method = deltaz_shared::rig::Method::ClosestApproach;
    for k in [0, 65_535, 65_536, total - 1] {
        let want = reconstruct(&rig, &dots[k..=k], method, None, None).unwrap()[0];
        let got: Vec<f64> = lines[k]
            .split(',')
            .skip(2)
            .map(|v| v.parse().unwrap())
            .collect();
        assert_eq!(
            got,
            [want.point.x, want.point.y, want.point.z, want.miss],
            "row {k}"
        );
    }
    // A bad row in the second batch: no output, old or new, and nothing temporary.
    std::fs::remove_file(d.join("many.ply")).unwrap();
    std::fs::remove_file(d.join("many.csv.out")).unwrap();
    let mut bad: Vec<String> = text.lines().map(str::to_owned).collect();
    bad[66_001] = format!("f150,{},x,200,dot", plate[0].0);
    let bad = bad.join("\n");
    std::fs::write(d.join("many.csv"), bad).unwrap();
    let out = deltaz_in(d, &args);
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains("many.csv:66002: `col` is not a number"),
        "{}",
        stderr(&out)
    );
    // A dot off the calibration's sensor.
    std::fs::write(
        d.join("off.csv"),
        "image,point,col,row\nf1,305,300,200\nf1,306,768.2,10\n",
    )
    .unwrap();
    let off = deltaz_in(
        d,
        &[
            "reconstruct",
            "--system",
            "system.json",
            "--obs",
            "off.csv",
            "--out",
            "off.ply",
        ],
    );
    assert!(
        stderr(&off).contains("off.csv:3: (768.2, 10) is off the 768 × 512 sensor"),
        "{}",
        stderr(&off)
    );
    let names: Vec<String> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        names
            .iter()
            .all(|n| !n.starts_with("many.") || n == "many.csv")
            && names.iter().all(|n| !n.contains(".tmp")),
        "{names:?}"
    );
}

/// The desk rig through `calibrate projector` with one image (p2) cut to three control points:
/// the image and the rays seen on one plate are listed on stderr and in system.json; the central
/// model determines those rays through the centre, the non-central one leaves them out;
/// `--strict` makes them an error and writes nothing.
#[test]
fn desk_rig_lists_left_out_images_and_rays() {
    use deltaz_host::io::system_file::SystemFile;
    use std::collections::BTreeMap;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scenario = Scenario::desk();
    write_simulation(d, &simulate(&scenario, 7)).unwrap();
    let (grid, inner) = true_camera(&scenario);
    write_camera(&d.join("camera.json"), &CameraFile::init(&grid, inner)).unwrap();
    let obs = std::fs::read_to_string(d.join("plate_obs.csv")).unwrap();
    let cut: String = obs
        .lines()
        .filter(|l| !l.starts_with("p2,C") || l.get(3..6).is_some_and(|p| p < "C04"))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(d.join("cut.csv"), &cut).unwrap();
    // The rays' plates among the images that resect (all but p2).
    let mut plates: BTreeMap<u16, usize> = BTreeMap::new();
    for l in cut.lines().skip(1) {
        let f: Vec<&str> = l.split(',').collect();
        if f[0] != "p2" && f[4] == "dot" {
            *plates.entry(f[1].parse().unwrap()).or_default() += 1;
        }
    }
    let single: Vec<u16> = plates
        .iter()
        .filter(|(_, n)| **n == 1)
        .map(|(id, _)| *id)
        .collect();
    assert!(!single.is_empty() && single.len() < plates.len() / 2);

    let strict = calibrate_with(d, "plate_control.csv", "cut.csv", "joint", &["--strict"]);
    assert!(!strict.status.success());
    assert!(
        stderr(&strict).contains("--strict: image \"p2\" left out"),
        "{}",
        stderr(&strict)
    );
    assert!(!d.join("system.json").exists());

    for (model, determined) in [("joint", true), ("noncentral", false)] {
        let out = calibrate(d, "plate_control.csv", "cut.csv", model);
        assert!(out.status.success(), "{model}: {}", stderr(&out));
        assert!(
            stderr(&out).contains("warning: image \"p2\" left out"),
            "{}",
            stderr(&out)
        );
        let (file, _) = SystemFile::load(&d.join("system.json")).unwrap();
        let w = &file.content.warnings;
        assert_eq!(w.left_out_images.len(), 1);
        assert_eq!(w.left_out_images[0].image, "p2");
        assert!(
            w.left_out_images[0]
                .why
                .starts_with("too few control points"),
            "{}",
            w.left_out_images[0].why
        );
        let rays = &file.content.projector.rays;
        if determined {
            assert_eq!(w.single_plane_rays, single);
            assert!(w.left_out_rays.is_empty());
            assert_eq!(rays.len(), plates.len());
        } else {
            assert_eq!(w.left_out_rays, single);
            assert!(w.single_plane_rays.is_empty());
            assert_eq!(rays.len(), plates.len() - single.len());
        }
    }
}
