//! Golden frames: the exact bytes of one frame of every message kind, so any change of the wire
//! format shows here (and must come with a new PROTOCOL_VERSION).

use deltaz_shared::protocol::calibration::IntersectionMethod;
use deltaz_shared::protocol::stream::{tag, view_request, FrameWriter, RequestView};
use deltaz_shared::protocol::{
    decode_request, decode_response, encode_frame, BoardClock, CalibrationSummary, Centroid,
    ClockSource, DeviceInfo, DeviceStats, Dot, ErrorCode, IdentifiedPoint, PointResult,
    PointStatus, Request, RequestBody, Response, ResponseBody, WireError, MAX_FRAME,
    PROTOCOL_VERSION,
};

fn requests() -> Vec<Request> {
    let body = [
        RequestBody::Info,
        RequestBody::UploadBegin {
            len: 300,
            crc: 0xDEAD_BEEF,
        },
        RequestBody::UploadChunk {
            offset: 1024,
            data: heapless::Vec::from_slice(&[1, 0, 3]).unwrap(),
        },
        RequestBody::UploadCommit,
        RequestBody::Compute {
            centroids: heapless::Vec::from_slice(&[
                Centroid {
                    id: 102,
                    col: 0x1234,
                    row: 0x00FF,
                },
                Centroid {
                    id: 101,
                    col: 1,
                    row: 2,
                },
            ])
            .unwrap(),
        },
        RequestBody::Stats,
        RequestBody::Reset,
        RequestBody::Identify {
            dots: heapless::Vec::from_slice(&[Dot {
                col: 0x1234,
                row: 0x00FF,
            }])
            .unwrap(),
        },
    ];
    body.into_iter()
        .enumerate()
        .map(|(i, body)| Request {
            seq: i as u32 + 1,
            body,
        })
        .collect()
}

fn responses() -> Vec<Response> {
    let body = [
        ResponseBody::Info(DeviceInfo {
            firmware: [0, 1, 0],
            protocol: PROTOCOL_VERSION,
            ray_capacity: 512,
            max_batch: 512,
            max_frame: MAX_FRAME as u32,
            max_calibration: 16384,
            calibration: Some(CalibrationSummary {
                fingerprint: 0x0123_4567_89AB_CDEF,
                generation: 2,
                rays: 440,
                centroid_bits: 6,
                camera_centre: [375.121, 364.541, 1842.675],
                method: IntersectionMethod::ClosestApproach,
            }),
            boot_error: Some(ErrorCode::IdentifierCapacity),
            clock: Some(BoardClock {
                hz: 84_000_000,
                source: ClockSource::InternalPll,
            }),
        }),
        ResponseBody::UploadReady { len: 300 },
        ResponseBody::ChunkAccepted { next_offset: 1027 },
        ResponseBody::Committed {
            fingerprint: 0x0123_4567_89AB_CDEF,
            generation: 2,
        },
        ResponseBody::Points {
            fingerprint: 42,
            points: heapless::Vec::from_slice(&[
                PointResult::Depth(0x17_7100),
                PointResult::Failed(PointStatus::UnknownRay),
            ])
            .unwrap(),
        },
        ResponseBody::Stats(DeviceStats {
            requests: 10,
            bad_frames: 1,
            points: 4400,
            last_compute_ticks: 26206,
            last_compute_points: 440,
            stack_peak: 60000,
        }),
        ResponseBody::Resetting,
        ResponseBody::Error(ErrorCode::NoCalibration),
        ResponseBody::Identified {
            fingerprint: 42,
            points: heapless::Vec::from_slice(&[
                IdentifiedPoint {
                    id: 203,
                    result: PointResult::Depth(0x17_7100),
                },
                IdentifiedPoint {
                    id: 0,
                    result: PointResult::Failed(PointStatus::Unassigned),
                },
            ])
            .unwrap(),
        },
    ];
    body.into_iter()
        .enumerate()
        .map(|(i, body)| Response {
            seq: i as u32 + 1,
            body,
        })
        .chain([WireError::BadCrc, WireError::Overrun].map(|e| Response {
            seq: 0,
            body: ResponseBody::Error(ErrorCode::Frame(e)),
        }))
        .collect()
}

/// The frames of [`requests`], in order. The first by hand: postcard of Info with seq 1 is
/// `01 00`; its CRC-32 (zlib) is 0x58c223be, little endian `be 23 c2 58`; COBS turns
/// `01 00 be 23 c2 58` into `02 01 05 be 23 c2 58`; then the delimiter `00`.
const REQUEST_FRAMES: [&str; 8] = [
    "02 01 05 be 23 c2 58 00",
    "0e 02 01 ac 02 ef fd b6 f5 0d 34 51 b7 c1 00",
    "07 03 02 80 08 03 01 06 03 d9 02 8c d8 00",
    "07 04 03 41 86 bc bc 00",
    // Ids 102 then 101: zigzag differences 204 (cc 01) and −1 (01).
    "09 05 04 02 cc 01 34 12 ff 03 01 01 02 02 05 c5 f7 74 55 00",
    "07 06 05 f6 41 e9 67 00",
    "07 07 06 0d 21 fb e7 00",
    "07 08 07 01 34 12 ff 05 8b 6d 29 7d 00",
];

/// The frames of [`responses`], in order.
const RESPONSE_FRAMES: [&str; 11] = [
    // Protocol 6 (06), max_frame 3,200 (varint 80 19); after the camera centre the method
    // (01: the closest approach), then boot_error Some(IdentifierCapacity): 01 0a, and the
    // clock: Some, 84,000,000 Hz (varint 80 fa 86 28), the internal oscillator's PLL (01).
    "02 01 01 02 01 3e 06 80 04 80 04 80 19 80 80 01 01 ef 9b af cd f8 ac d1 91 01 02 b8 03 06 \
     0e 2d b2 9d ef 71 77 40 2d b2 9d ef a7 c8 76 40 33 33 33 33 b3 ca 9c 40 01 01 0a 01 80 fa \
     86 28 01 7a f5 71 ce 00",
    "09 02 01 ac 02 69 ef 33 66 00",
    "07 03 02 83 08 26 e7 02 2e 00",
    "11 04 03 ef 9b af cd f8 ac d1 91 01 02 d0 af 85 68 00",
    // Depth 1500.25 mm (0x177100: 00 71 17, its zero taken by COBS), then unknown ray (f0 ff
    // ff); the CRC ff 5a f8 a5.
    "05 05 04 2a 02 0a 71 17 f0 ff ff ff 5a f8 a5 00",
    "13 06 05 0a 01 b0 22 de cc 01 b8 03 e0 d4 03 91 b8 d5 09 00",
    "07 07 06 0d 21 fb e7 00",
    "08 08 07 01 fb 2e 14 c9 00",
    // Ids 203 (zigzag 406: 96 03) at depth 1500.25 mm, then 0 (−203: 95 03) unassigned (f3 ff
    // ff).
    "07 09 08 2a 02 96 03 0c 71 17 95 03 f3 ff ff 9d 2a 87 2c 00",
    "01 02 07 06 02 b5 a8 05 ca 00",
    // Protocol 4: bytes lost in reception: seq 0, Error, Frame, WireError 7 (`00 07 00 07`), its
    // CRC-32 (zlib) 0xba6f5c3a.
    "01 02 07 06 07 3a 5c 6f ba 00",
];

fn bytes(hex: &str) -> Vec<u8> {
    hex.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

/// The bytes between the delimiters.
fn body(frame: &[u8]) -> Vec<u8> {
    assert_eq!(frame.last(), Some(&0), "a frame ends with its delimiter");
    assert!(
        !frame[..frame.len() - 1].contains(&0),
        "COBS leaves no other zero"
    );
    frame[..frame.len() - 1].to_vec()
}

#[test]
fn request_frames_are_golden() {
    let mut buf = [0u8; MAX_FRAME];
    for (request, golden) in requests().into_iter().zip(REQUEST_FRAMES) {
        let frame = encode_frame(&request, &mut buf).unwrap();
        assert_eq!(frame, &bytes(golden)[..], "{:?}", request.body);
        assert_eq!(decode_request(&mut body(frame)), Ok(request.clone()));
        // The device's view in place reads the same request.
        let mut frame = body(frame);
        let (seq, view) = view_request(&mut frame).unwrap();
        assert_eq!((seq, body_of(view)), (request.seq, request.body));
    }
}

/// The request a view stands for.
fn body_of(view: RequestView) -> RequestBody {
    match view {
        RequestView::Info => RequestBody::Info,
        RequestView::UploadBegin { len, crc } => RequestBody::UploadBegin { len, crc },
        RequestView::UploadChunk { offset, data } => RequestBody::UploadChunk {
            offset,
            data: heapless::Vec::from_slice(data).unwrap(),
        },
        RequestView::UploadCommit => RequestBody::UploadCommit,
        RequestView::Compute(batch) => RequestBody::Compute {
            centroids: batch.iter().collect(),
        },
        RequestView::Stats => RequestBody::Stats,
        RequestView::Reset => RequestBody::Reset,
        RequestView::Identify(batch) => RequestBody::Identify {
            dots: batch.iter().collect(),
        },
    }
}

/// The response written field by field, as the device does.
fn written(response: &Response, buf: &mut [u8]) -> usize {
    let seq = response.seq;
    let one = |buf: &mut [u8], tag, payload: &dyn erased::Put| {
        let mut w = FrameWriter::new(buf, seq, tag).unwrap();
        payload.put(&mut w);
        w.finish().unwrap().len()
    };
    match &response.body {
        ResponseBody::Info(i) => one(buf, tag::INFO, i),
        ResponseBody::UploadReady { len } => one(buf, tag::UPLOAD_READY, len),
        ResponseBody::ChunkAccepted { next_offset } => one(buf, tag::CHUNK_ACCEPTED, next_offset),
        ResponseBody::Committed {
            fingerprint,
            generation,
        } => one(buf, tag::COMMITTED, &(*fingerprint, *generation)),
        ResponseBody::Stats(s) => one(buf, tag::STATS, s),
        ResponseBody::Resetting => one(buf, tag::RESETTING, &()),
        ResponseBody::Error(e) => one(buf, tag::ERROR, e),
        ResponseBody::Points {
            fingerprint,
            points,
        } => {
            let mut w = FrameWriter::new(buf, seq, tag::POINTS).unwrap();
            w.put(fingerprint).unwrap();
            w.put(&(points.len() as u32)).unwrap();
            for p in points {
                w.put_point(p).unwrap();
            }
            w.finish().unwrap().len()
        }
        ResponseBody::Identified {
            fingerprint,
            points,
        } => {
            let mut w = FrameWriter::new(buf, seq, tag::IDENTIFIED).unwrap();
            w.put(fingerprint).unwrap();
            w.put(&(points.len() as u32)).unwrap();
            for p in points {
                w.put_identified(p.id, &p.result).unwrap();
            }
            w.finish().unwrap().len()
        }
    }
}

/// A payload of any type behind one reference.
mod erased {
    use deltaz_shared::protocol::stream::FrameWriter;
    use postcard::ser_flavors::{Cobs, Slice};

    pub trait Put {
        fn put(&self, w: &mut FrameWriter<Cobs<Slice>>);
    }

    impl<T: serde::Serialize> Put for T {
        fn put(&self, w: &mut FrameWriter<Cobs<Slice>>) {
            w.put(self).unwrap();
        }
    }
}

/// The points of a `Points` response streamed out (the device's way), with long runs of
/// non-zero bytes (full COBS blocks); other responses through [`written`].
fn streamed_out(response: &Response, out: &mut dyn FnMut(&[u8])) {
    let mut buf = [0u8; MAX_FRAME];
    match &response.body {
        ResponseBody::Points {
            fingerprint,
            points,
        } => {
            let mut w = FrameWriter::streamed(out, response.seq, tag::POINTS);
            w.put(fingerprint).unwrap();
            w.put(&(points.len() as u32)).unwrap();
            for p in points {
                w.put_point(p).unwrap();
            }
            w.finish().unwrap();
        }
        _ => {
            // The device's leading delimiter, then the frame written field by field.
            let len = written(response, &mut buf);
            out(&[0]);
            out(&buf[..len]);
        }
    }
}

/// A long `Points` answer (runs of more than 254 non-zero bytes) streamed out block by block is
/// the frame `encode_frame` makes.
#[test]
fn streamed_frames_equal_buffered_ones() {
    let points: heapless::Vec<PointResult, 512> = (0..300)
        .map(|i| PointResult::Depth(0x21_2121 + i))
        .collect();
    let response = Response {
        seq: 77,
        body: ResponseBody::Points {
            fingerprint: u64::MAX,
            points,
        },
    };
    let mut buf = [0u8; MAX_FRAME];
    let expected = encode_frame(&response, &mut buf).unwrap().to_vec();
    let mut out = Vec::new();
    streamed_out(&response, &mut |b| out.extend_from_slice(b));
    // Streamed, a frame starts with a delimiter: one cut short ends there.
    assert_eq!(out[0], 0);
    assert_eq!(out[1..], expected);
    assert_eq!(decode_response(&mut body(&out[1..])), Ok(response));
}

#[test]
fn response_frames_are_golden() {
    let mut buf = [0u8; MAX_FRAME];
    for (response, golden) in responses().into_iter().zip(RESPONSE_FRAMES) {
        let frame = encode_frame(&response, &mut buf).unwrap();
        assert_eq!(frame, &bytes(golden)[..], "{:?}", response.body);
        // The device writes the same bytes field by field.
        let mut streamed = [0u8; MAX_FRAME];
        let len = written(&response, &mut streamed);
        assert_eq!(&streamed[..len], &bytes(golden)[..], "{:?}", response.body);
        // And block by block, straight out, after a leading delimiter.
        let mut out = Vec::new();
        streamed_out(&response, &mut |b| out.extend_from_slice(b));
        assert_eq!(
            out,
            [&[0][..], &bytes(golden)].concat(),
            "{:?}",
            response.body
        );
        assert_eq!(decode_response(&mut body(frame)), Ok(response));
    }
}

/// Delta-coded ids whose sum leaves the u16 range are malformed (the CRC holds, the seq is
/// known).
#[test]
fn ray_id_below_zero_is_malformed() {
    let mut buf = [0u8; 64];
    // seq 9, Compute, one centroid, id difference −1 from 0, col/row bytes.
    let frame = encode_frame(&(9u32, 4u32, 1u32, -1i32, [1u8, 2, 3, 4]), &mut buf).unwrap();
    let len = frame.len();
    let mut copy = buf;
    assert_eq!(
        decode_request(&mut buf[..len - 1]),
        Err((9, WireError::Malformed))
    );
    assert_eq!(
        view_request(&mut copy[..len - 1]).err(),
        Some((9, WireError::Malformed))
    );
    let frame = encode_frame(&(9u32, 4u32, 1u32, 65535i32, [1u8, 2, 3, 4]), &mut buf).unwrap();
    let len = frame.len();
    assert!(matches!(
        decode_request(&mut buf[..len - 1]),
        Ok(Request {
            seq: 9,
            body: RequestBody::Compute { .. }
        })
    ));
}

#[test]
fn calibration_method_tags() {
    // The blob's method byte: postcard variant index.
    let mut buf = [0u8; 4];
    assert_eq!(
        postcard::to_slice(&IntersectionMethod::Paper, &mut buf).unwrap(),
        &[0]
    );
    assert_eq!(
        postcard::to_slice(&IntersectionMethod::ClosestApproach, &mut buf).unwrap(),
        &[1]
    );
}
