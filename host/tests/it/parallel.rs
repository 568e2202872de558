//! The adjustments on all cores give the numbers they give on one, to the bit: their parallel
//! loops (normal equations, Schur elimination, Cholesky factor, covariance, redundancy numbers)
//! cut the work into pieces that do not depend on the number of threads and sum in a fixed
//! order.

use deltaz_calib::bundle::CalibrationOptions;
use deltaz_host::simulate::{simulate, Scenario};
use deltaz_host::workflows::accuracy::{adjust_simulation_joint, bundle_camera};

/// `run` in a pool of `threads` threads.
fn on_threads<T: Send>(threads: usize, run: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(run)
}

/// A network of 24 field images × 300 targets (148 camera states: two pieces of columns) and
/// five plates: the bundle adjustment (with data snooping) and the joint adjustment on 1 and on
/// 3 threads print the same (`{:?}` of an f64 is exact: it reads back to the same bits).
#[test]
fn adjustments_are_the_same_on_one_thread_and_on_three() {
    let mut scenario = Scenario::large(24, 300);
    scenario.plate.images = Scenario::paper_five_plates().plate.images;
    scenario.plate.images.truncate(5);
    let sim = simulate(&scenario, 3);
    let run = || {
        let camera = bundle_camera(&sim, &CalibrationOptions::default()).unwrap();
        let (system, _) = adjust_simulation_joint(&sim, &camera, false, None).unwrap();
        (
            format!("{:?} {:?}", camera.problem, camera.solution),
            format!("{:?} {:?}", system.model, system.redundancy),
        )
    };
    let (camera_1, system_1) = on_threads(1, run);
    let (camera_3, system_3) = on_threads(3, run);
    assert!(camera_1 == camera_3, "the bundle adjustment differs");
    assert!(system_1 == system_3, "the joint adjustment differs");
    // The comparison is of the whole result: covariances included.
    assert!(camera_1.len() > 100_000 && system_1.len() > 10_000);
}
