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
/// up to [`WINDOW`] unanswered, one byte per byte time.
struct Host {
    frames: Vec<Vec<u8>>,
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
    /// One byte time: the next request byte, if the window lets it go, arrives in `ring`.
    /// Whether a byte arrived.
    fn tick(&mut self, ring: &RxRing<RX_RING>) -> bool {
        self.time += 1;
        let (frame, offset) = self.next;
        let Some(bytes) = self.frames.get(frame) else {
            return false;
        };
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
        self.next = if offset + 1 == bytes.len() {
            self.arrived.push(self.delivered);
            (frame + 1, 0)
        } else {
            (frame, offset + 1)
        };
        true
    }
}

/// The device's side: what it sends, each byte a byte time of the line.
struct Uart<'a> {
    host: &'a RefCell<Host>,
    ring: &'a RxRing<RX_RING>,
    sent: Vec<u8>,
}

impl embedded_io::ErrorType for Uart<'_> {
    type Error = core::convert::Infallible;
}

impl embedded_io::Write for Uart<'_> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        let mut host = self.host.borrow_mut();
        for &byte in buf {
            if byte == 0 && self.sent.last().is_some_and(|&b| b != 0) {
                host.flight.pop_front();
                let now = (host.time, host.delivered);
                host.answered.push(now);
            }
            self.sent.push(byte);
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
    let rig = pattern_rig();
    let mut device = Device::in_process();
    device.upload(&rig, 1).unwrap();
    let flash: InProcessFlash = device.into_transport().into_flash().unwrap();
    let bits = centroid_fraction_bits(rig.grid().width, rig.grid().height);
    let mut frames: Vec<Vec<u8>> = (0..6)
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
    frames.push(request(7, RequestBody::Reset));
    let boot = || {
        Box::new(Server::boot(
            Store::new(flash.clone(), InProcess::SLOTS).unwrap(),
            NoProbe,
        ))
    };

    // The answers a frame at a time (the byte-wise path, nothing in flight behind them).
    let mut alone = boot();
    let mut expected = Vec::new();
    frames.iter().flatten().for_each(|&b| {
        alone.push(b, &mut |bytes| expected.extend_from_slice(bytes));
    });

    let ring = RxRing::<RX_RING>::new();
    let host = RefCell::new(Host {
        frames: frames.clone(),
        next: (0, 0),
        flight: VecDeque::new(),
        time: 0,
        delivered: 0,
        arrived: Vec::new(),
        answered: Vec::new(),
        high_water: 0,
    });
    let mut uart = Uart {
        host: &host,
        ring: &ring,
        sent: Vec::new(),
    };
    let idle = || {
        assert!(
            host.borrow_mut().tick(&ring),
            "the line and the device both idle"
        )
    };
    let Ok(()) = boot().serve(&ring, idle, &mut uart);

    let got = answers(&uart.sent);
    assert_eq!(got.len(), frames.len());
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
    assert!(backlog >= request_len && backlog > RX_RING - 1, "{backlog}");
    // The line's answer direction is busy all the time: a frame per answer.
    assert!(period < answer_len as f64 + 16.0, "{period}");
    assert!(fps >= 40.0, "{fps}");
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
