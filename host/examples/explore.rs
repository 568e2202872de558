use deltaz_host::accuracy::*;
use deltaz_host::io::camera_file::PoseParams;
use deltaz_host::projector_calibration::Model;
use deltaz_host::simulate::{simulate, true_camera, Scenario};
use deltaz_shared::rig::Method;

fn five_plates(sigma: f64) -> Scenario {
    let mut sc = Scenario::paper();
    sc.noise.image_sigma_px = sigma;
    sc.plate.control_sigma = std::env::var("CS").map(|v| v.parse().unwrap()).unwrap_or(0.1);
    let base = sc.plate.images[0].to_array();
    sc.plate.images = (0..5)
        .map(|k| {
            let mut p = base;
            p[5] -= 100.0 * k as f64;
            p[1] += 0.004 * k as f64;
            PoseParams::from_array(p)
        })
        .collect();
    let mut unseen = base;
    unseen[5] -= 150.0;
    unseen[1] += 0.05;
    unseen[3] += 60.0;
    sc.plate.images.push(PoseParams::from_array(unseen));
    sc
}

fn main() {
    let (_, inner) = true_camera(&Scenario::paper());
    for seed in 0..6 {
        let sc = five_plates(0.05);
        let sim = simulate(&sc, seed);
        for model in [Model::Paper, Model::Joint, Model::Noncentral] {
            match calibrate_simulation(&sim, &inner, model, None, 5) {
                Ok(cal) => {
                    let t = against_truth(&sim, &cal, 5, Method::ClosestApproach).unwrap();
                    let (tf, h) = truth_figures(&t);
                    println!("unseen seed {seed} {model:?}: n {} err {:.3?} floor {:.3?} honesty {h:.2}", tf.points, tf.error.as_slice(), tf.floor.as_slice());
                }
                Err(e) => println!("unseen {model:?}: {e:#}"),
            }
        }
        // non-central projector
        let mut sc = five_plates(0.05);
        sc.rig.pattern.noncentral_mm = 30.0;
        sc.rig.pattern.distortion = 0.0;
        let sim = simulate(&sc, seed);
        for model in [Model::Paper, Model::Noncentral] {
            let cal = calibrate_simulation(&sim, &inner, model, None, 5).unwrap();
            let t = against_truth(&sim, &cal, 5, Method::ClosestApproach).unwrap();
            let (tf, h) = truth_figures(&t);
            println!("noncentral scen seed {seed} {model:?}: err {:.3?} floor {:.3?} honesty {h:.2}", tf.error.as_slice(), tf.floor.as_slice());
        }
        // Table 8
        let mut sc = Scenario::paper();
        sc.noise.image_sigma_px = 0.1;
        let sim = simulate(&sc, seed);
        let mut wrong = inner;
        wrong.cx = 0.0; wrong.cy = 0.0; wrong.k1 = 0.0; wrong.f = 40.0;
        for (name, inn) in [("right", inner), ("wrong", wrong)] {
            let cal = calibrate_simulation(&sim, &inn, Model::Paper, Some(&TABLE4_IDS), 3).unwrap();
            let (f, mse) = paper_experiment(&cal, 2, Method::Paper, 0.1).unwrap();
            let t = against_truth(&sim, &cal, 2, Method::Paper).unwrap();
            let (tf, _) = truth_figures(&t);
            println!("table8 seed {seed} {name}: nofit {:.3?} fit {:.3?} truth {:.3?} pose1 {:?}", f.error.as_slice(), mse.as_slice(), tf.error.as_slice(), cal.content.camera.pose);
        }
    }
}
