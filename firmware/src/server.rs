//! The framing layer around [`Device`]: bytes in, frames out, over any embedded-io serial port.
//!
//! Bytes collect until a 0x00 delimiter. Then:
//!
//! | frame | answer |
//! |---|---|
//! | empty (two delimiters) | none: an idle line or a resync |
//! | longer than [`MAX_REQUEST`] | `Error(Frame(Oversized))`, seq 0, the bytes dropped |
//! | bytes lost in reception ([`Received::Gap`]) | `Error(Frame(Overrun))`, seq 0, the bytes dropped |
//! | not COBS, short, bad CRC | `Error(Frame(..))`, seq 0 |
//! | CRC good, unknown kind or undecodable | `Error(Frame(..))` with the request's seq |
//! | a request | the device's response |

use crate::device::{Device, Probe};
use crate::rx_ring::{Received, RxRing};
use crate::store::Store;
use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use deltaz_shared::protocol::stream::view_request;
use deltaz_shared::protocol::{WireError, MAX_REQUEST};
use embedded_io::Write;
use embedded_storage::nor_flash::NorFlash;

/// A device behind its framing.
pub struct Server<F, P> {
    device: Device<F, P>,
    rx: [u8; MAX_REQUEST],
    rx_len: usize,
    /// The frame in progress is being dropped up to its delimiter, then answered with this.
    dropped: Option<WireError>,
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
            addr_of_mut!((*me).dropped).write(None);
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
                None => self.dropped = Some(WireError::Oversized),
            }
            return;
        }
        let len = core::mem::take(&mut self.rx_len);
        if let Some(error) = self.dropped.take() {
            self.device.refuse(0, error, tx);
        } else if let Some(frame) = self.rx.get_mut(..len).filter(|f| !f.is_empty()) {
            match view_request(frame) {
                Ok((seq, request)) => self.device.handle(seq, request, tx),
                Err((seq, error)) => self.device.refuse(seq, error, tx),
            }
        }
    }

    /// Bytes were lost before the next one: the frame in progress is dropped up to its
    /// delimiter and answered with `Overrun` (seq 0) there.
    pub fn gap(&mut self) {
        self.dropped = Some(WireError::Overrun);
    }

    /// Serve the bytes a board's RX interrupt queues in `ring`, answering on `tx`, until a
    /// `Reset` was answered (the board then restarts) or the port fails. `idle` runs whenever
    /// the ring is empty: the board sleeps until the next interrupt (and feeds its watchdog).
    pub fn serve<const N: usize, W: Write>(
        &mut self,
        ring: &RxRing<N>,
        mut idle: impl FnMut(),
        tx: &mut W,
    ) -> Result<(), W::Error> {
        loop {
            match ring.pop() {
                None => idle(),
                Some(Received::Gap) => self.gap(),
                Some(Received::Byte(byte)) => {
                    let mut failed = Ok(());
                    self.push(byte, &mut |bytes| {
                        if failed.is_ok() {
                            failed = tx.write_all(bytes);
                        }
                    });
                    failed?;
                    if byte == 0 {
                        tx.flush()?;
                        if self.device.reset_requested() {
                            return Ok(());
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::NoProbe;
    use crate::ram_flash::RamFlash;
    use deltaz_shared::protocol::{
        decode_response, encode_frame, ErrorCode, Request, RequestBody, Response, ResponseBody,
        MAX_FRAME,
    };

    /// The bytes the server sends.
    struct Line(Vec<u8>);

    impl embedded_io::ErrorType for Line {
        type Error = core::convert::Infallible;
    }

    impl Write for Line {
        fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
            self.0.extend_from_slice(buf);
            Ok(buf.len())
        }

        fn flush(&mut self) -> Result<(), Self::Error> {
            Ok(())
        }
    }

    fn frame(seq: u32, body: RequestBody) -> Vec<u8> {
        let mut buf = vec![0u8; MAX_FRAME];
        encode_frame(&Request { seq, body }, &mut buf)
            .unwrap()
            .to_vec()
    }

    /// A gap in the middle of a frame: that frame is answered `Overrun` (seq 0) at its
    /// delimiter, counted as a bad frame, and the frames after it are served.
    #[test]
    fn a_gap_drops_its_frame_and_the_next_is_served() {
        let store = Store::new(
            RamFlash::<{ 8 * 4096 }>::new(),
            [(0, 16384), (16384, 32768)],
        )
        .unwrap();
        let mut server = Server::boot(store, NoProbe);
        let info = frame(5, RequestBody::Info);
        let (head, tail) = info.split_at(info.len() / 2);
        let ring = RxRing::<256>::new();
        head.iter().for_each(|&b| ring.push(b));
        ring.lose();
        // Once the ring is drained (the gap taken), the rest arrives: the damaged frame's tail,
        // then Stats and Reset.
        let mut later = [[
            tail,
            &frame(6, RequestBody::Stats),
            &frame(7, RequestBody::Reset),
        ]
        .concat()]
        .into_iter();
        let mut out = Line(Vec::new());
        let idle = || later.next().unwrap().iter().for_each(|&b| ring.push(b));
        let Ok(()) = server.serve(&ring, idle, &mut out);
        let answers: Vec<Response> = out
            .0
            .split_mut(|&b| b == 0)
            .filter(|f| !f.is_empty())
            .map(|f| decode_response(f).unwrap())
            .collect();
        assert_eq!(answers.len(), 3, "{answers:?}");
        assert_eq!(
            answers[0],
            Response {
                seq: 0,
                body: ResponseBody::Error(ErrorCode::Frame(WireError::Overrun)),
            }
        );
        let ResponseBody::Stats(stats) = &answers[1].body else {
            panic!("{answers:?}");
        };
        assert_eq!((answers[1].seq, stats.bad_frames), (6, 1));
        assert_eq!(answers[2].seq, 7);
    }
}
