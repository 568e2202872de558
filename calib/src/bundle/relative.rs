//! Approximate values without control: relative orientation of the first pair by the essential
//! matrix (normalised eight-point algorithm), intersection of their common points, then space
//! resection of the other images one by one, intersecting new points as images are added. The
//! result has an arbitrary datum: the 1st image at the origin with R = I and a 1000 mm baseline.

use crate::resection::resect;
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::ExteriorOrientation;
use deltaz_shared::rotation::angles_from_matrix;
use nalgebra::{DMatrix, Matrix3, Vector2, Vector3};

/// The nominal length of the first baseline (mm): the free network's arbitrary scale.
pub const BASELINE_MM: f64 = 1000.0;

/// One observation for the initialisation: image, point, observed photo coordinates (mm).
pub type Seen = (usize, usize, Vector2<f64>);

/// The world direction of the ray through an observation.
fn ray(
    inner: &InnerOrientation<f64>,
    pose: &ExteriorOrientation<f64>,
    photo: &Vector2<f64>,
) -> Vector3<f64> {
    let refined = inner.refine(*photo);
    (pose.r_cam_world().transpose() * Vector3::new(refined.x, refined.y, -inner.f)).normalize()
}

/// The least-squares intersection of the rays of a point from posed images (None with fewer
/// than two or parallel rays).
pub fn intersect(
    inner: &InnerOrientation<f64>,
    poses: &[Option<ExteriorOrientation<f64>>],
    rays: impl Iterator<Item = (usize, Vector2<f64>)>,
) -> Option<Vector3<f64>> {
    let (mut n, mut rhs, mut count) = (Matrix3::zeros(), Vector3::zeros(), 0);
    for (image, photo) in rays {
        if let Some(pose) = &poses[image] {
            let d = ray(inner, pose, &photo);
            let p = Matrix3::identity() - d * d.transpose();
            n += p;
            rhs += p * pose.centre;
            count += 1;
        }
    }
    if count < 2 {
        return None;
    }
    let x = n.try_inverse()? * rhs;
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Relative orientation of image 1 with respect to image 0 (at the origin, R = I) from their
/// common points' normalised coordinates: (R, centre of image 1), baseline [`BASELINE_MM`].
fn relative_orientation(
    inner: &InnerOrientation<f64>,
    pairs: &[(Vector2<f64>, Vector2<f64>)],
) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    // Homogeneous camera-system directions x ∝ (u, v, 1); x2ᵀ E x1 = 0 with E = [t]× R.
    let h = |p: &Vector2<f64>| {
        let r = inner.refine(*p);
        Vector3::new(-r.x / inner.f, -r.y / inner.f, 1.0)
    };
    let mut a = DMatrix::zeros(pairs.len(), 9);
    for (i, (p1, p2)) in pairs.iter().enumerate() {
        let (x1, x2) = (h(p1), h(p2));
        for r in 0..3 {
            for c in 0..3 {
                a[(i, 3 * r + c)] = x2[r] * x1[c];
            }
        }
    }
    let eig = (a.transpose() * a).symmetric_eigen();
    let k = eig.eigenvalues.imin();
    let e = Matrix3::from_row_slice(eig.eigenvectors.column(k).as_slice());
    let svd = e.svd(true, true);
    let (mut u, mut vt) = (svd.u?, svd.v_t?);
    if u.determinant() < 0.0 {
        u = -u;
    }
    if vt.determinant() < 0.0 {
        vt = -vt;
    }
    let w = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let t = u.column(2).into_owned();
    let mut best = None;
    let mut best_count = 0;
    for r in [u * w * vt, u * w.transpose() * vt] {
        for t in [t, -t] {
            // Camera 2: x2 = R x1 + t; camera 1 at the origin. Count points in front of both
            // (the cameras look along −z: depth λ < 0 in x = λ (u, v, 1)).
            let count = pairs
                .iter()
                .filter(|(p1, p2)| {
                    let (d1, d2) = (h(p1), h(p2));
                    // λ1 R d1 + t = λ2 d2  →  [R d1, −d2] (λ1, λ2)ᵀ = −t
                    let m = nalgebra::Matrix3x2::from_columns(&[r * d1, -d2]);
                    let Some(inv) = (m.transpose() * m).try_inverse() else {
                        return false;
                    };
                    let l = inv * m.transpose() * -t;
                    l[0] < 0.0 && l[1] < 0.0
                })
                .count();
            if count > best_count {
                best_count = count;
                best = Some((r, -r.transpose() * t * BASELINE_MM));
            }
        }
    }
    best
}

/// Poses for every image without control (see the module docs); errors name the image.
pub fn initial_poses(
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    images: &[String],
    num_points: usize,
    seen: &[Seen],
) -> anyhow::Result<Vec<ExteriorOrientation<f64>>> {
    let in_image = |i: usize| -> Vec<(usize, Vector2<f64>)> {
        seen.iter()
            .filter(|s| s.0 == i)
            .map(|s| (s.1, s.2))
            .collect()
    };
    let first = in_image(0);
    let partner = (1..images.len())
        .max_by_key(|&i| {
            in_image(i)
                .iter()
                .filter(|(p, _)| first.iter().any(|(q, _)| q == p))
                .count()
        })
        .ok_or_else(|| anyhow::anyhow!("a free network needs at least two images"))?;
    let pairs: Vec<(Vector2<f64>, Vector2<f64>)> = in_image(partner)
        .iter()
        .filter_map(|(p, b)| first.iter().find(|(q, _)| q == p).map(|(_, a)| (*a, *b)))
        .collect();
    if pairs.len() < 8 {
        anyhow::bail!(
            "images {:?} and {:?} share {} points: a free network (no control) needs 8",
            images[0],
            images[partner],
            pairs.len()
        );
    }
    let (r, centre) = relative_orientation(inner, &pairs).ok_or_else(|| {
        anyhow::anyhow!(
            "relative orientation of {:?} and {:?} failed",
            images[0],
            images[partner]
        )
    })?;
    let (kappa, phi, omega) = angles_from_matrix(&r);
    let mut poses: Vec<Option<ExteriorOrientation<f64>>> = vec![None; images.len()];
    poses[0] = Some(ExteriorOrientation {
        kappa: 0.0,
        phi: 0.0,
        omega: 0.0,
        centre: Vector3::zeros(),
    });
    poses[partner] = Some(ExteriorOrientation {
        kappa,
        phi,
        omega,
        centre,
    });
    loop {
        let xyz: Vec<Option<Vector3<f64>>> = (0..num_points)
            .map(|j| {
                intersect(
                    inner,
                    &poses,
                    seen.iter().filter(|s| s.1 == j).map(|s| (s.0, s.2)),
                )
            })
            .collect();
        // The unposed image that sees the most intersected points.
        let known = |i: usize| {
            in_image(i)
                .iter()
                .filter(|(p, _)| xyz[*p].is_some())
                .count()
        };
        let Some(next) = (0..images.len())
            .filter(|&i| poses[i].is_none())
            .max_by_key(|&i| known(i))
        else {
            return Ok(poses.into_iter().flatten().collect());
        };
        let pts: Vec<(Vector2<f64>, Vector3<f64>)> = in_image(next)
            .iter()
            .filter_map(|(p, photo)| {
                let (col, row) = grid.photo_to_pixel(*photo);
                xyz[*p].map(|x| (Vector2::new(col, row), x))
            })
            .collect();
        let result = resect(grid, inner, &pts).map_err(|e| {
            anyhow::anyhow!(
                "image {:?}: cannot resect on the free network: {e}",
                images[next]
            )
        })?;
        poses[next] = Some(result.exterior);
    }
}
