//! The known-layout match of control targets ([`deltaz_measure::layout`]) on the paper
//! plate seen by the simulator's true camera: the distinct-target rule, its errors, and the
//! match among dot-like blobs.

use deltaz_host::simulate::{plate_targets, true_camera, Scenario};
use deltaz_measure::layout::{match_layout, Blob, Layout, LayoutError};
use deltaz_measure::target_field::{distinct_targets, DISTINCT_COUNT};
use deltaz_shared::collinearity::Camera;
use nalgebra::{Vector2, Vector3};
use rand::{RngExt, SeedableRng};

fn plate() -> Vec<(String, Vector3<f64>)> {
    plate_targets(&Scenario::paper())
}

#[test]
fn distinct_rule_and_layout_errors() {
    let points = plate();
    let mut d = distinct_targets(&points, DISTINCT_COUNT);
    d.sort();
    // The four plate-level points nearest the ring's centroid and the nearer row middle.
    assert_eq!(d, ["C03", "C06", "C10", "C11", "C15"]);
    assert_eq!(
        Layout::new(points.clone(), &["C03".into(), "X".into()]),
        Err(LayoutError::UnknownDistinct("X".into()))
    );
    // C08 is raised: the distinct targets must share one plane.
    let mixed: Vec<String> = ["C03", "C06", "C08", "C10"].map(String::from).to_vec();
    assert_eq!(
        Layout::new(points, &mixed),
        Err(LayoutError::DistinctNotCoplanar)
    );
}

/// The paper plate seen from Table 2's 1st pose among 300 dot-like blobs: every control
/// point labelled right; with two distinct targets missing the match fails instead of
/// guessing.
#[test]
fn plate_among_dots() {
    let scenario = Scenario::paper();
    let (grid, inner) = true_camera(&scenario);
    let camera = Camera {
        grid,
        inner,
        exterior: scenario.plate.images[0].into(),
    };
    let layout = Layout::with_default_distinct(plate()).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut blobs = Vec::new();
    let mut truth = Vec::new();
    for (k, (_, xyz)) in layout.points.iter().enumerate() {
        let (c, r) = camera.world_to_pixel(xyz).unwrap();
        if grid.contains(c, r) {
            let area = if layout.distinct.contains(&k) {
                300.0
            } else {
                90.0
            };
            let noise = Vector2::new(rng.random_range(-0.05..0.05), rng.random_range(-0.05..0.05));
            blobs.push(Blob {
                centre: Vector2::new(c, r) + noise,
                area,
            });
            truth.push(Some(k));
        }
    }
    while blobs.len() < 300 {
        let p = Vector2::new(rng.random_range(5.0..763.0), rng.random_range(5.0..507.0));
        if blobs.iter().all(|b| (b.centre - p).norm() > 12.0) {
            blobs.push(Blob {
                centre: p,
                area: 45.0,
            });
            truth.push(None);
        }
    }
    let m = match_layout(&layout, &blobs, &[], &grid, &inner, 8.0).unwrap();
    assert_eq!(m.labels, truth);
    assert!(m.rms_px < 0.1, "{}", m.rms_px);

    // Two distinct targets gone (e.g. covered): not enough to start, an error.
    let mut fewer = blobs.clone();
    for &k in &layout.distinct[..2] {
        let at = truth.iter().position(|t| *t == Some(k)).unwrap();
        fewer[at].area = 45.0;
        fewer[at].centre.x = -100.0;
    }
    assert!(match_layout(&layout, &fewer, &[], &grid, &inner, 8.0).is_err());
}
