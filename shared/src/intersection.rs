//! Intersection of the camera ray with a projector ray: the paper's λ (eqs 8, 9) and a
//! least-squares closest approach that uses all three coordinates.

use crate::projector::Ray;
use crate::{sqrt, Error, Result};
use nalgebra::{RealField, Vector3};

/// A reconstructed point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intersection<T: RealField> {
    /// The point (mm): the average of the camera-ray and projector-ray points.
    pub point: Vector3<T>,
    /// λ: the camera ray's parameter (eq. 6).
    pub lambda: T,
    /// λp: the projector ray's parameter (eq. 5).
    pub lambda_p: T,
    /// Distance between the two points averaged (mm): how far the rays miss each other.
    pub miss: T,
}

/// `a > b`, false when either is NaN (so NaN input counts as degenerate).
fn exceeds<T: RealField + Copy>(a: T, b: T) -> bool {
    a.partial_cmp(&b) == Some(core::cmp::Ordering::Greater)
}

/// Whether two directions are far enough from parallel: the sine of their angle, |a × b| /
/// (|a| |b|), is above √ε of the scalar (1.5e-8 for f64, 3.5e-4 for f32), compared squared
/// (`cross2` = |a × b|², `lengths2` = |a|² |b|²: no square root). NaN is degenerate.
fn not_parallel<T: RealField + Copy>(cross2: T, lengths2: T) -> bool {
    exceeds(cross2, T::default_epsilon() * lengths2)
}

/// Eqs (8) and (9): λ and λp from the X and Z equations of eqs (5) and (6),
///
/// ```text
/// λ  = ((X_p − X0)·n − (Z_p − Z0)·l) / (n·u − w·l)          (8)
/// λp = ((X_p − X0)·w − (Z_p − Z0)·u) / (n·u − w·l)          (9)
/// ```
///
/// with `camera` = (X0, (u, v, w)) and `projector` = (X_p, (l, m, n)). Returns
/// [`Error::DegenerateXZ`] when n·u − w·l vanishes (relative to the XZ lengths of both
/// directions), as it does for every point of a rig whose baseline lies along Y.
pub fn lambdas_eq8_eq9<T: RealField + Copy>(camera: &Ray<T>, projector: &Ray<T>) -> Result<(T, T)> {
    let (u, w) = (camera.direction.x, camera.direction.z);
    let (l, n) = (projector.direction.x, projector.direction.z);
    let denominator = n * u - w * l;
    if !not_parallel(denominator * denominator, (u * u + w * w) * (l * l + n * n)) {
        return Err(Error::DegenerateXZ);
    }
    let d = projector.point - camera.point;
    let lambda = (d.x * n - d.z * l) / denominator;
    let lambda_p = (d.x * w - d.z * u) / denominator;
    Ok((lambda, lambda_p))
}

/// The paper's intersection (section 2): λ from eq. (8) into eq. (4)/(6), λp from eq. (9) into
/// eq. (5), and the average of the two points. `miss` is their distance (only Y differs).
pub fn intersect_paper<T: RealField + Copy>(
    camera: &Ray<T>,
    projector: &Ray<T>,
) -> Result<Intersection<T>> {
    let (lambda, lambda_p) = lambdas_eq8_eq9(camera, projector)?;
    Ok(average(camera, projector, lambda, lambda_p))
}

/// Least-squares closest approach: the λ, λp minimising |X0 + λ(u, v, w) − X_p − λp(l, m, n)|²
/// over all three coordinates,
///
/// ```text
/// λ  = ((X_p − X0) × d_p) · (d_c × d_p) / |d_c × d_p|²
/// λp = ((X_p − X0) × d_c) · (d_c × d_p) / |d_c × d_p|²
/// ```
///
/// and the midpoint of the two closest points; `miss` is the rays' distance. Returns
/// [`Error::DegenerateGeometry`] when the rays are nearly parallel (sine of their angle below
/// √ε of the scalar).
#[inline]
pub fn closest_approach<T: RealField + Copy>(
    camera: &Ray<T>,
    projector: &Ray<T>,
) -> Result<Intersection<T>> {
    let (lambda, lambda_p) = closest_lambdas(camera, projector)?;
    Ok(average(camera, projector, lambda, lambda_p))
}

/// λ and λp of [`closest_approach`] alone.
#[inline]
pub fn closest_lambdas<T: RealField + Copy>(camera: &Ray<T>, projector: &Ray<T>) -> Result<(T, T)> {
    let normal = camera.direction.cross(&projector.direction);
    let n2 = normal.norm_squared();
    let lengths2 = camera.direction.norm_squared() * projector.direction.norm_squared();
    if !not_parallel(n2, lengths2) {
        return Err(Error::DegenerateGeometry);
    }
    let d = projector.point - camera.point;
    let lambda = d.cross(&projector.direction).dot(&normal) / n2;
    let lambda_p = d.cross(&camera.direction).dot(&normal) / n2;
    Ok((lambda, lambda_p))
}

/// The paper's intersection given λ (a device's answer): λp from the X and Z equations of
/// eqs (5), (6) in the least-squares sense, which is eq. (9)'s λp when λ is eq. (8)'s.
pub fn paper_at<T: RealField + Copy>(
    camera: &Ray<T>,
    projector: &Ray<T>,
    lambda: T,
) -> Result<Intersection<T>> {
    let (l, n) = (projector.direction.x, projector.direction.z);
    let d = camera.at(lambda) - projector.point;
    let ln2 = l * l + n * n;
    if !exceeds(ln2, T::zero()) {
        return Err(Error::DegenerateXZ);
    }
    Ok(average(
        camera,
        projector,
        lambda,
        (d.x * l + d.z * n) / ln2,
    ))
}

/// The closest approach given λ (a device's answer): λp of the projector ray's point nearest
/// the camera ray's point at λ, which is the common perpendicular's foot when λ is its.
pub fn closest_approach_at<T: RealField + Copy>(
    camera: &Ray<T>,
    projector: &Ray<T>,
    lambda: T,
) -> Result<Intersection<T>> {
    let p2 = projector.direction.norm_squared();
    if !exceeds(p2, T::zero()) {
        return Err(Error::DegenerateGeometry);
    }
    let d = camera.at(lambda) - projector.point;
    Ok(average(
        camera,
        projector,
        lambda,
        d.dot(&projector.direction) / p2,
    ))
}

fn average<T: RealField + Copy>(
    camera: &Ray<T>,
    projector: &Ray<T>,
    lambda: T,
    lambda_p: T,
) -> Intersection<T> {
    let on_camera = camera.at(lambda);
    let on_projector = projector.at(lambda_p);
    let half: T = nalgebra::convert(0.5);
    Intersection {
        point: (on_camera + on_projector) * half,
        lambda,
        lambda_p,
        miss: sqrt((on_camera - on_projector).norm_squared()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rays(
        point: Vector3<f64>,
        cam_origin: Vector3<f64>,
        proj_origin: Vector3<f64>,
    ) -> (Ray<f64>, Ray<f64>) {
        let cam = Ray {
            point: cam_origin,
            direction: (point - cam_origin) * 0.03,
        };
        let proj = Ray {
            point: proj_origin,
            direction: (point - proj_origin).normalize(),
        };
        (cam, proj)
    }

    #[test]
    fn both_methods_recover_a_point() {
        use crate::paper::{table2_exterior, TABLE3_GLOBAL};
        let x = Vector3::new(300.0, 350.0, 200.0);
        let (cam, proj) = rays(x, table2_exterior(0).centre, Vector3::from(TABLE3_GLOBAL));
        for hit in [
            intersect_paper(&cam, &proj).unwrap(),
            closest_approach(&cam, &proj).unwrap(),
        ] {
            assert!((hit.point - x).norm() < 1e-9);
            assert!(hit.miss < 1e-9);
            assert!((cam.at(hit.lambda) - x).norm() < 1e-9);
            assert!((proj.at(hit.lambda_p) - x).norm() < 1e-9);
        }
    }

    #[test]
    fn skew_rays_report_their_distance() {
        let cam = Ray {
            point: Vector3::zeros(),
            direction: Vector3::new(0.0, 0.0, -1.0),
        };
        let proj = Ray {
            point: Vector3::new(100.0, 0.7, 0.0),
            direction: Vector3::new(-1.0, 0.0, -1.0),
        };
        let hit = closest_approach(&cam, &proj).unwrap();
        assert!((hit.miss - 0.7_f64).abs() < 1e-12);
        assert!((hit.point - Vector3::new(0.0, 0.35, -100.0)).norm() < 1e-12);
    }

    /// A rig whose baseline lies along Y: eq. (8) is singular, the closest approach is not.
    #[test]
    fn y_baseline_rig() {
        let x = Vector3::new(40.0, -25.0, -1500.0);
        let (cam, proj) = rays(x, Vector3::zeros(), Vector3::new(0.0, 400.0, 0.0));
        assert_eq!(intersect_paper(&cam, &proj), Err(Error::DegenerateXZ));
        let hit = closest_approach(&cam, &proj).unwrap();
        assert!((hit.point - x).norm() < 1e-9);
    }

    #[test]
    fn parallel_and_nan_rays_are_errors() {
        let cam = Ray {
            point: Vector3::zeros(),
            direction: Vector3::new(0.1, 0.0, -1.0),
        };
        let proj = Ray {
            point: Vector3::new(100.0, 0.0, 0.0),
            direction: Vector3::new(0.1, 0.0, -1.0),
        };
        assert_eq!(
            closest_approach(&cam, &proj),
            Err(Error::DegenerateGeometry)
        );
        assert_eq!(intersect_paper(&cam, &proj), Err(Error::DegenerateXZ));
        let nan = Ray {
            direction: Vector3::new(f64::NAN, 0.0, -1.0),
            ..proj
        };
        assert_eq!(closest_approach(&cam, &nan), Err(Error::DegenerateGeometry));
        assert_eq!(intersect_paper(&cam, &nan), Err(Error::DegenerateXZ));
    }
}
