//! The device identifies unlabelled dots of torso frames with the host's result: the same ray
//! (or the same status) for every dot as the host's f64 `shared::identify`, and the same point
//! within 1 µm; in-process and over QEMU (the real firmware binary), with the instructions per
//! point under `-icount shift=0`.

use deltaz_host::io::system_file::SystemRig;
use deltaz_host::link::{Device, Qemu, Transport, WorldPoint};
use deltaz_shared::identify::{Assignment, DepthRange, Identifier};
use deltaz_shared::protocol::calibration::IdentifyParams;
use deltaz_shared::protocol::{Dot, PointStatus};
use deltaz_shared::rig::Method;
use deltaz_tests::firmware_elf;
use deltaz_tests::torso::{self, HEIGHT, WALL};
use std::time::Duration;

const FINGERPRINT: u64 = 0x1D_0000_0440;
const PARAMS: IdentifyParams = IdentifyParams {
    near: (WALL - HEIGHT - 20.0) as f32,
    far: (WALL + 20.0) as f32,
    tolerance: 1.0,
    cell: 16.0,
};

/// One frame: the torso's dots (true ids), then a copy of dot 10 moved by 0.2 px (both claim
/// one ray: a conflict) and a dot in the top-left corner, outside the pattern (unassigned).
fn frame(rig: &SystemRig, ridge: f64) -> (Vec<u16>, Vec<(f64, f64)>) {
    let dots = torso::dots(rig, ridge, 0.15);
    let mut ids: Vec<u16> = dots.iter().map(|d| d.0).collect();
    let mut pixels: Vec<(f64, f64)> = dots.iter().map(|d| (d.1, d.2)).collect();
    ids.extend([dots[10].0, u16::MAX]);
    pixels.extend([(dots[10].1 + 0.2, dots[10].2), (1.0, 1.0)]);
    (ids, pixels)
}

type Answer = Vec<(u16, Result<WorldPoint, PointStatus>)>;

/// Check the device's answer against the host's f64 identification and reconstruction of the
/// same fixed-point pixels; returns the number identified.
fn check_against_host(
    rig: &SystemRig,
    bits: u8,
    ids: &[u16],
    pixels: &[(f64, f64)],
    got: &Answer,
) -> usize {
    let host = Box::new(
        Identifier::<f64, 512, 2048, 8192>::new(
            rig,
            DepthRange {
                near: f64::from(PARAMS.near),
                far: f64::from(PARAMS.far),
            },
            f64::from(PARAMS.tolerance),
            f64::from(PARAMS.cell),
        )
        .unwrap(),
    );
    let quantised: Vec<(f64, f64)> = pixels
        .iter()
        .map(|&(c, r)| Dot::from_pixel(c, r, bits).unwrap().pixel(bits))
        .collect();
    let mut assigned = vec![Assignment::Unassigned; pixels.len()];
    let identified = host.identify_frame(&quantised, &mut assigned);
    assert_eq!(got.len(), pixels.len());
    let mut worst = 0.0_f64;
    for (i, (a, (id, result))) in assigned.iter().zip(got).enumerate() {
        match *a {
            Assignment::Ray { id: host_id, .. } => {
                assert_eq!(*id, host_id, "dot {i}");
                assert_eq!(*id, ids[i], "dot {i}: a wrong ray");
                let (c, r) = quantised[i];
                let host_point = rig
                    .reconstruct(host_id, c, r, Method::ClosestApproach)
                    .unwrap();
                let p = result.expect("an identified dot has a point");
                worst = worst.max((p.point - host_point.point).norm());
            }
            Assignment::Ambiguous { first, .. } => {
                assert_eq!(
                    (*id, *result),
                    (first, Err(PointStatus::Ambiguous)),
                    "dot {i}"
                )
            }
            Assignment::Conflict { id: host_id } => {
                assert_eq!(
                    (*id, *result),
                    (host_id, Err(PointStatus::Conflict)),
                    "dot {i}"
                )
            }
            Assignment::Unassigned => {
                assert_eq!((*id, *result), (0, Err(PointStatus::Unassigned)), "dot {i}")
            }
        }
    }
    let n = pixels.len();
    assert_eq!(
        got[n - 1],
        (0, Err(PointStatus::Unassigned)),
        "the corner dot"
    );
    assert_eq!(got[n - 2].1, Err(PointStatus::Conflict), "the copied dot");
    assert_eq!(
        got[10].1,
        Err(PointStatus::Conflict),
        "the original of the copy"
    );
    let true_dots = n - 2;
    println!(
        "{identified} of {true_dots} torso dots identified ({:.2} %), worst |device − host f64| = {:.3} µm",
        100.0 * identified as f64 / true_dots as f64,
        worst * 1e3
    );
    // The device's f32 depth (a few ulps of λ: under a micrometre at 2 m) and half a unit of
    // its quantisation on the wire (0.49 µm).
    assert!(worst < 1.5e-3, "{worst} mm");
    // Every true dot but the two made to conflict.
    assert!(
        identified as f64 >= 0.99 * (true_dots - 1) as f64,
        "{identified}"
    );
    identified
}

fn run<T: Transport>(device: &mut Device<T>, rig: &SystemRig) -> Vec<Answer> {
    let bits = device
        .upload_identifying(rig, FINGERPRINT, Method::ClosestApproach, Some(PARAMS))
        .expect("upload")
        .centroid_bits;
    [-40.0, 60.0]
        .into_iter()
        .map(|ridge| {
            let (ids, pixels) = frame(rig, ridge);
            assert!(ids.len() > 400, "{} dots", ids.len());
            let (sent0, received0) = device.byte_counts();
            let got = device.identify(&pixels).expect("identify");
            let (sent1, received1) = device.byte_counts();
            let n = pixels.len() as f64;
            let (request, response) = ((sent1 - sent0) as f64 / n, (received1 - received0) as f64 / n);
            println!(
                "unlabelled frame of {n} dots: request {request:.3} + response {response:.3} = {:.3} bytes per point",
                request + response
            );
            // 4 bytes a dot, 3 a result plus its delta-coded id (1-3 bytes, image order), and
            // the frames' headers, CRC, COBS and delimiters: measured 4.045 + 4.104.
            assert!((4.0..4.06).contains(&request), "{request}");
            assert!((4.05..4.15).contains(&response), "{response}");
            assert!(request + response < 8.2, "{}", request + response);
            check_against_host(rig, bits, &ids, &pixels, &got);
            got
        })
        .collect()
}

#[test]
fn in_process_device_identifies_like_the_host() {
    let rig = torso::rig();
    let mut device = Device::in_process();
    let answers = run(&mut device, &rig);
    // A depth range of 4.5 m and a 6 px tolerance: the grid's cells grow until it fits (no
    // refusal), and every dot is still the right ray or reported unidentified.
    let wide = IdentifyParams {
        near: 500.0,
        far: 5000.0,
        tolerance: 6.0,
        ..PARAMS
    };
    device
        .upload_identifying(&rig, FINGERPRINT + 2, Method::ClosestApproach, Some(wide))
        .expect("a wide range fits with larger cells");
    let (ids, pixels) = frame(&rig, -40.0);
    let got = device.identify(&pixels).unwrap();
    let right = ids
        .iter()
        .zip(&got)
        .filter(|(want, (id, r))| r.is_ok() && id == *want)
        .count();
    let wrong = ids
        .iter()
        .zip(&got)
        .filter(|(want, (id, r))| r.is_ok() && id != *want)
        .count();
    println!(
        "500-5,000 mm, 6 px: {right} of {} dots right, {wrong} wrong",
        ids.len()
    );
    assert_eq!(wrong, 0);
    device
        .upload_identifying(&rig, FINGERPRINT, Method::ClosestApproach, Some(PARAMS))
        .unwrap();
    assert_eq!(device.identify(&pixels).unwrap(), answers[0]);
    // Without identification parameters the device refuses, and says why.
    device.upload(&rig, FINGERPRINT + 1).unwrap();
    let err = device.identify(&[(100.0, 100.0)]).unwrap_err();
    assert!(err.to_string().contains("no depth range"), "{err}");
}

#[test]
fn qemu_device_identifies_like_the_host() {
    let rig = torso::rig();
    let qemu = Qemu::spawn(&firmware_elf()).expect("start QEMU");
    let mut device = Device::new(qemu).with_timeout(Duration::from_secs(30));
    let answers = run(&mut device, &rig);
    let stats = device.stats().expect("stats");
    let points = u32::from(stats.last_compute_points);
    println!(
        "identify + compute of {points} dots: {} SysTick ticks = {} instructions per point (icount shift=0, 40 per tick); stack peak {} bytes",
        stats.last_compute_ticks,
        stats.last_compute_ticks * 40 / points,
        stats.stack_peak
    );
    assert!(stats.last_compute_ticks > 0);
    // Deterministic under -icount: the bar for identification and compute together.
    let per_point = stats.last_compute_ticks * 40 / points;
    assert!(
        per_point <= 1_500,
        "{per_point} instructions per identified point (goal ≤ 1,500)"
    );
    // Bit for bit the in-process device's answers.
    assert_eq!(answers, run(&mut Device::in_process(), &rig));
}
