//! The client on a bad line: frames damaged, dropped, duplicated or split in both directions,
//! noise the device answers with seq 0, stale answers from an earlier run. Streams and uploads
//! complete with every point equal to the clean run; requests run once when nothing was lost.

use deltaz_host::io::system_file::SystemRig;
use deltaz_host::link::{Device, InProcess, LineCounts, PointOutcome, Transport};
use deltaz_host::simulate::images::true_rig;
use deltaz_host::simulate::Scenario;
use deltaz_shared::protocol::{encode_frame, ErrorCode, Response, ResponseBody, WireError};
use deltaz_tests::Rng;
use std::io;
use std::time::Duration;

/// The ways of damaging a frame: [`damage`]'s classes.
const CLASSES: u64 = 6;

/// One way of damaging a frame (its bytes up to and including the 0x00 delimiter): class
/// `class`, or one drawn at random.
fn damage(frame: &[u8], rng: &mut Rng, class: Option<u64>) -> Vec<u8> {
    let mut f = frame.to_vec();
    let body = f.len() - 1;
    match class.unwrap_or_else(|| rng.below(CLASSES)) {
        // A flipped bit (never making the delimiter).
        0 => {
            let i = rng.below(body as u64) as usize;
            let bit = 1u8 << rng.below(8);
            f[i] ^= if f[i] ^ bit == 0 {
                1 << ((bit.trailing_zeros() + 1) % 8)
            } else {
                bit
            };
        }
        // A dropped byte.
        1 => {
            f.remove(rng.below(body as u64) as usize);
        }
        // An inserted byte (a zero too: the frame splits).
        2 => {
            f.insert(rng.below(body as u64) as usize, rng.next_u64() as u8);
        }
        // Truncated, the rest lost (the next frame's delimiter ends it).
        3 => f.truncate(1 + rng.below(body as u64) as usize),
        // Lost entirely.
        4 => f.clear(),
        // Duplicated.
        _ => f.extend_from_slice(frame),
    }
    f
}

/// The in-process device behind a line that damages a fraction of the frames each way.
struct Noisy {
    inner: InProcess,
    rng: Rng,
    /// Damage one frame in `every` (per direction).
    every: usize,
    /// Damage of this class only (else any).
    class: Option<u64>,
    /// Damage the answers only (`Some(true)`), the requests only (`Some(false)`), or both.
    way: Option<bool>,
    /// Frames damaged so far.
    hits: u64,
    inbox: Vec<u8>,
    partial: Vec<u8>,
}

impl Noisy {
    fn new(every: usize, seed: u64) -> Self {
        Self {
            inner: InProcess::new(),
            rng: Rng(seed),
            every,
            class: None,
            way: None,
            hits: 0,
            inbox: Vec::new(),
            partial: Vec::new(),
        }
    }

    /// The same line damaging frames of `class` only.
    fn only(mut self, class: u64) -> Self {
        self.class = Some(class);
        self
    }

    /// The same line damaging only the answers (`true`) or only the requests.
    fn one_way(mut self, answers: bool) -> Self {
        self.way = Some(answers);
        self
    }

    /// Whether to damage the next frame going this way (`answer`: from the device).
    fn hit(&mut self, answer: bool) -> bool {
        if self.way.is_some_and(|w| w != answer) {
            return false;
        }
        let hit = self.every > 0 && self.rng.below(self.every as u64) == 0;
        self.hits += u64::from(hit);
        hit
    }
}

impl Transport for Noisy {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        // The client sends a delimiter, the frame and its delimiter.
        let mut out = Vec::new();
        for frame in bytes.split_inclusive(|&b| b == 0) {
            if frame.len() > 1 && self.hit(false) {
                out.extend(damage(frame, &mut self.rng, self.class));
            } else {
                out.extend_from_slice(frame);
            }
        }
        self.inner.send(&out)
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        if self.inbox.is_empty() {
            let mut chunk = [0u8; 8192];
            let n = self.inner.recv(&mut chunk, timeout)?;
            self.partial.extend_from_slice(&chunk[..n]);
            while let Some(end) = self.partial.iter().position(|&b| b == 0) {
                let frame: Vec<u8> = self.partial.drain(..=end).collect();
                if frame.len() > 1 && self.hit(true) {
                    let damaged = damage(&frame, &mut self.rng, self.class);
                    self.inbox.extend(damaged);
                } else {
                    self.inbox.extend(frame);
                }
            }
        }
        let n = buf.len().min(self.inbox.len());
        buf[..n].copy_from_slice(&self.inbox[..n]);
        self.inbox.drain(..n);
        Ok(n)
    }
}

fn rig() -> SystemRig {
    true_rig(&Scenario::paper())
}

/// 30 frames of the paper rig's dots on walls at three distances from the camera.
fn frames(rig: &SystemRig) -> Vec<Vec<(u16, f64, f64)>> {
    (0..30)
        .map(|k| {
            let depth = 1650.0 + 90.0 * (k % 3) as f64;
            rig.projector_centred()
                .rays()
                .iter()
                .filter_map(|r| {
                    let (col, row) = rig.pixel_at_depth(r.id, depth).ok()?;
                    rig.grid().contains(col, row).then_some((r.id, col, row))
                })
                .collect()
        })
        .collect()
}

fn stream(device: &mut Device<Noisy>, frames: &[Vec<(u16, f64, f64)>]) -> Vec<Vec<PointOutcome>> {
    device.upload(&rig(), 0x5EED).unwrap();
    device.compute_frames(frames).unwrap()
}

/// 10 % of the frames damaged each way, one of six ways: an upload and a pipelined stream
/// complete, every point bit-identical to the clean run.
#[test]
fn a_stream_and_an_upload_survive_ten_percent_damage_both_ways() {
    let rig = rig();
    let frames = frames(&rig);
    let sizes: Vec<usize> = frames.iter().map(Vec::len).collect();
    assert!(
        sizes.iter().all(|&n| n > 300),
        "the plates fill the image: {sizes:?}"
    );
    // A clean line resends nothing (a timeout long enough for a loaded machine).
    let mut clean = Device::new(Noisy::new(0, 1)).with_timeout(Duration::from_secs(2));
    let expected = stream(&mut clean, &frames);
    assert_eq!(clean.line_counts(), LineCounts::default());
    for (seed, window) in [(7, 1), (11, 4), (13, 8)] {
        let mut noisy = Device::new(Noisy::new(10, seed))
            .with_timeout(Duration::from_millis(50))
            .with_window(window);
        let got = stream(&mut noisy, &frames);
        assert_eq!(got, expected, "seed {seed}, window {window}");
        let line = noisy.line_counts();
        let hits = noisy.into_transport().hits;
        assert!(line.resent > 3, "the noise cost resends: {line:?}");
        assert!(line.resent <= hits && hits > 3, "{hits} damaged, {line:?}");
    }
}

/// 20 % of the frames damaged in one direction, one class at a time (truncation included: an
/// answer cut short ends at the next one's leading delimiter instead of taking it along): every
/// stream completes with every point bit-identical to the clean run, and no request is sent
/// again more often than frames were damaged (none for duplicated frames: nothing was lost).
#[test]
fn twenty_percent_of_any_one_class_either_way() {
    let rig = rig();
    let frames = frames(&rig);
    let mut clean = Device::new(Noisy::new(0, 1)).with_timeout(Duration::from_secs(2));
    let expected = stream(&mut clean, &frames);
    for class in 0..CLASSES {
        for answers in [false, true] {
            let line = Noisy::new(5, 31 + class).only(class).one_way(answers);
            let mut noisy = Device::new(line)
                .with_timeout(Duration::from_millis(50))
                .with_window(4);
            let got = stream(&mut noisy, &frames);
            let way = if answers { "answers" } else { "requests" };
            assert_eq!(got, expected, "class {class}, {way}");
            let line = noisy.line_counts();
            let hits = noisy.into_transport().hits;
            println!("class {class}, {way}: {hits} frames damaged, {line:?}");
            assert!(hits > 2, "class {class}, {way}: {hits}");
            if class == 5 {
                assert_eq!(line.resent, 0, "duplicates need no resend: {line:?}");
            } else {
                assert!(
                    line.resent > 0 && line.resent <= hits,
                    "class {class}, {way}: {hits} damaged, {line:?}"
                );
            }
        }
    }
}

/// A device whose every answer is preceded by a seq-0 "could not read" answer (line noise
/// between frames): each request is answered by its own answer and runs once, a stream of
/// 30 frames with 4 in flight included.
#[test]
fn seq_zero_answers_are_not_taken_for_the_request() {
    struct NoiseFirst(InProcess, Vec<u8>);
    impl Transport for NoiseFirst {
        fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
            let noise = Response {
                seq: 0,
                body: ResponseBody::Error(ErrorCode::Frame(WireError::BadCrc)),
            };
            let mut frame = [0u8; 64];
            self.1
                .extend_from_slice(encode_frame(&noise, &mut frame).unwrap());
            self.0.send(bytes)?;
            let mut chunk = [0u8; 4096];
            loop {
                let n = self.0.recv(&mut chunk, Duration::ZERO)?;
                if n == 0 {
                    return Ok(());
                }
                self.1.extend_from_slice(&chunk[..n]);
            }
        }
        fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
            if self.1.is_empty() {
                std::thread::sleep(timeout);
            }
            let n = buf.len().min(self.1.len());
            buf[..n].copy_from_slice(&self.1[..n]);
            self.1.drain(..n);
            Ok(n)
        }
    }
    let mut device =
        Device::new(NoiseFirst(InProcess::new(), Vec::new())).with_timeout(Duration::from_secs(2));
    device.upload(&rig(), 0xA).unwrap();
    let before = device.stats().unwrap().requests;
    let frames = frames(&rig());
    device.compute_frames(&frames[..5]).unwrap();
    let mut device = device.with_window(4);
    let mut twin = Device::in_process();
    twin.upload(&rig(), 0xA).unwrap();
    let expected = twin.compute_frames(&frames).unwrap();
    assert_eq!(device.compute_frames(&frames).unwrap(), expected);
    let after = device.stats().unwrap().requests;
    // 35 computes and the first Stats request: nothing ran twice.
    assert_eq!(after - before, 36);
    let line = device.line_counts();
    assert_eq!(line.resent, 0, "{line:?}");
    assert!(line.unreadable >= 36, "{line:?}");
}

/// Stale answers waiting on the line when the client starts (an earlier, killed run) are
/// drained, not taken for this run's.
#[test]
fn stale_answers_are_drained_on_open() {
    struct Stale(InProcess, Vec<u8>);
    impl Transport for Stale {
        fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
            self.0.send(bytes)
        }
        fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
            if !self.1.is_empty() {
                let n = buf.len().min(self.1.len());
                buf[..n].copy_from_slice(&self.1[..n]);
                self.1.drain(..n);
                return Ok(n);
            }
            self.0.recv(buf, timeout)
        }
    }
    let mut stale = Vec::new();
    for seq in 1..=3 {
        let mut frame = [0u8; 64];
        let r = Response {
            seq,
            body: ResponseBody::Error(ErrorCode::NoCalibration),
        };
        stale.extend_from_slice(encode_frame(&r, &mut frame).unwrap());
    }
    let mut device =
        Device::new(Stale(InProcess::new(), stale)).with_timeout(Duration::from_secs(2));
    assert_eq!(device.info().unwrap().calibration, None);
    assert_eq!(device.line_counts(), LineCounts::default());
}
