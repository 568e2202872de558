//! The typed client against the firmware's logic in-process.

use deltaz_firmware::smoke::{paper_rig, smoke_pixel, RAY};
use deltaz_host::link::{Device, DeviceError, InProcess, Transport};
use deltaz_shared::protocol::{Centroid, PointStatus};
use deltaz_shared::rig::Method;
use std::collections::VecDeque;
use std::io;
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

/// The in-process device behind a line that holds each request until the client reads: the
/// requests the client has sent and not yet had answered are in flight.
struct Held {
    inner: InProcess,
    sent: VecDeque<Vec<u8>>,
    /// The most requests, and request bytes, in flight at once.
    most: (usize, usize),
}

impl Transport for Held {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.sent.push_back(bytes.to_vec());
        let bytes = self.sent.iter().map(Vec::len).sum();
        self.most = (self.most.0.max(self.sent.len()), self.most.1.max(bytes));
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        if let Some(request) = self.sent.pop_front() {
            self.inner.send(&request)?;
        }
        self.inner.recv(buf, timeout)
    }
}

/// Past the first, a request goes out only while the requests in flight fit the byte budget
/// (`Device::with_in_flight_bytes`, what a board receives while it answers).
#[test]
fn requests_in_flight_stay_within_the_byte_budget() {
    let (col, row) = smoke_pixel().unwrap();
    let frames = vec![vec![(RAY, col, row); 300]; 6];
    let run = |window: usize, budget: usize| {
        let held = Held {
            inner: InProcess::new(),
            sent: VecDeque::new(),
            most: (0, 0),
        };
        let mut device = Device::new(held)
            .with_timeout(Duration::from_millis(20))
            .with_window(window)
            .with_in_flight_bytes(budget);
        device.upload(&paper_rig(), 1).unwrap();
        let points = device.compute_frames(&frames).unwrap();
        assert!(points.iter().flatten().all(Result::is_ok));
        device.into_transport().most
    };
    // One request at a time: its length.
    let (one, len) = run(1, usize::MAX);
    assert_eq!(one, 1);
    assert!(len > 300 * 5, "{len}");
    assert_eq!(run(4, usize::MAX), (4, 4 * len));
    assert_eq!(run(4, 2 * len), (2, 2 * len));
    assert_eq!(run(4, 2 * len - 1), (1, len));
}
