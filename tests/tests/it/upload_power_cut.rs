//! A power cut at every flash operation of an upload (the RAM flash stops after N operations, for
//! every N): after the reboot the device holds the old calibration or the new one, never a mix,
//! and computes exactly what that calibration computes.

use deltaz_firmware::smoke::{smoke_pixel, RAY};
use deltaz_host::link::{calibration_blob, Device, DeviceError, InProcess};
use deltaz_shared::protocol::{ErrorCode, CHUNK_SIZE};
use deltaz_shared::rig::{Method, Rig};
use deltaz_tests::pattern::pattern_rig;
use nalgebra::Vector3;
use std::time::Duration;

const OLD: u64 = 0x01D;
const NEW: u64 = 0x0E3;

#[test]
fn power_cut_at_every_flash_operation_of_an_upload() {
    let old_rig = pattern_rig();
    // The new calibration: the projector 20 mm further along X (every point moves).
    let new_rig = {
        let camera = deltaz_firmware::smoke::paper_camera();
        let shift = old_rig.camera_centre() + Vector3::new(20.0, 0.0, 0.0);
        let projector = old_rig.projector_centred().clone().shifted(shift);
        Rig::new(camera.grid, camera.inner, &camera.exterior, projector)
    };
    let blob = calibration_blob(&new_rig, NEW, Method::ClosestApproach).unwrap();
    let (col, row) = smoke_pixel().unwrap();
    let dot = [(RAY, col, row)];
    let quick = Duration::from_millis(1);

    let mut device = Device::in_process().with_timeout(quick);
    device.upload(&old_rig, OLD).unwrap();
    let old_point = device.compute(&dot).unwrap()[0].unwrap().point;
    let base = device_flash(device);
    let mut clean = Device::in_process();
    clean.upload(&new_rig, NEW).unwrap();
    let new_point = clean.compute(&dot).unwrap()[0].unwrap().point;
    assert!((new_point - old_point).norm() > 1.0, "every point moves");

    let mut outcomes = (0, 0);
    for cut in 0.. {
        let mut flash = base.clone();
        flash.cut_power_after(cut);
        let mut device = Device::new(InProcess::with_flash(flash)).with_timeout(quick);
        let result = device.upload(&new_rig, NEW);
        let mut flash = device_flash(device);
        flash.restore_power();
        let mut rebooted = Device::new(InProcess::with_flash(flash)).with_timeout(quick);
        let held = rebooted
            .info()
            .unwrap()
            .calibration
            .expect("a calibration")
            .fingerprint;
        // The host places the device's depths with the calibration the device says it holds.
        let rig = if held == NEW { &new_rig } else { &old_rig };
        rebooted.expect_system(rig, held).unwrap();
        let point = rebooted.compute(&dot).unwrap()[0].unwrap().point;
        match held {
            OLD => {
                assert!(
                    matches!(result, Err(DeviceError::Device(ErrorCode::Storage))),
                    "cut {cut}: {result:?}"
                );
                assert_eq!(
                    point, old_point,
                    "cut {cut}: old fingerprint, other numbers"
                );
                outcomes.0 += 1;
            }
            NEW => {
                assert_eq!(
                    point, new_point,
                    "cut {cut}: new fingerprint, other numbers"
                );
                outcomes.1 += 1;
                if result.is_ok() {
                    break;
                }
            }
            other => panic!("cut {cut}: fingerprint {other:x}"),
        }
    }
    // The store's operations: the erase at UploadBegin, one write per chunk as it arrives (the
    // last chunk's whole write units, then its remainder padded at the commit), the header; a
    // cut at any of them (cuts 0 .. operations − 1 tear one) leaves the old calibration.
    let unit = deltaz_host::link::InProcessFlash::WRITE;
    let last = blob.len() % CHUNK_SIZE;
    let operations = 1
        + blob.len() / CHUNK_SIZE
        + usize::from(last >= unit)
        + usize::from(!blob.len().is_multiple_of(unit))
        + 1;
    assert_eq!(
        outcomes,
        (operations, 1),
        "(old, new) over every cut; blob {} B",
        blob.len()
    );
}

fn device_flash(device: Device<InProcess>) -> deltaz_host::link::InProcessFlash {
    device
        .into_transport()
        .into_flash()
        .expect("a device that booted")
}
