//! The firmware binary for `mps2-an386` running in `qemu-system-arm`, its UART0 on a pty whose
//! host end this transport holds.
//!
//! QEMU runs with `-icount shift=0`: one guest instruction per virtual nanosecond, so SysTick
//! (25 MHz) counts 40 instructions per tick and the device's tick counts are repeatable.

use super::serial::Serial;
use super::Transport;
use serialport::{SerialPort, TTYPort};
use std::io;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

/// A QEMU process running the firmware, and the pty to its UART0.
pub struct Qemu {
    child: Child,
    link: Serial,
    // The device end stays open so the pty lives as long as QEMU may use it.
    _device_end: TTYPort,
}

impl Qemu {
    /// Start `qemu-system-arm -machine mps2-an386` with `elf`, its UART0 on a new pty.
    pub fn spawn(elf: &Path) -> io::Result<Self> {
        let (host_end, device_end) =
            TTYPort::pair().map_err(|e| io::Error::other(e.to_string()))?;
        let path = device_end
            .name()
            .ok_or_else(|| io::Error::other("the pty has no name"))?;
        let child = Command::new("qemu-system-arm")
            .args(["-machine", "mps2-an386", "-nographic", "-monitor", "none"])
            .args(["-icount", "shift=0", "-serial", &path, "-kernel"])
            .arg(elf)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|e| {
                io::Error::new(
                    e.kind(),
                    format!("cannot start qemu-system-arm (apt-get install qemu-system-arm): {e}"),
                )
            })?;
        let mut me = Self {
            child,
            link: Serial::from_port(Box::new(host_end)),
            _device_end: device_end,
        };
        me.skip_boot_line()?;
        Ok(me)
    }

    /// Read the firmware's boot line (the smoke point, ended by a 0x00) so that a session's
    /// first answers are not preceded by it: however long QEMU takes to boot, a clean line then
    /// carries nothing but answers. Gives up quietly after 10 s (the line's drain and the
    /// client's frame reader drop such text too, as damage).
    fn skip_boot_line(&mut self) -> io::Result<()> {
        let start = std::time::Instant::now();
        let mut byte = [0u8; 1];
        while start.elapsed() < Duration::from_secs(10) {
            if self.recv(&mut byte, Duration::from_millis(100))? == 1 && byte[0] == 0 {
                break;
            }
        }
        Ok(())
    }
}

impl Transport for Qemu {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.link.send(bytes)
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        if let Some(status) = self.child.try_wait()? {
            return Err(io::Error::other(format!("QEMU exited: {status}")));
        }
        self.link.recv(buf, timeout)
    }
}

impl Drop for Qemu {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
