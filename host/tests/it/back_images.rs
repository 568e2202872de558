//! The `back` scenario and its rendered frames: the rig's design (1,225 rays 20 mm apart on
//! the back, no two epipolar segments close over its 500 mm depth range), the frames measured
//! to their true centres and identified without a wrong ray, any rig rendering a back (the
//! paper's too), and `deltaz simulate --scenario back --images` writing the calibration, the
//! frames and their truth.

use deltaz_host::simulate::back::{BackModel, Deformity, Part};
use deltaz_host::simulate::back_frames::{render_back, BackFrame};
use deltaz_host::simulate::images::{true_rig, ImageSpec};
use deltaz_host::simulate::{load_scenario, Scenario};
use deltaz_measure::detect::GrayView;
use deltaz_measure::{host_identifier, measure, MeasureParams};
use deltaz_shared::identify::{Assignment, DepthRange};
use std::process::Command;

fn back_scenario() -> Scenario {
    load_scenario("back").unwrap()
}

/// The back frames' look in the scenario.
fn skin(s: &Scenario) -> ImageSpec {
    s.back.as_ref().unwrap().image_spec(&ImageSpec::default())
}

fn depth_range(s: &Scenario) -> DepthRange<f64> {
    let [near, far] = s.back.as_ref().unwrap().depth_range;
    DepthRange { near, far }
}

/// The rig as designed: 1,000-1,300 rays; over the working depth range no two rays' epipolar
/// segments come within 3 px (two tolerances of 1.5 px: a dot within 1 px of its own ray's
/// segment is then at least 2 px from any other's), and on a standing back the dots lie
/// about 20 mm apart.
#[test]
fn back_rig_design() {
    let s = back_scenario();
    let rig = true_rig(&s);
    let rays = rig.projector_centred().rays().len();
    assert!((1000..=1300).contains(&rays), "{rays} rays");
    let ident = host_identifier(&rig, depth_range(&s), 1.5, 16.0).unwrap();
    assert_eq!(ident.close_pairs(), 0, "rays too close to be told apart");
    let frame = render_back(
        &rig,
        "standing",
        &BackModel::standing(Deformity::thoracic()),
        &skin(&s),
        1,
    );
    let back: Vec<_> = frame.dots.iter().filter(|d| d.part == Part::Back).collect();
    assert!(back.len() > 300, "{} dots on the back", back.len());
    // The nearest neighbour of each dot on the back: 20 mm give or take the back's slope.
    let mut nearest: Vec<f64> = back
        .iter()
        .map(|a| {
            back.iter()
                .filter(|b| b.id != a.id)
                .map(|b| (a.point - b.point).norm())
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    nearest.sort_by(f64::total_cmp);
    let median = nearest[nearest.len() / 2];
    assert!(
        (18.0..=22.0).contains(&median),
        "median spacing {median:.2} mm"
    );
}

/// A frame's dots measured: (col, row) of each.
fn measured(frame: &BackFrame) -> Vec<(f64, f64)> {
    let img = frame.image.to_u8();
    let view = GrayView {
        width: img.width() as usize,
        height: img.height() as usize,
        pixels: img.as_raw().as_slice(),
        dn: 1.0,
    };
    let m = measure(&view, &MeasureParams::default());
    m.targets.iter().map(|t| (t.col, t.row)).collect()
}

/// Standing and bent forward, swayed, dim on the skin: 97 % of the drawn dots measured, each
/// within 0.4 px of its true centre (RMS 0.03-0.07 px per axis: the scenario's image σ of
/// 0.055 px), and identified over the depth range with the true rig: none wrong, 97 % identified.
#[test]
fn back_frames_measured_and_identified() {
    let s = back_scenario();
    let rig = true_rig(&s);
    let ident = host_identifier(&rig, depth_range(&s), 1.0, 16.0).unwrap();
    let models = s.back.as_ref().unwrap().models(3);
    for (k, (label, model)) in models.iter().enumerate() {
        let frame = render_back(&rig, label, model, &skin(&s), 10 + k as u64);
        let dots = measured(&frame);
        let mut assigned = vec![Assignment::Unassigned; dots.len()];
        ident.identify_frame(&dots, &mut assigned);
        let (mut sum2, mut wrong, mut identified, mut worst) = (0.0, 0, 0, 0.0_f64);
        for (dot, a) in dots.iter().zip(&assigned) {
            let truth = frame
                .dots
                .iter()
                .min_by(|a, b| {
                    let d = |t: &(f64, f64)| (t.0 - dot.0).hypot(t.1 - dot.1);
                    d(&a.pixel).total_cmp(&d(&b.pixel))
                })
                .unwrap();
            let miss = (truth.pixel.0 - dot.0).hypot(truth.pixel.1 - dot.1);
            worst = worst.max(miss);
            sum2 += miss * miss;
            match a {
                Assignment::Ray { id, .. } if *id != truth.id => wrong += 1,
                Assignment::Ray { .. } => identified += 1,
                _ => {}
            }
        }
        let rms = (sum2 / (2.0 * dots.len() as f64)).sqrt();
        let drawn = frame.dots.len();
        eprintln!(
            "{label}: {drawn} dots drawn, {} measured (worst {worst:.3} px, RMS {rms:.4} px per axis), {identified} identified, {wrong} wrong",
            dots.len()
        );
        assert!(
            dots.len() as f64 >= 0.97 * drawn as f64,
            "{label}: {} of {drawn} measured",
            dots.len()
        );
        assert!(
            worst < 0.4 && (0.03..=0.07).contains(&rms),
            "{label}: worst {worst:.3} px, RMS {rms:.4} px"
        );
        assert_eq!(wrong, 0, "{label}: wrong identifications");
        assert!(
            identified as f64 >= 0.97 * drawn as f64,
            "{label}: {identified} of {drawn} identified"
        );
    }
}

/// Any rig renders a back: the paper's (in its plate frame, 440 rays, the back at 1.5 m) puts
/// its dots on it, about 40 mm apart, measured where drawn.
#[test]
fn paper_rig_renders_a_back() {
    let rig = true_rig(&Scenario::paper());
    let frame = render_back(
        &rig,
        "paper",
        &BackModel::standing(Deformity::double()),
        &ImageSpec::default(),
        5,
    );
    let back = frame.dots.iter().filter(|d| d.part == Part::Back).count();
    assert!((60..=200).contains(&back), "{back} dots on the back");
    let dots = measured(&frame);
    assert!(dots.len() as f64 >= 0.97 * frame.dots.len() as f64);
    for d in &frame.dots {
        let miss = dots
            .iter()
            .map(|m| (m.0 - d.pixel.0).hypot(m.1 - d.pixel.1))
            .fold(f64::INFINITY, f64::min);
        assert!(
            miss < 0.25,
            "ray {}: nearest measured dot {miss:.3} px off",
            d.id
        );
    }
}

/// `deltaz simulate --scenario back --images`: the calibration files and its system.json (in
/// the camera system, 1,225 rays, with covariance), the back frames with their truth.
#[test]
fn simulate_back_scenario_cli() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sim");
    let run = Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .args(["simulate", "--scenario", "back", "--images", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(stdout.contains("6 back frames"), "{stdout}");
    for name in [
        "system.json",
        "plate_obs.csv",
        "images/p1.png",
        "images/back/standing_0.png",
        "images/back/bent_2.png",
        "images/back/truth.csv",
        "images/back/back.json",
    ] {
        assert!(out.join(name).is_file(), "{name} missing");
    }
    let (file, rig) =
        deltaz_host::io::system_file::SystemFile::load(&out.join("system.json")).unwrap();
    assert_eq!(rig.projector_centred().rays().len(), 1225);
    assert!(file.content.model().unwrap().is_some(), "no covariance");
    let truth = std::fs::read_to_string(out.join("images/back/truth.csv")).unwrap();
    let standing = truth
        .lines()
        .filter(|l| l.starts_with("standing_0,"))
        .count();
    assert!(standing > 400, "{standing} dots in standing_0");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("images/back/back.json")).unwrap())
            .unwrap();
    assert_eq!(json["deformity"], "thoracic");
    assert_eq!(json["frames"].as_array().unwrap().len(), 6);
}

/// A scenario's `back.backdrop`: a wall behind the subject in every frame, its dots drawn
/// where the projector's rays miss the body and the camera sees past it; a wall that would
/// cut the subject is refused.
#[test]
fn a_scenario_puts_a_wall_behind_the_back() {
    let text = include_str!("../../scenarios/back.toml");
    let with_wall = |at: &str| {
        Scenario::from_toml(&text.replace(
            "noise_sigma = 4.0",
            &format!("noise_sigma = 4.0\nbackdrop = {at}"),
        ))
    };
    let err = with_wall("1600.0").unwrap_err().to_string();
    assert!(
        err.contains("back.backdrop 1600 mm must stand behind the subject"),
        "{err}"
    );
    let s = with_wall("1700.0").unwrap();
    let models = s.back.as_ref().unwrap().models(3);
    assert!(models.iter().all(|(_, m)| m.backdrop == Some(1700.0)));
    let (label, model) = &models[0];
    let frame = render_back(&true_rig(&s), label, model, &skin(&s), 4);
    let wall: Vec<_> = frame
        .dots
        .iter()
        .filter(|d| d.part == Part::Backdrop)
        .collect();
    assert!(wall.len() > 300, "{} dots on the wall", wall.len());
    assert!(wall.iter().all(|d| (d.point.z + 1700.0).abs() < 1e-6));
    // None where the body hides the wall from the camera: the line of sight to each misses
    // the body (the model without its wall).
    let body = BackModel {
        backdrop: None,
        ..model.clone()
    };
    let origin = nalgebra::Vector3::zeros();
    assert!(wall.iter().all(|d| body.hit(&origin, &d.point).is_none()));
    let back = frame.dots.iter().filter(|d| d.part == Part::Back).count();
    assert!(back > 300, "{back} dots on the back");
}
