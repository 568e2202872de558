//! The perspective-three-point pose (Lambda Twist, Persson & Nordberg, ECCV 2018): the camera
//! poses that put three control points on their three bearings, up to four.
//!
//! With depths Λ = (λ1, λ2, λ3) along the unit bearings y_i, the distances give three quadrics
//! Λᵀ M_ij Λ = |x_i − x_j|² = a_ij (M_ij: λ_i² + λ_j² − 2 (y_i·y_j) λ_i λ_j). Two homogeneous
//! combinations D1 = a23 M12 − a12 M23 and D2 = a23 M13 − a13 M23 vanish on Λ, and so does every
//! member of their pencil; a singular member D0 (a root of the cubic det(D1 + γ D2) = 0) is
//! indefinite of rank 2, so its zero set is two planes through the origin. In each plane D1 (or
//! D2) leaves a quadratic in the ratio of two coordinates, and M12 gives the scale. The pose
//! follows from the three points in the camera system, λ_i y_i.

use super::nearest_rotation;
use nalgebra::{Matrix3, Vector3};

/// The poses (R, X0; x_cam = R (X − X0)) that put the points `world` on the unit `bearings`
/// (pointing from the camera to the points) at positive depths.
pub(super) fn p3p(
    bearings: &[Vector3<f64>; 3],
    world: &[Vector3<f64>; 3],
) -> Vec<(Matrix3<f64>, Vector3<f64>)> {
    let [y1, y2, y3] = bearings;
    let a12 = (world[0] - world[1]).norm_squared();
    let a13 = (world[0] - world[2]).norm_squared();
    let a23 = (world[1] - world[2]).norm_squared();
    let quadric = |i: usize, j: usize, c: f64| {
        let mut m = Matrix3::zeros();
        m[(i, i)] = 1.0;
        m[(j, j)] = 1.0;
        m[(i, j)] = -c;
        m[(j, i)] = -c;
        m
    };
    let m12 = quadric(0, 1, y1.dot(y2));
    let m13 = quadric(0, 2, y1.dot(y3));
    let m23 = quadric(1, 2, y2.dot(y3));
    let d1 = m12 * a23 - m23 * a12;
    let d2 = m13 * a23 - m23 * a13;
    // det(D1 + γ D2) = c3 γ³ + c2 γ² + c1 γ + c0, from its values at γ = 0, ±1 and ∞.
    let (c0, c3) = (d1.determinant(), d2.determinant());
    let (up, down) = ((d1 + d2).determinant(), (d1 - d2).determinant());
    let (c2, c1) = ((up + down) / 2.0 - c0, (up - down) / 2.0 - c3);
    // The singular members, monic in γ (D1 + γ D2) or in 1/γ (D1 / γ + D2), whichever is better
    // scaled.
    let singular: Vec<Matrix3<f64>> = if c3.abs() >= c0.abs() && c3 != 0.0 {
        real_cubic_roots(c2 / c3, c1 / c3, c0 / c3)
            .into_iter()
            .map(|g| d1 + d2 * g)
            .collect()
    } else if c0 != 0.0 {
        real_cubic_roots(c1 / c0, c2 / c0, c3 / c0)
            .into_iter()
            .map(|g| d1 * g + d2)
            .collect()
    } else {
        return Vec::new();
    };
    // Every singular member holds every solution: the first indefinite one is enough.
    let Some((s, [e1, e2, e3])) = singular.iter().find_map(|d0| {
        let eig = d0.symmetric_eigen();
        let mut order = [0, 1, 2];
        order.sort_by(|&a, &b| {
            eig.eigenvalues[b]
                .abs()
                .total_cmp(&eig.eigenvalues[a].abs())
        });
        let [s1, s2] = [order[0], order[1]].map(|k| eig.eigenvalues[k]);
        let axes = order.map(|k| eig.eigenvectors.column(k).into_owned());
        (s1 * s2 <= 0.0 && s1 != 0.0).then(|| ((-s2 / s1).sqrt(), axes))
    }) else {
        return Vec::new();
    };
    let mut poses = Vec::new();
    for normal in [e1 - e2 * s, e1 + e2 * s] {
        // Λ = α u + β w in the plane Λ · normal = 0.
        let (u, w) = (normal.cross(&e3).normalize(), e3);
        let restrict = |d: &Matrix3<f64>| (u.dot(&(d * u)), u.dot(&(d * w)), w.dot(&(d * w)));
        let (r1, r2) = (restrict(&d1), restrict(&d2));
        let norm = |(a, b, c): (f64, f64, f64)| a * a + 2.0 * b * b + c * c;
        let (a, b, c) = if norm(r1) >= norm(r2) { r1 } else { r2 };
        let disc = b * b - a * c;
        if disc < 0.0 {
            continue;
        }
        for root in [-b + disc.sqrt(), -b - disc.sqrt()] {
            let v = if a.abs() >= c.abs() {
                u * (root / a) + w
            } else {
                u + w * (root / c)
            };
            let q = v.dot(&(m12 * v));
            if q.is_nan() || q <= 0.0 {
                continue;
            }
            let mut depths = v * (a12 / q).sqrt();
            if depths.sum() < 0.0 {
                depths = -depths;
            }
            if depths.iter().all(|d| *d > 0.0) {
                poses.push(pose(bearings, world, &depths));
            }
        }
    }
    poses
}

/// The pose that maps the world points onto the camera-system points λ_i y_i: R from the two
/// edges from the first point and their cross product (nearest rotation), then X0.
fn pose(
    bearings: &[Vector3<f64>; 3],
    world: &[Vector3<f64>; 3],
    depths: &Vector3<f64>,
) -> (Matrix3<f64>, Vector3<f64>) {
    let p: [Vector3<f64>; 3] = std::array::from_fn(|i| bearings[i] * depths[i]);
    let frame = |x: &[Vector3<f64>; 3]| {
        let (a, b) = (x[1] - x[0], x[2] - x[0]);
        Matrix3::from_columns(&[a, b, a.cross(&b)])
    };
    let inverse = frame(world).try_inverse().unwrap_or_else(Matrix3::zeros);
    let (r, _) = nearest_rotation(&(frame(&p) * inverse));
    (r, world[0] - r.transpose() * p[0])
}

/// The real roots of x³ + a x² + b x + c (the companion matrix's real eigenvalues, polished by
/// Newton's method).
fn real_cubic_roots(a: f64, b: f64, c: f64) -> Vec<f64> {
    let companion = Matrix3::new(-a, -b, -c, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0);
    let f = |x: f64| ((x + a) * x + b) * x + c;
    let df = |x: f64| (3.0 * x + 2.0 * a) * x + b;
    companion
        .complex_eigenvalues()
        .iter()
        .filter(|z| z.im.abs() <= 1e-6 * (1.0 + z.re.abs()))
        .map(|z| {
            let mut x = z.re;
            for _ in 0..3 {
                let d = df(x);
                if d != 0.0 {
                    x -= f(x) / d;
                }
            }
            x
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use deltaz_shared::rotation::rotation_matrix;

    /// Exact bearings of three points from a known pose: one of the solutions is that pose.
    #[test]
    fn recovers_the_pose_among_its_solutions() {
        let r = rotation_matrix(0.4, -0.3, 0.2);
        let centre = Vector3::new(30.0, -20.0, 500.0);
        for world in [
            [
                Vector3::new(0.0, 0.0, 0.0),
                Vector3::new(120.0, 10.0, 0.0),
                Vector3::new(-20.0, 90.0, 40.0),
            ],
            [
                Vector3::new(-50.0, 0.0, 0.0),
                Vector3::new(50.0, 0.0, 0.0),
                Vector3::new(0.0, 0.0, 120.0),
            ],
        ] {
            let bearings = world.map(|x| (r * (x - centre)).normalize());
            let poses = p3p(&bearings, &world);
            assert!(!poses.is_empty() && poses.len() <= 4, "{}", poses.len());
            let best = poses
                .iter()
                .map(|(rr, c)| (rr - r).amax().max((c - centre).amax() / 500.0))
                .fold(f64::INFINITY, f64::min);
            assert!(best < 1e-9, "{best}");
        }
    }
}
