//! A serial port (a USB virtual COM port, a UART adapter, a pty).

use super::client::DeviceError;
use super::Transport;
use serialport::{SerialPort, SerialPortType};
use std::io::{self, Read, Write};
use std::path::Path;
use std::time::Duration;

/// The serial ports of this machine: (path, description).
pub fn list_ports() -> Result<Vec<(String, String)>, DeviceError> {
    let ports = serialport::available_ports()
        .map_err(|e| DeviceError::Io(io::Error::other(e.to_string())))?;
    Ok(ports
        .into_iter()
        .map(|p| {
            let what = match p.port_type {
                SerialPortType::UsbPort(u) => format!(
                    "USB {:04x}:{:04x} {}",
                    u.vid,
                    u.pid,
                    u.product.unwrap_or_default()
                ),
                SerialPortType::PciPort => "PCI".into(),
                SerialPortType::BluetoothPort => "Bluetooth".into(),
                SerialPortType::Unknown => "unknown".into(),
            };
            (p.port_name, what)
        })
        .collect())
}

/// A device on a serial port, 8N1, opened exclusively.
pub struct Serial {
    port: Box<dyn SerialPort>,
}

impl Serial {
    /// Open `path` at `baud`: [`DeviceError::Absent`] when there is no such port,
    /// [`DeviceError::Busy`] when another program holds it.
    pub fn open(path: &str, baud: u32) -> Result<Self, DeviceError> {
        if !Path::new(path).exists() {
            return Err(DeviceError::Absent(path.into()));
        }
        let port = serialport::new(path, baud)
            .timeout(Duration::from_millis(100))
            .open()
            .map_err(|e| {
                let text = e.to_string().to_lowercase();
                if text.contains("busy") || text.contains("temporarily unavailable") {
                    DeviceError::Busy(path.into())
                } else if e.kind() == serialport::ErrorKind::NoDevice {
                    DeviceError::Absent(path.into())
                } else {
                    DeviceError::Io(io::Error::other(format!("{path}: {e}")))
                }
            })?;
        Ok(Self { port })
    }

    /// A device on an already open port (for example the host end of a pty).
    pub fn from_port(port: Box<dyn SerialPort>) -> Self {
        Self { port }
    }
}

impl Transport for Serial {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        // A slow reader (QEMU's UART takes a byte at a time) must not time out a long frame.
        self.port
            .set_timeout(Duration::from_secs(10))
            .map_err(|e| io::Error::other(e.to_string()))?;
        self.port.write_all(bytes)?;
        self.port.flush()
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        self.port
            .set_timeout(timeout.max(Duration::from_millis(1)))
            .map_err(|e| io::Error::other(e.to_string()))?;
        match self.port.read(buf) {
            Err(e) if e.kind() == io::ErrorKind::TimedOut => Ok(0),
            other => other,
        }
    }
}
