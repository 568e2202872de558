//! The identifier on a few rays of the paper's rig: within the depth range only, ambiguity
//! and conflicts reported, capacities met by growing cells, f32 as f64.

use deltaz_shared::collinearity::{Camera, ExteriorOrientation};
use deltaz_shared::identify::{Assignment, DepthRange, Identifier, IdentifyError};
use deltaz_shared::paper::{DC40_GRID, TABLE1_INNER, TABLE3_CAMERA};
use deltaz_shared::projector::{Projector, ProjectorRay};
use deltaz_shared::rig::Rig;
use nalgebra::Vector3;

fn camera() -> Camera<f64> {
    Camera {
        grid: DC40_GRID,
        inner: TABLE1_INNER,
        exterior: ExteriorOrientation {
            kappa: 0.0133,
            phi: 0.0142,
            omega: -0.026,
            centre: Vector3::zeros(),
        },
    }
}

/// The projector of Table 3 (camera system); rays aimed at camera-system points at 1700 mm.
const PROJECTOR: [f64; 3] = TABLE3_CAMERA;

fn ray_at(id: u16, x: f64, y: f64) -> ProjectorRay<f64> {
    let cam = camera();
    let target = cam.exterior.camera_to_world(&Vector3::new(x, y, -1700.0));
    ProjectorRay {
        id,
        direction: (target - Vector3::from(PROJECTOR)).normalize(),
        offset: Vector3::zeros(),
    }
}

fn rig(rays: &[ProjectorRay<f64>]) -> Rig<f64, &[ProjectorRay<f64>]> {
    let cam = camera();
    let projector = Projector::new(Vector3::from(PROJECTOR), rays).unwrap();
    Rig::new(cam.grid, cam.inner, &cam.exterior, projector)
}

/// The pixel of ray `id` hitting a surface at camera distance `depth`.
fn dot(rays: &[ProjectorRay<f64>], id: u16, depth: f64) -> (f64, f64) {
    rig(rays).pixel_at_depth(id, depth).unwrap()
}

const DEPTH: DepthRange<f64> = DepthRange {
    near: 1550.0,
    far: 1850.0,
};
type Small = Identifier<f64, 16, 1600, 4000>;

#[test]
fn identifies_within_range_only() {
    let rays = [
        ray_at(1, -200.0, 100.0),
        ray_at(2, 0.0, -150.0),
        ray_at(101, 250.0, 50.0),
    ];
    let ident = Small::new(&rig(&rays), DEPTH, 0.5, 16.0).unwrap();
    assert!(ident.entries() > 3 && ident.close_pairs() == 0);
    for id in [1, 2, 101] {
        for depth in [1560.0, 1700.0, 1840.0] {
            let (c, r) = dot(&rays, id, depth);
            match ident.identify(c, r) {
                Assignment::Ray { id: got, distance } => {
                    assert_eq!(got, id);
                    // The segment is straight in the refined image; its fixed point (half
                    // a 1/16-pixel step per axis: ≤ 0.045 px) stays far below the
                    // tolerance.
                    assert!(distance < 0.065, "{distance}");
                }
                other => panic!("ray {id} at {depth}: {other:?}"),
            }
        }
        let (c, r) = dot(&rays, id, 1400.0);
        assert_eq!(
            ident.identify(c, r),
            Assignment::Unassigned,
            "outside the depth range"
        );
    }
    assert_eq!(
        ident.identify(-3.0, 10.0),
        Assignment::Unassigned,
        "outside the image"
    );
}

/// Two rays in one epipolar plane whose segments overlap: a dot where they do is ambiguous,
/// never guessed, and `close_pairs` reports the pair.
#[test]
fn ambiguity_is_reported() {
    let cam = camera();
    let a = ray_at(5, 0.0, 0.0);
    // Ray 6 hits, at 1750 mm, the camera ray of ray 5's point at 1650 mm: one pixel, two rays.
    let (p, r) = (Vector3::from(PROJECTOR), cam.exterior.r_cam_world());
    let on_a = p + a.direction * ((-1650.0 - (r * p).z) / (r * a.direction).z);
    let b = ProjectorRay {
        id: 6,
        direction: (on_a * (1750.0 / 1650.0) - p).normalize(),
        offset: Vector3::zeros(),
    };
    let rays = [a, b, ray_at(7, 300.0, 200.0)];
    let ident = Small::new(&rig(&rays), DEPTH, 0.5, 16.0).unwrap();
    let (c, row) = dot(&rays, 5, 1650.0);
    // Both segments pass through the dot: which is closer is the fixed point's rounding.
    match ident.identify(c, row) {
        Assignment::Ambiguous { first, second } => {
            assert!(
                [(5, 6), (6, 5)].contains(&(first, second)),
                "{first} {second}"
            )
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(ident.close_pairs(), 1);
}

/// Two dots claiming one ray are both conflicts; the others stay identified.
#[test]
fn conflicts_in_a_frame() {
    let rays = [
        ray_at(1, -200.0, 100.0),
        ray_at(2, 0.0, -150.0),
        ray_at(101, 250.0, 50.0),
    ];
    let ident = Small::new(&rig(&rays), DEPTH, 0.5, 16.0).unwrap();
    let dots = [
        dot(&rays, 2, 1600.0),
        dot(&rays, 1, 1700.0),
        dot(&rays, 2, 1640.0),
        (700.0, 20.0),
    ];
    let mut out = [Assignment::Unassigned; 4];
    assert_eq!(ident.identify_frame(&dots, &mut out), 1);
    assert_eq!(out[0], Assignment::Conflict { id: 2 });
    assert_eq!(out[1].id(), Some(1));
    assert_eq!(out[2], Assignment::Conflict { id: 2 });
    assert_eq!(out[3], Assignment::Unassigned);
}

#[test]
fn capacities_and_parameters() {
    let rays = [
        ray_at(1, -200.0, 100.0),
        ray_at(2, 0.0, -150.0),
        ray_at(101, 250.0, 50.0),
    ];
    let rig = rig(&rays);
    assert_eq!(
        Identifier::<f64, 2, 1600, 4000>::new(&rig, DEPTH, 0.5, 16.0).err(),
        Some(IdentifyError::TooManyRays)
    );
    // Too few cells or entries for 16-pixel cells: the cells grow until the grid fits.
    let coarse = Identifier::<f64, 4, 100, 4000>::new(&rig, DEPTH, 0.5, 16.0).unwrap();
    assert!(
        coarse.cell() > 16.0 * 1.2 && coarse.entries() >= 3,
        "{}",
        coarse.cell()
    );
    let sparse = Identifier::<f64, 4, 1600, 5>::new(&rig, DEPTH, 0.5, 16.0).unwrap();
    assert!(
        sparse.cell() > 16.0 * 1.2 && sparse.entries() <= 5,
        "{}",
        sparse.cell()
    );
    for id in [1, 2, 101] {
        let (c, r) = dot(&rays, id, 1700.0);
        assert_eq!(coarse.identify(c, r).id(), Some(id));
        assert_eq!(sparse.identify(c, r).id(), Some(id));
    }
    // Fewer entries than rays: no grid holds them.
    assert_eq!(
        Identifier::<f64, 4, 1600, 2>::new(&rig, DEPTH, 0.5, 16.0).err(),
        Some(IdentifyError::TooManyEntries)
    );
    let inverted = DepthRange {
        near: 1850.0,
        far: 1550.0,
    };
    assert_eq!(
        Small::new(&rig, inverted, 0.5, 16.0).err(),
        Some(IdentifyError::InvalidParameters)
    );
    // In place: a failed rebuild leaves no rays; a good one equals a new identifier.
    let mut ident = Box::new(Small::new(&rig, DEPTH, 0.5, 16.0).unwrap());
    let (c, r) = dot(&rays, 2, 1700.0);
    assert_eq!(ident.identify(c, r).id(), Some(2));
    assert_eq!(
        ident.rebuild(&rig, inverted, 0.5, 16.0),
        Err(IdentifyError::InvalidParameters)
    );
    assert_eq!((ident.segments().count(), ident.entries()), (0, 0));
    assert_eq!(ident.identify(c, r), Assignment::Unassigned);
    ident.rebuild(&rig, DEPTH, 0.5, 16.0).unwrap();
    let fresh = Small::new(&rig, DEPTH, 0.5, 16.0).unwrap();
    assert!(ident.segments().eq(fresh.segments()));
    assert_eq!(ident.entries(), fresh.entries());
    assert_eq!(ident.identify(c, r), fresh.identify(c, r));
}

/// The device's f32 identifier gives the host's f64 result.
#[test]
fn f32_matches_f64() {
    let rays: [ProjectorRay<f64>; 3] = [
        ray_at(1, -200.0, 100.0),
        ray_at(2, 0.0, -150.0),
        ray_at(101, 250.0, 50.0),
    ];
    let host = rig(&rays);
    let ident64 = Small::new(&host, DEPTH, 0.5, 16.0).unwrap();
    let c = |v: f64| v as f32;
    let device: Rig<f32, Vec<ProjectorRay<f32>>> = host.cast().unwrap();
    let ident32 = Identifier::<f32, 16, 1600, 4000>::new(
        &device,
        DepthRange {
            near: 1550.0,
            far: 1850.0,
        },
        0.5,
        16.0,
    )
    .unwrap();
    for id in [1, 2, 101] {
        for depth in [1400.0, 1560.0, 1700.0, 1840.0] {
            let (col, row) = dot(&rays, id, depth);
            assert_eq!(
                ident32.identify(c(col), c(row)).id(),
                ident64.identify(col, row).id()
            );
        }
    }
}
