//! `deltaz scan` on rendered frames of a plane at depths and tilts no calibration plate had:
//! every identified dot on its true ray, the points' error against the truth at the floor
//! propagated from the measured image noise, and the command's files.

use deltaz_host::measure::render::{Background, Scene, Spot};
use deltaz_host::measure::{host_identifier, LoadedImage, MeasureParams};
use deltaz_host::reconstruct::covariance;
use deltaz_host::scan::{plane_dots, scan, FramePoints, PlaneDot};
use deltaz_host::simulate::{images::true_rig, Scenario};
use deltaz_shared::identify::DepthRange;
use deltaz_shared::rig::Method;

/// A plane `depth` mm away tilted by `tilt`: its rendered frame and its dots' truth.
fn frame(
    rig: &deltaz_host::system::SystemRig,
    depth: f64,
    tilt: f64,
    seed: u64,
) -> (image::GrayImage, Vec<PlaneDot>) {
    let dots = plane_dots(rig, depth, tilt);
    let scene = Scene {
        width: rig.grid().width as usize,
        height: rig.grid().height as usize,
        spots: dots
            .iter()
            .map(|(_, (c, r), _)| Spot::circle(*c, *r, 4.0, 150.0))
            .collect(),
        background: Background::flat(30.0),
        falloff: 0.2,
        blur_sigma: 1.0,
        noise_sigma: 2.0,
        seed,
    };
    (scene.render().to_u8(), dots)
}

#[test]
fn plane_scanned_at_the_image_noise_floor() {
    let rig = true_rig(&Scenario::paper());
    let cases = [(1700.0, 0.12), (1760.0, -0.1), (1730.0, 0.0)];
    let frames: Vec<_> = cases
        .iter()
        .enumerate()
        .map(|(k, &(depth, tilt))| frame(&rig, depth, tilt, 40 + k as u64))
        .collect();
    let depth = DepthRange {
        near: 1600.0,
        far: 1860.0,
    };
    let identifier = host_identifier(&rig, depth, 1.0, 16.0).unwrap();
    let mut scanned: Vec<FramePoints> = Vec::new();
    let load = |i: usize| Ok((format!("f{i}"), LoadedImage::Eight(frames[i].0.clone())));
    let stats = scan(
        &rig,
        &identifier,
        &MeasureParams::default(),
        Method::ClosestApproach,
        frames.len(),
        load,
        |f| {
            scanned.push(f.clone());
            Ok(())
        },
    )
    .unwrap();
    assert_eq!(stats.frames, 3);
    // Every dot measured, 85 % identified (the rest ambiguous over 1600-1860 mm), each on its true ray (its pixel within a
    // fraction of a pixel of the true one).
    let mut pairs = Vec::new();
    for (f, (_, truth)) in scanned.iter().zip(&frames) {
        assert_eq!(f.dots, truth.len(), "frame {}: every dot measured", f.label);
        assert!(
            f.points.len() * 20 >= truth.len() * 17,
            "frame {}: {} of {} identified",
            f.label,
            f.points.len(),
            truth.len()
        );
        for (dot, p) in f.identified.iter().zip(&f.points) {
            let (_, (c, r), x) = truth.iter().find(|t| t.0 == dot.id).expect("a true ray");
            let px = (dot.col - c, dot.row - r);
            assert!(
                px.0.hypot(px.1) < 0.1,
                "frame {} ray {}: {px:?} px",
                f.label,
                dot.id
            );
            pairs.push((px, p.point - x, *dot));
        }
    }
    // The image noise measured against the truth (per axis), propagated to each point: the
    // points' error is at that floor.
    let n = pairs.len() as f64;
    let sigma_px = (pairs
        .iter()
        .map(|(px, _, _)| px.0 * px.0 + px.1 * px.1)
        .sum::<f64>()
        / (2.0 * n))
        .sqrt();
    let error2: f64 = pairs.iter().map(|(_, e, _)| e.norm_squared()).sum::<f64>() / n;
    let floor2: f64 = pairs
        .iter()
        .map(|(_, _, d)| {
            covariance(&rig, d, Method::ClosestApproach, sigma_px)
                .unwrap()
                .trace()
        })
        .sum::<f64>()
        / n;
    let ratio = (error2 / floor2).sqrt();
    println!(
        "plane scan: {} points, centroid σ {sigma_px:.4} px, 3D error RMS {:.3} mm, floor {:.3} mm, ratio {ratio:.2}",
        pairs.len(),
        error2.sqrt(),
        floor2.sqrt()
    );
    assert!(sigma_px < 0.02, "centroid σ {sigma_px} px");
    assert!((0.8..=1.25).contains(&ratio), "error / floor {ratio}");
}

/// The command on a calibrated system (the simulated paper rig at 0.1 px): a folder of two
/// frames gives two PLY files and one CSV with a frame column; a frame of another size than the
/// sensor stops the scan naming it, and no CSV is left.
#[test]
fn scan_command_files() {
    use deltaz_host::io::camera_file::{write_camera, CameraFile};
    use deltaz_host::simulate::{simulate, true_camera, write_simulation};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut scenario = Scenario::paper();
    scenario.noise.image_sigma_px = 0.1;
    write_simulation(d, &simulate(&scenario, 2)).unwrap();
    let (grid, inner) = true_camera(&scenario);
    write_camera(&d.join("camera.json"), &CameraFile::init(&grid, inner)).unwrap();
    let deltaz = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_deltaz"))
            .args(args)
            .current_dir(d)
            .output()
            .unwrap()
    };
    let args = [
        "calibrate",
        "projector",
        "--camera",
        "camera.json",
        "--control",
        "plate_control.csv",
        "--obs",
        "plate_obs.csv",
        "--out",
        "system.json",
        "--image-sigma-px",
        "0.1",
    ];
    assert!(deltaz(&args).status.success());
    // Frames of the true rig (what the camera sees), scanned through the calibrated system.
    let rig = true_rig(&scenario);
    std::fs::create_dir(d.join("frames")).unwrap();
    for (k, (depth, tilt)) in [(1710.0, 0.05), (1750.0, -0.05)].into_iter().enumerate() {
        let (img, _) = frame(&rig, depth, tilt, k as u64);
        img.save(d.join(format!("frames/f{k}.png"))).unwrap();
    }
    let scan_args = [
        "scan",
        "frames",
        "--system",
        "system.json",
        "--near",
        "1600",
        "--far",
        "1860",
        "--out",
        "clouds",
        "--csv",
        "all.csv",
    ];
    let out = deltaz(&scan_args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let csv = std::fs::read_to_string(d.join("all.csv")).unwrap();
    let frames: Vec<&str> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap())
        .collect();
    let per_frame = |f: &str| frames.iter().filter(|&&x| x == f).count();
    assert!(
        per_frame("0") > 350 && per_frame("1") > 350,
        "{} {}",
        per_frame("0"),
        per_frame("1")
    );
    for (k, label) in ["f0", "f1"].iter().enumerate() {
        let ply = std::fs::read(d.join(format!("clouds/{label}.ply"))).unwrap();
        let head = format!("element vertex {}\n", per_frame(&k.to_string()));
        assert!(
            ply.windows(head.len()).any(|w| w == head.as_bytes()),
            "{label}"
        );
    }
    // A frame of another size.
    std::fs::remove_file(d.join("all.csv")).unwrap();
    image::GrayImage::new(640, 480)
        .save(d.join("frames/f2.png"))
        .unwrap();
    let out = deltaz(&scan_args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("frame f2: the image is 640 × 480 pixels, the calibration's sensor 768 × 512"),
        "{err}"
    );
    assert!(!d.join("all.csv").exists());
}
