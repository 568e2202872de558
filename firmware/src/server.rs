//! The framing layer around [`Device`]: bytes in, frames out, over any embedded-io serial port.
//!
//! Bytes collect until a 0x00 delimiter. Then:
//!
//! | frame | answer |
//! |---|---|
//! | empty (two delimiters) | none: an idle line or a resync |
//! | longer than [`MAX_REQUEST`] | `Error(Frame(Oversized))`, seq 0, the bytes dropped |
//! | not COBS, short, bad CRC | `Error(Frame(..))`, seq 0 |
//! | CRC good, unknown kind or undecodable | `Error(Frame(..))` with the request's seq |
//! | a request | the device's response |

use crate::device::{Device, Probe};
use crate::store::Store;
use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use deltaz_shared::protocol::stream::view_request;
use deltaz_shared::protocol::{WireError, MAX_REQUEST};
use embedded_io::{Read, Write};
use embedded_storage::nor_flash::NorFlash;

/// A device behind its framing.
pub struct Server<F, P> {
    device: Device<F, P>,
    rx: [u8; MAX_REQUEST],
    rx_len: usize,
    overflow: bool,
}

impl<F: NorFlash, P: Probe> Server<F, P> {
    /// Boot a device on `store` (loading its newest valid calibration) and serve it.
    pub fn boot(store: Store<F>, probe: P) -> Self {
        let mut slot = MaybeUninit::uninit();
        Self::boot_in(&mut slot, store, probe);
        // SAFETY: `boot_in` wrote every field.
        unsafe { slot.assume_init() }
    }

    /// [`Server::boot`] into `slot` (a board's static): the server is written there in place,
    /// field by field (no copy of its tables passes through the stack), and never moves.
    pub fn boot_in(slot: &mut MaybeUninit<Self>, store: Store<F>, probe: P) -> &mut Self {
        let me = slot.as_mut_ptr();
        // SAFETY: every field of `*me` is written through a raw pointer to it (no reference to
        // uninitialised memory is made; the device through `init_in` on its own
        // `MaybeUninit`, which has its layout; zero bytes are valid u8 arrays) before
        // `assume_init_mut`.
        let server = unsafe {
            Device::init_in(&mut *addr_of_mut!((*me).device).cast(), store, probe);
            addr_of_mut!((*me).rx).write_bytes(0, 1);
            addr_of_mut!((*me).rx_len).write(0);
            addr_of_mut!((*me).overflow).write(false);
            slot.assume_init_mut()
        };
        server.device.load();
        server
    }

    /// The device.
    pub fn device(&self) -> &Device<F, P> {
        &self.device
    }

    /// Give the device back.
    pub fn into_device(self) -> Device<F, P> {
        self.device
    }

    /// Take one received byte; when it ends a frame, the response goes to `tx`, block by block
    /// as it is written (the request read in place, no transmit buffer).
    pub fn push(&mut self, byte: u8, tx: &mut dyn FnMut(&[u8])) {
        if byte != 0 {
            match self.rx.get_mut(self.rx_len) {
                Some(slot) => {
                    *slot = byte;
                    self.rx_len += 1;
                }
                None => self.overflow = true,
            }
            return;
        }
        let len = core::mem::take(&mut self.rx_len);
        if core::mem::take(&mut self.overflow) {
            self.device.refuse(0, WireError::Oversized, tx);
        } else if let Some(frame) = self.rx.get_mut(..len).filter(|f| !f.is_empty()) {
            match view_request(frame) {
                Ok((seq, request)) => self.device.handle(seq, request, tx),
                Err((seq, error)) => self.device.refuse(seq, error, tx),
            }
        }
    }

    /// Serve `io` until a `Reset` was answered (the board then restarts) or the port fails.
    pub fn serve<IO: Read + Write>(&mut self, io: &mut IO) -> Result<(), IO::Error> {
        let mut buf = [0u8; 64];
        loop {
            let n = io.read(&mut buf)?;
            let mut failed = Ok(());
            for &byte in buf.iter().take(n) {
                self.push(byte, &mut |bytes| {
                    if failed.is_ok() {
                        failed = io.write_all(bytes);
                    }
                });
            }
            failed?;
            io.flush()?;
            if self.device.reset_requested() {
                return Ok(());
            }
        }
    }
}
