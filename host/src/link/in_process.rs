//! The firmware's logic in this process, behind the same framing as a real device.

use super::Transport;
use deltaz_firmware::device::{NoProbe, MAX_CALIBRATION};
use deltaz_firmware::ram_flash::RamFlash;
use deltaz_firmware::server::Server;
use deltaz_firmware::store::{Store, HEADER};
use std::io;
use std::time::Duration;

/// One slot: the header and the largest calibration, rounded up to whole sectors.
const SLOT: usize = (HEADER + MAX_CALIBRATION).div_ceil(4096) * 4096;
/// The in-process device's flash: two slots.
pub type InProcessFlash = RamFlash<{ 2 * SLOT }>;

/// The device logic in-process, its calibration in a RAM flash that survives [`Transport`]
/// resets (a `Reset` request reboots the device from that flash, as a board would).
pub struct InProcess {
    server: Option<Box<Server<InProcessFlash, NoProbe>>>,
    outbox: Vec<u8>,
}

impl Default for InProcess {
    fn default() -> Self {
        Self::new()
    }
}

impl InProcess {
    /// The store's two slots in [`InProcessFlash`] (byte ranges).
    pub const SLOTS: [(u32, u32); 2] = [(0, SLOT as u32), (SLOT as u32, 2 * SLOT as u32)];

    /// A device with an empty flash.
    pub fn new() -> Self {
        Self::with_flash(InProcessFlash::new())
    }

    /// A device booting from `flash`.
    pub fn with_flash(flash: InProcessFlash) -> Self {
        Self {
            server: Some(boot(flash)),
            outbox: Vec::new(),
        }
    }
}

fn boot(flash: InProcessFlash) -> Box<Server<InProcessFlash, NoProbe>> {
    let store = Store::new(flash, InProcess::SLOTS)
        .unwrap_or_else(|_| unreachable!("a fixed valid layout"));
    Box::new(Server::boot(store, NoProbe))
}

impl InProcess {
    /// Switch the device off: its flash, to boot another one from.
    pub fn into_flash(self) -> Option<InProcessFlash> {
        self.server
            .map(|s| s.into_device().into_store().into_flash())
    }

    /// Restart the device from its flash, as a board does after a reset.
    fn reboot(&mut self) {
        if let Some(old) = self.server.take() {
            self.server = Some(boot(old.into_device().into_store().into_flash()));
        }
    }
}

impl Transport for InProcess {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        for &byte in bytes {
            let server = self
                .server
                .as_mut()
                .ok_or_else(|| io::Error::other("the in-process device failed to reboot"))?;
            let outbox = &mut self.outbox;
            server.push(byte, &mut |bytes| outbox.extend_from_slice(bytes));
            if server.device().reset_requested() {
                self.reboot();
            }
        }
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        if self.outbox.is_empty() {
            // Everything the device answers arrives during `send`: nothing more will come.
            std::thread::sleep(timeout);
        }
        let n = buf.len().min(self.outbox.len());
        buf[..n].copy_from_slice(&self.outbox[..n]);
        self.outbox.drain(..n);
        Ok(n)
    }
}
