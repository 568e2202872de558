//! Round trips through the whole model: project a point (eq. 1), intersect the camera ray with the
//! projector ray through that point (eqs 4-9), recover the point; and the f32 path against f64.

use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::{Camera, ExteriorOrientation};
use deltaz_shared::paper::{table2_exterior, DC40_GRID, TABLE1_INNER, TABLE3_GLOBAL};
use deltaz_shared::projector::{Projector, ProjectorRay};
use deltaz_shared::rig::{Method, Rig};
use deltaz_shared::Error;
use nalgebra::Vector3;
use proptest::prelude::*;

const DC40: PixelGrid<f64> = DC40_GRID;

fn table1() -> InnerOrientation<f64> {
    TABLE1_INNER
}

fn plane1() -> ExteriorOrientation<f64> {
    table2_exterior(0)
}

/// A 20 x 22 pattern spanning Table 4's rays (l 0.085..0.385, m −0.172..0.133), ids row·100 + col.
fn pattern() -> Vec<ProjectorRay<f64>> {
    let mut rays = Vec::new();
    for row in 0..20u16 {
        for col in 0..22u16 {
            let l = 0.085 + 0.300 * f64::from(col) / 21.0;
            let m = -0.172 + 0.305 * f64::from(row) / 19.0;
            let n = -(1.0 - l * l - m * m).sqrt();
            rays.push(ProjectorRay {
                id: row * 100 + col,
                direction: Vector3::new(l, m, n),
                offset: Vector3::zeros(),
            });
        }
    }
    rays
}

/// The f32 path agrees with f64 within 1 µm over the paper's working volume: camera 1400-1900 mm
/// from the object, the 440 rays of a 20 x 22 pattern around Table 4's.
#[test]
fn f32_agrees_with_f64_within_a_micrometre() {
    let exterior = plane1();
    let camera = Camera {
        grid: DC40,
        inner: table1(),
        exterior,
    };
    let projector = Projector::new(Vector3::from(TABLE3_GLOBAL), pattern()).unwrap();
    let rig64 = Rig::new(DC40, table1(), &exterior, projector.clone());
    let rig32: Rig<f32, Vec<ProjectorRay<f32>>> = rig64.cast().unwrap();
    let (mut worst, mut count) = (0.0_f64, 0);
    for distance in [1400.0, 1525.0, 1650.0, 1775.0, 1900.0] {
        let plate_z = exterior.centre.z - distance;
        for ray in projector.rays() {
            let line = projector.ray(ray.id).unwrap();
            let point = line.at((plate_z - line.point.z) / line.direction.z);
            let Ok((col, row)) = camera.world_to_pixel(&point) else {
                continue;
            };
            let (col32, row32) = (col as f32, row as f32);
            for method in [Method::Paper, Method::ClosestApproach] {
                let p64 = rig64
                    .reconstruct(ray.id, f64::from(col32), f64::from(row32), method)
                    .unwrap();
                let p32 = rig32.reconstruct(ray.id, col32, row32, method).unwrap();
                worst = worst.max((p32.point.map(f64::from) - p64.point).amax());
            }
            count += 1;
        }
    }
    assert!(count == 5 * 440, "all dots in view: {count}");
    eprintln!(
        "f32 vs f64 worst difference over {count} dots: {:.3} µm",
        worst * 1e3
    );
    assert!(worst < 1e-3, "f32 differs from f64 by {worst} mm");
}

/// A rig whose baseline lies along Y: eq. (8) is degenerate, the closest approach is not.
#[test]
fn y_baseline_rig_needs_the_closest_approach() {
    let exterior = ExteriorOrientation {
        kappa: 0.0,
        phi: 0.0,
        omega: 0.0,
        centre: Vector3::new(0.0, 0.0, 1600.0),
    };
    let camera = Camera {
        grid: DC40,
        inner: table1(),
        exterior,
    };
    let centre = Vector3::new(0.0, 450.0, 1600.0);
    let point = Vector3::new(35.0, -60.0, 0.0);
    let ray = ProjectorRay {
        id: 7,
        direction: (point - centre).normalize(),
        offset: Vector3::zeros(),
    };
    let rig = Rig::new(
        DC40,
        table1(),
        &exterior,
        Projector::new(centre, vec![ray]).unwrap(),
    );
    let (col, row) = camera.world_to_pixel(&point).unwrap();
    assert_eq!(
        rig.reconstruct(7, col, row, Method::Paper).unwrap_err(),
        Error::DegenerateXZ
    );
    let hit = rig
        .reconstruct(7, col, row, Method::ClosestApproach)
        .unwrap();
    assert!((hit.point - point).norm() < 1e-6, "{}", hit.point);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// Random rigs: project, intersect, recover the point to 1e-6 mm (f64).
    #[test]
    fn round_trip_random_rigs(
        angles in prop::array::uniform3(-0.3..0.3f64),
        centre in prop::array::uniform3(-500.0..500.0f64),
        baseline in prop::array::uniform3(-600.0..600.0f64),
        target in prop::array::uniform3(-150.0..150.0f64),
        distance in 800.0..2500.0f64,
        k1 in -1e-4..1e-4f64,
        p in prop::array::uniform2(-3e-5..3e-5f64),
    ) {
        let exterior = ExteriorOrientation {
            kappa: angles[0], phi: angles[1], omega: angles[2],
            centre: Vector3::from(centre),
        };
        // A point on the optical axis at `distance`, moved by `target` in the camera system.
        let r = exterior.r_cam_world();
        let point = exterior.camera_to_world(&(Vector3::new(0.0, 0.0, -distance) + Vector3::from(target)));
        let inner = InnerOrientation { k1, p1: p[0], p2: p[1], cx: 0.1, cy: -0.2, ..InnerOrientation::ideal(46.981) };
        let camera = Camera { grid: DC40, inner, exterior };
        let proj_centre = exterior.centre + r.transpose() * Vector3::from(baseline);
        prop_assume!((point - proj_centre).norm() > 100.0);
        let direction = (point - proj_centre).normalize();
        // Skip nearly parallel rays: the rig has no baseline seen from the point.
        let sine = direction.cross(&(point - exterior.centre).normalize()).norm();
        prop_assume!(sine > 0.02);
        let ray = ProjectorRay { id: 1, direction, offset: Vector3::zeros() };
        let rig = Rig::new(DC40, inner, &exterior, Projector::new(proj_centre, vec![ray]).unwrap());
        let (col, row) = camera.world_to_pixel(&point).unwrap();
        let hit = rig.reconstruct(1, col, row, Method::ClosestApproach).unwrap();
        prop_assert!((hit.point - point).norm() < 1e-6, "closest approach off by {}", (hit.point - point).norm());
        match rig.reconstruct(1, col, row, Method::Paper) {
            Ok(hit) => prop_assert!((hit.point - point).norm() < 1e-6, "eq. 8 off by {}", (hit.point - point).norm()),
            Err(e) => prop_assert_eq!(e, Error::DegenerateXZ),
        }
    }
}

type PatternRig = Rig<f64, Vec<ProjectorRay<f64>>>;

/// The paper's rig and a second geometry: camera looking down −Z at the origin, projector
/// 300 mm to its left; each with two depths across its working range.
fn two_rigs() -> [(PatternRig, [f64; 2]); 2] {
    let paper = Rig::new(
        DC40,
        table1(),
        &plane1(),
        Projector::new(Vector3::from(TABLE3_GLOBAL), pattern()).unwrap(),
    );
    let other = Rig::new(
        DC40,
        InnerOrientation::ideal(25.0),
        &ExteriorOrientation {
            kappa: 0.3,
            phi: -0.05,
            omega: 0.02,
            centre: Vector3::new(10.0, -20.0, 1000.0),
        },
        Projector::new(Vector3::new(-300.0, 0.0, 1000.0), pattern()).unwrap(),
    );
    [(paper, [1400.0, 1900.0]), (other, [700.0, 1100.0])]
}

/// The forward projection inverts the reconstruction: the pixel of ray `id` at a depth,
/// reconstructed, is the point at that depth (camera-system z = −depth), on two rigs.
#[test]
fn forward_projection_round_trip() {
    let rigs = two_rigs();
    for (rig, depths) in &rigs {
        let r = rig.r_cam_world();
        for ray in rig.projector_centred().rays().iter().step_by(37) {
            for &depth in depths {
                let point = rig.point_at_depth(ray.id, depth).unwrap();
                assert!(((r * point).z + depth).abs() < 1e-9, "camera z is −depth");
                let (col, row) = rig.pixel_at_depth(ray.id, depth).unwrap();
                let hit = rig
                    .reconstruct(ray.id, col, row, Method::ClosestApproach)
                    .unwrap();
                let expected = point + rig.camera_centre();
                assert!((hit.point - expected).norm() < 1e-6, "{}", hit.point);
            }
        }
    }
    assert_eq!(
        rigs[0].0.pixel_at_depth(9999, 1500.0),
        Err(Error::UnknownRay(9999))
    );
}

/// What a device answers is the depth of its intersection (λ·f); placed at that depth, the
/// intersection is found again, point and miss distance, by either method and with the rays
/// missing each other by up to a few millimetres (dots moved off their rays), on two rigs.
#[test]
fn placed_at_its_depth_an_intersection_is_found_again() {
    let mut widest = 0.0f64;
    for (rig, depths) in &two_rigs() {
        let r = rig.r_cam_world();
        for ray in rig.projector_centred().rays().iter().step_by(23) {
            for (k, &depth) in depths.iter().enumerate() {
                let (col, row) = rig.pixel_at_depth(ray.id, depth).unwrap();
                let (col, row) = (col + 1.5 * k as f64, row - 2.0 + 3.0 * k as f64);
                for method in [Method::Paper, Method::ClosestApproach] {
                    let hit = rig.reconstruct(ray.id, col, row, method).unwrap();
                    let at = rig
                        .depth_from(&mut Default::default(), ray.id, col, row, method)
                        .unwrap();
                    let on_camera = rig.camera_ray(col, row).at(hit.lambda);
                    assert!(((r * on_camera).z + at).abs() < 1e-9, "depth is −z");
                    let placed = rig
                        .reconstruct_at_depth(ray.id, col, row, at, method)
                        .unwrap();
                    assert!((placed.point - hit.point).norm() < 1e-9, "{method:?}");
                    assert!((placed.miss - hit.miss).abs() < 1e-9, "{method:?}");
                    assert!((placed.lambda_p - hit.lambda_p).abs() < 1e-9);
                    widest = widest.max(hit.miss);
                }
            }
        }
    }
    assert!(widest > 1.0, "the rays miss by up to {widest} mm");
}

/// One validation of a calibration: a sensor of no pixels, a zero focal length, no rays or a
/// NaN are refused; the paper's rig and its f32 cast pass.
#[test]
fn validation_of_a_calibration() {
    let projector = Projector::new(Vector3::from(TABLE3_GLOBAL), pattern()).unwrap();
    let rig = Rig::new(DC40, table1(), &plane1(), projector.clone());
    assert_eq!(rig.validate(), Ok(()));
    let cast: Rig<f32, Vec<ProjectorRay<f32>>> = rig.cast().unwrap();
    assert_eq!(cast.validate(), Ok(()));
    let empty_sensor = PixelGrid {
        width: 0,
        height: 0,
        ..DC40
    };
    let bad = Rig::new(empty_sensor, table1(), &plane1(), projector.clone());
    assert_eq!(bad.validate(), Err(Error::InvalidCalibration));
    let flat = InnerOrientation::ideal(0.0);
    let bad = Rig::new(DC40, flat, &plane1(), projector.clone());
    assert_eq!(bad.validate(), Err(Error::InvalidCalibration));
    let no_rays = Projector::new(Vector3::from(TABLE3_GLOBAL), Vec::new()).unwrap();
    let bad = Rig::new(DC40, table1(), &plane1(), no_rays);
    assert_eq!(bad.validate(), Err(Error::InvalidCalibration));
    let nan = InnerOrientation {
        k1: f64::NAN,
        ..table1()
    };
    let bad = Rig::new(DC40, nan, &plane1(), projector);
    assert_eq!(bad.validate(), Err(Error::NotFinite));
}
