//! The mesh on a flat lattice: a dot not measured inside it is a gap the surface spans, one
//! on its outline is not; how irregularly points lie, and points scattered at random refused.

use deltaz_surface::mesh::Mesh;
use deltaz_surface::{analyse, CommonShare, Frame, Options, ScanPoint, SurfaceError};
use nalgebra::{Matrix3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Uniform};

const SPACING: f64 = 10.0;

/// A flat 9 × 9 lattice 1.5 m from the camera, without the nodes `missing`.
fn lattice(missing: &[[i32; 2]]) -> Mesh {
    let rays: Vec<[i32; 2]> = (0..9)
        .flat_map(|j| (0..9).map(move |i| [i, j]))
        .filter(|r| !missing.contains(r))
        .collect();
    let at = |[i, j]: [i32; 2]| Vector3::new(f64::from(i), f64::from(j), 0.0) * SPACING;
    let points: Vec<_> = rays
        .iter()
        .map(|&r| at(r) - Vector3::z() * 1500.0)
        .collect();
    Mesh::over_lattice(&points, &rays)
}

/// The gaps of `mesh` (their triangles' corners, in spacings across x-y) and their area (in
/// cells).
fn gaps(mesh: &Mesh) -> (Vec<[[f64; 2]; 3]>, f64) {
    let corners: Vec<_> = Mesh::gaps(&mesh.triangles)
        .iter()
        .map(|t| t.map(|k| [mesh.points[k].x, mesh.points[k].y].map(|c| c / SPACING)))
        .collect();
    let area = |[a, b, c]: &[[f64; 2]; 3]| {
        0.5 * ((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])).abs()
    };
    let total = corners.iter().map(area).sum();
    (corners, total)
}

#[test]
fn a_dot_not_measured_is_a_gap_one_on_the_outline_is_not() {
    assert_eq!(gaps(&lattice(&[])).1, 0.0);
    // Inside: the half cell of each cell about it that has the dot as a corner (the diamond
    // of its four neighbours), within a cell of it.
    let (corners, area) = gaps(&lattice(&[[4, 4]]));
    assert!((area - 2.0).abs() < 1e-9, "{area} cells");
    let near = corners.iter().flatten();
    assert!(near
        .clone()
        .all(|c| (c[0] - 4.0).abs() <= 1.0 && (c[1] - 4.0).abs() <= 1.0));
    // Two apart inside: two such gaps; on the outline, a notch: nothing.
    let (_, area) = gaps(&lattice(&[[2, 2], [6, 5], [0, 4], [8, 8]]));
    assert!((area - 4.0).abs() < 1e-9, "{area} cells");
}

#[test]
fn irregularity_grows_as_points_leave_a_grid() {
    let scattered = |jitter: f64| {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let off = Uniform::new(-jitter * SPACING, jitter * SPACING).unwrap();
        let points: Vec<Vector3<f64>> = (0..40)
            .flat_map(|j| (0..40).map(move |i| [i, j]))
            .map(|[i, j]| {
                let mut at = |k: i32| f64::from(k - 20) * SPACING + off.sample(&mut rng);
                Vector3::new(at(i), at(j), -1500.0)
            })
            .collect();
        let mesh = Mesh::over_directions(&points);
        mesh.irregularity(&mesh.triangles)
    };
    let flat = lattice(&[]);
    assert!(flat.irregularity(&flat.triangles) < 1e-9);
    let [small, large] = [0.15, 0.5].map(scattered);
    assert!(
        (0.08..0.18).contains(&small),
        "jittered by 0.15: {small:.3}"
    );
    assert!((0.3..0.5).contains(&large), "jittered by 0.5: {large:.3}");
}

/// Points scattered at random over a back's curve are refused by the analysis, naming how
/// irregularly they lie.
#[test]
fn points_scattered_at_random_are_refused() {
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let field = Uniform::new(-200.0, 200.0).unwrap();
    // On a cylinder, bent as a back is (a plane is refused as one first).
    let points = (0..1600)
        .map(|_| {
            let [x, y] = [field.sample(&mut rng), field.sample(&mut rng)];
            ScanPoint {
                position: Vector3::new(x, y, -1500.0 - x * x / 400.0),
                covariance: Matrix3::identity() * 0.16,
                ray: None,
            }
        })
        .collect();
    let frame = Frame {
        points,
        calibration: None,
        common: CommonShare::None,
    };
    match analyse(&[frame], &Options::standing()) {
        Err(e @ SurfaceError::Scattered { irregularity, .. }) => {
            assert!(irregularity > 0.45, "{irregularity}");
            assert!(e.to_string().contains("scattered at random"), "{e}");
        }
        other => panic!("{other:?}"),
    }
}
