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
use crate::rx_ring::{Received, RxRing, RX_RING};
use crate::store::Store;
use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use deltaz_shared::protocol::stream::view_request;
use deltaz_shared::protocol::{WireError, MAX_REQUEST};
use embedded_io::Write;
use embedded_storage::nor_flash::NorFlash;

/// The request bytes (delimiters included) a host may keep in flight to a board, in at most
/// two requests: while [`Server::serve`] answers the first (held in its receive buffer), the
/// second is received behind it in that buffer and, past its end, in the RX ring.
pub const IN_FLIGHT_BYTES: usize = MAX_REQUEST + RX_RING - 1;

/// A device behind its framing.
pub struct Server<F, P> {
    device: Device<F, P>,
    rx: [u8; MAX_REQUEST],
    /// The frame in progress: its bytes are `rx[..frame.len]`.
    frame: Assembly,
}

/// A frame being received.
#[derive(Debug, Default, Clone, Copy)]
struct Assembly {
    /// Its bytes so far.
    len: usize,
    /// It is being dropped up to its delimiter, then answered with this.
    dropped: Option<WireError>,
}

impl Assembly {
    /// Store `byte` of the frame in `buf` (the frame's bytes from offset 0); `false` (the byte
    /// not taken) when `buf` is full.
    fn take(&mut self, byte: u8, buf: &mut [u8]) -> bool {
        let Some(slot) = buf.get_mut(self.len) else {
            return false;
        };
        *slot = byte;
        self.len += 1;
        true
    }

    /// Nothing received since the last delimiter: a delimiter now ends no frame (an idle line).
    fn is_idle(&self) -> bool {
        self.len == 0 && self.dropped.is_none()
    }
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
            addr_of_mut!((*me).frame).write(Assembly::default());
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
            self.take(byte);
            return;
        }
        let done = core::mem::take(&mut self.frame);
        if let Some(frame) = self.rx.get_mut(..done.len) {
            answer(&mut self.device, done, frame, tx);
        }
    }

    /// A byte of the frame in progress (a frame longer than the buffer is dropped).
    fn take(&mut self, byte: u8) {
        if !self.frame.take(byte, &mut self.rx) {
            self.frame.dropped = Some(WireError::Oversized);
        }
    }

    /// Bytes were lost before the next one: the frame in progress is dropped up to its
    /// delimiter and answered with `Overrun` (seq 0) there.
    fn gap(&mut self) {
        self.frame.dropped = Some(WireError::Overrun);
    }

    /// Serve the bytes a board's RX interrupt queues in `ring`, answering on `tx`, until a
    /// `Reset` was answered (the board then restarts) or the port fails. `idle` runs whenever
    /// the ring is empty: the board sleeps until the next interrupt (and, waiting for the
    /// host, feeds its watchdog). `progress` runs after every frame answered: a board feeds its
    /// watchdog there, so a stream that never lets the ring run empty keeps it fed, while a
    /// loop that stops answering (a stall) lets it bite.
    pub fn serve<const N: usize, W: Write>(
        &mut self,
        ring: &RxRing<N>,
        mut idle: impl FnMut(),
        mut progress: impl FnMut(),
        tx: &mut W,
    ) -> Result<(), W::Error> {
        loop {
            match ring.pop() {
                None => idle(),
                Some(Received::Gap) => self.gap(),
                Some(Received::Byte(0)) => loop {
                    // The next frame may be complete once this one is answered: answer it too.
                    let complete = self.answer_receiving(ring, tx)?;
                    tx.flush()?;
                    progress();
                    if self.device.reset_requested() {
                        return Ok(());
                    }
                    if !complete {
                        break;
                    }
                },
                Some(Received::Byte(byte)) => self.take(byte),
            }
        }
    }

    /// Answer the frame in progress (its delimiter was taken) on `tx` while the next one is
    /// received behind it: before each block of the answer goes out, the ring's bytes move
    /// into the receive buffer past this frame (see [`receive_ahead`]). Then the next frame's
    /// bytes move to the buffer's start, and the rest of it follows from the ring as usual.
    /// Whether the next frame's delimiter was taken (it is complete: answer it now).
    fn answer_receiving<const N: usize, W: Write>(
        &mut self,
        ring: &RxRing<N>,
        tx: &mut W,
    ) -> Result<bool, W::Error> {
        let done = core::mem::take(&mut self.frame);
        let Some((frame, spare)) = self.rx.split_at_mut_checked(done.len) else {
            return Ok(false);
        };
        let mut next = Assembly::default();
        let mut complete = false;
        let mut failed = Ok(());
        answer(&mut self.device, done, frame, &mut |bytes| {
            receive_ahead(ring, spare, &mut next, &mut complete);
            if failed.is_ok() {
                failed = tx.write_all(bytes);
            }
        });
        // The next frame's bytes to the buffer's start (a forward copy: they lie behind it).
        for to in 0..next.len {
            let byte = self.rx.get(done.len + to).copied();
            if let (Some(byte), Some(slot)) = (byte, self.rx.get_mut(to)) {
                *slot = byte;
            }
        }
        self.frame = next;
        failed.map(|()| complete)
    }
}

/// Answer the frame `done` (its bytes `frame`) on `tx`: nothing for an empty frame (an idle
/// line), `Error(Frame(..))` for a dropped or unreadable one, else the device's response.
fn answer<F: NorFlash, P: Probe>(
    device: &mut Device<F, P>,
    done: Assembly,
    frame: &mut [u8],
    tx: &mut dyn FnMut(&[u8]),
) {
    if let Some(error) = done.dropped {
        device.refuse(0, error, tx);
    } else if !frame.is_empty() {
        match view_request(frame) {
            Ok((seq, request)) => device.handle(seq, request, tx),
            Err((seq, error)) => device.refuse(seq, error, tx),
        }
    }
}

/// Move the bytes `ring` holds of the frame after the one being answered into `spare` (the
/// receive buffer past that frame), until its delimiter (then `complete`), a full `spare`
/// (the rest waits in the ring) or an empty ring. A gap drops that frame, as in
/// [`Server::gap`]; delimiters before its first byte are an idle line.
fn receive_ahead<const N: usize>(
    ring: &RxRing<N>,
    spare: &mut [u8],
    next: &mut Assembly,
    complete: &mut bool,
) {
    while !*complete && next.len < spare.len() {
        match ring.pop() {
            None => return,
            Some(Received::Gap) => next.dropped = Some(WireError::Overrun),
            Some(Received::Byte(0)) => *complete = !next.is_idle(),
            Some(Received::Byte(byte)) => {
                next.take(byte, spare);
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

    /// A server with no calibration.
    fn server() -> Server<RamFlash<{ 8 * 4096 }>, NoProbe> {
        let store = Store::new(
            RamFlash::<{ 8 * 4096 }>::new(),
            [(0, 16384), (16384, 32768)],
        )
        .unwrap();
        Server::boot(store, NoProbe)
    }

    /// Serve what `ring` holds; once it is empty, `later` arrives (ending with a Reset, which
    /// ends the loop). The answers, decoded.
    fn answers(ring: &RxRing<256>, later: Vec<u8>) -> Vec<Response> {
        let mut later = [later].into_iter();
        let mut out = Line(Vec::new());
        let idle = || later.next().unwrap().iter().for_each(|&b| ring.push(b));
        let Ok(()) = server().serve(ring, idle, || {}, &mut out);
        out.0
            .split_mut(|&b| b == 0)
            .filter(|f| !f.is_empty())
            .map(|f| decode_response(f).unwrap())
            .collect()
    }

    /// Frames that arrive while one is answered are received behind it: one complete there is
    /// answered next, and a gap there drops its frame (answered `Overrun`, seq 0).
    #[test]
    fn frames_received_during_an_answer_are_answered_in_order() {
        let info = frame(7, RequestBody::Info);
        let (head, tail) = info.split_at(info.len() / 2);
        let ring = RxRing::<256>::new();
        // All queued before the first answer: Info 5 is answered while Stats 6 and the head of
        // Info 7 are taken from the ring behind it, then the gap.
        [
            &frame(5, RequestBody::Info),
            &frame(6, RequestBody::Stats),
            head,
        ]
        .concat()
        .iter()
        .for_each(|&b| ring.push(b));
        ring.lose();
        let answers = answers(&ring, [tail, &frame(8, RequestBody::Reset)].concat());
        let seqs: Vec<u32> = answers.iter().map(|a| a.seq).collect();
        assert_eq!(seqs, [5, 6, 0, 8], "{answers:?}");
        assert!(matches!(answers[0].body, ResponseBody::Info(_)));
        let ResponseBody::Stats(stats) = &answers[1].body else {
            panic!("{answers:?}");
        };
        assert_eq!((stats.requests, stats.bad_frames), (2, 0));
        assert_eq!(
            answers[2].body,
            ResponseBody::Error(ErrorCode::Frame(WireError::Overrun))
        );
        assert!(matches!(answers[3].body, ResponseBody::Resetting));
    }

    /// A gap in the middle of a frame: that frame is answered `Overrun` (seq 0) at its
    /// delimiter, counted as a bad frame, and the frames after it are served.
    #[test]
    fn a_gap_drops_its_frame_and_the_next_is_served() {
        let info = frame(5, RequestBody::Info);
        let (head, tail) = info.split_at(info.len() / 2);
        let ring = RxRing::<256>::new();
        head.iter().for_each(|&b| ring.push(b));
        ring.lose();
        // Once the ring is drained (the gap taken), the rest arrives: the damaged frame's tail,
        // then Stats and Reset.
        let answers = answers(
            &ring,
            [
                tail,
                &frame(6, RequestBody::Stats),
                &frame(7, RequestBody::Reset),
            ]
            .concat(),
        );
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

    /// The logging shim ([`crate::logging`]) with its feature: the server's events reach `log`.
    #[cfg(feature = "log")]
    mod logging {
        use super::*;
        use std::sync::Mutex;

        /// The records logged, as `level message`.
        static RECORDS: Mutex<Vec<String>> = Mutex::new(Vec::new());

        struct Capture;

        impl log::Log for Capture {
            fn enabled(&self, _: &log::Metadata) -> bool {
                true
            }
            fn log(&self, record: &log::Record) {
                if record.target() == "deltaz::device" {
                    let line = format!("{} {}", record.level(), record.args());
                    RECORDS.lock().unwrap().push(line);
                }
            }
            fn flush(&self) {}
        }

        /// With the feature, a boot without a calibration and a bad frame are logged.
        #[test]
        fn events_reach_the_log_facade() {
            log::set_logger(&Capture).unwrap();
            log::set_max_level(log::LevelFilter::Trace);
            let store = Store::new(
                RamFlash::<{ 8 * 4096 }>::new(),
                [(0, 16384), (16384, 32768)],
            )
            .unwrap();
            let mut server = Server::boot(store, NoProbe);
            for &byte in b"\x07garbage\x00" {
                server.push(byte, &mut |_| {});
            }
            let records = RECORDS.lock().unwrap().clone();
            assert!(
                records
                    .iter()
                    .any(|r| r == "INFO boot: no stored calibration"),
                "{records:?}"
            );
            assert!(
                records.iter().any(|r| r.starts_with("DEBUG bad frame")),
                "{records:?}"
            );
        }
    }
}
