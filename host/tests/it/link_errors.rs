//! Clear errors on the link: a busy port, a silent device (timeout), a device that holds another
//! calibration.

use deltaz_firmware::smoke::paper_rig;
use deltaz_host::link::{Device, DeviceError, Serial, Transport};
use serialport::{SerialPort, TTYPort};
use std::io;
use std::time::{Duration, Instant};

#[test]
fn a_port_held_by_another_program_is_busy() {
    let (_host, device_end) = TTYPort::pair().unwrap();
    let path = device_end.name().unwrap();
    let first = Serial::open(&path, 115_200).expect("the first open succeeds");
    match Serial::open(&path, 115_200) {
        Err(DeviceError::Busy(p)) => assert_eq!(p, path),
        Err(e) => panic!("expected busy, got {e}"),
        Ok(_) => panic!("a second open of {path} succeeded"),
    }
    drop(first);
}

/// A line with nothing on the other end.
struct Silent;

impl Transport for Silent {
    fn send(&mut self, _: &[u8]) -> io::Result<()> {
        Ok(())
    }
    fn recv(&mut self, _: &mut [u8], timeout: Duration) -> io::Result<usize> {
        std::thread::sleep(timeout.min(Duration::from_millis(20)));
        Ok(0)
    }
}

#[test]
fn a_silent_device_times_out() {
    let timeout = Duration::from_millis(150);
    let mut device = Device::new(Silent).with_timeout(timeout);
    let start = Instant::now();
    match device.info() {
        Err(DeviceError::Timeout(t)) => assert_eq!(t, timeout),
        other => panic!("{other:?}"),
    }
    assert!(start.elapsed() >= timeout);
    let text = DeviceError::Timeout(timeout).to_string();
    assert_eq!(text, "the device did not answer within 150ms");
}

#[test]
fn another_calibration_is_named() {
    let mut device = Device::in_process().with_timeout(Duration::from_millis(10));
    device.upload(&paper_rig(), 0xAAAA).unwrap();
    let e = device.expect_calibration(0xBBBB).unwrap_err();
    assert_eq!(
        e.to_string(),
        "the device holds calibration 000000000000aaaa, not 000000000000bbbb"
    );
}

/// The in-process device behind a line that damages chosen sends (one bit, never making a zero).
struct Flaky {
    inner: deltaz_host::link::InProcess,
    sends: usize,
    damage: fn(usize) -> bool,
}

impl Transport for Flaky {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.sends += 1;
        let mut bytes = bytes.to_vec();
        if (self.damage)(self.sends) {
            let mid = bytes.len() / 2;
            bytes[mid] ^= if bytes[mid] == 0x40 { 0x20 } else { 0x40 };
        }
        self.inner.send(&bytes)
    }
    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        self.inner.recv(buf, timeout)
    }
}

#[test]
fn damaged_frames_are_sent_again() {
    let flaky = |damage| Flaky {
        inner: deltaz_host::link::InProcess::new(),
        sends: 0,
        damage,
    };
    // Sends 2 and 4 (the one chunk and the commit) arrive damaged once each.
    let mut device = Device::new(flaky(|n| n == 2 || n == 4)).with_timeout(Duration::from_secs(2));
    let summary = device.upload(&paper_rig(), 0xF1A).unwrap();
    assert_eq!(summary.fingerprint, 0xF1A);
    let sends = device.into_transport().sends;
    // Begin, the chunks, commit and Info, plus the two repeats.
    let chunks = deltaz_host::link::calibration_blob(
        &paper_rig(),
        0xF1A,
        deltaz_shared::rig::Method::ClosestApproach,
    )
    .unwrap()
    .len()
    .div_ceil(deltaz_shared::protocol::CHUNK_SIZE);
    assert_eq!(sends, 1 + chunks + 1 + 1 + 2);
    // A line that damages everything: the device's seq-0 answers are not taken for the
    // request's; after TRIES sends the client says what it saw.
    let mut device = Device::new(flaky(|_| true)).with_timeout(Duration::from_secs(2));
    match device.info() {
        Err(DeviceError::NoValidAnswer {
            tries,
            unreadable,
            damaged: 0,
            stale: 0,
        }) if tries == deltaz_host::link::TRIES && unreadable == tries as u64 => {}
        other => panic!("{other:?}"),
    }
    assert_eq!(device.into_transport().sends, deltaz_host::link::TRIES);
}
