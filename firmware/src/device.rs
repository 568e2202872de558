//! The device: requests in, responses out. It holds the active calibration as an f32 rig centred
//! on the camera (one ray table), the dot identifier built from it, an upload in progress (its
//! bytes go straight into the store's spare flash slot as they arrive), and the calibration
//! store.

use crate::logging::event;
use crate::store::{Pending, Store, StoreError};
use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::identify::{Assignment, DepthRange, Identifier, IdentifyError};
use deltaz_shared::projector::{Projector, RayCursor};
use deltaz_shared::protocol::calibration::{
    decode_calibration_from, CalibrationHeader, IdentifyParams,
};
use deltaz_shared::protocol::stream::{tag, Batch, FrameWriter, RequestView};
use deltaz_shared::protocol::{
    centroid_fraction_bits, BoardClock, CalibrationSummary, Centroid, DeviceInfo, DeviceStats, Dot,
    ErrorCode, PointResult, PointStatus, WireError, MAX_BATCH, MAX_FRAME, PROTOCOL_VERSION,
};
use deltaz_shared::ray_table::RayTable;
use deltaz_shared::rig::{Method, Rig};
use embedded_storage::nor_flash::NorFlash;
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;

/// The firmware version reported by `Info` (the crate version).
pub const FIRMWARE_VERSION: [u8; 3] = [0, 1, 0];
/// The most projector rays a calibration may hold (central; see [`Rays::capacity`] for a
/// non-central one).
pub const MAX_RAYS: usize = deltaz_shared::protocol::MAX_RAYS;
/// The longest calibration blob (bytes): [`MAX_RAYS`] rays of 8 bytes (or the non-central
/// ones of 17) plus the header. A board's store slots hold at least this much (the blob is
/// never in RAM).
pub const MAX_CALIBRATION: usize = 16 * 1024;

/// A calibration's projector rays, packed ([`deltaz_shared::ray_table`]), where the device
/// keeps them: 8 bytes a central ray.
pub type Rays = RayTable<{ deltaz_shared::protocol::RAY_POOL }>;

/// The device's rig: f32, centred on the camera (its camera centre is zero), over the ray table
/// the device holds in place.
pub type DeviceRig<'a> = Rig<f32, &'a Rays>;

/// Cells of the device's identifier grid.
pub const IDENTIFIER_CELLS: usize = 1536;
/// Cell entries of the device's identifier grid.
pub const IDENTIFIER_ENTRIES: usize = 5120;

/// The device's dot identifier: f32, [`MAX_RAYS`] rays, [`IDENTIFIER_CELLS`] cells (768 × 512
/// pixels in cells of 16; larger cells where needed), [`IDENTIFIER_ENTRIES`] cell entries.
pub type DeviceIdentifier = Identifier<f32, MAX_RAYS, IDENTIFIER_CELLS, IDENTIFIER_ENTRIES>;

/// The board's instruments: a tick counter timing the compute (SysTick on a board) and, where
/// the board measures it, the stack's high-water mark.
pub trait Probe {
    /// The counter now.
    fn now(&mut self) -> u32;
    /// Ticks since `start` (a reading of [`Probe::now`]); a full 32-bit up-counter by default.
    fn since(&mut self, start: u32) -> u32 {
        self.now().wrapping_sub(start)
    }
    /// The most stack used since boot (bytes); 0 when the board does not measure it.
    fn stack_peak(&mut self) -> u32 {
        0
    }
    /// The clock the board runs on, where it knows it.
    fn clock(&self) -> Option<BoardClock> {
        None
    }
}

/// No instruments: every compute takes 0 ticks.
pub struct NoProbe;

impl Probe for NoProbe {
    fn now(&mut self) -> u32 {
        0
    }
}

/// The active calibration: its rays are the device's ray table.
struct Active {
    grid: PixelGrid<f32>,
    inner: InnerOrientation<f32>,
    r_cam_world: Matrix3<f32>,
    projector_centre: Vector3<f32>,
    method: Method,
    summary: CalibrationSummary,
    identification: Option<IdentifyParams>,
}

impl Active {
    /// The rig over this calibration's rays, checked when it was activated.
    fn rig<'a>(&self, rays: &'a Rays) -> DeviceRig<'a> {
        let projector = Projector::from_checked(self.projector_centre, rays);
        Rig::from_centred(
            self.grid,
            self.inner,
            self.r_cam_world,
            Vector3::zeros(),
            projector,
        )
    }

    /// The result for one dot of ray `id`, the ray found from `cursor` (see
    /// [`Rig::reconstruct_from`]); a dot off the sensor gets [`PointStatus::OffSensor`].
    #[inline]
    fn point(&self, rig: &DeviceRig, cursor: &mut RayCursor, id: u16, dot: Dot) -> PointResult {
        let bits = self.summary.centroid_bits;
        if !dot.on_sensor(self.grid.width, self.grid.height, bits) {
            return PointResult::Failed(PointStatus::OffSensor);
        }
        let (col, row) = dot.pixel::<f32>(bits);
        match rig.depth_from(cursor, id, col, row, self.method) {
            Ok(depth) => PointResult::from_depth(depth),
            Err(e) => PointResult::from_error(e),
        }
    }

    /// Build `identifier` in place for this calibration (emptied when it carries no
    /// identification).
    fn build_identifier(
        &self,
        rays: &Rays,
        identifier: &mut DeviceIdentifier,
    ) -> Result<(), ErrorCode> {
        let Some(p) = self.identification else {
            identifier.clear();
            return Ok(());
        };
        let depth = DepthRange {
            near: p.near,
            far: p.far,
        };
        identifier
            .rebuild(&self.rig(rays), depth, p.tolerance, p.cell)
            .map_err(|e| match e {
                IdentifyError::InvalidParameters | IdentifyError::Geometry(..) => {
                    ErrorCode::InvalidCalibration
                }
                _ => ErrorCode::IdentifierCapacity,
            })
    }
}

/// An upload in progress: its bytes so far are in the store's spare slot.
struct Upload {
    pending: Pending,
    crc: u32,
}

/// The device logic, generic over the calibration flash and the board's instruments.
pub struct Device<F, P> {
    store: Store<F>,
    probe: P,
    active: Option<Active>,
    /// The active calibration's rays, filled in place (the table is large; moving it costs
    /// stack).
    rays: Rays,
    identifier: DeviceIdentifier,
    upload: Option<Upload>,
    /// Why the stored calibration failed to load at the last boot (or reload), if it did.
    boot_error: Option<ErrorCode>,
    stats: DeviceStats,
    reset: bool,
}

impl<F: NorFlash, P: Probe> Device<F, P> {
    /// A device holding no calibration yet, written in place into `slot` (see
    /// [`crate::server::Server::boot_in`]): the device is large (the ray table, the identifier)
    /// and every move of it costs stack. [`Device::load`] it there.
    pub(crate) fn init_in(slot: &mut MaybeUninit<Self>, store: Store<F>, probe: P) -> &mut Self {
        let me = slot.as_mut_ptr();
        // SAFETY: every field of `*me` is written through a raw pointer to it (no reference to
        // uninitialised memory is made; the identifier through `empty_in` on its own
        // `MaybeUninit`, which has its layout) before `assume_init_mut`.
        unsafe {
            addr_of_mut!((*me).store).write(store);
            addr_of_mut!((*me).probe).write(probe);
            addr_of_mut!((*me).active).write(None);
            // An empty table, zeroed in place (zero bytes are a valid empty table: no rays,
            // a model of plain integers and flags).
            addr_of_mut!((*me).rays).write_bytes(0, 1);
            DeviceIdentifier::empty_in(&mut *addr_of_mut!((*me).identifier).cast());
            addr_of_mut!((*me).upload).write(None);
            addr_of_mut!((*me).boot_error).write(None);
            addr_of_mut!((*me).stats).write(DeviceStats {
                requests: 0,
                bad_frames: 0,
                points: 0,
                last_compute_ticks: 0,
                last_compute_points: 0,
                stack_peak: 0,
            });
            addr_of_mut!((*me).reset).write(false);
            slot.assume_init_mut()
        }
    }

    /// Boot: load the newest valid calibration from the store, if any, and build its
    /// identifier in place.
    pub(crate) fn load(&mut self) {
        self.active = None;
        let Some(stored) = self.store.newest() else {
            event!(info, "boot: no stored calibration");
            return;
        };
        // A stored calibration was checked at its commit, identifier included: a failure here
        // (a firmware with smaller capacities, say) is reported by Info.
        match self.activate(stored.slot, stored.len) {
            Ok(mut active) => {
                active.summary.generation = stored.generation;
                event!(
                    info,
                    "boot: calibration {:016x} generation {} loaded",
                    active.summary.fingerprint,
                    stored.generation
                );
                self.active = Some(active);
                self.boot_error = None;
            }
            Err(e) => {
                event!(warn, "boot: the stored calibration failed to load: {:?}", e);
                self.boot_error = Some(e);
            }
        }
    }

    /// Whether a `Reset` was answered: the board should restart now.
    pub fn reset_requested(&self) -> bool {
        self.reset
    }

    /// Give the store back (a simulated reboot builds a new device from it).
    pub fn into_store(self) -> Store<F> {
        self.store
    }

    /// Count a frame that could not be read.
    fn count_bad_frame(&mut self) {
        self.stats.bad_frames = self.stats.bad_frames.wrapping_add(1);
    }

    /// Answer request `seq` (read in place, see [`RequestView`]): its response frame is handed
    /// to `tx` block by block as it is written (no transmit buffer). Every failure is found
    /// before the first byte goes out, and answered with an error instead.
    pub fn handle(&mut self, seq: u32, request: RequestView<'_>, tx: &mut dyn FnMut(&[u8])) {
        if seq == 0 {
            // Seq 0 is the device's own for frames it could not read: a request must not use it.
            event!(debug, "bad frame: a request with seq 0");
            self.count_bad_frame();
            return error_frame(tx, 0, ErrorCode::Frame(WireError::Malformed));
        }
        self.stats.requests = self.stats.requests.wrapping_add(1);
        let written = match request {
            RequestView::Info => reply(tx, seq, tag::INFO, &self.info()),
            RequestView::UploadBegin { len, crc } => self
                .begin(len as usize, crc)
                .and_then(|len| reply(tx, seq, tag::UPLOAD_READY, &len)),
            RequestView::UploadChunk { offset, data } => self
                .chunk(offset as usize, data)
                .and_then(|next| reply(tx, seq, tag::CHUNK_ACCEPTED, &next)),
            RequestView::UploadCommit => self
                .commit()
                .and_then(|done| reply(tx, seq, tag::COMMITTED, &done)),
            RequestView::Compute(centroids) => self.compute(seq, &centroids, tx),
            RequestView::Identify(dots) => self.identify(seq, &dots, tx),
            RequestView::Stats => {
                self.stats.stack_peak = self.probe.stack_peak();
                reply(tx, seq, tag::STATS, &self.stats)
            }
            RequestView::Reset => {
                event!(info, "reset requested");
                self.reset = true;
                reply(tx, seq, tag::RESETTING, &())
            }
        };
        if let Err(code) = written {
            error_frame(tx, seq, code);
        }
    }

    /// The answer to a frame that could not be read (`seq` 0 unless its CRC held): counted.
    pub fn refuse(&mut self, seq: u32, error: WireError, tx: &mut dyn FnMut(&[u8])) {
        event!(debug, "bad frame (seq {}): {:?}", seq, error);
        self.count_bad_frame();
        error_frame(tx, seq, ErrorCode::Frame(error))
    }

    fn info(&self) -> DeviceInfo {
        DeviceInfo {
            firmware: FIRMWARE_VERSION,
            protocol: PROTOCOL_VERSION,
            ray_capacity: MAX_RAYS as u16,
            max_batch: MAX_BATCH as u16,
            max_frame: MAX_FRAME as u32,
            max_calibration: self.max_calibration() as u32,
            calibration: self.active.as_ref().map(|a| a.summary),
            boot_error: self.boot_error,
            clock: self.probe.clock(),
        }
    }

    /// The longest blob accepted: what a slot holds, at most [`MAX_CALIBRATION`].
    fn max_calibration(&self) -> usize {
        self.store.capacity().min(MAX_CALIBRATION)
    }

    /// Start an upload: the store erases its spare slot (the active calibration stays).
    fn begin(&mut self, len: usize, crc: u32) -> Result<u32, ErrorCode> {
        self.upload = None;
        if len > self.max_calibration() {
            return Err(ErrorCode::TooLarge);
        }
        let pending = self.store.begin(len).map_err(storage)?;
        event!(info, "upload: {} bytes", len);
        self.upload = Some(Upload { pending, crc });
        Ok(len as u32)
    }

    /// The next bytes of the upload, written to the flash as they come. The last chunk again
    /// (its answer was lost) is answered again without writing.
    fn chunk(&mut self, offset: usize, data: &[u8]) -> Result<u32, ErrorCode> {
        let upload = self.upload.as_mut().ok_or(ErrorCode::NoUpload)?;
        let received = upload.pending.received();
        let end = offset.saturating_add(data.len());
        let again = !data.is_empty()
            && end == received
            && self.store.matches(&upload.pending, offset, data);
        if !again {
            if offset != received || end > upload.pending.len() {
                return Err(ErrorCode::ChunkOutOfOrder);
            }
            self.store
                .append(&mut upload.pending, data)
                .map_err(storage)?;
        }
        Ok(end as u32)
    }

    /// Check the uploaded blob in the flash, switch to it (ray table and identifier rebuilt in
    /// place), then make it the stored newest: its fingerprint and generation. On any failure
    /// the stored newest, the previous calibration, is loaded again.
    fn commit(&mut self) -> Result<(u64, u32), ErrorCode> {
        let mut upload = self.upload.take().ok_or(ErrorCode::NoUpload)?;
        let pending = &mut upload.pending;
        if pending.received() < pending.len() {
            self.upload = Some(upload);
            return Err(ErrorCode::UploadIncomplete);
        }
        if self.store.pending_crc(pending).map_err(storage)? != upload.crc {
            return Err(ErrorCode::UploadCrc);
        }
        self.active = None;
        let committed = self
            .activate(pending.slot, pending.len())
            .and_then(|active| {
                let stored = self.store.seal(pending).map_err(storage)?;
                Ok((active, stored))
            });
        match committed {
            Ok((mut active, stored)) => {
                active.summary.generation = stored.generation;
                self.boot_error = None;
                let summary = active.summary;
                event!(
                    info,
                    "upload committed: calibration {:016x} generation {}",
                    summary.fingerprint,
                    summary.generation
                );
                self.active = Some(active);
                Ok((summary.fingerprint, summary.generation))
            }
            Err(e) => {
                event!(
                    warn,
                    "upload refused: {:?}; the stored calibration reloaded",
                    e
                );
                self.load();
                Err(e)
            }
        }
    }

    /// The points of a batch of centroids, written straight into the response in `tx`.
    fn compute(
        &mut self,
        seq: u32,
        centroids: &Batch<'_, Centroid>,
        tx: &mut dyn FnMut(&[u8]),
    ) -> Result<(), ErrorCode> {
        let active = self.active.as_ref().ok_or(ErrorCode::NoCalibration)?;
        let start = self.probe.now();
        let rig = active.rig(&self.rays);
        let mut out = FrameWriter::streamed(tx, seq, tag::POINTS);
        out.put(&active.summary.fingerprint)
            .and_then(|()| out.put(&(centroids.len() as u32)))
            .map_err(ErrorCode::Frame)?;
        // The host sends a batch sorted by id: each ray is found just after the last one.
        let mut cursor = RayCursor::default();
        for c in centroids.iter() {
            out.put_point(&active.point(&rig, &mut cursor, c.id, c.dot()))
                .map_err(ErrorCode::Frame)?;
        }
        self.count_compute(start, centroids.len());
        out.finish().map_err(ErrorCode::Frame)
    }

    /// Identify unlabelled dots, each by itself, and compute the identified ones into the
    /// response in `tx` as they go (no per-dot table: two dots of one frame claiming one ray are
    /// the host's to find, over the whole frame however many requests carry it).
    fn identify(
        &mut self,
        seq: u32,
        dots: &Batch<'_, Dot>,
        tx: &mut dyn FnMut(&[u8]),
    ) -> Result<(), ErrorCode> {
        let active = self.active.as_ref().ok_or(ErrorCode::NoCalibration)?;
        if active.identification.is_none() {
            return Err(ErrorCode::NoIdentification);
        }
        let bits = active.summary.centroid_bits;
        let start = self.probe.now();
        let rig = active.rig(&self.rays);
        let mut out = FrameWriter::streamed(tx, seq, tag::IDENTIFIED);
        out.put(&active.summary.fingerprint)
            .and_then(|()| out.put(&(dots.len() as u32)))
            .map_err(ErrorCode::Frame)?;
        let mut cursor = RayCursor::default();
        for dot in dots.iter() {
            let (col, row) = dot.pixel::<f32>(bits);
            let (id, result) = match self.identifier.identify(col, row) {
                Assignment::Ray { id, .. } => (id, active.point(&rig, &mut cursor, id, dot)),
                Assignment::Ambiguous { first, .. } => {
                    (first, PointResult::Failed(PointStatus::Ambiguous))
                }
                Assignment::Conflict { id } => (id, PointResult::Failed(PointStatus::Conflict)),
                Assignment::Unassigned => (0, PointResult::Failed(PointStatus::Unassigned)),
            };
            out.put_identified(id, &result).map_err(ErrorCode::Frame)?;
        }
        self.count_compute(start, dots.len());
        out.finish().map_err(ErrorCode::Frame)
    }

    /// Count a compute of `points` points that began at tick `start`.
    fn count_compute(&mut self, start: u32, points: usize) {
        self.stats.last_compute_ticks = self.probe.since(start);
        self.stats.last_compute_points = points as u16;
        self.stats.points = self.stats.points.wrapping_add(points as u32);
    }

    /// Load the calibration in store slot `slot` (`len` bytes) into the ray table, checked by
    /// [`Rig::validate`] (every number finite, f and the pixel size positive, a sensor of at
    /// least one pixel, 1 to [`Rays::capacity`] rays sorted by id), and build its identifier.
    /// Its generation is left 0.
    fn activate(&mut self, slot: usize, len: usize) -> Result<Active, ErrorCode> {
        let rays = &mut self.rays;
        let store = &mut self.store;
        let mut first = true;
        rays.clear(rays.model());
        let header = decode_calibration_from(
            len,
            |offset, out| store.read(slot, offset, out),
            |header, record| {
                if core::mem::take(&mut first) {
                    rays.clear(header.model);
                }
                rays.push(record)
            },
        )
        .map_err(|_| ErrorCode::InvalidCalibration)?;
        let active = checked(header, rays).ok_or(ErrorCode::InvalidCalibration)?;
        active.build_identifier(&self.rays, &mut self.identifier)?;
        Ok(active)
    }
}

/// Send the response `tag` with `payload` to `tx`.
fn reply<T: Serialize>(
    tx: &mut dyn FnMut(&[u8]),
    seq: u32,
    tag: u32,
    payload: &T,
) -> Result<(), ErrorCode> {
    let mut out = FrameWriter::streamed(tx, seq, tag);
    out.put(payload).map_err(ErrorCode::Frame)?;
    out.finish().map_err(ErrorCode::Frame)
}

/// Send the response `Error(code)` to `tx` (a sink takes every byte: it cannot fail).
fn error_frame(tx: &mut dyn FnMut(&[u8]), seq: u32, code: ErrorCode) {
    let _ = reply(tx, seq, tag::ERROR, &code);
}

/// A store failure as the host sees it.
fn storage(e: StoreError) -> ErrorCode {
    match e {
        StoreError::TooLarge => ErrorCode::TooLarge,
        _ => ErrorCode::Storage,
    }
}

/// The active calibration of a decoded header over its rays, if [`Rig::validate`] and the
/// identification parameters pass.
fn checked(header: CalibrationHeader, rays: &Rays) -> Option<Active> {
    let CalibrationHeader {
        fingerprint,
        method,
        grid,
        inner,
        r_cam_world,
        camera_centre,
        projector_centre,
        identification,
        model: header_model,
        rays: header_rays,
        ..
    } = header;
    let header_rays = usize::from(header_rays);
    let params = identification.map_or([0.0; 4], |p| [p.near, p.far, p.tolerance, p.cell]);
    let finite =
        params.into_iter().all(f32::is_finite) && camera_centre.iter().all(|c| c.is_finite());
    let projector_centre = Vector3::from(projector_centre);
    let r_cam_world = Matrix3::from_row_slice(&r_cam_world);
    // The rays were checked as they were taken (sorted by id; integers: finite), and a table
    // of another model than the header's holds none of them.
    let projector = Projector::from_checked(projector_centre, rays);
    let rig = Rig::from_centred(grid, inner, r_cam_world, Vector3::zeros(), projector);
    let count = deltaz_shared::projector::RayStore::count(&rays);
    if !finite || rig.validate().is_err() || rays.model() != header_model || count != header_rays {
        return None;
    }
    let summary = CalibrationSummary {
        fingerprint,
        generation: 0,
        rays: count as u16,
        centroid_bits: centroid_fraction_bits(grid.width, grid.height),
        camera_centre,
        method,
    };
    Some(Active {
        grid,
        inner,
        r_cam_world,
        projector_centre,
        method: method.into(),
        summary,
        identification,
    })
}
