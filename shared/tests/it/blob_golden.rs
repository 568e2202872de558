//! Golden bytes of the stored calibration blob (`CALIBRATION_FORMAT` 2): what the host uploads
//! and the device keeps in flash. Reordering or retyping a field of `CalibrationHeader` or
//! `WireRay` changes these bytes, so the stored format cannot change without a new format number.

use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::protocol::calibration::{
    decode_calibration, encode_calibration, CalibrationHeader, IdentifyParams, IntersectionMethod,
    WireRay, CALIBRATION_FORMAT,
};

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
        rays: 2,
    }
}

fn rays() -> [WireRay; 2] {
    [
        WireRay {
            id: 7,
            direction: [0.0, 0.0, 1.0],
            offset: None,
        },
        WireRay {
            id: 300,
            direction: [0.6, 0.0, 0.8],
            offset: Some([1.0, -1.0, 0.0]),
        },
    ]
}

/// The blob: format (varint), fingerprint (varint), method (tag), the grid, the inner
/// orientation, R, the camera centre (f64), the projector centre, the identification (option
/// tag + 4 f32), the ray count, then each ray (id varint, 3 f32, option tag [+ 3 f32]).
const GOLDEN: &str = "\
    02 ef 9b af cd f8 ac d1 91 01 01 0a d7 23 3c 80 06 80 04 00 c0 bf 43 00 80 7f 43 00 00 3c 42 \
    00 00 00 00 00 00 00 00 17 b7 d1 b7 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 80 \
    3f 00 00 00 00 00 00 00 00 00 00 00 00 00 00 80 3f 00 00 00 00 00 00 00 00 00 00 00 00 00 00 \
    80 3f 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 90 9a 40 00 00 16 c3 00 \
    00 00 3f 00 00 00 40 01 00 00 c8 44 00 80 e8 44 00 00 80 3f 00 00 80 41 02 07 00 00 00 00 00 \
    00 00 00 00 00 80 3f 00 ac 02 9a 99 19 3f 00 00 00 00 cd cc 4c 3f 01 00 00 80 3f 00 00 80 bf \
    00 00 00 00";

fn bytes(hex: &str) -> Vec<u8> {
    hex.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

#[test]
fn stored_calibration_blob_is_golden() {
    let mut buf = [0u8; 512];
    let len = encode_calibration(&header(), rays(), &mut buf).unwrap();
    let hex: Vec<String> = buf[..len].iter().map(|b| format!("{b:02x}")).collect();
    assert_eq!(buf[..len], bytes(GOLDEN)[..], "{}", hex.join(" "));
    // And the golden bytes read back as the same calibration, rays in order.
    let mut read = Vec::new();
    let decoded = decode_calibration(&bytes(GOLDEN), |ray| {
        read.push(ray);
        true
    })
    .unwrap();
    assert_eq!(decoded, header());
    assert_eq!(read, rays());
}

#[test]
fn another_format_number_is_refused() {
    let mut golden = bytes(GOLDEN);
    golden[0] = CALIBRATION_FORMAT as u8 + 1;
    assert!(decode_calibration(&golden, |_| true).is_err());
}
