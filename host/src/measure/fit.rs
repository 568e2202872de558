//! The precise sub-pixel centre: a least-squares fit of a blurred-ellipse template to the pixels
//! around a blob (Gauss-Newton with Levenberg-Marquardt damping).
//!
//! The template is
//!
//! I(x, y) = b₀ + b_x (x − x̄) + b_y (y − ȳ) + A · Φ(−d(x, y) / s)
//!
//! with Φ the normal CDF, s the edge width (defocus blur and pixel integration together), and d the
//! signed distance to the ellipse (x − c)ᵀ Q (x − c) = 1 in its first-order form
//! d = (ρ − 1) ρ / |Q u|, ρ² = uᵀ Q u, u = x − c (exact for circles). A tilted background plane
//! is part of the model so that gradients of illumination do not pull the centre. Ten parameters:
//! c (2), Q (3), A, s, b₀, b_x, b_y.

use super::detect::{Blob, GrayView, Polarity};
use nalgebra::{SMatrix, SVector};

const N: usize = 10;
type Params = SVector<f64, N>;

/// The fitted template.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EllipseFit {
    /// Centre column (pixels).
    pub col: f64,
    /// Centre row (pixels).
    pub row: f64,
    /// Semi-major axis (pixels).
    pub semi_major: f64,
    /// Semi-minor axis (pixels).
    pub semi_minor: f64,
    /// Direction of the major axis from the column axis towards the row axis (rad).
    pub angle: f64,
    /// Target brightness above the background (DN).
    pub amplitude: f64,
    /// Edge width s (pixels).
    pub edge: f64,
    /// RMS of the fit residuals (DN).
    pub rms: f64,
}

/// Signed distance d to the ellipse edge at (x, y) and its gradient with respect to
/// (c_x, c_y, q11, q12, q22): with w = Q u, ρ² = uᵀ w, q = |w|, d = (ρ² − ρ)/q, so
/// ∂d = ((2ρ − 1) ∂ρ − d ∂q)/q, ∂ρ/∂c = −w/ρ, ∂q/∂c = −Q w/q, ∂ρ/∂(q11, q12, q22) =
/// (u_x², 2 u_x u_y, u_y²)/(2ρ), ∂q/∂(q11, q12, q22) = (w_x u_x, w_x u_y + w_y u_x, w_y u_y)/q.
fn distance(p: &Params, x: f64, y: f64) -> (f64, [f64; 5]) {
    let (ux, uy) = (x - p[0], y - p[1]);
    let (wx, wy) = (p[2] * ux + p[3] * uy, p[3] * ux + p[4] * uy);
    let rho = (ux * wx + uy * wy).max(0.0).sqrt();
    let q = wx.hypot(wy);
    if q < 1e-12 || rho < 1e-12 {
        // The very centre: deep inside, where the template is flat.
        return (-1.0 / p[2].max(p[4]).max(1e-12).sqrt(), [0.0; 5]);
    }
    let d = (rho - 1.0) * rho / q;
    let (qwx, qwy) = (p[2] * wx + p[3] * wy, p[3] * wx + p[4] * wy);
    let drho = [
        -wx / rho,
        -wy / rho,
        ux * ux / (2.0 * rho),
        ux * uy / rho,
        uy * uy / (2.0 * rho),
    ];
    let dq = [
        -qwx / q,
        -qwy / q,
        wx * ux / q,
        (wx * uy + wy * ux) / q,
        wy * uy / q,
    ];
    let k = 2.0 * rho - 1.0;
    let grad = core::array::from_fn(|i| (k * drho[i] - d * dq[i]) / q);
    (d, grad)
}

fn phi_cdf(t: f64) -> f64 {
    0.5 * libm::erfc(-t / std::f64::consts::SQRT_2)
}

fn phi_pdf(t: f64) -> f64 {
    (-0.5 * t * t).exp() / (2.0 * std::f64::consts::PI).sqrt()
}

/// One pixel of the window: position relative to the reference (x̄, ȳ) and its value.
struct Sample {
    x: f64,
    y: f64,
    v: f64,
}

/// The model value and its gradient with respect to the parameters.
fn model(p: &Params, s: &Sample) -> (f64, Params) {
    let (d, dd) = distance(p, s.x, s.y);
    let t = -d / p[6];
    let cdf = phi_cdf(t);
    let pdf = phi_pdf(t);
    let value = p[7] + p[8] * s.x + p[9] * s.y + p[5] * cdf;
    let mut g = Params::zeros();
    // ∂I/∂d = −A φ(t) / s.
    let di = -p[5] * pdf / p[6];
    for k in 0..5 {
        g[k] = di * dd[k];
    }
    g[5] = cdf;
    g[6] = p[5] * pdf * d / (p[6] * p[6]);
    g[7] = 1.0;
    g[8] = s.x;
    g[9] = s.y;
    (value, g)
}

fn cost(p: &Params, samples: &[Sample]) -> f64 {
    samples.iter().map(|s| (model(p, s).0 - s.v).powi(2)).sum()
}

/// Fit the template around `blob`. The window is the blob's box grown by `margin` pixels;
/// pixels inside any of `exclude` (other blobs' grown boxes) are left out. `background` is the
/// local background level (signed by polarity). `None` when the fit does not converge to a
/// sensible ellipse inside the window.
pub fn fit_template<P: Copy + Into<f64>>(
    img: &GrayView<P>,
    polarity: Polarity,
    blob: &Blob,
    background: f64,
    margin: usize,
    exclude: &[[usize; 4]],
) -> Option<EllipseFit> {
    let [c0, r0, c1, r1] = blob.bbox;
    let (wc0, wr0) = (c0.saturating_sub(margin), r0.saturating_sub(margin));
    let wc1 = (c1 + margin).min(img.width - 1);
    let wr1 = (r1 + margin).min(img.height - 1);
    let (xr, yr) = blob.gravity;
    let mut samples = Vec::with_capacity((wc1 - wc0 + 1) * (wr1 - wr0 + 1));
    for r in wr0..=wr1 {
        for c in wc0..=wc1 {
            let excluded = exclude
                .iter()
                .any(|b| c >= b[0] && c <= b[2] && r >= b[1] && r <= b[3]);
            if !excluded {
                samples.push(Sample {
                    x: c as f64 - xr,
                    y: r as f64 - yr,
                    v: img.signed(c, r, polarity),
                });
            }
        }
    }
    // Start: the gravity centre, the moments' ellipse (4·cov for a filled ellipse), peak, s = 1.
    let (a, b, c) = blob.cov;
    let det = 4.0 * (a * c - b * b);
    if det.is_nan() || det <= 0.0 || samples.len() <= N {
        return None;
    }
    let mut p = Params::from_column_slice(&[
        0.0,
        0.0,
        c / det,
        -b / det,
        a / det,
        blob.peak,
        1.0,
        background,
        0.0,
        0.0,
    ]);
    let mut lambda = 1e-3;
    let mut current = cost(&p, &samples);
    for _ in 0..30 {
        let mut jtj = SMatrix::<f64, N, N>::zeros();
        let mut jtr = Params::zeros();
        for s in &samples {
            let (v, g) = model(&p, s);
            jtj.syger(1.0, &g, &g, 1.0);
            jtr += g * (s.v - v);
        }
        let mut improved = false;
        for _ in 0..10 {
            let mut damped = jtj;
            for k in 0..N {
                damped[(k, k)] *= 1.0 + lambda;
            }
            let Some(chol) = damped.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let step = chol.solve(&jtr);
            let trial = p + step;
            let trial_cost = if trial[6] > 0.05 {
                cost(&trial, &samples)
            } else {
                f64::INFINITY
            };
            if trial_cost < current {
                let moved = step[0].hypot(step[1]);
                p = trial;
                current = trial_cost;
                lambda = (lambda * 0.3).max(1e-9);
                improved = moved > 1e-5;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    // The ellipse's axes from Q's eigenvalues: semi-axis = 1/√λ.
    let (q11, q12, q22) = (p[2], p[3], p[4]);
    let mean = (q11 + q22) / 2.0;
    let dev = (((q11 - q22) / 2.0).powi(2) + q12 * q12).sqrt();
    let (lmin, lmax) = (mean - dev, mean + dev);
    let (col, row) = (xr + p[0], yr + p[1]);
    let inside = col >= c0 as f64 - 0.5
        && col <= c1 as f64 + 0.5
        && row >= r0 as f64 - 0.5
        && row <= r1 as f64 + 0.5;
    if !(lmin > 0.0 && p[5] > 0.0 && p[6] < 10.0 && inside) {
        return None;
    }
    Some(EllipseFit {
        col,
        row,
        semi_major: 1.0 / lmin.sqrt(),
        semi_minor: 1.0 / lmax.sqrt(),
        angle: 0.5 * (-2.0 * q12).atan2(q22 - q11),
        amplitude: p[5],
        edge: p[6],
        rms: (current / samples.len() as f64).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The analytic gradient of the template agrees with central differences.
    #[test]
    fn gradient_matches_differences() {
        let p =
            Params::from_column_slice(&[0.3, -0.2, 0.05, 0.01, 0.08, 150.0, 1.1, 40.0, 0.1, -0.2]);
        for (x, y) in [(3.0, 1.0), (-2.5, 2.0), (0.5, -4.0), (1.0, 1.0)] {
            let s = Sample { x, y, v: 0.0 };
            let (_, g) = model(&p, &s);
            for k in 0..N {
                let h = 1e-6 * (1.0 + p[k].abs());
                let (mut a, mut b) = (p, p);
                a[k] += h;
                b[k] -= h;
                let num = (model(&a, &s).0 - model(&b, &s).0) / (2.0 * h);
                assert!(
                    (num - g[k]).abs() < 1e-5 * (1.0 + num.abs()),
                    "param {k} at ({x}, {y}): {num} vs {}",
                    g[k]
                );
            }
        }
    }
}
