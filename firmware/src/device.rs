//! The device: requests in, responses out. It holds the active calibration as an f32 rig centred
//! on the camera, the dot identifier built from it, an upload in progress, and the calibration
//! store.

use crate::store::{Store, StoreError};
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::identify::{Assignment, DepthRange, Identifier, IdentifyError};
use deltaz_shared::projector::{Projector, ProjectorRay};
use deltaz_shared::protocol::calibration::{
    decode_calibration, CalibrationHeader, IdentifyParams, WireRay,
};
use deltaz_shared::protocol::frame::CRC;
use deltaz_shared::protocol::{
    centroid_fraction_bits, CalibrationSummary, Centroid, DeviceInfo, DeviceStats, Dot, ErrorCode,
    IdentifiedPoint, PointResult, PointStatus, Request, RequestBody, Response, ResponseBody,
    MAX_BATCH, MAX_FRAME, PROTOCOL_VERSION,
};
use deltaz_shared::rig::{Method, Rig};
use embedded_storage::nor_flash::NorFlash;
use nalgebra::{Matrix3, Vector3};

/// The firmware version reported by `Info` (the crate version).
pub const FIRMWARE_VERSION: [u8; 3] = [0, 1, 0];
/// The most projector rays a calibration may hold.
pub const MAX_RAYS: usize = 512;
/// The longest calibration blob (bytes): [`MAX_RAYS`] rays of at most 28 bytes plus the header.
pub const MAX_CALIBRATION: usize = 16 * 1024;

/// A calibration's projector rays, f32, where the device keeps them.
type RayTable = heapless::Vec<ProjectorRay<f32>, MAX_RAYS>;

/// The device's rig: f32, centred on the camera (its camera centre is zero), over a ray table
/// the device holds in place.
pub type DeviceRig<'a> = Rig<f32, &'a [ProjectorRay<f32>]>;

/// The device's dot identifier: f32, [`MAX_RAYS`] rays, 2048 cells (768 × 512 pixels in cells
/// of 16), 4096 cell entries; about 43 KB.
pub type DeviceIdentifier = Identifier<f32, MAX_RAYS, 2048, 4096>;

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
}

/// No instruments: every compute takes 0 ticks.
pub struct NoProbe;

impl Probe for NoProbe {
    fn now(&mut self) -> u32 {
        0
    }
}

/// The active calibration: its rays are the device's ray table number `table`.
struct Active {
    table: usize,
    grid: PixelGrid<f32>,
    inner: InnerOrientation<f32>,
    r_cam_world: Matrix3<f32>,
    projector_centre: Vector3<f32>,
    method: Method,
    summary: CalibrationSummary,
    identification: Option<IdentifyParams>,
}

impl Active {
    /// The rig over this calibration's rays (`tables`, the device's two ray tables). The rays
    /// were checked at activation, so this cannot fail; should it, the calibration is invalid.
    fn rig<'a>(&self, tables: &'a [RayTable; 2]) -> Result<DeviceRig<'a>, ErrorCode> {
        let projector = Projector::new(self.projector_centre, &tables[self.table][..])
            .map_err(|_| ErrorCode::InvalidCalibration)?;
        Ok(Rig::from_centred(
            self.grid,
            self.inner,
            self.r_cam_world,
            Vector3::zeros(),
            projector,
        ))
    }

    /// The result for one centroid of ray `id` at pixel (col, row).
    fn point(&self, rig: &DeviceRig, id: u16, col: f32, row: f32) -> PointResult {
        match rig.reconstruct(id, col, row, self.method) {
            Ok(hit) => PointResult::from_camera_centred(&hit.point, hit.miss),
            Err(e) => PointResult::from_error(e),
        }
    }

    /// Build `identifier` in place for this calibration (emptied when it carries no
    /// identification).
    fn build_identifier(
        &self,
        tables: &[RayTable; 2],
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
            .rebuild(&self.rig(tables)?, depth, p.tolerance, p.cell)
            .map_err(|e| match e {
                IdentifyError::InvalidParameters | IdentifyError::Geometry(..) => {
                    ErrorCode::InvalidCalibration
                }
                _ => ErrorCode::IdentifierCapacity,
            })
    }
}

/// An upload in progress.
struct Upload {
    len: usize,
    crc: u32,
    received: usize,
}

/// The device logic, generic over the calibration flash and the board's instruments.
pub struct Device<F, P> {
    store: Store<F>,
    probe: P,
    active: Option<Active>,
    /// Two ray tables: the active calibration's and the one an upload is checked in, each
    /// filled in place (the table is large; moving it costs stack).
    tables: [RayTable; 2],
    identifier: DeviceIdentifier,
    upload: Option<Upload>,
    staging: [u8; MAX_CALIBRATION],
    stats: DeviceStats,
    reset: bool,
}

impl<F: NorFlash, P: Probe> Device<F, P> {
    /// A device holding no calibration yet: [`Device::load`] it where it will live (see
    /// [`crate::server::Server::boot_in`]), since the device is large (the staging buffer, the ray
    /// tables, the identifier) and every move of it costs stack.
    #[inline(always)]
    pub(crate) fn new(store: Store<F>, probe: P) -> Self {
        Self {
            store,
            probe,
            active: None,
            tables: [RayTable::new(), RayTable::new()],
            identifier: DeviceIdentifier::empty(),
            upload: None,
            staging: [0; MAX_CALIBRATION],
            stats: DeviceStats {
                requests: 0,
                bad_frames: 0,
                points: 0,
                last_compute_ticks: 0,
                last_compute_points: 0,
                stack_peak: 0,
            },
            reset: false,
        }
    }

    /// Boot: load the newest valid calibration from the store, if any, and build its
    /// identifier in place.
    pub(crate) fn load(&mut self) {
        self.active = self.load_stored();
        let built = match &self.active {
            Some(active) => active.build_identifier(&self.tables, &mut self.identifier),
            None => Ok(()),
        };
        // A stored calibration was checked at its commit, identifier included.
        if built.is_err() {
            self.active = None;
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
    pub fn count_bad_frame(&mut self) {
        self.stats.bad_frames = self.stats.bad_frames.wrapping_add(1);
    }

    /// Answer one request.
    pub fn handle(&mut self, request: Request) -> Response {
        self.stats.requests = self.stats.requests.wrapping_add(1);
        let body = match request.body {
            RequestBody::Info => Ok(ResponseBody::Info(self.info())),
            RequestBody::UploadBegin { len, crc } => self.begin(len as usize, crc),
            RequestBody::UploadChunk { offset, data } => self.chunk(offset as usize, &data),
            RequestBody::UploadCommit => self.commit(),
            RequestBody::Compute { centroids } => self.compute(&centroids),
            RequestBody::Identify { dots } => self.identify(&dots),
            RequestBody::Stats => {
                self.stats.stack_peak = self.probe.stack_peak();
                Ok(ResponseBody::Stats(self.stats))
            }
            RequestBody::Reset => {
                self.reset = true;
                Ok(ResponseBody::Resetting)
            }
        };
        Response {
            seq: request.seq,
            body: body.unwrap_or_else(ResponseBody::Error),
        }
    }

    fn info(&self) -> DeviceInfo {
        DeviceInfo {
            firmware: FIRMWARE_VERSION,
            protocol: PROTOCOL_VERSION,
            ray_capacity: MAX_RAYS as u16,
            max_batch: MAX_BATCH as u16,
            max_frame: MAX_FRAME as u32,
            max_calibration: self.store.capacity().min(MAX_CALIBRATION) as u32,
            calibration: self.active.as_ref().map(|a| a.summary),
        }
    }

    fn begin(&mut self, len: usize, crc: u32) -> Result<ResponseBody, ErrorCode> {
        self.upload = None;
        if len > self.store.capacity().min(MAX_CALIBRATION) {
            return Err(ErrorCode::TooLarge);
        }
        self.upload = Some(Upload {
            len,
            crc,
            received: 0,
        });
        Ok(ResponseBody::UploadReady { len: len as u32 })
    }

    fn chunk(&mut self, offset: usize, data: &[u8]) -> Result<ResponseBody, ErrorCode> {
        let upload = self.upload.as_mut().ok_or(ErrorCode::NoUpload)?;
        // `received` ≤ `len` ≤ MAX_CALIBRATION, so `end` cannot overflow once offset matches.
        if offset != upload.received {
            return Err(ErrorCode::ChunkOutOfOrder);
        }
        let end = offset + data.len();
        if end > upload.len {
            return Err(ErrorCode::ChunkOutOfOrder);
        }
        self.staging
            .get_mut(offset..end)
            .ok_or(ErrorCode::ChunkOutOfOrder)?
            .copy_from_slice(data);
        upload.received = end;
        Ok(ResponseBody::ChunkAccepted {
            next_offset: end as u32,
        })
    }

    fn commit(&mut self) -> Result<ResponseBody, ErrorCode> {
        let upload = self.upload.take().ok_or(ErrorCode::NoUpload)?;
        if upload.received < upload.len {
            self.upload = Some(upload);
            return Err(ErrorCode::UploadIncomplete);
        }
        let blob = &self.staging[..upload.len];
        if CRC.checksum(blob) != upload.crc {
            return Err(ErrorCode::UploadCrc);
        }
        // Validate completely before touching the flash, the identifier included (built in
        // place; on failure rebuilt for the calibration that stays active).
        let spare = self.active.as_ref().map_or(0, |a| 1 - a.table);
        let mut active = activate(blob, 0, spare, &mut self.tables[spare])
            .ok_or(ErrorCode::InvalidCalibration)?;
        let stored = active
            .build_identifier(&self.tables, &mut self.identifier)
            .and_then(|()| {
                self.store.save(blob).map_err(|e| match e {
                    StoreError::TooLarge => ErrorCode::TooLarge,
                    _ => ErrorCode::Storage,
                })
            });
        let stored = match stored {
            Ok(stored) => stored,
            Err(e) => {
                if let Some(old) = &self.active {
                    // It was built once already with these parameters.
                    let _ = old.build_identifier(&self.tables, &mut self.identifier);
                }
                return Err(e);
            }
        };
        active.summary.generation = stored.generation;
        let summary = active.summary;
        self.active = Some(active);
        Ok(ResponseBody::Committed {
            fingerprint: summary.fingerprint,
            generation: summary.generation,
        })
    }

    fn compute(&mut self, centroids: &[Centroid]) -> Result<ResponseBody, ErrorCode> {
        let active = self.active.as_ref().ok_or(ErrorCode::NoCalibration)?;
        let bits = active.summary.centroid_bits;
        let start = self.probe.now();
        let rig = active.rig(&self.tables)?;
        let points = centroids
            .iter()
            .map(|c| {
                let (col, row) = c.pixel::<f32>(bits);
                active.point(&rig, c.id, col, row)
            })
            .collect();
        let fingerprint = active.summary.fingerprint;
        self.count_compute(start, centroids.len());
        Ok(ResponseBody::Points {
            fingerprint,
            points,
        })
    }

    /// Identify unlabelled dots (the whole batch is one camera frame, so two dots claiming one
    /// ray are both conflicts), then compute the identified ones.
    fn identify(&mut self, dots: &[Dot]) -> Result<ResponseBody, ErrorCode> {
        let active = self.active.as_ref().ok_or(ErrorCode::NoCalibration)?;
        if active.identification.is_none() {
            return Err(ErrorCode::NoIdentification);
        }
        let bits = active.summary.centroid_bits;
        let start = self.probe.now();
        let rig = active.rig(&self.tables)?;
        let mut pixels = [(0.0f32, 0.0f32); MAX_BATCH];
        for (pixel, dot) in pixels.iter_mut().zip(dots) {
            *pixel = dot.pixel(bits);
        }
        let pixels = &pixels[..dots.len()];
        let mut found = [Assignment::Unassigned; MAX_BATCH];
        let found = &mut found[..dots.len()];
        self.identifier.identify_frame(pixels, found);
        let failed = |id, status| IdentifiedPoint {
            id,
            result: PointResult::Failed(status),
        };
        let points = pixels
            .iter()
            .zip(found.iter())
            .map(|(&(col, row), assignment)| match *assignment {
                Assignment::Ray { id, .. } => IdentifiedPoint {
                    id,
                    result: active.point(&rig, id, col, row),
                },
                Assignment::Ambiguous { first, .. } => failed(first, PointStatus::Ambiguous),
                Assignment::Conflict { id } => failed(id, PointStatus::Conflict),
                Assignment::Unassigned => failed(0, PointStatus::Unassigned),
            })
            .collect();
        let fingerprint = active.summary.fingerprint;
        self.count_compute(start, dots.len());
        Ok(ResponseBody::Identified {
            fingerprint,
            points,
        })
    }

    /// Count a compute of `points` points that began at tick `start`.
    fn count_compute(&mut self, start: u32, points: usize) {
        self.stats.last_compute_ticks = self.probe.since(start);
        self.stats.last_compute_points = points as u16;
        self.stats.points = self.stats.points.wrapping_add(points as u32);
    }

    fn load_stored(&mut self) -> Option<Active> {
        let (stored, blob) = self.store.load(&mut self.staging)?;
        activate(blob, stored.generation, 0, &mut self.tables[0])
    }
}

/// The f32 calibration of a blob, its rays written into `rays` (the device's ray table number
/// `table`), checked: every number finite, f and the pixel size positive, rays sorted with unit
/// directions, at most [`MAX_RAYS`].
fn activate(blob: &[u8], generation: u32, table: usize, rays: &mut RayTable) -> Option<Active> {
    rays.clear();
    let header = decode_calibration(blob, |r: WireRay| {
        let ray = ProjectorRay {
            id: r.id,
            direction: Vector3::from(r.direction),
            offset: r.offset.map_or(Vector3::zeros(), Vector3::from),
        };
        rays.push(ray).is_ok()
    })
    .ok()?;
    let CalibrationHeader {
        fingerprint,
        method,
        grid,
        inner,
        r_cam_world,
        camera_centre,
        projector_centre,
        identification,
        ..
    } = header;
    let numbers = [grid.pixel_size, grid.origin_col, grid.origin_row]
        .into_iter()
        .chain([
            inner.f, inner.cx, inner.cy, inner.k1, inner.k2, inner.k3, inner.p1, inner.p2,
        ])
        .chain(r_cam_world)
        .chain(identification.map_or([0.0; 4], |p| [p.near, p.far, p.tolerance, p.cell]));
    let finite =
        numbers.into_iter().all(f32::is_finite) && camera_centre.iter().all(|c| c.is_finite());
    if !finite || grid.pixel_size <= 0.0 || inner.f <= 0.0 {
        return None;
    }
    let projector_centre = Vector3::from(projector_centre);
    Projector::new(projector_centre, &rays[..]).ok()?;
    let summary = CalibrationSummary {
        fingerprint,
        generation,
        rays: rays.len() as u16,
        centroid_bits: centroid_fraction_bits(grid.width, grid.height),
        camera_centre,
    };
    Some(Active {
        table,
        grid,
        inner,
        r_cam_world: Matrix3::from_row_slice(&r_cam_world),
        projector_centre,
        method: method.into(),
        summary,
        identification,
    })
}
