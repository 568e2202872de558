//! The typed client against the firmware's logic in-process.

use deltaz_firmware::smoke::{paper_rig, smoke_pixel, RAY};
use deltaz_host::link::{Device, DeviceError};
use deltaz_shared::protocol::{Centroid, PointStatus};
use deltaz_shared::rig::Method;
use std::time::Duration;

#[test]
fn upload_compute_reset_and_errors() {
    let mut device = Device::in_process().with_timeout(Duration::from_millis(50));
    let info = device.info().unwrap();
    assert_eq!(info.calibration, None);
    assert!(matches!(
        device.compute(&[(RAY, 100.0, 100.0)]),
        Err(DeviceError::NoCalibration)
    ));

    let rig = paper_rig();
    let summary = device.upload(&rig, 0xDE17A).unwrap();
    assert_eq!(
        (summary.fingerprint, summary.rays, summary.generation),
        (0xDE17A, 1, 1)
    );
    assert_eq!(summary.centroid_bits, 6);

    let (col, row) = smoke_pixel().unwrap();
    let points = device
        .compute(&[(RAY, col, row), (RAY + 1, col, row)])
        .unwrap();
    let (qc, qr) = Centroid::from_pixel(RAY, col, row, 6)
        .unwrap()
        .pixel::<f64>(6);
    let host = rig
        .reconstruct(RAY, qc, qr, Method::ClosestApproach)
        .unwrap();
    let got = points[0].unwrap();
    let error = (got.point - host.point).norm();
    assert!(error < 1e-3, "device vs host f64: {error} mm");
    assert_eq!(points[1], Err(PointStatus::UnknownRay));

    // The calibration survives a reset; another fingerprint is a clear error.
    device.reset().unwrap();
    assert_eq!(device.expect_calibration(0xDE17A).unwrap().generation, 1);
    match device.expect_calibration(7) {
        Err(DeviceError::Fingerprint {
            expected: 7,
            device: Some(0xDE17A),
        }) => {}
        other => panic!("{other:?}"),
    }
    // A second upload is generation 2.
    assert_eq!(device.upload(&rig, 0xBEEF).unwrap().generation, 2);
    assert!(matches!(
        device.compute(&[(RAY, 1e6, 0.0)]),
        Err(DeviceError::Centroid(0))
    ));
}
