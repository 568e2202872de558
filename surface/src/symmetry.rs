//! The symmetry point of a section: the line in the section's plane (a, n) about which the
//! section over a window either side is most nearly its own mirror image.
//!
//! A section that is a symmetric profile rotated by θ and shifted is mirror symmetric about
//! the profile's axis, whatever θ; its symmetry point is where that axis meets the section, and
//! the section's slope there is tan θ. For a point P = (x, s(x)) and an axis through P at angle
//! θ from n (direction (−sin θ, cos θ)), each point Q = (x ± t, s(x ± t)) of the window maps to
//! Q' = P + M(Q − P), M the reflection, whose miss r = s(Q'_a) − Q'_n is minimised in the
//! weighted least-squares sense over (x, θ) (weights (1 − (t/w)²)², t < w). The point's
//! gradient over the surface's coefficients follows by implicit differentiation of the normal
//! equations, dp = −(JᵀΩJ)⁻¹ JᵀΩ (∂r/∂c) dc.

use crate::fit::Fit;
use crate::median;
use crate::spline::D;
use nalgebra::{DVector, Matrix2, Vector2};

/// A coarse candidate: position, misfit, slope.
pub(crate) type Candidate = (f64, f64, f64);

/// Samples of the window on each side.
const SAMPLES: usize = 24;

/// A level's symmetry point with the gradient of its position over the fit's unknowns.
#[derive(Debug, Clone)]
pub(crate) struct Symmetry {
    pub a: f64,
    pub gradient: DVector<f64>,
    /// The axis' tilt from n (rad, positive toward −a: the section's slope there is tan θ).
    pub theta: f64,
    pub theta_gradient: DVector<f64>,
}

struct Residual {
    r: f64,
    /// ∂r/∂(x, θ).
    jp: Vector2<f64>,
    /// ∂r/∂c as (a, d, weight) terms: weight × the gradient of s's value `d` at a.
    terms: [(f64, D, f64); 3],
}

fn reflection(theta: f64) -> (Matrix2<f64>, Matrix2<f64>) {
    let (s2, c2) = (2.0 * theta).sin_cos();
    let m = Matrix2::new(-c2, -s2, -s2, c2);
    let dm = Matrix2::new(2.0 * s2, -2.0 * c2, -2.0 * c2, -2.0 * s2);
    (m, dm)
}

/// The sample at offset `t` of the section at level v, mirrored by `m` about its point `p`:
/// the sample, its image and the image's miss r = s(image's a) − image's n.
fn mirrored(
    fit: &Fit,
    v: f64,
    (p, m): (Vector2<f64>, &Matrix2<f64>),
    t: f64,
) -> Option<(Vector2<f64>, Vector2<f64>, f64)> {
    let q = Vector2::new(p.x + t, fit.value(p.x + t, v, D::S)?);
    let image = p + m * (q - p);
    Some((q, image, fit.value(image.x, v, D::S)? - image.y))
}

/// The residual of the sample at offset `t` (signed) for the axis (x, θ) at level v.
fn residual(fit: &Fit, v: f64, x: f64, theta: f64, t: f64) -> Option<Residual> {
    let (m, dm) = reflection(theta);
    let s = |a: f64, d: D| fit.value(a, v, d);
    let p = Vector2::new(x, s(x, D::S)?);
    let (q, image, r) = mirrored(fit, v, (p, &m), t)?;
    let slope = s(image.x, D::A)?;
    let miss = |d: Vector2<f64>| slope * d.x - d.y;
    let dp = Vector2::new(1.0, s(x, D::A)?);
    let dq = Vector2::new(1.0, s(x + t, D::A)?);
    let id = Matrix2::identity();
    let dx = (id - m) * dp + m * dq;
    let dtheta = dm * (q - p);
    let n = Vector2::new(0.0, 1.0);
    Some(Residual {
        r,
        jp: Vector2::new(miss(dx), miss(dtheta)),
        terms: [
            (image.x, D::S, 1.0),
            (x, D::S, miss((id - m) * n)),
            (x + t, D::S, miss(m * n)),
        ],
    })
}

fn taper(t: f64, w: f64) -> f64 {
    (1.0 - (t / w).powi(2)).powi(2)
}

/// The window's offsets either side, `samples` a side, with their weights.
fn offsets(w: f64, samples: usize) -> impl Iterator<Item = (f64, f64)> {
    (0..samples).flat_map(move |k| {
        let t = w * (k as f64 + 0.5) / samples as f64;
        [(t, taper(t, w)), (-t, taper(t, w))]
    })
}

/// The odd part's misfit at x after a linear term, per unit weight (the criterion of the
/// coarse search), and the linear term's slope.
fn odd_misfit(fit: &Fit, v: f64, x: f64, w: f64) -> Option<(f64, f64)> {
    let (mut dd, mut dt, mut tt, mut total) = (0.0, 0.0, 0.0, 0.0);
    for (t, wt) in offsets(w, SAMPLES).filter(|(t, _)| *t > 0.0) {
        let d = fit.value(x + t, v, D::S)? - fit.value(x - t, v, D::S)?;
        dd += wt * d * d;
        dt += wt * d * t;
        tt += wt * t * t;
        total += wt;
    }
    Some(((dd - dt * dt / tt) / total, dt / (2.0 * tt)))
}

/// The section's asymmetry about the positions `across` (the coarse search's), against the
/// points' noise: the median of the odd part's misfit ([`odd_misfit`]) there, over the misfit
/// the fit's noise alone makes at x, `E[e] = Σ w_t var(d_t − b t) / Σ w_t`, d_t = s(x + t) −
/// s(x − t) and b their linear term (the fit's covariance: the points' own and the
/// calibration's common share), over a quarter of the misfit's samples (the integral is
/// smooth; each sample costs a solve with the fit's factor). Away from a back's symmetry line
/// its trunk is far from symmetric: tens to hundreds. A section symmetric about every point
/// (of even curvature) is asymmetric by its noise alone, and reads about 1 (NaN with neither
/// asymmetry nor noise).
pub(crate) fn asymmetry(fit: &Fit, v: f64, x: f64, w: f64, across: &[Candidate]) -> Option<f64> {
    let misfits: Vec<f64> = across
        .iter()
        .filter_map(|c| odd_misfit(fit, v, c.0, w).map(|m| m.0))
        .collect();
    if misfits.is_empty() {
        return None;
    }
    let typical = median(misfits);
    let half: Vec<(f64, f64)> = offsets(w, SAMPLES / 4).filter(|(t, _)| *t > 0.0).collect();
    let odd: Vec<DVector<f64>> = half
        .iter()
        .map(|(t, _)| {
            let mut g = fit.zero();
            fit.add(&mut g, x + t, v, D::S, 1.0);
            fit.add(&mut g, x - t, v, D::S, -1.0);
            g
        })
        .collect();
    let tt: f64 = half.iter().map(|(t, wt)| wt * t * t).sum();
    let mut linear = fit.zero();
    for ((t, wt), g) in half.iter().zip(&odd) {
        linear.axpy(wt * t / tt, g, 1.0);
    }
    let beyond: Vec<DVector<f64>> = half
        .iter()
        .zip(odd)
        .map(|((t, _), g)| g - &linear * *t)
        .collect();
    let (mut noise, mut total) = (0.0, 0.0);
    for ((_, wt), var) in half.iter().zip(fit.variances(&beyond)) {
        noise += wt * var;
        total += wt;
    }
    Some(typical / (noise / total))
}

/// The misfit of the reflection about the surface's normal at x (the refinement's residual,
/// blind to a turn of the section), per unit weight, and the slope there.
fn normal_misfit(fit: &Fit, v: f64, x: f64, w: f64) -> Option<(f64, f64)> {
    let slope = fit.value(x, v, D::A)?;
    let (m, _) = reflection(slope.atan());
    let p = Vector2::new(x, fit.value(x, v, D::S)?);
    let (mut rr, mut total) = (0.0, 0.0);
    for (t, wt) in offsets(w, SAMPLES) {
        let (_, _, r) = mirrored(fit, v, (p, &m), t)?;
        rr += wt * r * r;
        total += wt;
    }
    Some((rr / total, slope))
}

/// The coarse search over [lo, hi] (a quarter knot apart) in a section measured over `run`:
/// each candidate's odd-part misfit over the window times that over a wider one (a paraspinal
/// muscle's crest looks symmetric close by, the trunk about it does not), and the window's
/// linear term's slope. The wider window is one for all candidates, up to twice the window as
/// far as the run allows about each: a narrower one near the run's edge would hold less of the
/// trunk, and favour the candidates there. (The levels search to a window and a knot from
/// their run's ends, so it is wider than the window only where the run is over two knots wider
/// than the median: the shoulders, the hips.) Each local minimum is then found to within
/// [`TOLERANCE`]: at a spinous groove the misfit's minimum is narrower than the step, and a
/// candidate a few mm beside it scores worse than a false axis elsewhere.
///
/// `about_normal` (standing): the misfit is the reflection's about the surface's normal at
/// each candidate, not the odd part's after its linear term, which a section turned with the
/// subject no longer fits (its two sides foreshorten unequally): on the real backs turned from
/// the camera, one lost its line at +5° with the odd part and held it to +7° about the normal.
/// Bent forward a section is a convex arc, mirror symmetric about every normal, and the odd
/// part in the camera's frame breaks that tie (about the normal, one real back's scoliometer
/// reading moved with the lattice's placement by 6.5 times its σ).
pub(crate) fn coarse(
    fit: &Fit,
    v: f64,
    w: f64,
    (lo, hi): (f64, f64),
    run: (f64, f64),
    about_normal: bool,
) -> Vec<Candidate> {
    let step = fit.grid.step / 4.0;
    let count = ((hi - lo) / step).floor() as usize;
    let wide = (2.0 * w).min(lo - run.0).min(run.1 - hi).max(w);
    let misfit = |x: f64, w: f64| {
        if about_normal {
            normal_misfit(fit, v, x, w)
        } else {
            odd_misfit(fit, v, x, w)
        }
    };
    let at = |x: f64| {
        let (e, b) = misfit(x, w)?;
        let (e_wide, _) = misfit(x, wide)?;
        Some((x, e * e_wide, b))
    };
    let scan: Vec<_> = (0..=count)
        .filter_map(|k| at(lo + k as f64 * step))
        .collect();
    // Each local minimum is searched between its neighbours; a range's end where the misfit
    // still falls outward stands for a minimum beyond it, and is searched a step further out
    // (so that it competes as fairly as the refined minima; a path through it drops the level).
    let refined = |k: usize| {
        let c = scan[k];
        let (p, n) = (k.checked_sub(1).map(|j| scan[j]), scan.get(k + 1));
        let minimum = p.is_none_or(|p| c.1 < p.1) && n.is_none_or(|n| c.1 <= n.1);
        let (a, b) = match (p, n) {
            (Some(p), Some(n)) => (p.0, n.0),
            (None, _) => (c.0 - step, c.0),
            (_, None) => (c.0, c.0 + step),
        };
        let found = minimum.then(|| least(&at, a, b)).flatten();
        found.filter(|r| r.1 < c.1).unwrap_or(c)
    };
    (0..scan.len()).map(refined).collect()
}

/// The coarse search's refinement of a local minimum (mm).
const TOLERANCE: f64 = 0.05;

/// The least of `f` over (a, b) by golden-section search, to within [`TOLERANCE`].
fn least(f: &impl Fn(f64) -> Option<Candidate>, mut a: f64, mut b: f64) -> Option<Candidate> {
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let mut p = f(b - g * (b - a))?;
    let mut q = f(a + g * (b - a))?;
    while b - a > TOLERANCE {
        if p.1 < q.1 {
            b = q.0;
            q = p;
            p = f(b - g * (b - a))?;
        } else {
            a = p.0;
            p = q;
            q = f(a + g * (b - a))?;
        }
    }
    Some(if p.1 < q.1 { p } else { q })
}

/// The symmetry point at level v with a window of half-width `w`: from the best of the coarse
/// `candidates` within `near` (a from, a to), Gauss-Newton on the reflection, kept within
/// [lo, hi].
pub(crate) fn symmetry_at(
    fit: &Fit,
    v: f64,
    w: f64,
    candidates: &[Candidate],
    near: (f64, f64),
    (lo, hi): (f64, f64),
) -> Option<Symmetry> {
    let step = fit.grid.step / 4.0;
    let (mut x, mut theta) = candidates
        .iter()
        .filter(|c| (near.0..=near.1).contains(&c.0))
        .min_by(|p, q| p.1.total_cmp(&q.1))
        .map(|&(x, _, b)| (x, b.atan()))?;
    let mut solved = None;
    for _ in 0..30 {
        let mut ata = Matrix2::zeros();
        let mut atr = Vector2::zeros();
        let mut rows = Vec::with_capacity(2 * SAMPLES);
        for (t, wt) in offsets(w, SAMPLES) {
            let r = residual(fit, v, x, theta, t)?;
            ata += wt * r.jp * r.jp.transpose();
            atr += wt * r.jp * r.r;
            rows.push((wt, r));
        }
        let inv = ata.try_inverse()?;
        let d = inv * atr;
        x -= d.x.clamp(-step, step);
        theta -= d.y.clamp(-0.05, 0.05);
        if !(lo..=hi).contains(&x) {
            return None;
        }
        solved = Some((inv, rows));
        if d.x.abs() < 1e-6 && d.y.abs() < 1e-8 {
            break;
        }
    }
    let (inv, rows) = solved?;
    let mut gradient = fit.zero();
    let mut theta_gradient = fit.zero();
    for (wt, r) in &rows {
        // d(x, θ) = −(JᵀΩJ)⁻¹ JᵀΩ ∂r/∂c
        let k = -(inv * r.jp) * *wt;
        for &(a, d, weight) in &r.terms {
            fit.add(&mut gradient, a, v, d, k.x * weight);
            fit.add(&mut theta_gradient, a, v, d, k.y * weight);
        }
    }
    Some(Symmetry {
        a: x,
        gradient,
        theta,
        theta_gradient,
    })
}
