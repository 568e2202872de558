//! The image observation residual and its analytic Jacobian.
//!
//! Camera model: eq. (1) with the refinement of `shared::camera` applied to the observation
//! (Brown-Conrady, the close-range convention of Fraser):
//!
//! ```text
//! x_cam = R(κ, φ, ω) (X − X0)                                   eq. (2), (3)
//! x̄ = x_obs − cx,  ȳ = y_obs − cy                              observed photo coordinates (mm)
//! refined = (x̄, ȳ) + Δ(x̄, ȳ; k1, k2, k3, p1, p2)
//! v = refined − (−f x_cam / z_cam, −f y_cam / z_cam)             residual (mm), eq. (1)
//! ```
//!
//! Parameter blocks: inner [f, cx, cy, k1, k2, k3, p1, p2], pose [κ, φ, ω, X0, Y0, Z0],
//! point [X, Y, Z].

use deltaz_shared::camera::InnerOrientation;
use deltaz_shared::collinearity::ExteriorOrientation;
use nalgebra::{Matrix2x3, Matrix3, SMatrix, Vector2, Vector3};

/// The inner block's size.
pub const INNER: usize = 8;
/// The pose block's size.
pub const POSE: usize = 6;

/// The inner parameters' names, in the order of [`inner_to_array`].
pub const INNER_NAMES: [&str; INNER] = ["f", "cx", "cy", "k1", "k2", "k3", "p1", "p2"];

/// The inner parameters in the order f, cx, cy, k1, k2, k3, p1, p2.
pub fn inner_to_array(p: &InnerOrientation<f64>) -> [f64; INNER] {
    [p.f, p.cx, p.cy, p.k1, p.k2, p.k3, p.p1, p.p2]
}

/// The inner orientation from values in the order of [`INNER_NAMES`].
pub fn inner_from_array(a: [f64; INNER]) -> InnerOrientation<f64> {
    let [f, cx, cy, k1, k2, k3, p1, p2] = a;
    InnerOrientation {
        f,
        cx,
        cy,
        k1,
        k2,
        k3,
        p1,
        p2,
    }
}

/// A residual's value and its derivatives by parameter block.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageResidual {
    /// v (mm): refined observation minus projection.
    pub value: Vector2<f64>,
    /// ∂v/∂[f, cx, cy, k1, k2, k3, p1, p2].
    pub d_inner: SMatrix<f64, 2, INNER>,
    /// ∂v/∂[κ, φ, ω, X0, Y0, Z0].
    pub d_pose: SMatrix<f64, 2, POSE>,
    /// ∂v/∂[X, Y, Z].
    pub d_point: Matrix2x3<f64>,
    /// z of the point in the camera system (negative in front of the camera).
    pub z_cam: f64,
}

/// The elementary rotations of eq. (2) and their derivatives: (M, dM/dangle).
fn elementary(angle: f64, axis: usize) -> (Matrix3<f64>, Matrix3<f64>) {
    let (s, c) = angle.sin_cos();
    match axis {
        // M_x(ω)
        0 => (
            Matrix3::new(1.0, 0.0, 0.0, 0.0, c, s, 0.0, -s, c),
            Matrix3::new(0.0, 0.0, 0.0, 0.0, -s, c, 0.0, -c, -s),
        ),
        // M_y(φ)
        1 => (
            Matrix3::new(c, 0.0, -s, 0.0, 1.0, 0.0, s, 0.0, c),
            Matrix3::new(-s, 0.0, -c, 0.0, 0.0, 0.0, c, 0.0, -s),
        ),
        // M_z(κ)
        _ => (
            Matrix3::new(c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0),
            Matrix3::new(-s, c, 0.0, -c, -s, 0.0, 0.0, 0.0, 0.0),
        ),
    }
}

/// R = M_z(κ) M_y(φ) M_x(ω) and its derivatives with respect to κ, φ, ω.
pub fn rotation_and_derivatives(
    pose: &ExteriorOrientation<f64>,
) -> (Matrix3<f64>, [Matrix3<f64>; 3]) {
    let (mz, dz) = elementary(pose.kappa, 2);
    let (my, dy) = elementary(pose.phi, 1);
    let (mx, dx) = elementary(pose.omega, 0);
    (mz * my * mx, [dz * my * mx, mz * dy * mx, mz * my * dx])
}

/// The residual of one observation (observed photo coordinates, mm) and its Jacobian.
pub fn image_residual(
    inner: &InnerOrientation<f64>,
    observed: &Vector2<f64>,
    pose: &ExteriorOrientation<f64>,
    point: &Vector3<f64>,
) -> ImageResidual {
    let (r, dr) = rotation_and_derivatives(pose);
    let d = point - pose.centre;
    let cam = r * d;
    let (f, z) = (inner.f, cam.z);
    let projection = Vector2::new(-f * cam.x / z, -f * cam.y / z);
    let reduced = observed - Vector2::new(inner.cx, inner.cy);
    let refined = reduced + inner.distortion(reduced);
    let value = refined - projection;

    let (x, y) = (reduced.x, reduced.y);
    let r2 = x * x + y * y;
    let jr = inner.refine_jacobian(reduced);
    let mut d_inner = SMatrix::<f64, 2, INNER>::zeros();
    d_inner.set_column(0, &Vector2::new(cam.x / z, cam.y / z));
    d_inner.set_column(1, &-jr.column(0));
    d_inner.set_column(2, &-jr.column(1));
    d_inner.set_column(3, &(reduced * r2));
    d_inner.set_column(4, &(reduced * r2 * r2));
    d_inner.set_column(5, &(reduced * r2 * r2 * r2));
    d_inner.set_column(6, &Vector2::new(r2 + 2.0 * x * x, 2.0 * x * y));
    d_inner.set_column(7, &Vector2::new(2.0 * x * y, r2 + 2.0 * y * y));

    // ∂v/∂x_cam = −∂projection/∂x_cam
    let dv_dcam = Matrix2x3::new(
        f / z,
        0.0,
        -f * cam.x / (z * z),
        0.0,
        f / z,
        -f * cam.y / (z * z),
    );
    let mut d_pose = SMatrix::<f64, 2, POSE>::zeros();
    for (k, dri) in dr.iter().enumerate() {
        d_pose.set_column(k, &(dv_dcam * (dri * d)));
    }
    let d_point = dv_dcam * r;
    d_pose.fixed_columns_mut::<3>(3).copy_from(&-d_point);
    ImageResidual {
        value,
        d_inner,
        d_pose,
        d_point,
        z_cam: z,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use deltaz_shared::rotation::rotation_matrix;

    fn setup() -> (
        InnerOrientation<f64>,
        Vector2<f64>,
        ExteriorOrientation<f64>,
        Vector3<f64>,
    ) {
        let inner = InnerOrientation {
            f: 46.981,
            cx: -0.133,
            cy: 0.208,
            k1: 6.3e-5,
            k2: -2e-8,
            k3: 1e-11,
            p1: 2e-5,
            p2: -1.5e-5,
        };
        let pose = ExteriorOrientation {
            kappa: 0.3,
            phi: -0.2,
            omega: 0.15,
            centre: Vector3::new(375.0, 364.0, 1842.0),
        };
        (
            inner,
            Vector2::new(9.5, -6.25),
            pose,
            Vector3::new(310.0, 83.0, 200.0),
        )
    }

    #[test]
    fn rotation_matches_eq2() {
        let (_, _, pose, _) = setup();
        let (r, _) = rotation_and_derivatives(&pose);
        let expect = rotation_matrix(pose.kappa, pose.phi, pose.omega);
        assert!((r - expect).norm() < 1e-15);
    }

    /// Every column of the analytic Jacobian agrees with central differences.
    #[test]
    fn jacobian_matches_finite_differences() {
        let (inner, obs, pose, point) = setup();
        let res = image_residual(&inner, &obs, &pose, &point);
        let value = |i: &InnerOrientation<f64>, p: &ExteriorOrientation<f64>, x: &Vector3<f64>| {
            image_residual(i, &obs, p, x).value
        };
        let mut worst = 0.0_f64;
        for k in 0..INNER {
            let mut a = inner_to_array(&inner);
            let h = 1e-6 * a[k].abs().max(1e-7);
            a[k] += h;
            let up = inner_from_array(a);
            a[k] -= 2.0 * h;
            let down = inner_from_array(a);
            let num = (value(&up, &pose, &point) - value(&down, &pose, &point)) / (2.0 * h);
            let scale = res.d_inner.column(k).norm().max(1.0);
            worst = worst.max((num - res.d_inner.column(k)).norm() / scale);
        }
        for k in 0..POSE {
            let mut a = [
                pose.kappa,
                pose.phi,
                pose.omega,
                pose.centre.x,
                pose.centre.y,
                pose.centre.z,
            ];
            let h = if k < 3 { 1e-7 } else { 1e-4 };
            let make = |a: [f64; 6]| ExteriorOrientation {
                kappa: a[0],
                phi: a[1],
                omega: a[2],
                centre: Vector3::new(a[3], a[4], a[5]),
            };
            a[k] += h;
            let up = make(a);
            a[k] -= 2.0 * h;
            let down = make(a);
            let num = (value(&inner, &up, &point) - value(&inner, &down, &point)) / (2.0 * h);
            let scale = res.d_pose.column(k).norm().max(1e-3);
            worst = worst.max((num - res.d_pose.column(k)).norm() / scale);
        }
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = 1e-4;
            let num =
                (value(&inner, &pose, &(point + d)) - value(&inner, &pose, &(point - d))) / 2e-4;
            worst = worst.max((num - res.d_point.column(k)).norm() / res.d_point.column(k).norm());
        }
        assert!(worst < 1e-6, "worst relative Jacobian error {worst}");
    }

    /// The residual vanishes for the exact observation of a point.
    #[test]
    fn zero_for_exact_observation() {
        let (inner, _, pose, point) = setup();
        let cam = pose.world_to_camera(&point);
        let refined = deltaz_shared::collinearity::project_camera_point(inner.f, &cam).unwrap();
        let observed = inner.unrefine(refined).unwrap();
        let res = image_residual(&inner, &observed, &pose, &point);
        assert!(res.value.norm() < 1e-12 && res.z_cam < 0.0);
    }
}
