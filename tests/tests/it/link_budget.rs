//! Bytes per point on the link, counted over the encoded frames of a full 440-dot frame, and the
//! frame rate they allow over a 2 Mbaud UART (8N1: 10 bits a byte, full duplex).

use deltaz_host::link::Device;
use deltaz_tests::pattern::{pattern_rig, plate_centroids};

/// The labelled budget: 8.14 bytes per point for request and response together (protocol 5:
/// 15.13), asserted to the hundredth's neighbourhood (8.1-8.2).
#[test]
fn bytes_per_point_of_a_440_dot_frame() {
    let rig = pattern_rig();
    let mut device = Device::in_process();
    device.upload(&rig, 1).unwrap();
    let frame = plate_centroids(&rig, 100.0, (0.0, 0.0));
    assert_eq!(frame.len(), 440, "every dot of the pattern is seen");
    let (sent0, received0) = device.byte_counts();
    let points = device.compute(&frame).unwrap();
    assert!(points.iter().all(Result::is_ok));
    let (sent1, received1) = device.byte_counts();
    let request = (sent1 - sent0) as f64 / 440.0;
    let response = (received1 - received0) as f64 / 440.0;
    let per_direction = 2e6 / 10.0; // bytes/s each way
    let fps = per_direction / (440.0 * request.max(response));
    println!(
        "440-dot frame: request {request:.3} + response {response:.3} = {:.3} bytes per point; \
         {fps:.1} frames/s at 2 Mbaud (full duplex), {:.1} if both directions shared the line",
        request + response,
        per_direction / (440.0 * (request + response))
    );
    // 5 bytes a centroid (a one-byte id difference: the client sends the batch sorted by id,
    // and the pattern's row changes, 21 → 100, are a difference of 79), 3 a result (the
    // depth), plus headers, CRC, COBS and delimiters.
    assert!((5.0..5.1).contains(&request), "{request}");
    assert!((3.0..3.1).contains(&response), "{response}");
    // Measured 8.14 (5.09 + 3.05).
    assert!(
        (8.1..8.2).contains(&(request + response)),
        "{}",
        request + response
    );
    assert!(fps >= 85.0);
}

/// `device stream --simulate` of a calibration in the camera system puts its plates in front of
/// the camera (the planes Z = 0, 100, 200 of that system pass through the camera and see no
/// dot), and in a plate frame on the planes Z = 0, 100, 200 of that frame as before.
#[test]
fn simulated_plates_lie_in_front_of_the_camera_in_either_frame() {
    use deltaz_host::io::system_file::SystemFrame;
    use deltaz_host::workflows::stream::{plate_dots, simulated_plates};
    let rig = deltaz_tests::torso::rig();
    assert!(
        plate_dots(&rig, 0.0).is_empty(),
        "Z = 0 of the camera system"
    );
    let plates = simulated_plates(&rig, &SystemFrame::Camera).unwrap();
    for plate in &plates {
        assert!(plate.len() > 300, "{} dots", plate.len());
    }
    let plate_frame = SystemFrame::Plate { image: "p1".into() };
    let pattern = pattern_rig();
    let plates = simulated_plates(&pattern, &plate_frame).unwrap();
    assert_eq!(plates[0], plate_dots(&pattern, 0.0));
    assert_eq!(plates[2], plate_dots(&pattern, 200.0));
}
