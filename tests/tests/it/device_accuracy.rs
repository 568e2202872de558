//! The device's f32 model against the host's f64 reconstruction, both intersection methods, over
//! the full pattern on three plates (in-process: the same code the QEMU test runs on ARM, where
//! it gives the same numbers bit for bit).

use deltaz_host::link::Device;
use deltaz_shared::protocol::Centroid;
use deltaz_shared::rig::Method;
use deltaz_tests::pattern::{pattern_rig, plate_centroids};

#[test]
fn device_matches_host_f64_within_a_micrometre() {
    let rig = pattern_rig();
    for method in [Method::ClosestApproach, Method::Paper] {
        let mut device = Device::in_process();
        let bits = device.upload_with(&rig, 3, method).unwrap().centroid_bits;
        let mut worst = 0.0_f64;
        let mut n = 0;
        for z in [0.0, 100.0, 200.0] {
            let frame = plate_centroids(&rig, z, (0.21, -0.13));
            for (&(id, col, row), got) in frame.iter().zip(device.compute(&frame).unwrap()) {
                let (qc, qr) = Centroid::from_pixel(id, col, row, bits)
                    .unwrap()
                    .pixel::<f64>(bits);
                let host = rig.reconstruct(id, qc, qr, method).unwrap();
                let got = got.unwrap();
                worst = worst.max((got.point - host.point).norm());
                assert!(
                    // Half a unit of the 2⁻⁸ mm miss code plus the f32 error.
                    (got.miss - host.miss).abs() <= 0.5 / 256.0 + 1e-3,
                    "{method:?} ray {id}: miss {} vs {}",
                    got.miss,
                    host.miss
                );
                n += 1;
            }
        }
        println!(
            "{method:?}: {n} points, worst |device − host f64| = {:.3} µm",
            worst * 1e3
        );
        assert_eq!(n, 3 * 440);
        assert!(worst < 1e-3, "{method:?}: {worst} mm");
    }
}
