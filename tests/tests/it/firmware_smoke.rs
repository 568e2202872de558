//! The firmware smoke: the real board binary runs under QEMU (mps2-an386), computes one
//! intersection at boot in f32 and prints it over UART0; it must match the host's f64 result.

use deltaz_firmware::smoke::{paper_rig, smoke_pixel, RAY};
use deltaz_shared::rig::Method;
use deltaz_tests::{firmware_elf, run_qemu_until};
use std::time::Duration;

#[test]
fn qemu_prints_the_host_point() {
    let elf = firmware_elf();
    let output = run_qemu_until(&elf, "\n", Duration::from_secs(60));
    let line = output
        .lines()
        .find(|l| l.starts_with("deltaz smoke point"))
        .unwrap_or_else(|| panic!("no smoke line from the firmware; it printed {output:?}"));
    let printed: Vec<f64> = line
        .split_whitespace()
        .skip(3)
        .map(|v| v.parse().expect("a number"))
        .collect();
    let (col, row) = smoke_pixel().unwrap();
    // The host's f64 result for the same f32-rounded pixel.
    let host = paper_rig()
        .reconstruct(
            RAY,
            f64::from(col as f32),
            f64::from(row as f32),
            Method::ClosestApproach,
        )
        .unwrap()
        .point;
    assert!(
        host.z.abs() < 1e-3,
        "the smoke dot lies on the plate Z = 0: {host}"
    );
    for (axis, (p, h)) in printed.iter().zip(host.iter()).enumerate() {
        // Printed to 6 decimals; the f32 device agrees with f64 within 1 µm.
        assert!((p - h).abs() < 1e-3, "axis {axis}: device {p} vs host {h}");
    }
}
