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
