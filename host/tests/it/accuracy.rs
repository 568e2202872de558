//! Accuracy on simulated rigs (issue 4): the paper's experiment over 20 seeds, an unseen plate
//! against the image-noise floor, the honesty of the propagated σ, Table 8's wrong inner
//! orientation, and the non-central model against a non-central projector.
//!
//! The camera's inner orientation is the simulator's truth here (camera calibration is tested
//! apart); every plate image is resected (step 4) from the noisy plate control and images.

use crate::honesty::assert_honest;
use deltaz_calib::projector_calibration::Model;
use deltaz_host::io::observations::PointKind;
use deltaz_host::simulate::{simulate, true_camera, Scenario, Simulation};
use deltaz_host::workflows::accuracy::{
    against_truth, calibrate_simulation, paper_experiment, truth_figures, Calibrated, TABLE4_IDS,
};
use deltaz_shared::collinearity::{Camera, ExteriorOrientation};
use deltaz_shared::rig::Method;
use nalgebra::Vector3;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

fn paper_scenario(sigma_px: f64) -> Scenario {
    let mut sc = Scenario::paper();
    sc.noise.image_sigma_px = sigma_px;
    sc
}

/// The true projector centre carried into a calibration's rig frame (through its resected
/// camera pose): R1ᵀ c_cam + X0_1.
fn true_centre_in_rig(sim: &Simulation, cal: &Calibrated) -> Vector3<f64> {
    let c_cam = Vector3::from(sim.truth.projector.centre_camera);
    cal.rig.r_cam_world().transpose() * c_cam + cal.rig.camera_centre()
}

/// Per-axis medians over seeds of the paper experiment's errors with no fit (9 rays, 3 plates,
/// the 3rd image's dots against their eq. (10) plate coordinates), and how many seeds had the
/// centre within 3σ on every axis.
fn paper_runs(sigma_px: f64, seeds: u64) -> (Vector3<f64>, Vector3<f64>, usize) {
    let (_, inner) = true_camera(&Scenario::paper());
    let mut errors = [Vec::new(), Vec::new(), Vec::new()];
    let mut floors = Vec::new();
    let mut centre_ok = 0;
    for seed in 0..seeds {
        let sim = simulate(&paper_scenario(sigma_px), seed);
        let cal = calibrate_simulation(&sim, &inner, Model::Paper, Some(&TABLE4_IDS), 3).unwrap();
        let (fig, _) = paper_experiment(&cal, 2, Method::Paper, sigma_px).unwrap();
        for (axis, e) in errors.iter_mut().enumerate() {
            e.push(fig.error[axis]);
        }
        floors.push(fig.floor);
        // The centre and its σ from the joint adjustment of the same data (the eq. (12) least
        // squares treats its correlated equations as independent and under-states σ by ~1.4x).
        let joint = calibrate_simulation(&sim, &inner, Model::Joint, Some(&TABLE4_IDS), 3).unwrap();
        let miss = joint.projector.centre - true_centre_in_rig(&sim, &joint);
        if (0..3).all(|a| miss[a].abs() <= 3.0 * joint.projector.centre_sigma[a]) {
            centre_ok += 1;
        }
    }
    let med = Vector3::from_fn(|a, _| median(errors[a].clone()));
    let floor = floors.iter().sum::<Vector3<f64>>() / floors.len() as f64;
    (med, floor, centre_ok)
}

/// Section 6.2.3 at 0.1 px over 20 seeds: the median per-axis error with no similarity fit is
/// within Table 7's 0.141 / 0.206 / 0.559 mm (which the paper reached only after a fit), and the
/// centre lies within 3σ of the truth. At 0.5 px the errors grow in proportion to the noise.
#[test]
fn paper_experiment_beats_table7_without_a_fit() {
    let (med, floor, centre_ok) = paper_runs(0.1, 20);
    println!(
        "0.1 px: median error {:.3?} mm, floor {:.3?} mm, centre within 3σ in {centre_ok}/20",
        med.as_slice(),
        floor.as_slice()
    );
    let table7 = Vector3::new(0.141, 0.206, 0.559);
    for a in 0..3 {
        assert!(med[a] <= table7[a], "axis {a}: {} > {}", med[a], table7[a]);
    }
    assert!(
        centre_ok >= 19,
        "centre within 3σ in only {centre_ok}/20 seeds"
    );
    let (med5, floor5, centre_ok5) = paper_runs(0.5, 20);
    println!(
        "0.5 px: median error {:.3?} mm, floor {:.3?} mm, centre within 3σ in {centre_ok5}/20",
        med5.as_slice(),
        floor5.as_slice()
    );
    let ratio = med5.z / med.z;
    assert!(
        (3.5..=6.5).contains(&ratio),
        "0.5 px / 0.1 px error ratio {ratio}"
    );
    assert!((floor5.z / floor.z - 5.0).abs() < 0.1);
}

/// Five plates 100 mm apart and a sixth, tilted, not used in the calibration.
fn five_plates_and_unseen(sigma_px: f64) -> Scenario {
    let mut sc = Scenario::paper_five_plates();
    sc.noise.image_sigma_px = sigma_px;
    sc
}

/// An unseen plate, 440 rays, 5 plates, 0.05 px: the per-axis error (camera system, no fit) is
/// within 1.25x of the image-noise floor, and the propagated σ (image + calibration) is honest.
#[test]
fn unseen_plate_reaches_the_floor_with_honest_sigma() {
    let (_, inner) = true_camera(&Scenario::paper());
    for seed in [3, 4] {
        let sim = simulate(&five_plates_and_unseen(0.05), seed);
        let cal = calibrate_simulation(&sim, &inner, Model::Joint, None, 5).unwrap();
        let cmp = against_truth(&sim, &cal, 5, Method::ClosestApproach).unwrap();
        let (fig, honesty) = truth_figures(&cmp);
        println!(
            "seed {seed}: {} points, error {:.3?} mm, floor {:.3?} mm, RMS(e/σ) {honesty:.3}",
            fig.points,
            fig.error.as_slice(),
            fig.floor.as_slice()
        );
        assert_eq!(fig.points, 440);
        assert!(
            fig.floor.z > 0.2 && fig.floor.z < 0.4,
            "floor {}",
            fig.floor
        );
        for a in 0..3 {
            assert!(
                fig.error[a] <= 1.25 * fig.floor[a],
                "axis {a}: {} vs floor {}",
                fig.error[a],
                fig.floor[a]
            );
        }
        assert_honest(honesty, format_args!("seed {seed}: held-out points"));
    }
}

/// Table 8: cx = cy = k1 = 0 and f = 40 instead of Table 1's values. Against the truth the
/// surface is wrong by centimetres; in the paper's own comparison (eq. 10 reference, same wrong
/// camera) the scatter grows too.
#[test]
fn table8_wrong_inner_orientation_degrades() {
    let (_, right) = true_camera(&Scenario::paper());
    let mut wrong = right;
    wrong.cx = 0.0;
    wrong.cy = 0.0;
    wrong.k1 = 0.0;
    wrong.f = 40.0;
    let mut scatter = [Vec::new(), Vec::new()];
    let mut truth_z = [Vec::new(), Vec::new()];
    for seed in 0..7 {
        let sim = simulate(&paper_scenario(0.1), seed);
        for (k, inner) in [right, wrong].iter().enumerate() {
            let cal =
                calibrate_simulation(&sim, inner, Model::Paper, Some(&TABLE4_IDS), 3).unwrap();
            let (fig, _) = paper_experiment(&cal, 2, Method::Paper, 0.1).unwrap();
            scatter[k].push(fig.error.norm());
            let (t, _) = truth_figures(&against_truth(&sim, &cal, 2, Method::Paper).unwrap());
            truth_z[k].push(t.error.z);
        }
    }
    let (s_right, s_wrong) = (median(scatter[0].clone()), median(scatter[1].clone()));
    let (t_right, t_wrong) = (median(truth_z[0].clone()), median(truth_z[1].clone()));
    println!("scatter vs eq. 10: {s_right:.3} -> {s_wrong:.3} mm; Z vs truth: {t_right:.3} -> {t_wrong:.1} mm");
    assert!(s_wrong > 1.2 * s_right);
    assert!(t_right < 1.0 && t_wrong > 100.0);
}

/// The simulation's projector made non-central: each ray moved sideways by a cubic function of
/// its angle from the bundle's axis (a lens aberration: 4000 mm × |d|² d, d the direction minus the
/// axis, up to about 40 mm at the corners), and every plate dot
/// re-imaged through it with fresh noise.
const NONCENTRAL_K: f64 = 4000.0;

fn make_noncentral(sim: &mut Simulation, seed: u64) {
    let rays = &mut sim.truth.projector.rays;
    let axis = rays
        .iter()
        .map(|r| Vector3::from(r.camera))
        .sum::<Vector3<f64>>()
        .normalize();
    for r in rays.iter_mut() {
        let d = Vector3::from(r.camera) - axis;
        let offset = Vector3::new(d.x, d.y, 0.0) * (NONCENTRAL_K * d.norm_squared());
        r.offset_camera = offset.into();
    }
    let (grid, inner) = (sim.camera_init.grid(), true_camera(&Scenario::paper()).1);
    let images: Vec<String> = sim
        .truth
        .plate
        .images
        .iter()
        .map(|i| i.image.clone())
        .collect();
    let centre = Vector3::from(sim.truth.projector.centre_camera);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let sigma = sim.truth.noise.image_sigma_px;
    for o in sim
        .plate_obs
        .iter_mut()
        .filter(|o| o.kind == PointKind::Dot)
    {
        let k = images.iter().position(|i| *i == o.image).unwrap();
        let pose: ExteriorOrientation<f64> = sim.truth.plate.images[k].camera.into();
        let ray = sim
            .truth
            .projector
            .rays
            .iter()
            .find(|r| r.id.to_string() == o.point)
            .unwrap();
        let r_k = pose.r_cam_world();
        let normal: Vector3<f64> = r_k.column(2).into();
        let start = centre + Vector3::from(ray.offset_camera);
        let dir = Vector3::from(ray.camera);
        let hit = start + dir * ((-pose.centre.z - normal.dot(&start)) / normal.dot(&dir));
        let camera = Camera {
            grid,
            inner,
            exterior: pose,
        };
        let (col, row) = camera.world_to_pixel(&pose.camera_to_world(&hit)).unwrap();
        let noise: [f64; 2] = [
            StandardNormal.sample(&mut rng),
            StandardNormal.sample(&mut rng),
        ];
        o.col = col + sigma * noise[0];
        o.row = row + sigma * noise[1];
    }
}

/// With a non-central projector, `noncentral` beats `paper` by at least 3x in Z on the unseen
/// plate.
#[test]
fn noncentral_model_absorbs_projector_aberration() {
    let (_, inner) = true_camera(&Scenario::paper());
    let mut sim = simulate(&five_plates_and_unseen(0.05), 5);
    make_noncentral(&mut sim, 5);
    let mut z = Vec::new();
    for model in [Model::Paper, Model::Noncentral] {
        let cal = calibrate_simulation(&sim, &inner, model, None, 5).unwrap();
        let (fig, _) =
            truth_figures(&against_truth(&sim, &cal, 5, Method::ClosestApproach).unwrap());
        println!(
            "{model:?}: error {:.3?} mm, floor {:.3?} mm",
            fig.error.as_slice(),
            fig.floor.as_slice()
        );
        z.push(fig.error.z);
    }
    assert!(z[0] >= 3.0 * z[1], "paper {} vs noncentral {}", z[0], z[1]);
}
