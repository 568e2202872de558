//! The desk-scale rig ([`Scenario::desk`]), a geometry unlike the paper's: robust resection of
//! every plate image, including those that see a single raised control point.

use deltaz_host::io::camera_file::PoseParams;
use deltaz_host::io::observations::PointKind;
use deltaz_host::simulate::{simulate, true_camera, Scenario};
use deltaz_host::workflows::plates::resect_images;
use std::path::Path;

/// Every plate image resects (5 seeds), its pose within 4σ of the truth; at least one image of
/// the rig sees exactly one raised point, the case where a general 3D start used to fail.
#[test]
fn every_desk_plate_image_resects() {
    let scenario = Scenario::desk();
    let (grid, inner) = true_camera(&scenario);
    let raised: Vec<String> = scenario
        .plate
        .control
        .iter()
        .enumerate()
        .filter(|(_, c)| c[2] > 0.0)
        .map(|(i, _)| format!("C{:02}", i + 1))
        .collect();
    for seed in 1..=5 {
        let sim = simulate(&scenario, seed);
        let one_raised = (1..=scenario.plate.images.len())
            .filter(|k| {
                let image = format!("p{k}");
                let seen = sim
                    .plate_obs
                    .iter()
                    .filter(|o| o.image == image && o.kind == PointKind::Control)
                    .filter(|o| raised.contains(&o.point))
                    .count();
                seen == 1
            })
            .count();
        assert!(one_raised >= 1, "no image sees a single raised point");
        let results = resect_images(
            Path::new("plate_obs.csv"),
            &grid,
            &inner,
            &sim.plate_obs,
            &sim.plate_control,
        )
        .unwrap();
        assert_eq!(results.len(), scenario.plate.images.len());
        for ((image, r), truth) in results.iter().zip(&scenario.plate.images) {
            let est = PoseParams::from(r.exterior).to_array();
            for (k, (e, t)) in est.iter().zip(truth.to_array()).enumerate() {
                let z = (e - t) / r.sigma[k];
                assert!(z.abs() < 4.0, "seed {seed} {image} parameter {k}: {z:.1}σ");
            }
        }
    }
}
