//! The upload form of a calibrated rig (see `deltaz_shared::protocol::calibration`).

use deltaz_shared::projector::ProjectorRay;
use deltaz_shared::protocol::calibration::{
    encode_calibration, CalibrationHeader, IdentifyParams, CALIBRATION_FORMAT,
};
use deltaz_shared::ray_table::{PackError, RayModel};
use deltaz_shared::rig::{Method, Rig};

/// The calibration blob of `rig` for the device: the rig cast to f32 ([`Rig::cast`]: the
/// projector centre X_p − X0 computed in f64 first), the camera centre kept in f64, the rays
/// sorted by id (as the rig holds them), packed from their f64 directions and offsets
/// ([`RayModel`]). Fails with why when there are more than 65535 rays or the rays cannot be
/// packed. No identification of unlabelled dots (see [`calibration_blob_identifying`]).
pub fn calibration_blob<S: AsRef<[ProjectorRay<f64>]>>(
    rig: &Rig<f64, S>,
    fingerprint: u64,
    method: Method,
) -> Result<Vec<u8>, &'static str> {
    calibration_blob_identifying(rig, fingerprint, method, None)
}

/// [`calibration_blob`] with the parameters the device identifies unlabelled dots with.
pub fn calibration_blob_identifying<S: AsRef<[ProjectorRay<f64>]>>(
    rig: &Rig<f64, S>,
    fingerprint: u64,
    method: Method,
    identification: Option<IdentifyParams>,
) -> Result<Vec<u8>, &'static str> {
    let device: Rig<f32, Vec<ProjectorRay<f32>>> =
        rig.cast().map_err(|_| "the rig does not cast to f32")?;
    let projector = device.projector_centred();
    let rays = rig.projector_centred().rays();
    let model = RayModel::fit(rays).map_err(pack_error)?;
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
        model,
        rays: u16::try_from(rays.len()).map_err(|_| "more than 65535 rays")?,
    };
    let records = rays
        .iter()
        .map(|r| model.pack(r))
        .collect::<Result<Vec<_>, _>>()
        .map_err(pack_error)?;
    let mut buf = vec![0u8; 256 + model.record() * rays.len()];
    let len = encode_calibration(&header, records, &mut buf)
        .map_err(|_| "the calibration does not encode")?;
    buf.truncate(len);
    Ok(buf)
}

fn pack_error(e: PackError) -> &'static str {
    match e {
        PackError::NoDominantAxis => {
            "the projector's rays spread over more than a half-space (no axis they all point along)"
        }
        PackError::OffsetRange(_) => "a ray's offset from the projector centre exceeds 2048 mm",
    }
}
