//! The typed device client: one method per request.

use super::calibration::calibration_blob_identifying;
use super::in_process::InProcess;
use super::Transport;
use deltaz_shared::projector::ProjectorRay;
use deltaz_shared::protocol::calibration::IdentifyParams;
use deltaz_shared::protocol::frame::CRC;
use deltaz_shared::protocol::{
    decode_response, encode_frame, CalibrationSummary, Centroid, DeviceInfo, DeviceStats, Dot,
    ErrorCode, PointResult, PointStatus, Request, RequestBody, ResponseBody, WireError, CHUNK_SIZE,
    MAX_BATCH, MAX_FRAME, PROTOCOL_VERSION,
};
use deltaz_shared::rig::{Method, Rig};
use nalgebra::Vector3;
use std::io;
use std::time::{Duration, Instant};

/// How long a request waits for its response by default.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(3);
/// Upload attempts when the device reports a CRC failure of the whole blob.
const UPLOAD_ATTEMPTS: usize = 3;
/// Sends of one request the device could not read (damaged on the line).
const SEND_ATTEMPTS: usize = 3;

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
    /// No response within the timeout.
    Timeout(Duration),
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
}

impl std::fmt::Display for DeviceError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DeviceError::Io(e) => write!(f, "link failed: {e}"),
            DeviceError::Absent(p) => write!(f, "no device at {p}"),
            DeviceError::Busy(p) => write!(f, "{p} is busy (in use by another program)"),
            DeviceError::Timeout(t) => write!(f, "the device did not answer within {t:?}"),
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
    /// The point: the device's camera-centred point plus the camera centre (in f64).
    pub point: Vector3<f64>,
    /// The rays' miss distance (mm, a lower bound at 0.93 mm and above).
    pub miss: f64,
}

/// A device behind a transport.
pub struct Device<T> {
    transport: T,
    seq: u32,
    timeout: Duration,
    pending: Vec<u8>,
    calibration: Option<CalibrationSummary>,
    sent: u64,
    received: u64,
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
            seq: 0,
            timeout: DEFAULT_TIMEOUT,
            pending: Vec::new(),
            calibration: None,
            sent: 0,
            received: 0,
        }
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
            .ok_or(DeviceError::Calibration("more than 65535 rays"))?;
        self.upload_blob(&blob, fingerprint)
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
    /// `deltaz_shared::protocol::delta`).
    pub fn compute(
        &mut self,
        centroids: &[(u16, f64, f64)],
    ) -> Result<Vec<std::result::Result<WorldPoint, PointStatus>>> {
        let calibration = self.calibration()?;
        let mut out = Vec::with_capacity(centroids.len());
        for (b, batch) in centroids.chunks(MAX_BATCH).enumerate() {
            let mut order: Vec<usize> = (0..batch.len()).collect();
            order.sort_by_key(|&i| batch[i].0);
            let mut wire = heapless::Vec::new();
            for &i in &order {
                let (id, col, row) = batch[i];
                let c = Centroid::from_pixel(id, col, row, calibration.centroid_bits)
                    .ok_or(DeviceError::Centroid(b * MAX_BATCH + i))?;
                wire.push(c)
                    .unwrap_or_else(|_| unreachable!("batches of MAX_BATCH"));
            }
            match self.call(RequestBody::Compute { centroids: wire })? {
                ResponseBody::Points {
                    fingerprint,
                    points,
                } if points.len() == batch.len() => {
                    self.check_fingerprint(&calibration, fingerprint)?;
                    let mut results = vec![Err(PointStatus::Degenerate); batch.len()];
                    for (&i, p) in order.iter().zip(&points) {
                        results[i] = world_point(&calibration, p);
                    }
                    out.extend(results);
                }
                _ => return Err(DeviceError::Unexpected("Points")),
            }
        }
        Ok(out)
    }

    /// Unlabelled dots `(col, row)` (pixels) of one camera frame: the device identifies each
    /// (the ray id, see [`deltaz_shared::protocol::IdentifiedPoint`] for the id of a status)
    /// and computes its point. The calibration must carry identification parameters
    /// ([`Device::upload_identifying`]). At most [`MAX_BATCH`] dots: a frame is one batch, since
    /// two dots claiming one ray are found only within a batch.
    pub fn identify(
        &mut self,
        dots: &[(f64, f64)],
    ) -> Result<Vec<(u16, std::result::Result<WorldPoint, PointStatus>)>> {
        let calibration = self.calibration()?;
        if dots.len() > MAX_BATCH {
            return Err(DeviceError::Device(ErrorCode::Frame(WireError::BufferFull)));
        }
        let mut wire = heapless::Vec::new();
        for (i, &(col, row)) in dots.iter().enumerate() {
            let dot = Dot::from_pixel(col, row, calibration.centroid_bits)
                .ok_or(DeviceError::Centroid(i))?;
            wire.push(dot)
                .unwrap_or_else(|_| unreachable!("at most MAX_BATCH dots"));
        }
        match self.call(RequestBody::Identify { dots: wire })? {
            ResponseBody::Identified {
                fingerprint,
                points,
            } if points.len() == dots.len() => {
                self.check_fingerprint(&calibration, fingerprint)?;
                Ok(points
                    .iter()
                    .map(|p| (p.id, world_point(&calibration, &p.result)))
                    .collect())
            }
            _ => Err(DeviceError::Unexpected("Identified")),
        }
    }

    /// The active calibration, asked for when not known yet.
    fn calibration(&mut self) -> Result<CalibrationSummary> {
        match self.calibration {
            Some(c) => Ok(c),
            None => self.info()?.calibration.ok_or(DeviceError::NoCalibration),
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

    /// Send one request and wait for the response with its seq. A request the device could not
    /// read (a frame damaged on the line: COBS, length or CRC) was not executed, so it is sent
    /// again, up to [`SEND_ATTEMPTS`] times.
    fn call(&mut self, body: RequestBody) -> Result<ResponseBody> {
        self.seq = self.seq.wrapping_add(1).max(1);
        let request = Request {
            seq: self.seq,
            body,
        };
        // A leading delimiter ends any partial frame the device holds.
        let mut buf = vec![0u8; MAX_FRAME + 1];
        let len = encode_frame(&request, &mut buf[1..])
            .map_err(|e| DeviceError::Device(ErrorCode::Frame(e)))?
            .len();
        let frame = &buf[..=len];
        let mut attempt = 1;
        loop {
            match self.exchange(frame) {
                Err(DeviceError::Device(ErrorCode::Frame(
                    WireError::BadCrc | WireError::Cobs | WireError::TooShort,
                ))) if attempt < SEND_ATTEMPTS => attempt += 1,
                result => return result,
            }
        }
    }

    /// Send a frame and wait for the response with the current seq; frames that do not decode
    /// or carry another seq (boot text, stale answers) are skipped.
    fn exchange(&mut self, frame: &[u8]) -> Result<ResponseBody> {
        self.pending.clear();
        self.transport.send(frame)?;
        self.sent += frame.len() as u64;
        let deadline = Instant::now() + self.timeout;
        loop {
            while let Some(end) = self.pending.iter().position(|&b| b == 0) {
                let mut frame: Vec<u8> = self.pending.drain(..=end).collect();
                frame.pop();
                if frame.is_empty() {
                    continue;
                }
                match decode_response(&mut frame) {
                    Ok(r) if r.seq == self.seq => return answer(r.body),
                    // The device could not read a request: ours, as we wait for no other.
                    Ok(r) if r.seq == 0 => return answer(r.body),
                    _ => {}
                }
            }
            let left = deadline.saturating_duration_since(Instant::now());
            let mut chunk = [0u8; 4096];
            let n = self.transport.recv(&mut chunk, left)?;
            self.received += n as u64;
            self.pending.extend_from_slice(&chunk[..n]);
            if n == 0 && Instant::now() >= deadline {
                return Err(DeviceError::Timeout(self.timeout));
            }
        }
    }
}

/// A result from the device in world coordinates: the camera centre (f64) added back.
fn world_point(
    calibration: &CalibrationSummary,
    p: &PointResult,
) -> std::result::Result<WorldPoint, PointStatus> {
    match *p {
        PointResult::Point { .. } => Ok(WorldPoint {
            point: p.camera_centred_mm().unwrap_or_default()
                + Vector3::from(calibration.camera_centre),
            miss: p.miss_mm().unwrap_or_default(),
        }),
        PointResult::Failed(status) => Err(status),
    }
}

fn answer(body: ResponseBody) -> Result<ResponseBody> {
    match body {
        ResponseBody::Error(code) => Err(DeviceError::Device(code)),
        body => Ok(body),
    }
}
