//! Bad input to the device's framing and requests: each gets its specified answer and the device
//! serves the next good frame; and a seeded fuzz of 10⁶ inputs that must never stop it.

use deltaz_firmware::smoke::{paper_rig, smoke_pixel, RAY};
use deltaz_host::link::{calibration_blob, InProcess, Transport};
use deltaz_shared::protocol::frame::CRC;
use deltaz_shared::protocol::{
    decode_response, encode_frame, Centroid, ErrorCode, PointResult, PointStatus, Request,
    RequestBody, Response, ResponseBody, WireError, CHUNK_SIZE, MAX_FRAME,
};
use deltaz_shared::rig::Method;
use deltaz_tests::Rng;
use serde::Serialize;
use std::time::Duration;

/// Send raw bytes (between delimiters) and return every response the device sent.
fn exchange(device: &mut InProcess, bytes: &[u8]) -> Vec<Response> {
    let mut wire = vec![0];
    wire.extend_from_slice(bytes);
    wire.push(0);
    device.send(&wire).unwrap();
    let mut out = vec![0u8; 1 << 16];
    let n = device.recv(&mut out, Duration::ZERO).unwrap();
    out[..n]
        .split(|&b| b == 0)
        .filter(|f| !f.is_empty())
        .map(|f| decode_response(&mut f.to_vec()).expect("the device sends good frames"))
        .collect()
}

/// One frame of any serialisable value (no delimiter).
fn frame_of<T: Serialize>(value: &T) -> Vec<u8> {
    let mut buf = vec![0u8; MAX_FRAME];
    let mut frame = encode_frame(value, &mut buf).unwrap().to_vec();
    frame.pop();
    frame
}

fn request(seq: u32, body: RequestBody) -> Vec<u8> {
    frame_of(&Request { seq, body })
}

fn answer(device: &mut InProcess, bytes: &[u8]) -> Response {
    let responses = exchange(device, bytes);
    assert_eq!(responses.len(), 1, "{responses:?}");
    responses.into_iter().next().unwrap()
}

fn error(seq: u32, code: ErrorCode) -> Response {
    Response {
        seq,
        body: ResponseBody::Error(code),
    }
}

fn frame_error(seq: u32, e: WireError) -> Response {
    error(seq, ErrorCode::Frame(e))
}

/// The device still answers a good request.
fn serves(device: &mut InProcess, seq: u32) {
    let r = answer(device, &request(seq, RequestBody::Info));
    assert!(
        matches!(r, Response { seq: s, body: ResponseBody::Info(_) } if s == seq),
        "{r:?}"
    );
}

fn compute(ids: &[u16]) -> RequestBody {
    let (col, row) = smoke_pixel().unwrap();
    let centroids = ids
        .iter()
        .map(|&id| Centroid::from_pixel(id, col, row, 6).unwrap())
        .collect::<Vec<_>>();
    RequestBody::Compute {
        centroids: heapless::Vec::from_slice(&centroids).unwrap(),
    }
}

fn upload(device: &mut InProcess, blob: &[u8], crc: u32, seq: u32) -> Response {
    let len = blob.len() as u32;
    answer(device, &request(seq, RequestBody::UploadBegin { len, crc }));
    for (i, chunk) in blob.chunks(CHUNK_SIZE).enumerate() {
        let data = heapless::Vec::from_slice(chunk).unwrap();
        let offset = (i * CHUNK_SIZE) as u32;
        answer(
            device,
            &request(seq, RequestBody::UploadChunk { offset, data }),
        );
    }
    answer(device, &request(seq, RequestBody::UploadCommit))
}

#[test]
fn every_bad_frame_gets_its_answer() {
    let mut device = InProcess::new();
    let info = request(1, RequestBody::Info);

    // Compute before any upload.
    assert_eq!(
        answer(&mut device, &request(2, compute(&[RAY]))),
        error(2, ErrorCode::NoCalibration)
    );
    serves(&mut device, 3);
    // Random bytes: a COBS code byte (0x37) that runs past the frame's end.
    assert_eq!(
        answer(&mut device, &[0x37, 0x91, 0xfe, 0x12, 0x44, 0x03]),
        frame_error(0, WireError::Cobs)
    );
    serves(&mut device, 4);
    // Truncated: the Info frame without its last byte (the COBS code 05 runs past the end).
    assert_eq!(
        answer(&mut device, &info[..info.len() - 1]),
        frame_error(0, WireError::Cobs)
    );
    // Too short for a CRC: a COBS frame of 3 bytes.
    assert_eq!(
        answer(&mut device, &[0x04, 1, 2, 3]),
        frame_error(0, WireError::TooShort)
    );
    serves(&mut device, 5);
    // Wrong CRC: one bit of the CRC flipped (COBS stays valid).
    let mut bad = info.clone();
    bad[4] ^= 0x01;
    assert_eq!(answer(&mut device, &bad), frame_error(0, WireError::BadCrc));
    serves(&mut device, 6);
    // Unknown message: seq 9, kind 99, CRC good.
    assert_eq!(
        answer(&mut device, &frame_of(&(9u32, 99u32))),
        frame_error(9, WireError::UnknownMessage)
    );
    // Malformed: a Compute announcing 5 centroids and holding none; a trailing byte after Info.
    assert_eq!(
        answer(&mut device, &frame_of(&(10u32, 4u32, 5u8))),
        frame_error(10, WireError::Malformed)
    );
    assert_eq!(
        answer(&mut device, &frame_of(&(11u32, 0u32, 7u8))),
        frame_error(11, WireError::Malformed)
    );
    serves(&mut device, 12);
    // Oversized: more bytes than MAX_FRAME before a delimiter.
    assert_eq!(
        answer(&mut device, &vec![0x55; MAX_FRAME + 10]),
        frame_error(0, WireError::Oversized)
    );
    serves(&mut device, 13);

    // Bad upload parameters and states.
    let blob = calibration_blob(&paper_rig(), 77, Method::ClosestApproach).unwrap();
    let crc = CRC.checksum(&blob);
    let chunk = |offset| RequestBody::UploadChunk {
        offset,
        data: heapless::Vec::from_slice(&blob[..8]).unwrap(),
    };
    assert_eq!(
        answer(&mut device, &request(20, chunk(0))),
        error(20, ErrorCode::NoUpload)
    );
    assert_eq!(
        answer(&mut device, &request(21, RequestBody::UploadCommit)),
        error(21, ErrorCode::NoUpload)
    );
    let huge = RequestBody::UploadBegin { len: 1 << 20, crc };
    assert_eq!(
        answer(&mut device, &request(22, huge)),
        error(22, ErrorCode::TooLarge)
    );
    let begin = RequestBody::UploadBegin {
        len: blob.len() as u32,
        crc,
    };
    answer(&mut device, &request(23, begin));
    assert_eq!(
        answer(&mut device, &request(24, chunk(8))),
        error(24, ErrorCode::ChunkOutOfOrder)
    );
    // An offset near 2³² must not overflow on a 32-bit device.
    assert_eq!(
        answer(&mut device, &request(24, chunk(u32::MAX - 3))),
        error(24, ErrorCode::ChunkOutOfOrder)
    );
    answer(&mut device, &request(25, chunk(0)));
    assert_eq!(
        answer(&mut device, &request(26, RequestBody::UploadCommit)),
        error(26, ErrorCode::UploadIncomplete)
    );
    assert_eq!(
        upload(&mut device, &blob, crc ^ 1, 27),
        error(27, ErrorCode::UploadCrc)
    );
    let mut garbage = blob.clone();
    garbage[0] = 9; // format 9
    let g = CRC.checksum(&garbage);
    assert_eq!(
        upload(&mut device, &garbage, g, 28),
        error(28, ErrorCode::InvalidCalibration)
    );
    // Still no calibration after all that; then a good upload.
    assert_eq!(
        answer(&mut device, &request(29, compute(&[RAY]))),
        error(29, ErrorCode::NoCalibration)
    );
    let committed = upload(&mut device, &blob, crc, 30);
    assert!(
        matches!(
            committed.body,
            ResponseBody::Committed {
                fingerprint: 77,
                generation: 1
            }
        ),
        "{committed:?}"
    );

    // An unknown ray id gets its per-point status; the known one its point.
    match answer(&mut device, &request(31, compute(&[RAY, 9999]))).body {
        ResponseBody::Points {
            fingerprint: 77,
            points,
        } => {
            assert!(matches!(points[0], PointResult::Depth(_)));
            assert_eq!(points[1], PointResult::Failed(PointStatus::UnknownRay));
        }
        other => panic!("{other:?}"),
    }
    serves(&mut device, 32);
}

/// 10⁶ inputs of three kinds (random bytes; random payloads with a good CRC, so they reach the
/// message decoder; valid frames with a few bytes changed): every frame gets exactly one answer,
/// and every 10,000 inputs a good request is still served.
#[test]
fn fuzz_a_million_frames() {
    let mut device = InProcess::new();
    let blob = calibration_blob(&paper_rig(), 5, Method::ClosestApproach).unwrap();
    upload(&mut device, &blob, CRC.checksum(&blob), 1);
    let valid = request(7, compute(&[RAY, 1, 12, 12, 300]));
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let (mut frames, mut answers) = (0usize, 0usize);
    for i in 0..1_000_000u32 {
        let input = match i % 3 {
            0 => {
                let n = rng.below(80) as usize;
                rng.bytes(n)
            }
            1 => {
                let mut payload: [u8; 24] = rng.bytes(24).try_into().unwrap();
                payload[1] = rng.below(9) as u8; // mostly known kinds
                frame_of(&payload)
            }
            _ => {
                let mut f = valid.clone();
                for _ in 0..=rng.below(3) {
                    let at = rng.below(f.len() as u64) as usize;
                    f[at] = rng.next_u64() as u8;
                }
                f
            }
        };
        frames += input.split(|&b| b == 0).filter(|f| !f.is_empty()).count();
        answers += exchange(&mut device, &input).len();
        if i % 10_000 == 0 {
            serves(&mut device, 1);
        }
    }
    assert_eq!(answers, frames, "one answer per frame");
    assert!(frames > 1_000_000);
}

/// Calibrations that decode but are not valid: each is refused before it becomes the stored
/// newest (its bytes went only into the spare slot) and the previous calibration stays active.
#[test]
fn invalid_calibrations_are_refused() {
    use deltaz_shared::protocol::calibration::{decode_calibration, encode_calibration};
    use deltaz_shared::protocol::{MAX_NONCENTRAL_RAYS, MAX_RAYS};
    use deltaz_shared::ray_table::NONCENTRAL_RECORD;
    let mut device = InProcess::new();
    let good = calibration_blob(&paper_rig(), 1, Method::ClosestApproach).unwrap();
    let committed = upload(&mut device, &good, CRC.checksum(&good), 1);
    assert!(matches!(
        committed.body,
        ResponseBody::Committed { fingerprint: 1, .. }
    ));

    let mut records: Vec<Vec<u8>> = Vec::new();
    let header = decode_calibration(&good, |_, r| {
        records.push(r.to_vec());
        true
    })
    .unwrap();
    // The first ray's record under another id (a non-central record's offset zero).
    let ray = |id: u16| {
        let mut r = [0u8; NONCENTRAL_RECORD];
        r[..8].copy_from_slice(&records[0][..8]);
        r[..2].copy_from_slice(&id.to_le_bytes());
        r
    };
    let first = ray(u16::from_le_bytes([records[0][0], records[0][1]]));
    let mut nan_f = header.clone();
    nan_f.inner.f = f32::NAN;
    let mut zero_pixel = header.clone();
    zero_pixel.grid.pixel_size = 0.0;
    let too_many: Vec<_> = (0..MAX_RAYS as u16 + 1).map(ray).collect();
    let mut noncentral = header.clone();
    noncentral.model.noncentral = true;
    let too_many_noncentral: Vec<_> = (0..MAX_NONCENTRAL_RAYS as u16 + 1).map(ray).collect();
    let mut no_pixels = header.clone();
    no_pixels.grid.width = 0;
    no_pixels.grid.height = 0;
    let cases: Vec<(&str, _, Vec<[u8; NONCENTRAL_RECORD]>)> = vec![
        ("NaN focal length", nan_f, vec![first]),
        ("zero pixel size", zero_pixel, vec![first]),
        ("unsorted rays", header.clone(), vec![ray(5), ray(3)]),
        ("duplicate ray", header.clone(), vec![ray(5), ray(5)]),
        ("1,321 central rays", header.clone(), too_many),
        ("622 non-central rays", noncentral, too_many_noncentral),
        ("no rays", header.clone(), vec![]),
        ("a 0 × 0 sensor", no_pixels, vec![first]),
    ];
    for (i, (what, mut h, rays)) in cases.into_iter().enumerate() {
        h.rays = rays.len() as u16;
        h.fingerprint = 100 + i as u64;
        let mut blob = vec![0u8; 16 * 1024];
        let len = encode_calibration(&h, rays, &mut blob).unwrap();
        blob.truncate(len);
        let seq = 10 + i as u32;
        assert_eq!(
            upload(&mut device, &blob, CRC.checksum(&blob), seq),
            error(seq, ErrorCode::InvalidCalibration),
            "{what}"
        );
        match answer(&mut device, &request(seq, RequestBody::Info)).body {
            ResponseBody::Info(info) => {
                let c = info.calibration.unwrap();
                assert_eq!((c.fingerprint, c.generation), (1, 1), "{what}");
            }
            other => panic!("{other:?}"),
        }
    }
}

/// A request with seq 0 (the device's own for frames it could not read) is refused; a centroid
/// off the sensor gets a status, not a point.
#[test]
fn seq_zero_and_off_sensor_centroids() {
    let mut device = InProcess::new();
    assert_eq!(
        answer(&mut device, &request(0, RequestBody::Info)),
        frame_error(0, WireError::Malformed)
    );
    let good = calibration_blob(&paper_rig(), 1, Method::ClosestApproach).unwrap();
    upload(&mut device, &good, CRC.checksum(&good), 1);
    let (col, row) = smoke_pixel().unwrap();
    let on = Centroid::from_pixel(RAY, col, row, 6).unwrap();
    // 800 px: inside the fixed point's range (1024 px at 1/64), off the 768-pixel-wide sensor.
    let off = Centroid::from_pixel(RAY, 800.0, row, 6).unwrap();
    let centroids = heapless::Vec::from_slice(&[on, off]).unwrap();
    match answer(&mut device, &request(2, RequestBody::Compute { centroids })).body {
        ResponseBody::Points { points, .. } => {
            assert!(matches!(points[0], PointResult::Depth(_)));
            assert_eq!(points[1], PointResult::Failed(PointStatus::OffSensor));
        }
        other => panic!("{other:?}"),
    }
}

/// A stored calibration the firmware cannot load (its CRC holds, its content does not) is not
/// activated, and Info says why instead of the device resetting in a loop.
#[test]
fn a_boot_failure_is_reported_by_info() {
    use deltaz_firmware::store::Store;
    use deltaz_host::link::InProcessFlash;
    let mut store = Store::new(InProcessFlash::new(), InProcess::SLOTS).unwrap();
    store.save(b"not a calibration").unwrap();
    let mut device = InProcess::with_flash(store.into_flash());
    match answer(&mut device, &request(1, RequestBody::Info)).body {
        ResponseBody::Info(info) => {
            assert_eq!(info.calibration, None);
            assert_eq!(info.boot_error, Some(ErrorCode::InvalidCalibration));
        }
        other => panic!("{other:?}"),
    }
    // A good upload clears it.
    let good = calibration_blob(&paper_rig(), 1, Method::ClosestApproach).unwrap();
    upload(&mut device, &good, CRC.checksum(&good), 2);
    match answer(&mut device, &request(3, RequestBody::Info)).body {
        ResponseBody::Info(info) => assert_eq!(info.boot_error, None),
        other => panic!("{other:?}"),
    }
}
