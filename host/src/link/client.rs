//! The typed device client: one method per request.

use super::calibration::calibration_blob_identifying;
use super::in_process::InProcess;
use super::Transport;
use deltaz_calib::reconstruct::SystemRig;
use deltaz_shared::projector::{Projector, ProjectorRay};
use deltaz_shared::protocol::calibration::IdentifyParams;
use deltaz_shared::protocol::frame::CRC;
use deltaz_shared::protocol::{
    decode_response, encode_frame, CalibrationSummary, Centroid, DeviceInfo, DeviceStats, Dot,
    ErrorCode, PointResult, PointStatus, Request, RequestBody, Response, ResponseBody, WireError,
    CHUNK_SIZE, MAX_BATCH, MAX_FRAME, PROTOCOL_VERSION,
};
use deltaz_shared::rig::{Method, Rig};
use nalgebra::Vector3;
use std::io;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How long a request waits for its response by default (per try).
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(3);
/// Upload attempts when the device reports a CRC failure of the whole blob.
const UPLOAD_ATTEMPTS: usize = 3;
/// Sends of one request whose answer is missing or damaged (requests are idempotent: Compute
/// and Identify compute again, a chunk is taken again at its offset, Info and Stats read). With
/// a fifth of the frames damaged one way, a request fails all 8 with odds of 2.6·10⁻⁶.
pub const TRIES: usize = 8;
/// Requests in flight by default when a stream is pipelined ([`Device::with_window`]).
pub const DEFAULT_WINDOW: usize = 4;
/// After line noise or a damaged answer, how long the oldest request in flight still waits for
/// its answer before it is sent again (at most the timeout).
const GRACE: Duration = Duration::from_millis(200);

/// What can go wrong talking to a device.
#[derive(Debug)]
#[non_exhaustive]
pub enum DeviceError {
    /// The port or transport failed.
    Io(io::Error),
    /// No device at this path.
    Absent(String),
    /// The port is in use by another program.
    Busy(String),
    /// No response within the timeout, nothing heard at all, after every try.
    Timeout(Duration),
    /// No valid answer after every try, but the line carried something.
    NoValidAnswer {
        /// Sends of the request.
        tries: usize,
        /// Frames that did not decode (damaged on the line).
        damaged: u64,
        /// The device's answers to frames it could not read (seq 0).
        unreadable: u64,
        /// Answers to other requests (stale, or duplicated).
        stale: u64,
    },
    /// The device answered with an error.
    Device(ErrorCode),
    /// The device answered with another kind of response than the request asks for.
    Unexpected(&'static str),
    /// The device speaks another protocol version.
    Protocol(u16),
    /// The device holds another calibration than expected (or none).
    Fingerprint {
        /// The fingerprint expected.
        expected: u64,
        /// The device's, if it has a calibration.
        device: Option<u64>,
    },
    /// The device holds no calibration.
    NoCalibration,
    /// Centroid `index` lies off the sensor's fixed-point range.
    Centroid(usize),
    /// The rig cannot be encoded for the device.
    Calibration(&'static str),
    /// The device's points asked for, but the host does not hold the device's calibration to
    /// place them with (see [`Device::expect_system`]).
    NotHeld(u64),
}

impl std::fmt::Display for DeviceError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DeviceError::Io(e) => write!(f, "link failed: {e}"),
            DeviceError::Absent(p) => write!(f, "no device at {p}"),
            DeviceError::Busy(p) => write!(f, "{p} is busy (in use by another program)"),
            DeviceError::Timeout(t) => write!(f, "the device did not answer within {t:?}"),
            DeviceError::NoValidAnswer {
                tries,
                damaged,
                unreadable,
                stale,
            } => write!(
                f,
                "no valid answer after {tries} tries: the line carried {damaged} damaged \
                 frames, {unreadable} answers to frames the device could not read and \
                 {stale} answers to other requests"
            ),
            DeviceError::Device(code) => write!(f, "the device refused: {code}"),
            DeviceError::Unexpected(what) => write!(f, "the device did not answer with {what}"),
            DeviceError::Protocol(v) => write!(
                f,
                "the device speaks protocol {v}, this host {PROTOCOL_VERSION}"
            ),
            DeviceError::Fingerprint { expected, device } => match device {
                Some(d) => write!(
                    f,
                    "the device holds calibration {d:016x}, not {expected:016x}"
                ),
                None => write!(
                    f,
                    "the device holds no calibration (expected {expected:016x})"
                ),
            },
            DeviceError::NoCalibration => write!(f, "the device holds no calibration"),
            DeviceError::Centroid(i) => write!(f, "centroid {i} lies off the sensor"),
            DeviceError::Calibration(why) => write!(f, "cannot upload the calibration: {why}"),
            DeviceError::NotHeld(fingerprint) => write!(
                f,
                "the host places the device's points with the device's calibration \
                 ({fingerprint:016x}) and was not given it: give its system file"
            ),
        }
    }
}

impl std::error::Error for DeviceError {}

impl From<io::Error> for DeviceError {
    fn from(e: io::Error) -> Self {
        DeviceError::Io(e)
    }
}

/// The client's result type.
pub type Result<T> = std::result::Result<T, DeviceError>;

/// A point from the device in world coordinates (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldPoint {
    /// The point: placed in f64 on the camera ray at the device's depth
    /// ([`Rig::reconstruct_at_depth`]).
    pub point: Vector3<f64>,
    /// The rays' miss distance (mm).
    pub miss: f64,
}

/// A device behind a transport.
pub struct Device<T> {
    transport: T,
    seq: u32,
    timeout: Duration,
    window: usize,
    /// The most request bytes in flight (delimiters included) when more than one is.
    in_flight_bytes: usize,
    drained: bool,
    pending: Vec<u8>,
    calibration: Option<CalibrationSummary>,
    /// The calibration the host holds for the device (in f64: what its depths are placed
    /// with), by fingerprint.
    held: Option<(u64, Arc<SystemRig>)>,
    sent: u64,
    received: u64,
    line: LineCounts,
}

/// What the client saw on the line besides the answers it waited for.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LineCounts {
    /// Requests sent again (their answer was missing or damaged).
    pub resent: u64,
    /// Frames that did not decode.
    pub damaged: u64,
    /// The device's answers to frames it could not read (seq 0).
    pub unreadable: u64,
    /// Answers with a seq not in flight (stale, duplicated).
    pub stale: u64,
}

/// A request in flight.
struct InFlight {
    /// Its place in the caller's list.
    index: usize,
    seq: u32,
    frame: Vec<u8>,
    tries: usize,
    /// When it was first sent, as a count of sends: the device answers in this order, and an
    /// answer arriving may be that of the first send even when the request was sent again.
    first: u64,
    /// When it was last sent, as a count of sends.
    order: u64,
    deadline: Instant,
}

impl Device<InProcess> {
    /// The firmware's logic in this process (an empty flash).
    pub fn in_process() -> Self {
        Self::new(InProcess::new())
    }
}

impl<T: Transport> Device<T> {
    /// A client over `transport` with [`DEFAULT_TIMEOUT`].
    pub fn new(transport: T) -> Self {
        Self {
            transport,
            seq: fresh_seq(),
            timeout: DEFAULT_TIMEOUT,
            window: DEFAULT_WINDOW,
            in_flight_bytes: usize::MAX,
            drained: false,
            pending: Vec::new(),
            calibration: None,
            held: None,
            sent: 0,
            received: 0,
            line: LineCounts::default(),
        }
    }

    /// The same client keeping up to `window` requests in flight in a stream (at least 1).
    pub fn with_window(mut self, window: usize) -> Self {
        self.window = window.max(1);
        self
    }

    /// The same client keeping a second request in flight only while the requests in flight
    /// come to at most `bytes` (delimiters included): what a device receives while it answers.
    pub fn with_in_flight_bytes(mut self, bytes: usize) -> Self {
        self.in_flight_bytes = bytes;
        self
    }

    /// What the line carried besides the expected answers, so far.
    pub fn line_counts(&self) -> LineCounts {
        self.line
    }

    /// The same client with another response timeout.
    pub fn with_timeout(mut self, timeout: Duration) -> Self {
        self.timeout = timeout;
        self
    }

    /// Close the client, keeping the transport.
    pub fn into_transport(self) -> T {
        self.transport
    }

    /// Bytes sent and received so far (frames and delimiters).
    pub fn byte_counts(&self) -> (u64, u64) {
        (self.sent, self.received)
    }

    /// Versions, capacities and the active calibration.
    pub fn info(&mut self) -> Result<DeviceInfo> {
        match self.call(RequestBody::Info)? {
            ResponseBody::Info(info) => {
                if info.protocol != PROTOCOL_VERSION {
                    return Err(DeviceError::Protocol(info.protocol));
                }
                self.calibration = info.calibration;
                Ok(info)
            }
            _ => Err(DeviceError::Unexpected("Info")),
        }
    }

    /// The active calibration, checked to be `fingerprint`.
    pub fn expect_calibration(&mut self, fingerprint: u64) -> Result<CalibrationSummary> {
        match self.info()?.calibration {
            Some(c) if c.fingerprint == fingerprint => Ok(c),
            other => Err(DeviceError::Fingerprint {
                expected: fingerprint,
                device: other.map(|c| c.fingerprint),
            }),
        }
    }

    /// [`Device::expect_calibration`], and the host holds `rig` (that calibration, in f64) to
    /// place the device's points with: a device that already holds the calibration.
    pub fn expect_system<S: AsRef<[ProjectorRay<f64>]>>(
        &mut self,
        rig: &Rig<f64, S>,
        fingerprint: u64,
    ) -> Result<CalibrationSummary> {
        let summary = self.expect_calibration(fingerprint)?;
        self.hold(rig, fingerprint);
        Ok(summary)
    }

    /// Hold `rig` as the calibration of `fingerprint`.
    fn hold<S: AsRef<[ProjectorRay<f64>]>>(&mut self, rig: &Rig<f64, S>, fingerprint: u64) {
        let p = rig.projector_centred();
        let projector = Projector::from_checked(p.centre(), p.rays().to_vec());
        let held = Rig::from_centred(
            *rig.grid(),
            *rig.inner(),
            *rig.r_cam_world(),
            rig.camera_centre(),
            projector,
        );
        self.held = Some((fingerprint, Arc::new(held)));
    }

    /// Upload `rig` with the closest-approach intersection (see [`Device::upload_with`]).
    pub fn upload<S: AsRef<[ProjectorRay<f64>]>>(
        &mut self,
        rig: &Rig<f64, S>,
        fingerprint: u64,
    ) -> Result<CalibrationSummary> {
        self.upload_with(rig, fingerprint, Method::ClosestApproach)
    }

    /// Upload `rig` as the device's calibration, computed with `method`; verified by reading the
    /// fingerprint back.
    pub fn upload_with<S: AsRef<[ProjectorRay<f64>]>>(
        &mut self,
        rig: &Rig<f64, S>,
        fingerprint: u64,
        method: Method,
    ) -> Result<CalibrationSummary> {
        self.upload_identifying(rig, fingerprint, method, None)
    }

    /// [`Device::upload_with`], and the device identifies unlabelled dots
    /// ([`Device::identify`]) with `identification`.
    pub fn upload_identifying<S: AsRef<[ProjectorRay<f64>]>>(
        &mut self,
        rig: &Rig<f64, S>,
        fingerprint: u64,
        method: Method,
        identification: Option<IdentifyParams>,
    ) -> Result<CalibrationSummary> {
        let blob = calibration_blob_identifying(rig, fingerprint, method, identification)
            .map_err(DeviceError::Calibration)?;
        let summary = self.upload_blob(&blob, fingerprint)?;
        self.hold(rig, fingerprint);
        Ok(summary)
    }

    /// Upload a calibration blob in chunks, retried when the device reports a CRC failure, and
    /// verified by reading the fingerprint back.
    pub fn upload_blob(&mut self, blob: &[u8], fingerprint: u64) -> Result<CalibrationSummary> {
        let len =
            u32::try_from(blob.len()).map_err(|_| DeviceError::Device(ErrorCode::TooLarge))?;
        for attempt in 1..=UPLOAD_ATTEMPTS {
            match self.call(RequestBody::UploadBegin {
                len,
                crc: CRC.checksum(blob),
            })? {
                ResponseBody::UploadReady { .. } => {}
                _ => return Err(DeviceError::Unexpected("UploadReady")),
            }
            for (i, chunk) in blob.chunks(CHUNK_SIZE).enumerate() {
                let offset = (i * CHUNK_SIZE) as u32;
                let data = heapless::Vec::from_slice(chunk)
                    .unwrap_or_else(|_| unreachable!("chunks of CHUNK_SIZE"));
                match self.call(RequestBody::UploadChunk { offset, data })? {
                    ResponseBody::ChunkAccepted { next_offset }
                        if next_offset == offset + chunk.len() as u32 => {}
                    _ => return Err(DeviceError::Unexpected("ChunkAccepted")),
                }
            }
            match self.call(RequestBody::UploadCommit) {
                Ok(ResponseBody::Committed { .. }) => break,
                // A commit sent again after its answer was lost finds the upload done: the
                // fingerprint read back below tells whether it committed.
                Err(DeviceError::Device(ErrorCode::NoUpload)) => break,
                Err(DeviceError::Device(ErrorCode::UploadCrc)) if attempt < UPLOAD_ATTEMPTS => {}
                Ok(_) => return Err(DeviceError::Unexpected("Committed")),
                Err(e) => return Err(e),
            }
        }
        self.expect_calibration(fingerprint)
    }

    /// The 3D points of one or more camera frames' centroids `(ray id, col, row)` (pixels), in
    /// order; a centroid without a point gets its status. Split into batches the device takes,
    /// each sent sorted by ray id (the compact form of the ids, see
    /// `deltaz_shared::protocol::delta`), pipelined.
    pub fn compute(&mut self, centroids: &[(u16, f64, f64)]) -> Result<Vec<PointOutcome>> {
        let batches: Vec<&[(u16, f64, f64)]> = centroids.chunks(MAX_BATCH).collect();
        Ok(self.compute_frames(&batches)?.concat())
    }

    /// [`Device::compute`] of several frames (each at most [`MAX_BATCH`] centroids), keeping up
    /// to the window ([`Device::with_window`]) of requests in flight: the device receives the
    /// next frame while it sends the answer to the previous one.
    pub fn compute_frames<F: AsRef<[(u16, f64, f64)]>>(
        &mut self,
        frames: &[F],
    ) -> Result<Vec<Vec<PointOutcome>>> {
        let (calibration, rig) = self.placing()?;
        let mut orders = Vec::with_capacity(frames.len());
        // Each request's rays and the pixels its fixed point stands for, in the wire's order.
        let mut sent: Vec<Vec<(u16, (f64, f64))>> = Vec::with_capacity(frames.len());
        let mut requests = Vec::with_capacity(frames.len());
        let mut first = 0;
        for frame in frames {
            let frame = frame.as_ref();
            if frame.len() > MAX_BATCH {
                return Err(DeviceError::Device(ErrorCode::Frame(WireError::BufferFull)));
            }
            let mut order: Vec<usize> = (0..frame.len()).collect();
            order.sort_by_key(|&i| frame[i].0);
            let mut wire = heapless::Vec::new();
            let mut placed = Vec::with_capacity(frame.len());
            for &i in &order {
                let (id, col, row) = frame[i];
                let c = Centroid::from_pixel(id, col, row, calibration.centroid_bits)
                    .ok_or(DeviceError::Centroid(first + i))?;
                placed.push((id, c.pixel(calibration.centroid_bits)));
                wire.push(c)
                    .unwrap_or_else(|_| unreachable!("at most MAX_BATCH per frame"));
            }
            first += frame.len();
            orders.push(order);
            sent.push(placed);
            requests.push(RequestBody::Compute { centroids: wire });
        }
        let mut out: Vec<Vec<PointOutcome>> = Vec::with_capacity(frames.len());
        out.resize_with(frames.len(), Vec::new);
        let mut fingerprints = Vec::new();
        self.pipeline(requests, |k, body| match body {
            ResponseBody::Points {
                fingerprint,
                points,
            } if points.len() == orders[k].len() => {
                fingerprints.push(fingerprint);
                let mut results = vec![Err(PointStatus::Degenerate); points.len()];
                for ((&i, &(id, pixel)), p) in orders[k].iter().zip(&sent[k]).zip(&points) {
                    results[i] = place(&rig, &calibration, id, pixel, p);
                }
                out[k] = results;
                Ok(())
            }
            _ => Err(DeviceError::Unexpected("Points")),
        })?;
        for fingerprint in fingerprints {
            self.check_fingerprint(&calibration, fingerprint)?;
        }
        Ok(out)
    }

    /// Unlabelled dots `(col, row)` (pixels) of one camera frame: the device identifies each
    /// (the ray id, see [`deltaz_shared::protocol::IdentifiedPoint`] for the id of a status)
    /// and computes its point. The calibration must carry identification parameters
    /// ([`Device::upload_identifying`]). A frame of more than [`MAX_BATCH`] dots goes as several
    /// requests; two dots of the frame claiming one ray are both [`PointStatus::Conflict`]
    /// (as the host's `identify_frame` finds them).
    pub fn identify(&mut self, dots: &[(f64, f64)]) -> Result<Vec<(u16, PointOutcome)>> {
        Ok(self.identify_frames(&[dots])?.concat())
    }

    /// [`Device::identify`] of several frames, pipelined as in [`Device::compute_frames`].
    pub fn identify_frames<F: AsRef<[(f64, f64)]>>(
        &mut self,
        frames: &[F],
    ) -> Result<Vec<Vec<(u16, PointOutcome)>>> {
        let (calibration, rig) = self.placing()?;
        let mut requests = Vec::with_capacity(frames.len());
        // The frame of each request, and each request's length.
        let (mut owners, mut sent) = (Vec::new(), Vec::new());
        let mut first = 0;
        for (k, frame) in frames.iter().enumerate() {
            for batch in frame.as_ref().chunks(MAX_BATCH) {
                let mut wire = heapless::Vec::new();
                let mut pixels = Vec::with_capacity(batch.len());
                for (i, &(col, row)) in batch.iter().enumerate() {
                    let dot = Dot::from_pixel(col, row, calibration.centroid_bits)
                        .ok_or(DeviceError::Centroid(first + i))?;
                    pixels.push(dot.pixel(calibration.centroid_bits));
                    wire.push(dot)
                        .unwrap_or_else(|_| unreachable!("at most MAX_BATCH dots"));
                }
                first += batch.len();
                owners.push(k);
                sent.push(pixels);
                requests.push(RequestBody::Identify { dots: wire });
            }
        }
        let mut batches: Vec<Vec<(u16, PointOutcome)>> = Vec::new();
        batches.resize_with(requests.len(), Vec::new);
        let mut fingerprints = Vec::new();
        self.pipeline(requests, |b, body| match body {
            ResponseBody::Identified {
                fingerprint,
                points,
            } if points.len() == sent[b].len() => {
                fingerprints.push(fingerprint);
                batches[b] = points
                    .iter()
                    .zip(&sent[b])
                    .map(|(p, &pixel)| (p.id, place(&rig, &calibration, p.id, pixel, &p.result)))
                    .collect();
                Ok(())
            }
            _ => Err(DeviceError::Unexpected("Identified")),
        })?;
        for fingerprint in fingerprints {
            self.check_fingerprint(&calibration, fingerprint)?;
        }
        let mut out: Vec<Vec<(u16, PointOutcome)>> = Vec::with_capacity(frames.len());
        out.resize_with(frames.len(), Vec::new);
        for (k, batch) in owners.into_iter().zip(batches) {
            out[k].extend(batch);
        }
        for frame in &mut out {
            mark_conflicts(frame);
        }
        Ok(out)
    }

    /// The active calibration, asked for when not known yet.
    fn calibration(&mut self) -> Result<CalibrationSummary> {
        match self.calibration {
            Some(c) => Ok(c),
            None => self.info()?.calibration.ok_or(DeviceError::NoCalibration),
        }
    }

    /// The active calibration and the rig the host holds for it.
    fn placing(&mut self) -> Result<(CalibrationSummary, Arc<SystemRig>)> {
        let calibration = self.calibration()?;
        match &self.held {
            Some((fingerprint, rig)) if *fingerprint == calibration.fingerprint => {
                Ok((calibration, Arc::clone(rig)))
            }
            _ => Err(DeviceError::NotHeld(calibration.fingerprint)),
        }
    }

    /// A fingerprint in a response other than the calibration's: forget it and say so.
    fn check_fingerprint(
        &mut self,
        calibration: &CalibrationSummary,
        fingerprint: u64,
    ) -> Result<()> {
        if fingerprint == calibration.fingerprint {
            return Ok(());
        }
        self.calibration = None;
        Err(DeviceError::Fingerprint {
            expected: calibration.fingerprint,
            device: Some(fingerprint),
        })
    }

    /// Counters and the ticks of the last compute.
    pub fn stats(&mut self) -> Result<DeviceStats> {
        match self.call(RequestBody::Stats)? {
            ResponseBody::Stats(s) => Ok(s),
            _ => Err(DeviceError::Unexpected("Stats")),
        }
    }

    /// Restart the device; it loads its stored calibration again.
    pub fn reset(&mut self) -> Result<()> {
        self.calibration = None;
        match self.call(RequestBody::Reset)? {
            ResponseBody::Resetting => Ok(()),
            _ => Err(DeviceError::Unexpected("Resetting")),
        }
    }

    /// Send one request and wait for its answer (see [`Device::pipeline`]).
    fn call(&mut self, body: RequestBody) -> Result<ResponseBody> {
        let mut response = None;
        self.pipeline([body], |_, body| {
            response = Some(body);
            Ok(())
        })?;
        response.ok_or(DeviceError::Unexpected("an answer"))
    }

    /// Send `requests`, keeping up to the window of them in flight, and hand each answer with
    /// the request's index to `answered` (in the order they arrive). Each request gets a fresh
    /// seq; answers with another seq are ignored (stale answers of an earlier run, duplicates,
    /// and the device's seq-0 answers to frames it could not read, which say only that *some*
    /// frame was damaged). A request is sent again, with its seq, when its answer is overdue:
    /// after the timeout, when a later request was answered (the device answers in order), or
    /// shortly after a damaged frame or a seq-0 answer; after [`TRIES`] sends it fails, saying
    /// what the line carried. An error answer fails the whole call.
    fn pipeline(
        &mut self,
        requests: impl IntoIterator<Item = RequestBody>,
        mut answered: impl FnMut(usize, ResponseBody) -> Result<()>,
    ) -> Result<()> {
        if !std::mem::replace(&mut self.drained, true) {
            self.drain()?;
        }
        let seen_before = self.line;
        let mut requests = requests.into_iter().enumerate();
        let mut flight: Vec<InFlight> = Vec::new();
        let mut order = 0u64;
        let grace = GRACE.min(self.timeout);
        // The next request, encoded, waiting for room in the window.
        let mut next: Option<(usize, u32, Vec<u8>)> = None;
        loop {
            while flight.len() < self.window {
                if next.is_none() {
                    let Some((index, body)) = requests.next() else {
                        break;
                    };
                    let seq = self.next_seq();
                    // A leading delimiter ends any partial frame the device holds.
                    let mut frame = vec![0u8; MAX_FRAME + 1];
                    let len = encode_frame(&Request { seq, body }, &mut frame[1..])
                        .map_err(|e| DeviceError::Device(ErrorCode::Frame(e)))?
                        .len();
                    frame.truncate(len + 1);
                    next = Some((index, seq, frame));
                }
                let in_flight: usize = flight.iter().map(|f| f.frame.len()).sum();
                let Some((index, seq, frame)) = next.take_if(|(_, _, frame)| {
                    flight.is_empty() || in_flight + frame.len() <= self.in_flight_bytes
                }) else {
                    break;
                };
                self.send(&frame)?;
                order += 1;
                flight.push(InFlight {
                    index,
                    seq,
                    frame,
                    tries: 1,
                    first: order,
                    order,
                    deadline: Instant::now() + self.timeout,
                });
            }
            let Some(until) = flight.iter().map(|f| f.deadline).min() else {
                return Ok(());
            };
            let oldest = flight.iter().map(|f| f.order).min().unwrap_or(0);
            let frame = self.next_frame(until)?;
            // The time the wait ended: the grace after noise runs from here, however long the
            // wait was.
            let now = Instant::now();
            match frame {
                Some(Ok(response)) => {
                    if let Some(k) = flight.iter().position(|f| f.seq == response.seq) {
                        let done = flight.swap_remove(k);
                        // The device answers in order: requests sent before this one was first
                        // sent and still unanswered were lost, or their answers were (the answer
                        // may be to its first send: those sent between its sends are not late).
                        for f in flight.iter_mut().filter(|f| f.order < done.first) {
                            f.deadline = now;
                        }
                        answered(done.index, answer(response.body)?)?;
                    } else if response.seq == 0 {
                        self.line.unreadable += 1;
                        shorten(&mut flight, oldest, now + grace);
                    } else {
                        self.line.stale += 1;
                    }
                }
                Some(Err(_)) => {
                    self.line.damaged += 1;
                    shorten(&mut flight, oldest, now + grace);
                }
                None => {}
            }
            let now = Instant::now();
            for f in flight.iter_mut().filter(|f| f.deadline <= now) {
                if f.tries >= TRIES {
                    let seen = LineCounts {
                        resent: 0,
                        damaged: self.line.damaged - seen_before.damaged,
                        unreadable: self.line.unreadable - seen_before.unreadable,
                        stale: self.line.stale - seen_before.stale,
                    };
                    return Err(if seen == LineCounts::default() {
                        DeviceError::Timeout(self.timeout)
                    } else {
                        DeviceError::NoValidAnswer {
                            tries: TRIES,
                            damaged: seen.damaged,
                            unreadable: seen.unreadable,
                            stale: seen.stale,
                        }
                    });
                }
                self.transport.send(&f.frame)?;
                self.sent += f.frame.len() as u64;
                self.line.resent += 1;
                order += 1;
                f.tries += 1;
                f.order = order;
                f.deadline = now + self.timeout;
            }
        }
    }

    /// The next seq: never 0 (the device's own for frames it could not read).
    fn next_seq(&mut self) -> u32 {
        self.seq = self.seq.wrapping_add(1).max(1);
        self.seq
    }

    fn send(&mut self, frame: &[u8]) -> Result<()> {
        self.transport.send(frame)?;
        self.sent += frame.len() as u64;
        Ok(())
    }

    /// Drop whatever the line holds from before this session (a stale answer of an earlier,
    /// killed run, boot text): read until it stays quiet for a moment.
    fn drain(&mut self) -> Result<()> {
        self.pending.clear();
        let mut chunk = [0u8; 4096];
        let quiet = Duration::from_millis(20).min(self.timeout);
        for _ in 0..1024 {
            let n = self.transport.recv(&mut chunk, quiet)?;
            self.received += n as u64;
            if n == 0 {
                break;
            }
        }
        Ok(())
    }

    /// The next complete frame decoded (`Err` when damaged), or `None` when none completes by
    /// `deadline`. Empty frames (idle delimiters) are skipped.
    fn next_frame(
        &mut self,
        deadline: Instant,
    ) -> Result<Option<std::result::Result<Response, WireError>>> {
        loop {
            while let Some(end) = self.pending.iter().position(|&b| b == 0) {
                let mut frame: Vec<u8> = self.pending.drain(..=end).collect();
                frame.pop();
                if !frame.is_empty() {
                    return Ok(Some(decode_response(&mut frame)));
                }
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            let mut chunk = [0u8; 4096];
            let n = self.transport.recv(&mut chunk, left)?;
            self.received += n as u64;
            self.pending.extend_from_slice(&chunk[..n]);
        }
    }
}

/// A point from the device, or the status of a centroid without one.
pub type PointOutcome = std::result::Result<WorldPoint, PointStatus>;

/// One frame's identified dots: every ray the device identified more than one dot as becomes a
/// [`PointStatus::Conflict`] for all of them (neither is trusted, as
/// `deltaz_shared::identify::Identifier::identify_frame` does on the host). A dot claims its
/// ray unless it is ambiguous or unassigned.
fn mark_conflicts(frame: &mut [(u16, PointOutcome)]) {
    let claims =
        |r: &PointOutcome| !matches!(r, Err(PointStatus::Ambiguous | PointStatus::Unassigned));
    let mut count = std::collections::HashMap::<u16, usize>::new();
    for (id, r) in frame.iter() {
        if claims(r) {
            *count.entry(*id).or_default() += 1;
        }
    }
    for (id, r) in frame.iter_mut() {
        if claims(r) && count.get(id).is_some_and(|&n| n > 1) {
            *r = Err(PointStatus::Conflict);
        }
    }
}

/// Let the request sent as `order` wait no later than `until`.
fn shorten(flight: &mut [InFlight], order: u64, until: Instant) {
    for f in flight.iter_mut().filter(|f| f.order == order) {
        f.deadline = f.deadline.min(until);
    }
}

/// A seq no earlier run is likely to have used: from the clock and the process id.
fn fresh_seq() -> u32 {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default();
    now.subsec_nanos() ^ (now.as_secs() as u32).rotate_left(7) ^ std::process::id().rotate_left(16)
}

/// The world point of the device's result for the dot of ray `id` it was sent at `pixel`
/// (the fixed point's position): placed at the device's depth by the calibration's method.
fn place(
    rig: &SystemRig,
    calibration: &CalibrationSummary,
    id: u16,
    (col, row): (f64, f64),
    result: &PointResult,
) -> PointOutcome {
    let depth = match result {
        PointResult::Depth(_) => result.depth_mm().unwrap_or_default(),
        PointResult::Failed(status) => return Err(*status),
    };
    rig.reconstruct_at_depth(id, col, row, depth, calibration.method.into())
        .map(|hit| WorldPoint {
            point: hit.point,
            miss: hit.miss,
        })
        .map_err(PointStatus::of)
}

fn answer(body: ResponseBody) -> Result<ResponseBody> {
    match body {
        ResponseBody::Error(code) => Err(DeviceError::Device(code)),
        body => Ok(body),
    }
}
