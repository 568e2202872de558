//! `deltaz scan` on rendered frames of a plane at depths and tilts no calibration plate had:
//! every identified dot on its true ray, the points' error against the truth at the floor
//! propagated from the measured image noise, and the command's files. The helpers here scan
//! the other test objects too ([`crate::objects`]).

use crate::cli::deltaz_in;
use deltaz_calib::projector_calibration::DotObservation;
use deltaz_calib::reconstruct::covariance;
use deltaz_calib::system_adjustment::{Frame, PointShares, SystemModel};
use deltaz_host::io::system_file::SystemRig;
use deltaz_host::report::object_accuracy::{error_against_truth, AtFloor, ObjectPoint};
use deltaz_host::simulate::objects::{object_dots, object_frame, Object, ObjectDot};
use deltaz_host::simulate::{images::true_rig, Scenario};
use deltaz_host::workflows::scan::{on_device, on_host, scan, FramePoints};
use deltaz_measure::{host_identifier, LoadedImage, MeasureParams};
use deltaz_shared::identify::DepthRange;
use deltaz_shared::rig::Method;
use nalgebra::{DMatrix, Matrix3, Vector3};

/// An object's rendered frame and its dots' truth.
pub(crate) fn frame(
    rig: &SystemRig,
    object: &Object,
    seed: u64,
) -> (image::GrayImage, Vec<ObjectDot>) {
    let dots = object_dots(rig, object);
    (object_frame(rig, &dots, seed), dots)
}

/// A scanned dot against its truth.
pub(crate) struct Matched {
    /// Measured minus true pixel (col, row).
    pub px: (f64, f64),
    /// The reconstructed point.
    pub point: Vector3<f64>,
    /// The true point.
    pub truth: Vector3<f64>,
    /// The identified dot.
    pub dot: DotObservation,
}

/// Scan `frames` in process with the true rig, identifying over `near..far` mm: every dot is
/// measured, at least `identified` of them identified, each on its true ray (its pixel within
/// 0.1 px of the true one). The matched dots, frame by frame.
pub(crate) fn scan_frames(
    rig: &SystemRig,
    frames: &[(image::GrayImage, Vec<ObjectDot>)],
    (near, far): (f64, f64),
    identified: f64,
) -> Vec<Vec<Matched>> {
    let identifier = host_identifier(rig, DepthRange { near, far }, 1.0, 16.0).unwrap();
    let mut scanned: Vec<FramePoints> = Vec::new();
    let load = |i: usize| Ok((format!("f{i}"), LoadedImage::Eight(frames[i].0.clone())));
    let stats = scan(
        rig,
        &MeasureParams::default(),
        frames.len(),
        load,
        on_host(rig, &identifier, Method::ClosestApproach),
        |f| {
            scanned.push(f.clone());
            Ok(())
        },
    )
    .unwrap();
    assert_eq!(stats.frames, frames.len());
    scanned
        .iter()
        .zip(frames)
        .map(|(f, (_, truth))| {
            assert_eq!(f.dots, truth.len(), "frame {}: every dot measured", f.label);
            assert!(
                f.found.points.len() as f64 >= truth.len() as f64 * identified,
                "frame {}: {} of {} identified",
                f.label,
                f.found.points.len(),
                truth.len()
            );
            f.found
                .identified
                .iter()
                .zip(&f.found.points)
                .map(|(dot, p)| {
                    let (_, (c, r), x) = truth.iter().find(|t| t.0 == dot.id).expect("a true ray");
                    let px = (dot.col - c, dot.row - r);
                    assert!(
                        px.0.hypot(px.1) < 0.1,
                        "frame {} ray {}: {px:?} px",
                        f.label,
                        dot.id
                    );
                    Matched {
                        px,
                        point: p.point,
                        truth: *x,
                        dot: *dot,
                    }
                })
                .collect()
        })
        .collect()
}

/// What scanned points are computed and their floor propagated with: a rig and, for a system
/// calibrated from images, its model (the calibration's covariance); with none, the true rig.
pub(crate) struct Instrument {
    /// The rig the points are computed with.
    pub rig: SystemRig,
    /// The calibration's model, None for the true rig.
    pub model: Option<SystemModel>,
}

impl Instrument {
    /// The core parameters' covariance (0 × 0 for the true rig).
    pub fn core(&self) -> DMatrix<f64> {
        self.model
            .as_ref()
            .map_or_else(|| DMatrix::zeros(0, 0), |m| m.core_covariance.clone())
    }

    /// A matched dot's covariance shares, the image share at `sigma_px` per axis.
    fn shares(&self, dot: &DotObservation, sigma_px: f64) -> PointShares {
        let image = covariance(&self.rig, dot, Method::ClosestApproach, sigma_px).unwrap();
        match &self.model {
            Some(model) => PointShares {
                image,
                ..model
                    .reconstruct_shares(
                        &model.core_split().unwrap(),
                        self.rig.grid(),
                        dot,
                        Method::ClosestApproach,
                        Frame::Camera,
                    )
                    .unwrap()
            },
            None => PointShares {
                point: Vector3::zeros(),
                image,
                ray: Matrix3::zeros(),
                common: DMatrix::zeros(3, 0),
            },
        }
    }
}

/// The image noise measured against the truth (σ per axis, pixels), checked to be small, and
/// each matched dot as an object point with its covariance shares: the image's from that σ,
/// the calibration's from the instrument.
pub(crate) fn propagated(
    instrument: &Instrument,
    frames: &[Vec<Matched>],
) -> (f64, Vec<Vec<ObjectPoint>>) {
    let all = frames.iter().flatten();
    let n = all.clone().count() as f64;
    let sigma_px = (all.map(|m| m.px.0 * m.px.0 + m.px.1 * m.px.1).sum::<f64>() / (2.0 * n)).sqrt();
    assert!(sigma_px < 0.02, "centroid σ {sigma_px} px");
    let points = frames
        .iter()
        .map(|f| {
            f.iter()
                .map(|m| ObjectPoint {
                    point: m.point,
                    truth: m.truth,
                    shares: instrument.shares(&m.dot, sigma_px),
                })
                .collect()
        })
        .collect();
    (sigma_px, points)
}

/// The points' RMS error against the truth and its floor ([`error_against_truth`]: image
/// noise and calibration), after checking their ratio: at most 1.25, and at least 0.8 times
/// the share of the floor independent from point to point (the image noise and each ray's own
/// error; the calibration's error common to all points is one draw, and may happen to be
/// small).
pub(crate) fn error_at_floor(
    name: &str,
    instrument: &Instrument,
    frames: &[Vec<Matched>],
) -> AtFloor {
    let (sigma_px, points) = propagated(instrument, frames);
    let figure = error_against_truth(&points.concat(), &instrument.core());
    let own = figure.own_mm.unwrap();
    let (ratio, least) = (figure.ratio(), 0.8 * own / figure.floor_mm);
    println!(
        "{name}: {} points, centroid σ {sigma_px:.4} px, 3D error RMS {:.3} mm, floor {:.3} mm \
         (image and rays' own {:.3} mm), ratio {ratio:.2} (at least {least:.2})",
        figure.points, figure.rms_mm, figure.floor_mm, own
    );
    assert!(
        (least..=1.25).contains(&ratio),
        "{name}: error / floor {ratio}, at least {least}"
    );
    figure
}

#[test]
fn plane_scanned_at_the_image_noise_floor() {
    let rig = true_rig(&Scenario::paper());
    let cases = [(1700.0, 0.12), (1760.0, -0.1), (1730.0, 0.0)];
    let frames: Vec<_> = cases
        .iter()
        .enumerate()
        .map(|(k, &(depth, tilt))| frame(&rig, &Object::Plane { depth, tilt }, 40 + k as u64))
        .collect();
    // 85 % identified (the rest ambiguous over 1600-1860 mm).
    let matched = scan_frames(&rig, &frames, (1600.0, 1860.0), 0.85);
    let instrument = Instrument { rig, model: None };
    error_at_floor("plane scan", &instrument, &matched);
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
    let deltaz = |args: &[&str]| deltaz_in(d, args);
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
        let (img, _) = frame(&rig, &Object::Plane { depth, tilt }, k as u64);
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
        "--host",
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
        .skip(2)
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
    // Through the in-process device, one PLY with each point's frame index, the summary as
    // JSON: the same rays per frame as the host's CSV, none off the sensor.
    let mut device_args: Vec<&str> = scan_args[..scan_args.len() - 1].to_vec();
    device_args[11] = "one.csv";
    device_args.extend(["--one-file", "--json", "--quiet"]);
    let out = deltaz(&device_args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(summary["frames"], 2);
    assert_eq!(summary["off_sensor"].as_u64(), Some(0));
    let labels: Vec<String> = deltaz_host::io::ply::read_points(&d.join("clouds/scan.ply"))
        .unwrap()
        .into_iter()
        .map(|(label, _)| label)
        .collect();
    let rows: Vec<String> = std::fs::read_to_string(d.join("one.csv"))
        .unwrap()
        .lines()
        .skip(2)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f.len(), 7, "frame,image,point,X,Y,Z,miss: {l}");
            format!("{}:{}", f[0], f[2])
        })
        .collect();
    assert_eq!(labels, rows);
    let host_rows: Vec<String> = csv
        .lines()
        .skip(2)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            format!("{}:{}", f[0], f[2])
        })
        .collect();
    let same = rows.iter().filter(|r| host_rows.contains(r)).count();
    assert!(
        same * 100 >= host_rows.len() * 99,
        "{same} of {}",
        host_rows.len()
    );
    assert_eq!(summary["points"].as_u64(), Some(rows.len() as u64));
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

/// A frame's identification and intersection ([`on_host`], [`on_device`]).
type Identify<'a> =
    dyn FnMut(&[(f64, f64)]) -> anyhow::Result<deltaz_host::workflows::scan::Identified> + 'a;

/// Centroids as the wire carries them (1/2^bits px), exactly representable in f32 and f64.
fn quantised(dots: &[(f64, f64)], bits: u8) -> Vec<(f64, f64)> {
    dots.iter()
        .map(|&(c, r)| {
            deltaz_shared::protocol::Dot::from_pixel(c, r, bits)
                .unwrap()
                .pixel::<f64>(bits)
        })
        .collect()
}

/// The rig's identification for `depth`, on the host and uploaded to an in-process device (with
/// the device's centroid bits).
fn host_and_device(
    rig: &deltaz_host::io::system_file::SystemRig,
    depth: DepthRange<f64>,
    cell: f64,
) -> (
    Box<deltaz_measure::HostIdentifier>,
    deltaz_host::link::Device<deltaz_host::link::InProcess>,
    u8,
) {
    let identifier = host_identifier(rig, depth, 1.0, cell).unwrap();
    let mut device = deltaz_host::link::Device::in_process();
    let params = deltaz_host::workflows::scan::identify_params(depth, 1.0, cell);
    let summary = device
        .upload_identifying(rig, 11, Method::ClosestApproach, Some(params))
        .unwrap();
    (identifier, device, summary.centroid_bits)
}

/// Scanning through the in-process device (f32, Identify requests) gives the host scan's (f64)
/// points on the same wire-quantised centroids: the same rays for all but a few dots at the
/// tolerance's edge, each point within 1 µm (f32 rounding at 1.7 m: ulp 0.12 µm, a few
/// roundings through eqs 6-8, plus the wire's 0.24 µm step), the miss distance within the
/// wire's 3.9 µm step; on the paper rig and on the desk rig (2448 × 2048, 660-740 mm: the
/// device's lookup holds no wider range at that size).
#[test]
fn device_scan_equals_host_scan() {
    let cases = [
        (
            Scenario::paper(),
            1600.0,
            1860.0,
            16.0,
            [(1700.0, 0.1), (1760.0, -0.08)],
        ),
        (
            Scenario::desk(),
            660.0,
            740.0,
            64.0,
            [(680.0, 0.1), (720.0, -0.1)],
        ),
    ];
    for (scenario, near, far, cell, planes) in cases {
        let rig = true_rig(&scenario);
        let images: Vec<_> = planes
            .iter()
            .enumerate()
            .map(|(k, &(d, t))| frame(&rig, &Object::Plane { depth: d, tilt: t }, 70 + k as u64).0)
            .collect();
        let (identifier, mut device, bits) = host_and_device(&rig, DepthRange { near, far }, cell);
        let run = |identify: &mut Identify| {
            let mut out: Vec<FramePoints> = Vec::new();
            let load = |i: usize| Ok((format!("f{i}"), LoadedImage::Eight(images[i].clone())));
            scan(
                &rig,
                &MeasureParams::default(),
                images.len(),
                load,
                |d: &[(f64, f64)]| identify(&quantised(d, bits)),
                |f| {
                    out.push(f.clone());
                    Ok(())
                },
            )
            .unwrap();
            out
        };
        let mut host = on_host(&rig, &identifier, Method::ClosestApproach);
        let host = run(&mut host);
        let mut dev = on_device(&rig, &mut device);
        let dev = run(&mut dev);
        let (mut common, mut worst, mut worst_miss) = (0, 0.0f64, 0.0f64);
        for (h, d) in host.iter().zip(&dev) {
            assert_eq!((h.dots, h.found.off_sensor), (d.dots, d.found.off_sensor));
            assert!(
                h.found.points.len() > 300,
                "{} points",
                h.found.points.len()
            );
            let mut same = 0;
            for (dot, p) in h.found.identified.iter().zip(&h.found.points) {
                let Some(k) = d.found.identified.iter().position(|x| x == dot) else {
                    continue;
                };
                same += 1;
                worst = worst.max((d.found.points[k].point - p.point).norm());
                worst_miss = worst_miss.max((d.found.points[k].miss - p.miss).abs());
            }
            common += same;
            let differ = h.found.points.len() + d.found.points.len() - 2 * same;
            assert!(
                differ * 200 <= h.found.points.len(),
                "{}: {differ} dots identified differently of {}",
                h.label,
                h.found.points.len()
            );
        }
        println!(
            "{} x {}: {common} points in common, device - host ≤ {:.3} µm, miss ≤ {:.2} µm",
            rig.grid().width,
            rig.grid().height,
            worst * 1e3,
            worst_miss * 1e3
        );
        // The device's f32 depth (a few ulps of λ: under a micrometre at 2 m) and half a unit
        // of its quantisation on the wire (0.49 µm).
        assert!(worst < 1.5e-3, "device vs host {worst} mm");
        assert!(worst_miss < 1e-4, "miss {worst_miss} mm");
    }
}

/// Dots moved off their epipolar lines get miss distances up to a few millimetres: the device's
/// (placed by the host at the device's depth) equal the host's (f64) to a micrometre, beyond
/// the 0.93 mm protocol 5 could say too; two dots off the sensor are rejected and counted on
/// both sides.
#[test]
fn wide_misses_kept_and_off_sensor_dots_rejected() {
    let rig = true_rig(&Scenario::paper());
    let (identifier, mut device, bits) = host_and_device(
        &rig,
        DepthRange {
            near: 1680.0,
            far: 1800.0,
        },
        16.0,
    );
    let mut dots: Vec<(f64, f64)> = object_dots(
        &rig,
        &Object::Plane {
            depth: 1740.0,
            tilt: 0.0,
        },
    )
    .iter()
    .enumerate()
    .map(|(k, (_, (c, r), _))| {
        let shift = 0.15 * (k % 6) as f64;
        if k % 2 == 0 {
            (c + shift, *r)
        } else {
            (*c, r + shift)
        }
    })
    .collect();
    dots.extend([(768.2, 100.0), (100.0, 512.0)]);
    let dots = quantised(&dots, bits);
    let host = on_host(&rig, &identifier, Method::ClosestApproach)(&dots).unwrap();
    let dev = on_device(&rig, &mut device)(&dots).unwrap();
    assert_eq!((host.off_sensor, dev.off_sensor), (2, 2));
    let (mut wide, mut worst) = (0, 0.0f64);
    for (dot, p) in dev.identified.iter().zip(&dev.points) {
        let truth = deltaz_calib::reconstruct::reconstruct(
            &rig,
            &[*dot],
            Method::ClosestApproach,
            None,
            None,
        )
        .unwrap()[0]
            .miss;
        worst = worst.max((p.miss - truth).abs());
        wide += usize::from(truth > 0.934);
    }
    println!(
        "{} points, {wide} with a miss beyond 0.934 mm; device - host miss ≤ {:.3} µm",
        dev.points.len(),
        worst * 1e3
    );
    assert!(wide > 10, "{wide} wide misses");
    assert!(worst < 1e-3, "device miss {worst} mm from the host's");
}
