//! The calibration blob the host uploads: `postcard(CalibrationHeader) ‖ record × rays`, each
//! ray a packed record of the device's ray table ([`crate::ray_table`]: 8 bytes a central ray).
//!
//! Everything is already centred on the camera (see [`crate::rig`]): the projector centre is
//! X_p − X0, computed in f64 on the host, so the device's f32 arithmetic works on small
//! differences. R is sent as a matrix (no trigonometry on the device) and the rays are sorted by
//! id, packed by the host from its f64 rays ([`RayModel::pack`]): the device copies them into
//! its ray table as they are.

use super::frame::WireError;
use crate::camera::{InnerOrientation, PixelGrid};
use crate::ray_table::{RayModel, NONCENTRAL_RECORD};
use crate::rig::Method;
use serde::{Deserialize, Serialize};

/// The blob format written in [`CalibrationHeader::format`].
pub const CALIBRATION_FORMAT: u16 = 3;

/// How the device identifies unlabelled dots (see [`crate::identify`]): it builds the epipolar
/// segments and their lookup grid from these when it loads the calibration. The depth range is
/// part of the calibration, not of each request, because the lookup grid depends on it and
/// building it takes far longer than a frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct IdentifyParams {
    /// Nearest surface distance from the camera centre along its axis (mm).
    pub near: f32,
    /// Farthest surface distance (mm).
    pub far: f32,
    /// Largest distance of a dot from its ray's epipolar segment (pixels).
    pub tolerance: f32,
    /// Side of the lookup grid's square cells (pixels).
    pub cell: f32,
}

/// How the device intersects the rays (see [`Method`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum IntersectionMethod {
    /// Eqs (8)-(9).
    Paper,
    /// Least-squares closest approach.
    ClosestApproach,
}

impl From<IntersectionMethod> for Method {
    fn from(m: IntersectionMethod) -> Self {
        match m {
            IntersectionMethod::Paper => Method::Paper,
            IntersectionMethod::ClosestApproach => Method::ClosestApproach,
        }
    }
}

impl From<Method> for IntersectionMethod {
    fn from(m: Method) -> Self {
        match m {
            Method::Paper => IntersectionMethod::Paper,
            Method::ClosestApproach => IntersectionMethod::ClosestApproach,
        }
    }
}

/// Everything but the rays.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationHeader {
    /// [`CALIBRATION_FORMAT`].
    pub format: u16,
    /// The host's fingerprint of the calibration (from its system file).
    pub fingerprint: u64,
    /// The intersection the device computes.
    pub method: IntersectionMethod,
    /// The camera's raster.
    pub grid: PixelGrid<f32>,
    /// The camera's inner orientation.
    pub inner: InnerOrientation<f32>,
    /// R of eq. (2), world → camera, row-major.
    pub r_cam_world: [f32; 9],
    /// The camera centre X0 (world, mm), kept in f64 for the host to add back.
    pub camera_centre: [f64; 3],
    /// The projector centre relative to the camera centre, X_p − X0 (mm).
    pub projector_centre: [f32; 3],
    /// Identification of unlabelled dots, if the device should do it.
    pub identification: Option<IdentifyParams>,
    /// How the rays are packed.
    pub model: RayModel,
    /// The number of rays that follow.
    pub rays: u16,
}

/// Write the blob into `buf`; returns its length. `rays` must yield `header.rays` records
/// ([`RayModel::pack`]; the first `header.model.record()` bytes of each are written).
pub fn encode_calibration(
    header: &CalibrationHeader,
    rays: impl IntoIterator<Item = [u8; NONCENTRAL_RECORD]>,
    buf: &mut [u8],
) -> Result<usize, WireError> {
    let mut len = postcard::to_slice(header, buf)
        .map_err(|_| WireError::BufferFull)?
        .len();
    let size = header.model.record();
    let mut count = 0usize;
    for ray in rays {
        let out = buf.get_mut(len..len + size).ok_or(WireError::BufferFull)?;
        out.copy_from_slice(ray.get(..size).ok_or(WireError::Malformed)?);
        len += size;
        count += 1;
    }
    if count != usize::from(header.rays) {
        return Err(WireError::Malformed);
    }
    Ok(len)
}

/// Bytes read at once for the header (longer than its longest encoding, 165 bytes).
const HEADER_WINDOW: usize = 192;

/// Read a blob: returns the header after handing it and every ray's record, in order, to
/// `take_ray` (which may refuse one, for example when its table is full). Fails on another format, a
/// short or long blob, or a refused ray.
pub fn decode_calibration(
    blob: &[u8],
    take_ray: impl FnMut(&CalibrationHeader, &[u8]) -> bool,
) -> Result<CalibrationHeader, WireError> {
    decode_calibration_from(
        blob.len(),
        |offset, out: &mut [u8]| {
            out.copy_from_slice(blob.get(offset..offset + out.len()).ok_or(())?);
            Ok::<(), ()>(())
        },
        take_ray,
    )
}

/// [`decode_calibration`] of a blob of `len` bytes that `read(offset, out)` fetches piecewise
/// (a blob in flash: no copy of it in RAM, only a window of `HEADER_WINDOW` bytes).
pub fn decode_calibration_from<E>(
    len: usize,
    mut read: impl FnMut(usize, &mut [u8]) -> Result<(), E>,
    mut take_ray: impl FnMut(&CalibrationHeader, &[u8]) -> bool,
) -> Result<CalibrationHeader, WireError> {
    let mut window = [0u8; HEADER_WINDOW];
    let mut at = 0;
    let header: CalibrationHeader = next_item(len, &mut at, &mut read, &mut window)?;
    if header.format != CALIBRATION_FORMAT {
        return Err(WireError::UnknownMessage);
    }
    let size = header.model.record();
    for _ in 0..header.rays {
        if at + size > len {
            return Err(WireError::Malformed);
        }
        let record = window.get_mut(..size).unwrap_or_default();
        read(at, record).map_err(|_| WireError::Malformed)?;
        at += size;
        if !take_ray(&header, record) {
            return Err(WireError::Malformed);
        }
    }
    if at == len {
        Ok(header)
    } else {
        Err(WireError::Malformed)
    }
}

/// The item at `*at` of a blob of `len` bytes, read into `window`; `*at` moves past it.
fn next_item<T: for<'de> Deserialize<'de>, E>(
    len: usize,
    at: &mut usize,
    read: &mut impl FnMut(usize, &mut [u8]) -> Result<(), E>,
    window: &mut [u8],
) -> Result<T, WireError> {
    let n = len.saturating_sub(*at).min(window.len());
    let window = window.get_mut(..n).unwrap_or_default();
    read(*at, window).map_err(|_| WireError::Malformed)?;
    let (item, rest) = postcard::take_from_bytes::<T>(window).map_err(|_| WireError::Malformed)?;
    *at += window.len() - rest.len();
    Ok(item)
}
