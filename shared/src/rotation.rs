//! Eq. (2): the rotation matrix R = M_z(κ) M_y(φ) M_x(ω).

use nalgebra::{Matrix3, RealField};

/// Eq. (2): R = M_z(κ) M_y(φ) M_x(ω), mapping world vectors into the camera system
/// (`x_cam = R (X − X0)`):
///
/// ```text
/// [  cosφ cosκ    cosω sinκ + sinω sinφ cosκ    sinω sinκ − cosω sinφ cosκ ]
/// [ −cosφ sinκ    cosω cosκ − sinω sinφ sinκ    sinω cosκ + cosω sinφ sinκ ]
/// [  sinφ        −sinω cosφ                     cosω cosφ                  ]
/// ```
pub fn rotation_matrix<T: RealField + Copy>(kappa: T, phi: T, omega: T) -> Matrix3<T> {
    let (sk, ck) = kappa.sin_cos();
    let (sp, cp) = phi.sin_cos();
    let (so, co) = omega.sin_cos();
    Matrix3::new(
        cp * ck,
        co * sk + so * sp * ck,
        so * sk - co * sp * ck,
        -cp * sk,
        co * ck - so * sp * sk,
        so * ck + co * sp * sk,
        sp,
        -so * cp,
        co * cp,
    )
}

/// The angles (κ, φ, ω) of a rotation matrix of the form of eq. (2) (φ in [−π/2, π/2]).
pub fn angles_from_matrix<T: RealField + Copy>(r: &Matrix3<T>) -> (T, T, T) {
    let phi = r[(2, 0)].clamp(-T::one(), T::one()).asin();
    let kappa = (-r[(1, 0)]).atan2(r[(0, 0)]);
    let omega = (-r[(2, 1)]).atan2(r[(2, 2)]);
    (kappa, phi, omega)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn is_mz_my_mx() {
        let (k, p, o): (f64, f64, f64) = (0.3, -0.2, 0.1);
        let mx = Matrix3::new(1.0, 0.0, 0.0, 0.0, o.cos(), o.sin(), 0.0, -o.sin(), o.cos());
        let my = Matrix3::new(p.cos(), 0.0, -p.sin(), 0.0, 1.0, 0.0, p.sin(), 0.0, p.cos());
        let mz = Matrix3::new(k.cos(), k.sin(), 0.0, -k.sin(), k.cos(), 0.0, 0.0, 0.0, 1.0);
        assert!((rotation_matrix(k, p, o) - mz * my * mx).norm() < 1e-15);
    }

    #[test]
    fn angles_round_trip() {
        let r = rotation_matrix(0.013301_f64, 0.01418, -0.026);
        let (k, p, o) = angles_from_matrix(&r);
        assert!((k - 0.013301).abs() < 1e-15 && (p - 0.01418).abs() < 1e-15);
        assert!((o + 0.026).abs() < 1e-15);
        assert!((r * r.transpose() - Matrix3::identity()).norm() < 1e-15);
    }

    /// Table 3: the projector centre in the camera system is R (X_global − X0) with the 1st plane's
    /// exterior orientation of Table 2.
    #[test]
    fn table3_projector_centre_in_camera_system() {
        use crate::paper::{table2_exterior, TABLE3_CAMERA, TABLE3_GLOBAL};
        let cam = table2_exterior(0).world_to_camera(&Vector3::from(TABLE3_GLOBAL));
        let table3 = Vector3::from(TABLE3_CAMERA);
        assert!((cam - table3).amax() < 0.01, "{cam} vs {table3}");
    }
}
