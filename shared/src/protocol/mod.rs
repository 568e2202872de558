//! The wire protocol between host and device (the ICD): one table of messages, then plain serde
//! types. Both ends use this module; the firmware needs no allocator for it.
//!
//! # Messages
//!
//! Every request carries a sequence number that its response echoes (seq 0 is reserved for the
//! device's answer to a frame it could not read far enough to learn the seq).
//!
//! | request ([`RequestBody`]) | response ([`ResponseBody`]) |
//! |---|---|
//! | `Info` | `Info(DeviceInfo)`: firmware and protocol version, capacities, calibration or none, why the stored one failed to load at boot, the board's clock |
//! | `UploadBegin { len, crc }` | `UploadReady { len }` |
//! | `UploadChunk { offset, data }` | `ChunkAccepted { next_offset }` |
//! | `UploadCommit` | `Committed { fingerprint, generation }` |
//! | `Compute { centroids }` | `Points { fingerprint, points }` (one [`PointResult`] per centroid, in order) |
//! | `Stats` | `Stats(DeviceStats)`: counters and the ticks of the last compute |
//! | `Reset` | `Resetting` (then the device restarts) |
//! | `Identify { dots }` | `Identified { fingerprint, points }` (one [`IdentifiedPoint`] per dot, in order) |
//!
//! Any request may instead get `Error(ErrorCode)`: a bad frame, bad state or bad parameters.
//!
//! # Frames
//! See [`frame`]: `COBS(postcard(message) ‖ CRC-32(postcard bytes), little endian) ‖ 0x00`.
//!
//! # Compact per-point forms
//! A labelled centroid is 5 bytes: its ray id as the difference to the previous centroid's id
//! (a zigzag varint, one byte when the batch is sorted by id; see [`delta`]) and col, row as u16
//! fixed point ([`Dot`], [`Centroid`]). A result is 3 bytes: the depth of the point in units of
//! 2⁻¹⁰ mm, or a status ([`PointResult`]); the host, which holds the calibration in f64 (its
//! fingerprint checked), places the point on the camera ray through the centroid it sent at
//! that depth, and its miss distance follows ([`crate::rig::Rig::reconstruct_at_depth`]). With
//! the frame overhead a 440-dot frame costs 8.1 bytes per point for request and response
//! together.
//!
//! An unlabelled dot ([`RequestBody::Identify`]) is 4 bytes; its answer ([`IdentifiedPoint`]) is
//! the delta-coded id of the ray the device identified (1-3 bytes: the dots come in image order)
//! and the 3-byte result. The device identifies with [`crate::identify`] (f32), its lookup grid
//! built when the calibration is loaded, over the depth range and tolerance the calibration
//! carries ([`calibration::IdentifyParams`]), each dot by itself: two dots of one frame claiming
//! one ray are found by the host, over the whole frame (which may take several requests).

pub mod calibration;
pub mod delta;
pub mod fixed;
pub mod frame;
pub mod stream;

pub use fixed::{
    centroid_fraction_bits, Centroid, Dot, IdentifiedPoint, PointResult, PointStatus,
    DEPTH_UNITS_PER_MM,
};
pub use frame::{decode_request, decode_response, encode_frame, WireError};

use serde::{Deserialize, Serialize};

/// The protocol version reported in [`DeviceInfo`]; a change of the wire format increments it.
pub const PROTOCOL_VERSION: u16 = 6;
/// The most centroids in one `Compute` request.
pub const MAX_BATCH: usize = 512;
/// The bytes of a device's ray table ([`crate::ray_table::RayTable`]).
pub const RAY_POOL: usize = 1320 * crate::ray_table::CENTRAL_RECORD;
/// The most projector rays a device's calibration holds (its [`DeviceInfo::ray_capacity`]),
/// known to the host before anything is sent: central rays; a non-central calibration holds
/// [`MAX_NONCENTRAL_RAYS`].
pub const MAX_RAYS: usize = RAY_POOL / crate::ray_table::CENTRAL_RECORD;
/// The most rays of a non-central calibration (each with its offset).
pub const MAX_NONCENTRAL_RAYS: usize = RAY_POOL / crate::ray_table::NONCENTRAL_RECORD;
/// The most bytes in one upload chunk.
pub const CHUNK_SIZE: usize = 1024;
/// The longest encoded frame either end sends or accepts, delimiter included: a full
/// `Identified` response (at most 6 bytes per point: a 3-byte id difference and the 3-byte
/// result) plus headers, CRC and COBS overhead.
pub const MAX_FRAME: usize = 6 * MAX_BATCH + 128;
/// The longest request frame, delimiter included: a full `Compute` (at most 7 bytes per
/// centroid: a 3-byte id difference and the 4-byte dot) plus headers, CRC and COBS overhead;
/// what the device's receive buffer holds.
pub const MAX_REQUEST: usize = 7 * MAX_BATCH + 64;

/// A request from the host.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Request {
    /// Sequence number (≥ 1), echoed by the response.
    pub seq: u32,
    /// What is asked.
    pub body: RequestBody,
}

/// What a request asks for (see the table in the module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
// No allocator on the device: the batch lives inline, so the variants differ in size.
#[allow(clippy::large_enum_variant)]
pub enum RequestBody {
    /// Versions, capacities and the active calibration.
    Info,
    /// Start a calibration upload of `len` bytes whose CRC-32 is `crc`.
    UploadBegin {
        /// Total length of the calibration blob (bytes).
        len: u32,
        /// CRC-32 (ISO-HDLC) of the whole blob.
        crc: u32,
    },
    /// The blob's bytes from `offset` on; chunks arrive in order.
    UploadChunk {
        /// Where `data` starts in the blob.
        offset: u32,
        /// Up to [`CHUNK_SIZE`] bytes.
        data: heapless::Vec<u8, CHUNK_SIZE>,
    },
    /// Check the blob, store it power-fail safe and make it the active calibration.
    UploadCommit,
    /// One camera frame's centroids.
    Compute {
        /// Up to [`MAX_BATCH`] centroids; their ids delta-coded on the wire (see [`delta`]).
        #[serde(with = "delta")]
        centroids: heapless::Vec<Centroid, MAX_BATCH>,
    },
    /// Counters and the timing of the last compute.
    Stats,
    /// Restart the device (the stored calibration is loaded again at boot).
    Reset,
    /// Dots of a camera frame without ray ids: the device identifies each (epipolar segments,
    /// see [`crate::identify`]) and computes the points (conflicts between dots are the
    /// host's to find).
    Identify {
        /// Up to [`MAX_BATCH`] dots.
        dots: heapless::Vec<Dot, MAX_BATCH>,
    },
}

/// The number of [`RequestBody`] variants: a tag at or above it is an unknown message.
pub const REQUEST_KINDS: u32 = 8;

/// A response from the device.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Response {
    /// The request's sequence number (0 when the request could not be read).
    pub seq: u32,
    /// The answer.
    pub body: ResponseBody,
}

/// What the device answers (see the table in the module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
// No allocator on the device: the batch lives inline, so the variants differ in size.
#[allow(clippy::large_enum_variant)]
pub enum ResponseBody {
    /// Answer to `Info`.
    Info(DeviceInfo),
    /// The upload may proceed; `len` bytes are expected.
    UploadReady {
        /// The announced length.
        len: u32,
    },
    /// A chunk was taken; the next one starts at `next_offset`.
    ChunkAccepted {
        /// Bytes received so far.
        next_offset: u32,
    },
    /// The calibration is stored and active.
    Committed {
        /// Its fingerprint.
        fingerprint: u64,
        /// Its generation in the store (increments with every commit).
        generation: u32,
    },
    /// The points of one `Compute` request, in the order of its centroids.
    Points {
        /// The fingerprint of the calibration that computed them.
        fingerprint: u64,
        /// One result per centroid.
        points: heapless::Vec<PointResult, MAX_BATCH>,
    },
    /// Answer to `Stats`.
    Stats(DeviceStats),
    /// The device restarts after sending this.
    Resetting,
    /// The request failed.
    Error(ErrorCode),
    /// The identified points of one `Identify` request, in the order of its dots.
    Identified {
        /// The fingerprint of the calibration that identified and computed them.
        fingerprint: u64,
        /// One result per dot; the ids delta-coded on the wire (see [`delta`]).
        #[serde(with = "delta")]
        points: heapless::Vec<IdentifiedPoint, MAX_BATCH>,
    },
}

/// The device's description of itself.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DeviceInfo {
    /// Firmware version (major, minor, patch).
    pub firmware: [u8; 3],
    /// [`PROTOCOL_VERSION`] of the firmware.
    pub protocol: u16,
    /// The most projector rays a calibration may hold.
    pub ray_capacity: u16,
    /// The most centroids per `Compute`.
    pub max_batch: u16,
    /// The longest frame accepted (bytes, delimiter included).
    pub max_frame: u32,
    /// The longest calibration blob accepted (bytes).
    pub max_calibration: u32,
    /// The active calibration, if any.
    pub calibration: Option<CalibrationSummary>,
    /// Why the stored calibration could not be loaded at boot (it is then not active), if it
    /// could not.
    pub boot_error: Option<ErrorCode>,
    /// The clock the board runs on, where the board knows it.
    pub clock: Option<BoardClock>,
}

/// A board's core clock, as `Info` reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct BoardClock {
    /// The core clock (Hz).
    pub hz: u32,
    /// Where it comes from.
    pub source: ClockSource,
}

/// Where a board's core clock comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ClockSource {
    /// The external clock (a crystal, or the ST-LINK's 8 MHz MCO) through the PLL.
    External,
    /// The internal RC oscillator through the PLL: the external clock did not start.
    InternalPll,
    /// The internal RC oscillator alone: neither the external clock nor the PLL started.
    Internal,
    /// The board's one fixed clock (an emulated board).
    Fixed,
}

impl core::fmt::Display for ClockSource {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            ClockSource::External => "the external clock through the PLL",
            ClockSource::InternalPll => {
                "the internal oscillator through the PLL (the external clock did not start)"
            }
            ClockSource::Internal => {
                "the internal oscillator alone (neither the external clock nor the PLL started)"
            }
            ClockSource::Fixed => "the board's fixed clock",
        })
    }
}

/// What identifies the active calibration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CalibrationSummary {
    /// The host's fingerprint of the calibration.
    pub fingerprint: u64,
    /// Its generation in the store.
    pub generation: u32,
    /// Number of projector rays.
    pub rays: u16,
    /// Fraction bits of the centroid fixed point for this sensor ([`centroid_fraction_bits`]).
    pub centroid_bits: u8,
    /// The camera centre X0 (world, mm).
    pub camera_centre: [f64; 3],
    /// How the device intersects the rays: the host places the points of its depths
    /// ([`PointResult`]) by the same method.
    pub method: calibration::IntersectionMethod,
}

/// Counters and timing, for diagnosis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct DeviceStats {
    /// Good requests handled since boot.
    pub requests: u32,
    /// Frames answered with a framing error since boot.
    pub bad_frames: u32,
    /// Points computed since boot.
    pub points: u32,
    /// Clock ticks spent in the last `Compute` (the board's tick: SysTick at 25 MHz on mps2-an386).
    pub last_compute_ticks: u32,
    /// Centroids in the last `Compute`.
    pub last_compute_points: u16,
    /// The most stack used since boot (bytes; 0 when the board does not measure it).
    pub stack_peak: u32,
}

/// Why a request failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum ErrorCode {
    /// The frame could not be read (see [`WireError`]); it was dropped.
    Frame(WireError),
    /// `Compute` before any calibration was stored.
    NoCalibration,
    /// A chunk or commit without an upload in progress.
    NoUpload,
    /// An upload longer than the device's capacity.
    TooLarge,
    /// A chunk that does not start where the previous one ended, or runs past the length.
    ChunkOutOfOrder,
    /// Commit before all announced bytes arrived.
    UploadIncomplete,
    /// The blob's CRC differs from the one announced: upload again.
    UploadCrc,
    /// The blob is not a valid calibration (format, rays unsorted or not unit, too many rays).
    InvalidCalibration,
    /// The calibration store failed to write or verify; the previous calibration stays active.
    Storage,
    /// `Identify` with a calibration that carries no identification parameters.
    NoIdentification,
    /// The calibration's identification parameters need more lookup grid entries than the
    /// device holds even with its cells as large as the image (more rays than entries).
    IdentifierCapacity,
}

impl core::fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            ErrorCode::Frame(e) => return write!(f, "bad frame: {e}"),
            ErrorCode::NoCalibration => "the device holds no calibration",
            ErrorCode::NoUpload => "no upload in progress",
            ErrorCode::TooLarge => "the upload exceeds the device's capacity",
            ErrorCode::ChunkOutOfOrder => "the chunk does not continue the upload",
            ErrorCode::UploadIncomplete => "commit before all bytes arrived",
            ErrorCode::UploadCrc => "the uploaded bytes do not match the announced CRC",
            ErrorCode::InvalidCalibration => "the uploaded blob is not a valid calibration",
            ErrorCode::Storage => "the calibration store failed; the previous one stays active",
            ErrorCode::NoIdentification => {
                "the calibration carries no depth range for identifying dots"
            }
            ErrorCode::IdentifierCapacity => {
                "the calibration has more rays than the device's identifier holds entries"
            }
        })
    }
}
