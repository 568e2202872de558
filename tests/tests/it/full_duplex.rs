//! The firmware's serve loop on a simulated full-duplex 2 Mbaud line: each byte the device sends
//! takes one byte time, in which one byte of the host's queued requests arrives in the RX ring
//! (while the device sends nothing, the line delivers a byte per idle wait). The host keeps
//! requests in flight as it does on a real port: two at most, within
//! [`IN_FLIGHT_BYTES`](deltaz_firmware::server::IN_FLIGHT_BYTES).

use deltaz_firmware::device::NoProbe;
use deltaz_firmware::rx_ring::{RxRing, RX_RING};
use deltaz_firmware::server::{Server, IN_FLIGHT_BYTES};
use deltaz_firmware::store::Store;
use deltaz_host::link::{Device, InProcess, InProcessFlash};
use deltaz_shared::protocol::{
    centroid_fraction_bits, encode_frame, Centroid, Request, RequestBody, MAX_FRAME, MAX_REQUEST,
};
use deltaz_tests::pattern::{pattern_rig, plate_centroids};
use std::cell::RefCell;
use std::collections::VecDeque;

/// Requests on a real port: at most this many in flight.
const WINDOW: usize = 2;

/// The host's side of the line: request frames (each with its leading delimiter) sent in order,
/// up to [`WINDOW`] unanswered, one byte per byte time: `frames` over and over until the byte
/// time `until`, then `last` (a Reset, which ends the serve loop).
struct Host {
    frames: Vec<Vec<u8>>,
    last: Vec<u8>,
    until: usize,
    /// The frame being sent and its next byte.
    next: (usize, usize),
    /// Lengths of the requests sent and not yet answered, oldest first.
    flight: VecDeque<usize>,
    /// Byte times so far.
    time: usize,
    /// Request bytes delivered so far.
    delivered: usize,
    /// Bytes delivered when each request's last byte arrived.
    arrived: Vec<usize>,
    /// Byte times and bytes delivered when each answer's delimiter went out.
    answered: Vec<(usize, usize)>,
    /// The most bytes queued in the ring.
    high_water: usize,
}

impl Host {
    /// A host sending `frames` (in a loop until byte time `until`, once when 0), then `last`.
    fn new(frames: Vec<Vec<u8>>, last: Vec<u8>, until: usize) -> Self {
        Self {
            frames,
            last,
            until,
            next: (0, 0),
            flight: VecDeque::new(),
            time: 0,
            delivered: 0,
            arrived: Vec::new(),
            answered: Vec::new(),
            high_water: 0,
        }
    }

    /// One byte time: the next request byte, if the window lets it go, arrives in `ring`.
    /// Whether a byte arrived.
    fn tick(&mut self, ring: &RxRing<RX_RING>) -> bool {
        self.time += 1;
        let (frame, offset) = self.next;
        let bytes = match frame {
            usize::MAX => &self.last,
            _ => &self.frames[frame % self.frames.len()],
        };
        if frame == usize::MAX && offset == bytes.len() {
            return false;
        }
        if offset == 0 {
            let in_flight: usize = self.flight.iter().sum();
            if self.flight.len() == WINDOW || in_flight + bytes.len() > IN_FLIGHT_BYTES {
                return false;
            }
            self.flight.push_back(bytes.len());
        }
        ring.push(bytes[offset]);
        self.delivered += 1;
        self.high_water = self.high_water.max(ring.queued());
        self.next = match (offset + 1 == bytes.len(), frame) {
            (true, usize::MAX) => (frame, offset + 1),
            (true, _) => {
                self.arrived.push(self.delivered);
                let next = frame + 1;
                let done = next % self.frames.len() == 0 && self.time >= self.until;
                (if done { usize::MAX } else { next }, 0)
            }
            (false, _) => (frame, offset + 1),
        };
        true
    }
}

/// The device's side: what it sends, each byte a byte time of the line (kept when `keep`).
struct Uart<'a> {
    host: &'a RefCell<Host>,
    ring: &'a RxRing<RX_RING>,
    keep: bool,
    sent: Vec<u8>,
    /// The last byte sent.
    last: u8,
}

impl embedded_io::ErrorType for Uart<'_> {
    type Error = core::convert::Infallible;
}

impl embedded_io::Write for Uart<'_> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        let mut host = self.host.borrow_mut();
        for &byte in buf {
            if byte == 0 && self.last != 0 {
                host.flight.pop_front();
                let now = (host.time, host.delivered);
                host.answered.push(now);
            }
            if self.keep {
                self.sent.push(byte);
            }
            self.last = byte;
            host.tick(self.ring);
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// Answers split at their delimiters.
fn answers(line: &[u8]) -> Vec<&[u8]> {
    line.split(|&b| b == 0).filter(|f| !f.is_empty()).collect()
}

/// Six 440-dot Compute frames queued at once, then a Reset (which ends the serve loop): every
/// answer is the one the device gives a frame at a time, in order, with no overrun; the ring
/// never holds more than a stated share of itself, where a device that only took bytes from the
/// ring between frames would have had to hold the whole next request.
#[test]
fn two_440_dot_requests_in_flight_fit_the_ring_at_line_rate() {
    let (flash, frames, reset) = setup();
    let boot = || {
        Box::new(Server::boot(
            Store::new(flash.clone(), InProcess::SLOTS).unwrap(),
            NoProbe,
        ))
    };

    // The answers a frame at a time (the byte-wise path, nothing in flight behind them).
    let mut alone = boot();
    let mut expected = Vec::new();
    frames.iter().chain([&reset]).flatten().for_each(|&b| {
        alone.push(b, &mut |bytes| expected.extend_from_slice(bytes));
    });

    let ring = RxRing::<RX_RING>::new();
    let host = RefCell::new(Host::new(frames.clone(), reset, 0));
    let mut uart = Uart {
        host: &host,
        ring: &ring,
        keep: true,
        sent: Vec::new(),
        last: 0,
    };
    let idle = || {
        assert!(
            host.borrow_mut().tick(&ring),
            "the line and the device both idle"
        )
    };
    let Ok(()) = boot().serve(&ring, idle, || {}, &mut uart);

    let got = answers(&uart.sent);
    assert_eq!(got.len(), frames.len() + 1);
    assert_eq!(
        got,
        answers(&expected),
        "answers differ from the frame-at-a-time device"
    );
    let host = host.into_inner();
    let request_len = frames[1].len();
    let answer_len = got[1].len() + 1;
    // Without the transfer during the answer, every byte arriving between a request's end and
    // its answer's end would wait in the ring.
    let backlog = host
        .arrived
        .iter()
        .zip(&host.answered)
        .map(|(arrived, (_, delivered))| delivered - arrived)
        .max()
        .unwrap();
    // Steady state: byte times between the ends of consecutive compute answers.
    let period = (host.answered[5].0 - host.answered[1].0) as f64 / 4.0;
    let fps = 2e6 / 10.0 / period;
    println!(
        "request {request_len} B, answer {answer_len} B; ring high-water {} of {} B with the \
         transfer, {backlog} B without; {period:.0} byte times per frame: {fps:.1} frames/s at \
         2 Mbaud",
        host.high_water,
        RX_RING - 1
    );
    // The next request fills the buffer behind the one answered (MAX_REQUEST less it, its
    // delimiters not stored), the rest waits in the ring, plus at most a COBS block (255 B) sent
    // between two transfers.
    let excess = request_len - (MAX_REQUEST - (request_len - 2));
    assert!(
        host.high_water <= excess + 255,
        "{} > {excess} + 255",
        host.high_water
    );
    assert!(
        host.high_water + 128 < RX_RING,
        "high-water {} B leaves under 128 B of the ring",
        host.high_water
    );
    assert!(backlog > RX_RING - 1, "{backlog}");
    // The line's busier direction (the requests: 5 bytes a centroid against 3 a result) is
    // busy all the time: a frame per request.
    assert!(answer_len < request_len, "{answer_len} {request_len}");
    assert!(period < request_len as f64 + 16.0, "{period}");
    assert!(fps >= 85.0, "{fps}");
}

/// A device's flash holding the paper pattern's calibration, six 440-dot Compute requests on
/// plates 7 mm apart, and a Reset request.
fn setup() -> (InProcessFlash, Vec<Vec<u8>>, Vec<u8>) {
    let rig = pattern_rig();
    let mut device = Device::in_process();
    device.upload(&rig, 1).unwrap();
    let flash: InProcessFlash = device.into_transport().into_flash().unwrap();
    let bits = centroid_fraction_bits(rig.grid().width, rig.grid().height);
    let frames: Vec<Vec<u8>> = (0..6)
        .map(|k| {
            let mut dots = plate_centroids(&rig, 100.0 + 7.0 * k as f64, (0.0, 0.0));
            assert_eq!(dots.len(), 440);
            dots.sort_by_key(|d| d.0);
            let centroids = dots
                .iter()
                .map(|&(id, col, row)| Centroid::from_pixel(id, col, row, bits).unwrap())
                .collect();
            request(k + 1, RequestBody::Compute { centroids })
        })
        .collect();
    (flash, frames, request(7, RequestBody::Reset))
}

/// Ten minutes of line time (120,000,000 byte times at 2 Mbaud 8N1, simulated: the test takes
/// seconds), two 440-dot requests always in flight, so the receive ring never runs empty for
/// long and the idle wait seldom runs: the serve loop feeds the watchdog after every answer
/// (progress), and the longest gap between feeds stays far below the watchdog's period (about
/// 5 s, at least 3.4 s at the LSI's fastest).
#[test]
fn ten_minutes_of_streaming_feed_the_watchdog_by_progress() {
    const BYTE_TIMES_PER_S: usize = 200_000;
    let (flash, frames, reset) = setup();
    let mut server = Box::new(Server::boot(
        Store::new(flash, InProcess::SLOTS).unwrap(),
        NoProbe,
    ));
    let ring = RxRing::<RX_RING>::new();
    let host = RefCell::new(Host::new(frames, reset, 600 * BYTE_TIMES_PER_S));
    // (the byte time of the last feed, the longest gap, feeds in the idle wait, after answers)
    let feeds = RefCell::new((0usize, 0usize, 0usize, 0usize));
    let feed = |idle: bool| {
        let now = host.borrow().time;
        let mut f = feeds.borrow_mut();
        f.1 = f.1.max(now - f.0);
        f.0 = now;
        if idle {
            f.2 += 1;
        } else {
            f.3 += 1;
        }
    };
    let mut uart = Uart {
        host: &host,
        ring: &ring,
        keep: false,
        sent: Vec::new(),
        last: 0,
    };
    let idle = || {
        feed(true);
        assert!(
            host.borrow_mut().tick(&ring),
            "the line and the device both idle"
        )
    };
    let Ok(()) = server.serve(&ring, idle, || feed(false), &mut uart);
    let host = host.into_inner();
    let (_, gap, idle_feeds, progress_feeds) = feeds.into_inner();
    let seconds = host.time as f64 / BYTE_TIMES_PER_S as f64;
    let answers = host.answered.len();
    println!(
        "{seconds:.0} s of line time: {answers} answers, the watchdog fed {progress_feeds} times \
         after an answer and {idle_feeds} times in the idle wait; longest gap {gap} byte times \
         ({:.1} ms)",
        gap as f64 / BYTE_TIMES_PER_S as f64 * 1e3
    );
    assert!(seconds >= 600.0, "{seconds}");
    assert_eq!(answers, host.arrived.len() + 1, "every request answered");
    assert!(answers as f64 >= 40.0 * 600.0, "{answers} answers");
    // Every answer fed it (and the first request's leading delimiter, an empty frame).
    assert!(
        (answers..=answers + 1).contains(&progress_feeds),
        "{progress_feeds}"
    );
    // An answer takes 4,414 byte times: a feed at least every 0.1 s, 34 times within the
    // watchdog's shortest period.
    assert!(
        gap < BYTE_TIMES_PER_S / 10,
        "{gap} byte times between feeds"
    );
}

/// `body` as request `seq` on the line: a leading delimiter, the frame, its delimiter.
fn request(seq: u32, body: RequestBody) -> Vec<u8> {
    let mut buf = vec![0u8; MAX_FRAME + 1];
    let len = encode_frame(&Request { seq, body }, &mut buf[1..])
        .unwrap()
        .len();
    buf.truncate(len + 1);
    buf
}
