//! The upload form of a calibrated rig (see `deltaz_shared::protocol::calibration`).

use deltaz_shared::projector::ProjectorRay;
use deltaz_shared::protocol::calibration::{
    encode_calibration, CalibrationHeader, IdentifyParams, WireRay, CALIBRATION_FORMAT,
};
use deltaz_shared::rig::{Method, Rig};
use nalgebra::Vector3;

/// The calibration blob of `rig` for the device: the rig cast to f32 ([`Rig::cast`]: the
/// projector centre X_p − X0 computed in f64 first), the camera centre kept in f64, the rays
/// sorted by id (as the rig holds them) with offsets only for a non-central model. `None` when
/// there are more than 65535 rays. No identification of unlabelled dots (see
/// [`calibration_blob_identifying`]).
pub fn calibration_blob<S: AsRef<[ProjectorRay<f64>]>>(
    rig: &Rig<f64, S>,
    fingerprint: u64,
    method: Method,
) -> Option<Vec<u8>> {
    calibration_blob_identifying(rig, fingerprint, method, None)
}

/// [`calibration_blob`] with the parameters the device identifies unlabelled dots with.
pub fn calibration_blob_identifying<S: AsRef<[ProjectorRay<f64>]>>(
    rig: &Rig<f64, S>,
    fingerprint: u64,
    method: Method,
    identification: Option<IdentifyParams>,
) -> Option<Vec<u8>> {
    let device: Rig<f32, Vec<ProjectorRay<f32>>> = rig.cast().ok()?;
    let projector = device.projector_centred();
    let rays = projector.rays();
    let r = device.r_cam_world();
    let header = CalibrationHeader {
        format: CALIBRATION_FORMAT,
        fingerprint,
        method: method.into(),
        grid: *device.grid(),
        inner: *device.inner(),
        r_cam_world: std::array::from_fn(|i| r[(i / 3, i % 3)]),
        camera_centre: rig.camera_centre().into(),
        projector_centre: projector.centre().into(),
        identification,
        rays: u16::try_from(rays.len()).ok()?,
    };
    let wire = rays.iter().map(|r| WireRay {
        id: r.id,
        direction: r.direction.into(),
        offset: (r.offset != Vector3::zeros()).then(|| r.offset.into()),
    });
    let mut buf = vec![0u8; 256 + 32 * rays.len()];
    let len = encode_calibration(&header, wire, &mut buf).ok()?;
    buf.truncate(len);
    Some(buf)
}
