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
//!
//! # Speed
//! The fit is the measurement's inner loop (thousands of blobs per frame), so it is written for
//! the machine: the window's pixels are kept in a reused [`Scratch`] (no allocation per blob) as
//! f32 (the positions are relative to the gravity centre, a few pixels, and the residuals a few
//! DN: f32 carries them to 10⁻⁶ px); every iteration is one pass that evaluates the template and
//! its gradient on [`LANES`] pixels at a time (one AVX2 register where the processor has it),
//! branch-free with a polynomial exp and erfc, into the normal equations (f64 only for the
//! 10 × 10 solve); it starts from the blob's gravity
//! centre and moments and stops when the centre moves less than [`CENTRE_TOLERANCE`].

use super::detect::{Blob, GrayView, Polarity};
use nalgebra::{SMatrix, SVector};

const N: usize = 10;
type Params = SVector<f64, N>;

/// Pixels evaluated together (the width the compiler vectorises the pass to).
pub const LANES: usize = 8;

/// The fit stops when the centre moves less than this (pixels).
pub const CENTRE_TOLERANCE: f64 = 1e-3;

/// At most this many Gauss-Newton steps.
const MAX_ITERATIONS: usize = 20;

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
    /// Passes over the window (evaluations of the normal equations).
    pub passes: u32,
}

/// The window's pixels, structure of arrays, padded to a multiple of [`LANES`] with pixels of
/// weight 0. Reused from blob to blob: one per thread.
#[derive(Debug, Clone, Default)]
pub struct Scratch {
    x: Vec<f32>,
    y: Vec<f32>,
    v: Vec<f32>,
    weight: Vec<f32>,
}

impl Scratch {
    fn clear(&mut self) {
        self.x.clear();
        self.y.clear();
        self.v.clear();
        self.weight.clear();
    }

    fn push(&mut self, x: f32, y: f32, v: f32, weight: f32) {
        self.x.push(x);
        self.y.push(y);
        self.v.push(v);
        self.weight.push(weight);
    }

    /// The pixels `first..=last` of one image row (weight 1), positions relative to
    /// (`xr`, `yr`).
    fn push_span(
        &mut self,
        (first, last): (usize, usize),
        row: usize,
        (xr, yr): (f64, f64),
        values: impl Iterator<Item = f64>,
    ) {
        let n = last + 1 - first;
        self.x
            .extend((first..=last).map(|c| (c as f64 - xr) as f32));
        self.y
            .extend(std::iter::repeat_n((row as f64 - yr) as f32, n));
        self.v.extend(values.map(|v| v as f32));
        self.weight.extend(std::iter::repeat_n(1.0, n));
    }
}

/// e^x for x ≤ 0 (clamped at −87): 2ⁿ · e^f with f = x − n ln 2, |f| ≤ ln 2 / 2, by a degree-6
/// Taylor polynomial (relative error below 10⁻⁶). Branch-free, so the pass vectorises.
#[inline(always)]
fn exp_neg(x: f32) -> f32 {
    // Round to nearest by adding 1.5·2²³ (no call to `round`, which would stop vectorisation).
    const SHIFT: f32 = 12_582_912.0;
    let shifted = x.max(-87.0) * std::f32::consts::LOG2_E + SHIFT;
    let n = shifted - SHIFT;
    // ln 2 split in two (Cody-Waite) so that n · ln 2 loses nothing to rounding.
    let f = (x.max(-87.0) - n * 0.693_145_75) - n * 1.428_606_8e-6;
    let p = 1.0
        + f * (1.0
            + f * (0.5 + f * (1.0 / 6.0 + f * (1.0 / 24.0 + f * (1.0 / 120.0 + f / 720.0)))));
    p * f32::from_bits(
        (shifted
            .to_bits()
            .wrapping_sub(SHIFT.to_bits())
            .wrapping_add(127))
            << 23,
    )
}

/// Φ(t) and φ(t), the normal CDF and density: erfc by Abramowitz & Stegun 7.1.26 (absolute error
/// below 1.5·10⁻⁷) sharing its exponential with the density.
#[inline(always)]
fn normal_cdf_pdf(t: f32) -> (f32, f32) {
    let z = t.abs() * std::f32::consts::FRAC_1_SQRT_2;
    let k = 1.0 / (1.0 + 0.327_591_1 * z);
    let poly = k
        * (0.254_829_6
            + k * (-0.284_496_74 + k * (1.421_413_7 + k * (-1.453_152_1 + k * 1.061_405_4))));
    let e = exp_neg(-z * z);
    let tail = 0.5 * poly * e;
    let cdf = if t >= 0.0 { 1.0 - tail } else { tail };
    (cdf, e * 0.398_942_3)
}

/// The template at one pixel (x, y relative to the reference): its value and gradient with
/// respect to the parameters p = (c_x, c_y, q11, q12, q22, A, s, b₀, b_x, b_y).
///
/// The signed distance d and its gradient with respect to (c_x, c_y, q11, q12, q22): with
/// w = Q u, ρ² = uᵀ w, q = |w|, d = (ρ² − ρ)/q, so ∂d = ((2ρ − 1) ∂ρ − d ∂q)/q, ∂ρ/∂c = −w/ρ,
/// ∂q/∂c = −Q w/q, ∂ρ/∂(q11, q12, q22) = (u_x², 2 u_x u_y, u_y²)/(2ρ),
/// ∂q/∂(q11, q12, q22) = (w_x u_x, w_x u_y + w_y u_x, w_y u_y)/q. At the very centre (ρ or q
/// vanishing) the template is flat: d = −1/√max(q11, q22), no gradient.
#[inline(always)]
fn model(p: &[f32; N], x: f32, y: f32) -> (f32, [f32; N]) {
    let (ux, uy) = (x - p[0], y - p[1]);
    let (wx, wy) = (p[2] * ux + p[3] * uy, p[3] * ux + p[4] * uy);
    let rho = (ux * wx + uy * wy).max(1e-12).sqrt();
    let q = (wx * wx + wy * wy).max(1e-24).sqrt();
    let centre = rho < 1e-6 || q < 1e-6;
    let d = if centre {
        -1.0 / p[2].max(p[4]).max(1e-12).sqrt()
    } else {
        (rho - 1.0) * rho / q
    };
    let (qwx, qwy) = (p[2] * wx + p[3] * wy, p[3] * wx + p[4] * wy);
    let (inv_rho, inv_q) = (1.0 / rho, 1.0 / q);
    let drho = [
        -wx * inv_rho,
        -wy * inv_rho,
        0.5 * ux * ux * inv_rho,
        ux * uy * inv_rho,
        0.5 * uy * uy * inv_rho,
    ];
    let dq = [
        -qwx * inv_q,
        -qwy * inv_q,
        wx * ux * inv_q,
        (wx * uy + wy * ux) * inv_q,
        wy * uy * inv_q,
    ];
    let inv_s = 1.0 / p[6];
    let (cdf, pdf) = normal_cdf_pdf(-d * inv_s);
    // ∂I/∂d = −A φ(t) / s.
    let di = if centre {
        0.0
    } else {
        -p[5] * pdf * inv_s * inv_q
    };
    let k = 2.0 * rho - 1.0;
    let g = [
        di * (k * drho[0] - d * dq[0]),
        di * (k * drho[1] - d * dq[1]),
        di * (k * drho[2] - d * dq[2]),
        di * (k * drho[3] - d * dq[3]),
        di * (k * drho[4] - d * dq[4]),
        cdf,
        p[5] * pdf * d * inv_s * inv_s,
        1.0,
        x,
        y,
    ];
    (p[7] + p[8] * x + p[9] * y + p[5] * cdf, g)
}

/// Entries of the upper triangle of the 10 × 10 normal matrix.
const PAIRS: usize = N * (N + 1) / 2;

/// The normal equations at p: JᵀJ, Jᵀr and the cost Σ r².
struct Normal {
    jtj: SMatrix<f64, N, N>,
    jtr: Params,
    cost: f64,
}

/// One pass over the window ([`normal_equations_lanes`]), in 256-bit registers where the
/// processor has AVX2 (the same operations lane by lane: the same sums to the bit).
fn normal_equations(p: &Params, s: &Scratch) -> Normal {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: a `target_feature` function only requires that the processor has the
        // feature, which was detected just above.
        return unsafe { normal_equations_avx2(p, s) };
    }
    normal_equations_lanes(p, s)
}

/// [`normal_equations_lanes`] compiled for AVX2: [`LANES`] f32 are one register.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn normal_equations_avx2(p: &Params, s: &Scratch) -> Normal {
    normal_equations_lanes(p, s)
}

/// One pass over the window, [`LANES`] pixels at a time (lane-wise sums, added up at the end).
#[inline(always)]
fn normal_equations_lanes(p: &Params, s: &Scratch) -> Normal {
    let pf: [f32; N] = core::array::from_fn(|k| p[k] as f32);
    let mut jtj = [[0f32; LANES]; PAIRS];
    let mut jtr = [[0f32; LANES]; N];
    let mut cost = [0f32; LANES];
    let chunks =
        s.x.chunks_exact(LANES)
            .zip(s.y.chunks_exact(LANES))
            .zip(s.v.chunks_exact(LANES).zip(s.weight.chunks_exact(LANES)));
    for ((x, y), (v, w)) in chunks {
        let mut g = [[0f32; LANES]; N];
        let mut r = [0f32; LANES];
        for l in 0..LANES {
            let (value, gl) = model(&pf, x[l], y[l]);
            r[l] = (v[l] - value) * w[l];
            for k in 0..N {
                g[k][l] = gl[k] * w[l];
            }
        }
        for l in 0..LANES {
            cost[l] += r[l] * r[l];
        }
        // The upper triangle row by row: row a holds the pairs (a, a..N).
        let mut rest = &mut jtj[..];
        for (a, (ga, jtr)) in g.iter().zip(&mut jtr).enumerate() {
            for l in 0..LANES {
                jtr[l] += ga[l] * r[l];
            }
            let (row, tail) = rest.split_at_mut(N - a);
            rest = tail;
            for (acc, gb) in row.iter_mut().zip(&g[a..]) {
                for l in 0..LANES {
                    acc[l] += ga[l] * gb[l];
                }
            }
        }
    }
    let sum = |lanes: &[f32; LANES]| lanes.iter().map(|&v| f64::from(v)).sum::<f64>();
    let mut m = SMatrix::<f64, N, N>::zeros();
    let mut pair = 0;
    for a in 0..N {
        for b in a..N {
            m[(a, b)] = sum(&jtj[pair]);
            m[(b, a)] = m[(a, b)];
            pair += 1;
        }
    }
    Normal {
        jtj: m,
        jtr: Params::from_fn(|k, _| sum(&jtr[k])),
        cost: sum(&cost),
    }
}

/// The starting ellipse (q11, q12, q22) and amplitude: the second moments of the window's
/// pixels weighted by their height above the background, counting only those above a tenth of
/// the peak (noise far out would inflate the moments). For a disc of radius R blurred by σ these
/// are about R²/4 + 0.8 σ² (the blur's share with the cut tails), σ ≈ 1 px; the amplitude is the
/// flux over the ellipse's area. Falls back on the blob's thresholded moments.
fn start_ellipse(s: &Scratch, blob: &Blob, background: f64) -> Option<([f64; 3], f64)> {
    let cut = 0.1 * blob.peak;
    let (mut m0, mut mx, mut my, mut mxx, mut mxy, mut myy) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for (((&x, &y), &v), &weight) in s.x.iter().zip(&s.y).zip(&s.v).zip(&s.weight) {
        let w = f64::from(v) - background;
        if weight > 0.0 && w > cut {
            let (x, y) = (f64::from(x), f64::from(y));
            m0 += w;
            mx += w * x;
            my += w * y;
            mxx += w * x * x;
            mxy += w * x * y;
            myy += w * y * y;
        }
    }
    let (mx, my) = (mx / m0, my / m0);
    let weighted = (
        mxx / m0 - mx * mx - 0.8,
        mxy / m0 - mx * my,
        myy / m0 - my * my - 0.8,
    );
    let ellipse = |(a, b, c): (f64, f64, f64)| {
        let det = 4.0 * (a * c - b * b);
        (det > 0.0 && a > 0.0).then(|| ([c / det, -b / det, a / det], det))
    };
    match ellipse(weighted) {
        Some((q, det)) => Some((q, m0 / (std::f64::consts::PI * det.sqrt()))),
        None => ellipse(blob.cov).map(|(q, _)| (q, blob.peak)),
    }
}

/// The pixels of `window` (`[c0, r0, c1, r1]`, inclusive) outside `exclude`, row by row as
/// spans: `visit(row, first, last)`. `exclude` holds row runs `[c0, r, c1, r]` in row order and,
/// within a row, in column order without overlaps (as [`super::components::RunLabels::foreign_runs`]
/// gives them).
pub fn for_each_span(
    window: [usize; 4],
    exclude: &[[usize; 4]],
    mut visit: impl FnMut(usize, usize, usize),
) {
    let [c0, r0, c1, r1] = window;
    let mut runs = exclude.iter().peekable();
    for r in r0..=r1 {
        while runs.next_if(|run| run[1] < r).is_some() {}
        let mut c = c0;
        while let Some(run) = runs.next_if(|run| run[1] == r) {
            let end = run[0].min(c1 + 1);
            if end > c {
                visit(r, c, end - 1);
            }
            c = c.max(run[2] + 1);
        }
        if c <= c1 {
            visit(r, c, c1);
        }
    }
}

/// Fit the template around `blob`. The window is the blob's box grown by `margin` pixels;
/// pixels in `exclude` (row runs of other blobs, see [`for_each_span`]) are left out.
/// `background` is the local background level (signed by polarity). `None` when the fit does
/// not converge to a sensible ellipse inside the window.
pub fn fit_template<P: Copy + Into<f64>>(
    img: &GrayView<P>,
    polarity: Polarity,
    blob: &Blob,
    background: f64,
    margin: usize,
    exclude: &[[usize; 4]],
    scratch: &mut Scratch,
) -> Option<EllipseFit> {
    let [c0, r0, c1, r1] = blob.bbox;
    let window = [
        c0.saturating_sub(margin),
        r0.saturating_sub(margin),
        (c1 + margin).min(img.width - 1),
        (r1 + margin).min(img.height - 1),
    ];
    let (xr, yr) = blob.gravity;
    scratch.clear();
    for_each_span(window, exclude, |r, first, last| {
        let values = (first..=last).map(|c| img.signed(c, r, polarity));
        scratch.push_span((first, last), r, (xr, yr), values);
    });
    let count = scratch.x.len();
    while !scratch.x.len().is_multiple_of(LANES) {
        scratch.push(0.0, 0.0, 0.0, 0.0);
    }
    // Start: the gravity centre, the ellipse and amplitude from the window's moments.
    let (q, amplitude) = start_ellipse(scratch, blob, background)?;
    if count <= N {
        return None;
    }
    let mut p = Params::from_column_slice(&[
        0.0, 0.0, q[0], q[1], q[2], amplitude, 1.0, background, 0.0, 0.0,
    ]);
    let mut lambda = 1e-3;
    let mut current = normal_equations(&p, scratch);
    let mut passes = 1;
    for _ in 0..MAX_ITERATIONS {
        let mut damped = current.jtj;
        for k in 0..N {
            damped[(k, k)] *= 1.0 + lambda;
        }
        let Some(chol) = damped.cholesky() else {
            lambda *= 10.0;
            continue;
        };
        let step = chol.solve(&current.jtr);
        let trial = p + step;
        if trial[6] <= 0.05 {
            lambda *= 10.0;
            continue;
        }
        // Converged (the centre moves less than the tolerance, the ellipse, amplitude and edge
        // by less than 10⁻³ of themselves): the last Gauss-Newton step is taken without another
        // pass.
        let shape = (step[2].abs() + step[3].abs() + step[4].abs()) / (p[2].abs() + p[4].abs());
        let settled = shape < 1e-2 && step[5].abs() < 1e-2 * p[5] && step[6].abs() < 1e-2 * p[6];
        if step[0].hypot(step[1]) < CENTRE_TOLERANCE && settled && lambda < 1e-2 {
            p = trial;
            break;
        }
        let at_trial = normal_equations(&trial, scratch);
        passes += 1;
        if at_trial.cost >= current.cost {
            lambda *= 10.0;
            if lambda > 1e6 {
                break;
            }
            continue;
        }
        p = trial;
        current = at_trial;
        lambda = (lambda * 0.3).max(1e-9);
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
        rms: (current.cost / count as f64).sqrt(),
        passes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    /// The analytic gradient of the template agrees with central differences (of the f32
    /// template: steps of 2·10⁻³ keep its rounding, about 10⁻⁵ of the value, near 10⁻³).
    #[test]
    fn gradient_matches_differences() {
        let p = [0.3, -0.2, 0.05, 0.01, 0.08, 150.0, 1.1, 40.0, 0.1, -0.2];
        for (x, y) in [(3.0, 1.0), (-2.5, 2.0), (0.5, -4.0), (1.0, 1.0)] {
            let (_, g) = model(&p, x, y);
            for k in 0..N {
                let h = 2e-3 * (1.0 + p[k].abs());
                let (mut a, mut b) = (p, p);
                a[k] += h;
                b[k] -= h;
                let num = (model(&a, x, y).0 - model(&b, x, y).0) / (2.0 * h);
                assert!(
                    (num - g[k]).abs() < 1e-2 * (1.0 + num.abs()),
                    "param {k} at ({x}, {y}): {num} vs {}",
                    g[k]
                );
            }
        }
    }

    /// The AVX2 pass and the portable one give the same normal equations to the bit (the same
    /// operations lane by lane: no fused multiply-add, IEEE division and square root), on a
    /// window of a noisy blurred ellipse padded with weight-0 pixels, at the start, near and at
    /// the fitted parameters. Skips visibly on a processor without AVX2.
    #[test]
    fn avx2_and_portable_passes_agree_to_the_bit() {
        #[cfg(target_arch = "x86_64")]
        {
            let avx2 = std::arch::is_x86_feature_detected!("avx2");
            if !deltaz_testkit::require("avx2", avx2, "an x86-64 processor with AVX2") {
                return;
            }
            let truth = [0.3, -0.2, 0.05, 0.01, 0.08, 150.0, 1.1, 40.0, 0.1, -0.2];
            let mut s = Scratch::default();
            let mut rng = StdRng::seed_from_u64(1);
            for r in -7..=7 {
                for c in -8..=8 {
                    let (x, y) = (c as f32, r as f32);
                    let noise = rng.random_range(-2.0..2.0);
                    s.push(x, y, model(&truth, x, y).0 + noise, 1.0);
                }
            }
            while s.x.len() % LANES != 0 {
                s.push(0.0, 0.0, 0.0, 0.0);
            }
            for p in [
                [0.0, 0.0, 0.06, 0.0, 0.06, 120.0, 1.5, 38.0, 0.0, 0.0],
                [
                    0.28, -0.19, 0.051, 0.011, 0.079, 149.0, 1.12, 40.2, 0.09, -0.21,
                ],
                truth.map(f64::from),
            ] {
                let p = Params::from_column_slice(&p);
                // SAFETY: AVX2 was detected above.
                let fast = unsafe { normal_equations_avx2(&p, &s) };
                let portable = normal_equations_lanes(&p, &s);
                let bits = |n: &Normal| {
                    let mut v: Vec<u64> = n.jtj.iter().map(|x| x.to_bits()).collect();
                    v.extend(n.jtr.iter().map(|x| x.to_bits()));
                    v.push(n.cost.to_bits());
                    v
                };
                assert_eq!(bits(&fast), bits(&portable), "at {p}");
                assert!(portable.cost > 0.0 && portable.jtj[(5, 5)] > 0.0);
            }
        }
    }

    /// The polynomial exp and normal CDF against the library's, over the range the fit uses.
    #[test]
    fn fast_exp_and_cdf() {
        for k in 0..=2000 {
            let x = f64::from((-0.04 * k as f64) as f32);
            let fast = f64::from(exp_neg(x as f32));
            assert!((fast - x.exp()).abs() <= 1e-6 * x.exp(), "exp({x}): {fast}");
            for t in [x / 8.0, -x / 8.0] {
                let (cdf, pdf) = normal_cdf_pdf(t as f32);
                let exact = 0.5 * libm::erfc(-t / std::f64::consts::SQRT_2);
                let density = (-0.5 * t * t).exp() / (2.0 * std::f64::consts::PI).sqrt();
                assert!(
                    (f64::from(cdf) - exact).abs() < 3e-7,
                    "Φ({t}): {cdf} vs {exact}"
                );
                assert!((f64::from(pdf) - density).abs() < 1e-7, "φ({t}): {pdf}");
            }
        }
    }
}
