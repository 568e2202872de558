//! The link to the device: a typed [`Device`] client over a byte [`Transport`].
//!
//! Three transports carry the same frames: [`InProcess`] (the firmware's own logic in this
//! process, the default without a port), [`Serial`] (a serial port) and [`Qemu`] (the firmware
//! binary in `qemu-system-arm`, on a pty).

mod calibration;
mod client;
mod in_process;
mod qemu;
mod serial;

pub use calibration::{calibration_blob, calibration_blob_identifying};
pub use client::{
    Device, DeviceError, LineCounts, PointOutcome, WorldPoint, DEFAULT_TIMEOUT, DEFAULT_WINDOW,
    TRIES,
};
pub use in_process::{InProcess, InProcessFlash};
pub use qemu::Qemu;
pub use serial::{list_ports, Serial};

use std::io;
use std::time::Duration;

/// Bytes to and from a device.
pub trait Transport {
    /// Send all of `bytes`.
    fn send(&mut self, bytes: &[u8]) -> io::Result<()>;
    /// Read what has arrived, waiting up to `timeout` for the first byte; `Ok(0)` on timeout.
    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize>;
}

impl<T: Transport + ?Sized> Transport for Box<T> {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        (**self).send(bytes)
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        (**self).recv(buf, timeout)
    }
}

/// The step (px) a device's centroids are quantised to on the wire for a sensor of `width` ×
/// `height` pixels: its points carry that rounding (a uniform error, variance step²/12 per
/// coordinate).
pub fn centroid_step_px(width: u32, height: u32) -> f64 {
    0.5_f64.powi(i32::from(deltaz_shared::protocol::centroid_fraction_bits(
        width, height,
    )))
}
