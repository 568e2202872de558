//! The back analysis through the whole image path on the `back` scenario's rig, Monte Carlo:
//! each draw calibrates the rig anew from its simulated plates and field (`calibrate system`'s
//! chain: its own calibration error and covariance), places the subject anew on the lattice
//! (anywhere within a dot cell), renders the backs through the true rig (its own image noise),
//! measures, identifies and intersects their dots with the
//! calibration and analyses the points with their covariance (image noise, each ray's own
//! error and the calibration's common share) against the model's truth.
//!
//! The device stage: the firmware's logic in this process ([`Device::in_process`]), holding the
//! draw's calibration with the identification over the rig's working depth; its points carry
//! the wire's centroid quantisation, which their covariance includes.

use crate::back_sim::{check_line_and_rotation, placed, swayed_thoracic, IndexErrors};
use deltaz_host::io::system_file::SystemFile;
use deltaz_host::link::{centroid_step_px, Device};
use deltaz_host::simulate::back::{BackModel, Deformity, Trunk};
use deltaz_host::simulate::back_frames::render_backs;
use deltaz_host::simulate::images::{true_rig, ImageSpec};
use deltaz_host::simulate::{load_scenario, simulate, Scenario};
use deltaz_host::workflows::back::Calibration;
use deltaz_host::workflows::back_scan::scan_back;
use deltaz_host::workflows::scan::{identify_params, on_device};
use deltaz_host::workflows::system::calibrate_simulation;
use deltaz_shared::identify::DepthRange;
use deltaz_shared::rig::Method;
use deltaz_surface::{BackAnalysis, Options};
use rayon::prelude::*;
use std::path::Path;
use std::sync::OnceLock;

/// Draws of each case.
const DRAWS: u64 = 30;
/// The dots' spacing on the back (mm).
const SPACING: f64 = 20.0;
/// Identification tolerance (px).
const TOLERANCE_PX: f64 = 1.0;

/// Identification's lookup cell (px): the device's grid grows from it until it fits.
const CELL_PX: f64 = 32.0;

/// One draw's calibration and the identification over the working depth.
struct Draw {
    calibration: Calibration,
    fingerprint: u64,
    depth: DepthRange<f64>,
}

fn scenario() -> Scenario {
    load_scenario("back").unwrap()
}

/// The draws' calibrations, made once for every test of this module.
fn draws() -> &'static [Draw] {
    static DRAWS_: OnceLock<Vec<Draw>> = OnceLock::new();
    DRAWS_.get_or_init(|| {
        let s = scenario();
        let [near, far] = s.back.as_ref().unwrap().depth_range;
        (0..DRAWS)
            .into_par_iter()
            .map(|k| {
                let system = calibrate_simulation(&simulate(&s, 1800 + k)).unwrap();
                let rig = system.content.rig().unwrap();
                let file = SystemFile::new(system.content).unwrap();
                let fingerprint = file.fingerprint_u64().unwrap();
                let calibration = Calibration::new(file, rig, Path::new("system.json")).unwrap();
                Draw {
                    calibration,
                    fingerprint,
                    depth: DepthRange { near, far },
                }
            })
            .collect()
    })
}

/// Frames of `models` [`placed`] anew on the lattice (by draw `k`) rendered through the true
/// rig (noise seeded by `k`), scanned with the draw's calibration and analysed with
/// `options`; with the first frame's model as placed, the truth.
fn scanned(
    draw: &Draw,
    k: u64,
    models: &[BackModel],
    options: &Options,
) -> (BackModel, BackAnalysis) {
    let models = placed(models, SPACING, k);
    let labelled: Vec<_> = models
        .iter()
        .enumerate()
        .map(|(i, m)| (format!("frame_{i}"), m.clone()))
        .collect();
    let s = scenario();
    let spec = s.back.as_ref().unwrap().image_spec(&ImageSpec::default());
    let frames = render_backs(&true_rig(&s), &labelled, &spec, k);
    let images: Vec<_> = frames
        .iter()
        .map(|f| (f.label.clone(), f.image.to_u8()))
        .collect();
    let name = models[0].deformity.name;
    let analysis = identify_and_intersect(draw, name, &images, options);
    (models[0].clone(), analysis)
}

/// The device stage of the path: an in-process device holding the draw's calibration.
fn identify_and_intersect(
    draw: &Draw,
    name: &str,
    images: &[(String, image::GrayImage)],
    options: &Options,
) -> BackAnalysis {
    let rig = draw.calibration.rig();
    let mut device = Device::in_process();
    device
        .upload_identifying(
            rig,
            draw.fingerprint,
            Method::ClosestApproach,
            Some(identify_params(draw.depth, TOLERANCE_PX, CELL_PX)),
        )
        .unwrap_or_else(|e| panic!("{name}: upload: {e}"));
    let grid = rig.grid();
    let step = centroid_step_px(grid.width, grid.height);
    let identify = on_device(rig, &mut device);
    scan_back(
        name,
        &draw.calibration,
        images,
        identify,
        Some(step),
        options,
    )
    .unwrap_or_else(|e| panic!("{name}: {e:#}"))
    .analysis
}

/// Every draw of `models` (frame 0's truth), on one thread per core: not rayon's, since a
/// scan blocks on its measuring thread, whose measurement runs on rayon's threads.
fn monte_carlo(models: &[BackModel], options: &Options, seed: u64) -> IndexErrors {
    let draws = draws();
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
    let chunk = draws.len().div_ceil(threads);
    let analyses: Vec<(BackModel, BackAnalysis)> = std::thread::scope(|s| {
        let workers: Vec<_> = draws
            .chunks(chunk)
            .enumerate()
            .map(|(c, part)| {
                s.spawn(move || {
                    let first = seed + (c * chunk) as u64;
                    let scan =
                        |(i, d): (usize, &Draw)| scanned(d, first + i as u64, models, options);
                    part.iter().enumerate().map(scan).collect::<Vec<_>>()
                })
            })
            .collect();
        workers
            .into_iter()
            .flat_map(|w| w.join().expect("a Monte Carlo thread panicked"))
            .collect()
    });
    let mut errors = IndexErrors::default();
    for (truth, a) in &analyses {
        errors.add(truth, a);
    }
    errors
}

fn report(what: &str, e: &IndexErrors) {
    let line = |name: &str, x: &crate::back_sim::Errors, unit: &str| {
        format!("{name} {:.3} {unit} ({:.2})", x.rms(), x.z())
    };
    eprintln!(
        "{what} (image path, {DRAWS} draws; RMS error (RMS error/σ)): {}, {}, {}, {}, {}, {}, {}, {}, {}, {}, {}, {}, {}, {}, {}; largest |rotation| up to {:.2}°; levels left out {}, wild points {}, planes left out {}; sagittal mid-height excess {}; asymmetry over the noise {}",
        line("symmetry x", &e.symmetry_x, "mm"),
        line("rotation", &e.rotation, "°"),
        line("skin angle", &e.skin_angle, "°"),
        line("largest rotation", &e.rotation_max, "°"),
        line("largest lateral deviation", &e.lateral_deviation_max, "mm"),
        line("RMS rotation", &e.rotation_rms, "°"),
        line("RMS lateral deviation", &e.lateral_deviation_rms, "mm"),
        line("trunk imbalance", &e.trunk_imbalance, "mm"),
        line("trunk inclination", &e.trunk_inclination, "°"),
        line("ATR", &e.atr, "°"),
        line("largest ATR", &e.atr_max, "°"),
        line("kyphosis", &e.kyphosis, "°"),
        line("lordosis", &e.lordosis, "°"),
        line("asymmetry map", &e.asymmetry, "mm"),
        line("largest asymmetry", &e.asymmetry_max, "mm"),
        e.largest_rotation.iter().fold(0.0_f64, |m, x| m.max(*x)),
        e.left_out,
        e.wild,
        e.planes,
        e.mid_excess_range(),
        e.asymmetry_over_noise_range(),
    );
}

/// The bars ([`check_line_and_rotation`]: σ holds the sampling terms for the detail
/// between the dots, deltaz-surface's `K_LINE`); kyphosis and lordosis within 1.5° RMS,
/// error/σ 0.8-1.6.
fn check(what: &str, e: &IndexErrors) {
    report(what, e);
    check_line_and_rotation(what, e);
    for (name, x) in [("kyphosis", &e.kyphosis), ("lordosis", &e.lordosis)] {
        let z = x.z();
        assert!(
            (0.8..=1.6).contains(&z),
            "{what}: {name} RMS of error/σ {z:.2}"
        );
        assert!(
            x.count() >= 30 && x.rms() <= 1.5,
            "{what}: {name} RMS {:.2}°",
            x.rms()
        );
    }
}

fn standing(deformity: Deformity, trunk: Trunk, seed: u64) -> IndexErrors {
    let model = BackModel {
        trunk,
        ..BackModel::standing(deformity)
    };
    monte_carlo(&[model], &Options::standing(), seed)
}

#[test]
fn image_path_straight_back() {
    let e = standing(Deformity::straight(), Trunk::default(), 100);
    check("straight", &e);
    let largest = e.largest_rotation.iter().fold(0.0_f64, |m, x| m.max(*x));
    assert!(
        largest <= 1.0,
        "a straight back's largest |rotation| {largest:.2}°"
    );
}

#[test]
fn image_path_curves() {
    for (deformity, seed) in [
        (Deformity::thoracic(), 200),
        (Deformity::lumbar(), 300),
        (Deformity::double(), 400),
        (Deformity::severe(), 500),
    ] {
        let name = deformity.name;
        check(name, &standing(deformity, Trunk::default(), seed));
    }
}

/// A second body: slimmer, flatter, a stronger kyphosis, the vertebral axis nearer the skin.
#[test]
fn image_path_second_trunk() {
    let trunk = Trunk {
        length: 430.0,
        half_width: [150.0, 128.0, 168.0],
        depth: 80.0,
        scapula: 9.0,
        scapula_offset: 80.0,
        kyphosis: 28.0,
        lordosis: 16.0,
        axis_depth: 45.0,
        ..Trunk::default()
    };
    check(
        "second trunk, double",
        &standing(Deformity::double(), trunk, 600),
    );
}

/// Bent forward: the virtual scoliometer within 0.5° of the true surface's, its σ honest.
#[test]
fn image_path_scoliometer() {
    for (deformity, seed) in [(Deformity::straight(), 700), (Deformity::thoracic(), 800)] {
        let name = deformity.name;
        let straight = deformity.curves.is_empty();
        let e = monte_carlo(
            &[BackModel::forward_bent(deformity)],
            &Options::forward_bent(),
            seed,
        );
        report(&format!("{name} bent forward"), &e);
        assert!(e.atr.rms() <= 0.5, "{name}: ATR RMS {:.3}°", e.atr.rms());
        let bar = if straight { 1.0 } else { 0.5 };
        assert!(
            e.atr_max.rms() <= bar,
            "{name}: largest ATR RMS {:.3}°",
            e.atr_max.rms()
        );
        e.atr.assert_honest(&format!("{name}: ATR"));
    }
}

/// Three frames swayed by a few mm and about a degree, registered and combined: unbiased
/// beyond their σ (the bars; the rotation's error/σ 1.08, 1.29 before its σ held the
/// frames' registration). That registration turns every level alike: the RMS rotation and
/// the skin angle hold it whole (error/σ 0.91 and 0.99; 1.62 and 1.12 without).
#[test]
fn image_path_swayed_frames() {
    let models = swayed_thoracic();
    let e = monte_carlo(&models, &Options::standing(), 900);
    check("three swayed frames", &e);
    for (name, x) in [
        ("RMS rotation", &e.rotation_rms),
        ("skin angle", &e.skin_angle),
    ] {
        x.assert_honest(&format!("three swayed frames: {name}"));
    }
    let bias = e.rotation.mean();
    assert!(bias.abs() <= 0.1, "rotation biased by {bias:.3}°");
}

/// A wall behind the subject, its dots seen around the back (about 600 of them), the issue's
/// bars held. Within the working depth (1,700 mm from the camera, 200 mm behind the back) it
/// is identified, and left out as a plane in every draw. Beyond it (1,900 mm) the device,
/// which knows the working depth only, identifies 70-110 of its dots to a wrong ray (measured
/// with the true rig), reconstructed in front of the wall apart from the back; their conflicts
/// cost the back about 25 of its 380 dots, and no plane is seen.
#[test]
fn image_path_wall_behind() {
    for (wall, seed, planes) in [(1700.0, 1000, DRAWS), (1900.0, 1100, 0)] {
        let model = BackModel {
            backdrop: Some(wall),
            ..BackModel::standing(Deformity::thoracic())
        };
        let e = monte_carlo(&[model], &Options::standing(), seed);
        let what = format!("thoracic, a wall {wall} mm from the camera");
        check(&what, &e);
        assert_eq!(e.planes as u64, planes, "{what}: planes left out");
    }
}
