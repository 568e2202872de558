//! Accuracy assessment (section 6.2.3): reconstructed points against reference points.
//!
//! - The 7-parameter similarity of Table 6, `reconstructed = λ R(κ, φ, ω) (reference − T)`, fitted
//!   by least squares with the residuals on the reconstructed side (closed form, Umeyama 1991).
//! - Table 7: the reconstructed points carried into the reference frame, `Rᵀ reconstructed / λ + T`,
//!   the fit's residuals `v = λ R (reference − T) − reconstructed` (observation + v = model), and
//!   the "MSE" row, the per-axis sample standard deviation `sqrt(Σ v² / (n − 1))`.
//! - Beyond the paper: the absolute errors `reconstructed − reference` with no fit at all, and the
//!   flatness, the RMS distance of the reconstructed points from their best-fitting plane.

use anyhow::{bail, Context, Result};
use deltaz_shared::rotation::{angles_from_matrix, rotation_matrix};
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;

/// Table 6: `reconstructed = λ R(κ, φ, ω) (reference − T)`, T = (Xc, Yc, Zc).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Similarity {
    /// κ (rad).
    pub kappa: f64,
    /// φ (rad).
    pub phi: f64,
    /// ω (rad).
    pub omega: f64,
    /// T = (Xc, Yc, Zc) (mm), in the reference frame.
    pub translation: Vector3<f64>,
    /// λ, the scale.
    pub scale: f64,
}

impl Similarity {
    /// R(κ, φ, ω) of eq. (2).
    pub fn rotation(&self) -> Matrix3<f64> {
        rotation_matrix(self.kappa, self.phi, self.omega)
    }

    /// A reference point carried to the reconstructed side: λ R (reference − T).
    pub fn forward(&self, reference: &Vector3<f64>) -> Vector3<f64> {
        self.rotation() * (reference - self.translation) * self.scale
    }

    /// A reconstructed point carried into the reference frame (Table 7): Rᵀ reconstructed / λ + T.
    pub fn inverse(&self, reconstructed: &Vector3<f64>) -> Vector3<f64> {
        self.rotation().transpose() * reconstructed / self.scale + self.translation
    }
}

/// Least-squares similarity between matched point lists, minimising
/// Σ |reconstructed − λ R (reference − T)|² (Umeyama's closed form: the SVD of the cross
/// covariance, with the reflection removed).
pub fn fit_similarity(
    reconstructed: &[Vector3<f64>],
    reference: &[Vector3<f64>],
) -> Result<Similarity> {
    check_matched(reconstructed, reference, 3)?;
    let (mean_rec, rec) = centred(reconstructed);
    let (mean_ref, refc) = centred(reference);
    let cross: Matrix3<f64> = rec.iter().zip(&refc).map(|(a, b)| a * b.transpose()).sum();
    let ref_spread: f64 = refc.iter().map(|v| v.norm_squared()).sum();
    if ref_spread <= 0.0 {
        bail!("the reference points all coincide: no similarity can be fitted");
    }
    let svd = cross.svd(true, true);
    let (u, v_t) = match (svd.u, svd.v_t) {
        (Some(u), Some(v_t)) => (u, v_t),
        _ => bail!("the SVD of the cross covariance failed"),
    };
    let mut signs = Vector3::new(1.0, 1.0, 1.0);
    if (u * v_t).determinant() < 0.0 {
        signs.z = -1.0;
    }
    let rotation = u * Matrix3::from_diagonal(&signs) * v_t;
    // nalgebra sorts singular values in decreasing order, so the sign goes on the smallest.
    let scale = svd.singular_values.component_mul(&signs).sum() / ref_spread;
    if !(scale.is_finite() && scale > 0.0) {
        bail!("the points are degenerate (collinear): the similarity is undetermined");
    }
    // reconstructed = λ R reference + t with t = mean_rec − λ R mean_ref = −λ R T.
    let t = mean_rec - rotation * mean_ref * scale;
    let (kappa, phi, omega) = angles_from_matrix(&rotation);
    Ok(Similarity {
        kappa,
        phi,
        omega,
        translation: -(rotation.transpose() * t) / scale,
        scale,
    })
}

/// The whole assessment of one reconstructed point set against its reference.
#[derive(Debug, Clone, Serialize)]
pub struct Assessment {
    /// Table 6.
    pub similarity: Similarity,
    /// Table 7's coordinates: the reconstructed points in the reference frame.
    pub transformed: Vec<Vector3<f64>>,
    /// Table 7's error rows: v = λ R (reference − T) − reconstructed.
    pub residuals: Vec<Vector3<f64>>,
    /// Table 7's "MSE" row: sqrt(Σ v² / (n − 1)) per axis (mm).
    pub mse: Vector3<f64>,
    /// reconstructed − reference with no fit (mm).
    pub absolute_errors: Vec<Vector3<f64>>,
    /// The sample standard deviation of the absolute errors per axis (mm).
    pub absolute_std: Vector3<f64>,
    /// The mean absolute error per axis (mm): the bias no fit removes.
    pub absolute_mean: Vector3<f64>,
    /// The RMS distance of the reconstructed points from their best-fitting plane (mm).
    pub flatness_rms: f64,
}

/// Everything of [`Assessment`] for matched points (same order, at least four points).
pub fn assess(reconstructed: &[Vector3<f64>], reference: &[Vector3<f64>]) -> Result<Assessment> {
    check_matched(reconstructed, reference, 4)?;
    let similarity = fit_similarity(reconstructed, reference)?;
    let transformed = reconstructed
        .iter()
        .map(|p| similarity.inverse(p))
        .collect();
    let residuals: Vec<_> = reconstructed
        .iter()
        .zip(reference)
        .map(|(rec, r)| similarity.forward(r) - rec)
        .collect();
    let absolute_errors: Vec<_> = reconstructed
        .iter()
        .zip(reference)
        .map(|(rec, r)| rec - r)
        .collect();
    let (absolute_mean, centred_errors) = centred(&absolute_errors);
    Ok(Assessment {
        similarity,
        transformed,
        mse: sample_std_about(&residuals, Vector3::zeros()),
        absolute_std: sample_std_about(&centred_errors, Vector3::zeros()),
        absolute_mean,
        residuals,
        absolute_errors,
        flatness_rms: plane_rms(reconstructed)?,
    })
}

impl Assessment {
    /// The `--json` form: {kappa, phi, omega, Xc, Yc, Zc, lambda, transformed, residuals,
    /// mse: [x, y, z], absolute_std: [x, y, z], absolute_mean, flatness_rms}, points labelled.
    pub fn to_json(&self, labels: &[String]) -> serde_json::Value {
        let s = &self.similarity;
        let labelled = |points: &[Vector3<f64>]| -> Vec<serde_json::Value> {
            labels
                .iter()
                .zip(points)
                .map(|(l, p)| serde_json::json!({"point": l, "X": p.x, "Y": p.y, "Z": p.z}))
                .collect()
        };
        serde_json::json!({
            "kappa": s.kappa, "phi": s.phi, "omega": s.omega,
            "Xc": s.translation.x, "Yc": s.translation.y, "Zc": s.translation.z,
            "lambda": s.scale,
            "transformed": labelled(&self.transformed),
            "residuals": labelled(&self.residuals),
            "mse": [self.mse.x, self.mse.y, self.mse.z],
            "absolute_std": [self.absolute_std.x, self.absolute_std.y, self.absolute_std.z],
            "absolute_mean": [self.absolute_mean.x, self.absolute_mean.y, self.absolute_mean.z],
            "flatness_rms": self.flatness_rms,
        })
    }

    /// Tables 6 and 7 as text.
    pub fn to_text(&self, labels: &[String]) -> String {
        let s = &self.similarity;
        let mut out = format!(
            "Similarity (Table 6): kappa {:.7} phi {:.7} omega {:.7} rad, Xc {:.4} Yc {:.4} Zc {:.4} mm, lambda {:.6}\n\
             point        X (mm)      Y (mm)      Z (mm)     vX      vY      vZ\n",
            s.kappa, s.phi, s.omega, s.translation.x, s.translation.y, s.translation.z, s.scale
        );
        for ((l, t), v) in labels.iter().zip(&self.transformed).zip(&self.residuals) {
            out += &format!(
                "{l:<8} {:>11.3} {:>11.3} {:>11.3} {:>7.3} {:>7.3} {:>7.3}\n",
                t.x, t.y, t.z, v.x, v.y, v.z
            );
        }
        out += &format!(
            "MSE (n-1 std of residuals): {:.4} {:.4} {:.4} mm\n\
             no fit: mean error {:.4} {:.4} {:.4} mm, std {:.4} {:.4} {:.4} mm\n\
             flatness (RMS from fitted plane): {:.4} mm\n",
            self.mse.x,
            self.mse.y,
            self.mse.z,
            self.absolute_mean.x,
            self.absolute_mean.y,
            self.absolute_mean.z,
            self.absolute_std.x,
            self.absolute_std.y,
            self.absolute_std.z,
            self.flatness_rms
        );
        out
    }
}

/// Matches reconstructed points to reference points by label (in the reconstructed order);
/// a label missing from the reference is an error naming it.
pub fn match_points(
    reconstructed: &[(String, Vector3<f64>)],
    reference: &[(String, Vector3<f64>)],
) -> Result<Matched> {
    let lookup: std::collections::HashMap<&str, Vector3<f64>> =
        reference.iter().map(|(l, p)| (l.as_str(), *p)).collect();
    let mut matched = Matched::default();
    for (label, p) in reconstructed {
        let r = lookup
            .get(label.as_str())
            .with_context(|| format!("point {label:?} is not in the reference"))?;
        matched.labels.push(label.clone());
        matched.reconstructed.push(*p);
        matched.reference.push(*r);
    }
    Ok(matched)
}

/// Refuses points that (nearly) lie on one line: the similarity's rotation about that line
/// would be arbitrary. The spread across the line must be at least 1e-3 of the spread along it.
pub fn check_not_collinear(points: &[Vector3<f64>]) -> Result<()> {
    let n = points.len().max(1) as f64;
    let mean = points.iter().sum::<Vector3<f64>>() / n;
    let scatter = points
        .iter()
        .map(|p| (p - mean) * (p - mean).transpose())
        .sum::<Matrix3<f64>>();
    let mut spread = scatter.symmetric_eigenvalues().map(|v| v.max(0.0).sqrt());
    spread.as_mut_slice().sort_by(|a, b| b.total_cmp(a));
    if spread[1] < 1e-3 * spread[0] {
        bail!(
            "the matched points are (nearly) collinear (spread {:.3e} mm across their line, \
             {:.3e} mm along it): the rotation about that line is undetermined",
            spread[1],
            spread[0]
        );
    }
    Ok(())
}

/// Points matched by label.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Matched {
    /// The labels.
    pub labels: Vec<String>,
    /// Reconstructed points.
    pub reconstructed: Vec<Vector3<f64>>,
    /// Their reference points.
    pub reference: Vec<Vector3<f64>>,
}

/// Per-axis sqrt(Σ (v − centre)² / (n − 1)).
pub fn sample_std_about(values: &[Vector3<f64>], centre: Vector3<f64>) -> Vector3<f64> {
    let n = values.len();
    if n < 2 {
        return Vector3::repeat(f64::NAN);
    }
    let sum: Vector3<f64> = values
        .iter()
        .map(|v| (v - centre).component_mul(&(v - centre)))
        .sum();
    (sum / (n - 1) as f64).map(f64::sqrt)
}

/// The RMS distance of points from their least-squares plane (the plane through the centroid
/// normal to the direction of least spread).
pub fn plane_rms(points: &[Vector3<f64>]) -> Result<f64> {
    if points.len() < 3 {
        bail!("a plane needs at least 3 points, got {}", points.len());
    }
    let (_, centred_points) = centred(points);
    let scatter: Matrix3<f64> = centred_points.iter().map(|v| v * v.transpose()).sum();
    let eigen = scatter.symmetric_eigen();
    let smallest = eigen.eigenvalues.min().max(0.0);
    Ok((smallest / points.len() as f64).sqrt())
}

fn centred(points: &[Vector3<f64>]) -> (Vector3<f64>, Vec<Vector3<f64>>) {
    let mean = points.iter().sum::<Vector3<f64>>() / points.len().max(1) as f64;
    (mean, points.iter().map(|p| p - mean).collect())
}

fn check_matched(a: &[Vector3<f64>], b: &[Vector3<f64>], minimum: usize) -> Result<()> {
    if a.len() != b.len() {
        bail!(
            "{} reconstructed points but {} reference points",
            a.len(),
            b.len()
        );
    }
    if a.len() < minimum {
        bail!("need at least {minimum} matched points, got {}", a.len());
    }
    if let Some(p) = a.iter().chain(b).find(|p| !p.iter().all(|c| c.is_finite())) {
        bail!("a point is not finite: {p:?}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Table 5 (reconstructed X, Y, Z and the error rows, reconstructed − reference) for the rays
    /// 01, 02, 03, 11, 12, 13, 21, 22, 23.
    const TABLE5: [([f64; 3], [f64; 3]); 9] = [
        ([43.161, 85.613, 216.417], [-1.280, 0.983, 16.417]),
        ([310.371, 83.755, 216.126], [-3.646, 1.032, 16.126]),
        ([602.154, 76.648, 214.399], [-5.750, 0.874, 14.399]),
        ([38.361, 341.798, 216.116], [-1.556, -1.272, 16.116]),
        ([302.043, 348.593, 215.657], [-3.782, -1.177, 15.657]),
        ([589.534, 355.892, 215.842], [-5.957, -1.061, 15.842]),
        ([31.696, 592.934, 216.478], [-1.676, -3.338, 16.478]),
        ([295.196, 610.164, 215.883], [-3.901, -3.156, 15.883]),
        ([581.149, 628.259, 213.808], [-5.737, -2.696, 13.808]),
    ];

    /// Table 7: coordinates after the similarity and the error rows.
    const TABLE7: [([f64; 3], [f64; 3]); 9] = [
        ([44.644, 84.865, 199.826], [-0.201, -0.233, 0.173]),
        ([313.903, 82.825, 200.338], [0.113, -0.101, -0.335]),
        ([607.924, 75.480, 199.474], [-0.018, 0.291, 0.522]),
        ([39.969, 343.018, 199.660], [-0.050, 0.051, 0.338]),
        ([305.678, 349.700, 199.997], [0.146, 0.070, 0.003]),
        ([595.378, 356.873, 201.055], [0.109, 0.078, -1.047]),
        ([33.409, 596.085, 200.152], [-0.038, 0.185, -0.151]),
        ([298.942, 613.281, 200.358], [0.153, 0.037, -0.356]),
        ([587.105, 631.337, 199.140], [-0.215, -0.379, 0.854]),
    ];

    fn table5_points() -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let rec: Vec<_> = TABLE5.iter().map(|(p, _)| Vector3::from(*p)).collect();
        let reference = TABLE5
            .iter()
            .map(|(p, e)| Vector3::from(*p) - Vector3::from(*e))
            .collect();
        (rec, reference)
    }

    #[test]
    fn table5_references_lie_at_z200() {
        let (_, reference) = table5_points();
        assert!(reference.iter().all(|r| (r.z - 200.0).abs() < 1e-9));
    }

    /// Table 6 to the digits of the errata's unrounded fit (and so to the printed digits).
    #[test]
    fn table6_parameters() {
        let (rec, reference) = table5_points();
        let s = fit_similarity(&rec, &reference).unwrap();
        let checks = [
            ("kappa", s.kappa, -0.0006225, 5e-8),
            ("phi", s.phi, -0.0029948, 5e-8),
            ("omega", s.omega, 0.0005836, 5e-8),
            ("Xc", s.translation.x, 1.7513, 5e-5),
            ("Yc", s.translation.y, -1.2506, 5e-5),
            ("Zc", s.translation.z, -18.4310, 5e-5),
            ("lambda", s.scale, 0.992386, 5e-7),
        ];
        for (name, got, want, tol) in checks {
            assert!((got - want).abs() <= tol, "{name}: {got} vs {want}");
        }
    }

    /// Table 7's coordinates (to 0.001 mm), its error rows (to the printed 0.001 mm) and its MSE
    /// row (0.1415, 0.2068, 0.5595 unrounded; printed truncated as 0.141, 0.206, 0.559).
    #[test]
    fn table7_coordinates_residuals_and_mse() {
        let (rec, reference) = table5_points();
        let a = assess(&rec, &reference).unwrap();
        for (k, (coords, errors)) in TABLE7.iter().enumerate() {
            let dc = (a.transformed[k] - Vector3::from(*coords)).amax();
            let de = (a.residuals[k] - Vector3::from(*errors)).amax();
            assert!(
                dc <= 0.0015,
                "point {k}: {} vs {coords:?}",
                a.transformed[k]
            );
            assert!(de <= 0.0015, "point {k}: {} vs {errors:?}", a.residuals[k]);
        }
        let want = Vector3::new(0.1415, 0.2068, 0.5595);
        assert!((a.mse - want).amax() < 0.0006, "MSE {}", a.mse);
        assert_eq!(
            (a.mse * 1000.0).map(f64::trunc),
            Vector3::new(141.0, 206.0, 559.0)
        );
    }

    /// No fit: Table 5's error rows themselves; the Z errors are about +15.6 mm on average.
    #[test]
    fn absolute_errors_and_flatness() {
        let (rec, reference) = table5_points();
        let a = assess(&rec, &reference).unwrap();
        for (k, (_, e)) in TABLE5.iter().enumerate() {
            assert!((a.absolute_errors[k] - Vector3::from(*e)).amax() < 1e-9);
        }
        let mean_z = TABLE5.iter().map(|(_, e)| e[2]).sum::<f64>() / 9.0;
        assert!((a.absolute_mean.z - mean_z).abs() < 1e-9);
        // The plate is tilted by the similarity's φ but flat to about the Z residuals.
        assert!(
            a.flatness_rms > 0.3 && a.flatness_rms < a.mse.z,
            "{}",
            a.flatness_rms
        );
    }

    #[test]
    fn exact_similarity_is_recovered() {
        let truth = Similarity {
            kappa: 0.3,
            phi: -0.2,
            omega: 0.1,
            translation: Vector3::new(10.0, -20.0, 5.0),
            scale: 1.05,
        };
        let reference: Vec<_> = (0..6)
            .map(|k| {
                Vector3::new(
                    f64::from(k) * 50.0,
                    f64::from(k * k) * 7.0,
                    f64::from(k % 2) * 30.0,
                )
            })
            .collect();
        let rec: Vec<_> = reference.iter().map(|r| truth.forward(r)).collect();
        let s = fit_similarity(&rec, &reference).unwrap();
        assert!((s.kappa - 0.3).abs() < 1e-12 && (s.phi + 0.2).abs() < 1e-12);
        assert!((s.omega - 0.1).abs() < 1e-12 && (s.scale - 1.05).abs() < 1e-12);
        assert!((s.translation - truth.translation).norm() < 1e-9);
        let a = assess(&rec, &reference).unwrap();
        assert!(a.mse.amax() < 1e-9 && a.flatness_rms > 1.0);
    }

    #[test]
    fn bad_input_is_an_error() {
        let p = vec![Vector3::new(1.0, 2.0, 3.0); 5];
        assert!(assess(&p[..4], &p).is_err());
        assert!(assess(&p, &p).is_err(), "coincident points");
        let mut q = p.clone();
        q[2].x = f64::NAN;
        assert!(assess(&q, &p).is_err());
    }
}
