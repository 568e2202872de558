//! Golden bytes of the stored calibration blob (`CALIBRATION_FORMAT` 3): what the host uploads
//! and the device keeps in flash. Reordering or retyping a field of `CalibrationHeader` or the
//! packing of a ray (`RayModel`) changes these bytes, so the stored format cannot change without
//! a new format number.

use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::projector::ProjectorRay;
use deltaz_shared::protocol::calibration::{
    decode_calibration, encode_calibration, CalibrationHeader, IdentifyParams, IntersectionMethod,
    CALIBRATION_FORMAT,
};
use deltaz_shared::ray_table::{RayModel, NONCENTRAL_RECORD};
use nalgebra::Vector3;

fn header() -> CalibrationHeader {
    CalibrationHeader {
        format: CALIBRATION_FORMAT,
        fingerprint: 0x0123_4567_89ab_cdef,
        method: IntersectionMethod::ClosestApproach,
        grid: PixelGrid {
            pixel_size: 0.01,
            width: 768,
            height: 512,
            origin_col: 383.5,
            origin_row: 255.5,
        },
        inner: InnerOrientation {
            k1: -2.5e-5,
            ..InnerOrientation::ideal(47.0)
        },
        r_cam_world: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        camera_centre: [0.0, 0.0, 1700.0],
        projector_centre: [-150.0, 0.5, 2.0],
        identification: Some(IdentifyParams {
            near: 1600.0,
            far: 1860.0,
            tolerance: 1.0,
            cell: 16.0,
        }),
        model: model(),
        rays: 2,
    }
}

/// Two rays along +z, one with an offset: a non-central model, slopes of 0.75 at most.
fn rays() -> [ProjectorRay<f64>; 2] {
    [
        ProjectorRay {
            id: 7,
            direction: Vector3::new(0.0, 0.0, 1.0),
            offset: Vector3::zeros(),
        },
        ProjectorRay {
            id: 300,
            direction: Vector3::new(0.6, 0.0, 0.8),
            offset: Vector3::new(1.0, -1.0, 0.0),
        },
    ]
}

fn model() -> RayModel {
    RayModel::fit(&rays()).unwrap()
}

fn records() -> Vec<[u8; NONCENTRAL_RECORD]> {
    rays().iter().map(|r| model().pack(r).unwrap()).collect()
}

/// The blob: format (varint), fingerprint (varint), method (tag), the grid, the inner
/// orientation, R, the camera centre (f64), the projector centre, the identification (option
/// tag + 4 f32), the ray model (axis 2 = z, positive, 24 fraction bits, the slopes' centres
/// 0.375 · 2²⁴ = 6,291,456 (zigzag varint 80 80 80 06) and 0, non-central), the ray count, then
/// each ray's 17-byte record (id u16, the two slopes' differences from their centres i24 in
/// 2⁻²⁴, the offset 3 × i24 in 2⁻¹² mm): ray 7's x slope 0 is −0x60_0000 (00 00 a0), ray 300's
/// 0.75 is +0x60_0000, its offset x 1 mm = 0x00_1000.
const GOLDEN: &str = "\
    03 ef 9b af cd f8 ac d1 91 01 01 0a d7 23 3c 80 06 80 04 00 c0 bf 43 00 80 7f 43 00 00 3c 42 \
    00 00 00 00 00 00 00 00 17 b7 d1 b7 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 80 \
    3f 00 00 00 00 00 00 00 00 00 00 00 00 00 00 80 3f 00 00 00 00 00 00 00 00 00 00 00 00 00 00 \
    80 3f 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 90 9a 40 00 00 16 c3 00 \
    00 00 3f 00 00 00 40 01 00 00 c8 44 00 80 e8 44 00 00 80 3f 00 00 80 41 02 00 18 80 80 80 06 \
    00 01 02 07 00 00 00 a0 00 00 00 00 00 00 00 00 00 00 00 00 2c 01 00 00 60 00 00 00 00 10 00 \
    00 f0 ff 00 00 00";

fn bytes(hex: &str) -> Vec<u8> {
    hex.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

#[test]
fn stored_calibration_blob_is_golden() {
    let mut buf = [0u8; 512];
    assert_eq!(
        model(),
        RayModel {
            axis: 2,
            negative: false,
            bits: 24,
            centre: [6_291_456, 0],
            noncentral: true
        }
    );
    let len = encode_calibration(&header(), records(), &mut buf).unwrap();
    let hex: Vec<String> = buf[..len].iter().map(|b| format!("{b:02x}")).collect();
    assert_eq!(buf[..len], bytes(GOLDEN)[..], "{}", hex.join(" "));
    // And the golden bytes read back as the same calibration, rays in order.
    let mut read = Vec::new();
    let decoded = decode_calibration(&bytes(GOLDEN), |_, ray| {
        read.push(ray.to_vec());
        true
    })
    .unwrap();
    assert_eq!(decoded, header());
    let want: Vec<Vec<u8>> = records().iter().map(|r| r.to_vec()).collect();
    assert_eq!(read, want);
}

#[test]
fn another_format_number_is_refused() {
    let mut golden = bytes(GOLDEN);
    golden[0] = CALIBRATION_FORMAT as u8 + 1;
    assert!(decode_calibration(&golden, |_, _| true).is_err());
}
