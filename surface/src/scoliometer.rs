//! The virtual scoliometer: the line resting on a section across the trunk, over a window
//! either side of the symmetry point (of all lines above the section, the lowest over the
//! symmetry point); its angle is the angle of trunk rotation (ATR).
//!
//! It rests on two contact points a₁ < x < a₂ (or touches at the symmetry point itself where
//! the section is convex there); to first order the contacts do not move with the surface, so
//! the slope's gradient is (∇s(a₂) − ∇s(a₁)) / (a₂ − a₁) (or that of ∂s/∂a at the point).

use crate::fit::Fit;
use crate::spline::D;
use nalgebra::DVector;

/// Sampling of the section (mm).
const STEP: f64 = 1.0;

/// A reading: the resting line's slope and its gradient over the fit's unknowns.
#[derive(Debug, Clone)]
pub(crate) struct Reading {
    pub slope: f64,
    pub gradient: DVector<f64>,
}

/// The height over `centre` of the lowest line of slope `m` above `section` ((a, n) samples).
fn height_over(section: &[(f64, f64)], centre: f64, m: f64) -> f64 {
    let over = section.iter().map(|&(a, n)| n - m * (a - centre));
    over.fold(f64::NEG_INFINITY, f64::max)
}

/// The slope of the line resting on `section` ((a, n) samples) across `centre`: of all lines
/// above the section, the lowest over `centre` (its height there is convex in the slope:
/// a ternary search within ±1.5, 56°). The simulator's true reading takes it on the exact
/// surface.
pub fn resting_slope(section: &[(f64, f64)], centre: f64) -> f64 {
    let (mut lo, mut hi) = (-1.5_f64, 1.5_f64);
    for _ in 0..100 {
        let (m1, m2) = (lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0);
        if height_over(section, centre, m1) < height_over(section, centre, m2) {
            hi = m2;
        } else {
            lo = m1;
        }
    }
    0.5 * (lo + hi)
}

/// The slope of the line resting on the section at level v over `window`, across the
/// symmetry point `centre` (whose gradient is `centre_gradient`).
pub(crate) fn resting_line(
    fit: &Fit,
    v: f64,
    centre: f64,
    centre_gradient: &DVector<f64>,
    window: (f64, f64),
) -> Option<Reading> {
    let left = ((centre - window.0) / STEP).floor() as usize;
    let right = ((window.1 - centre) / STEP).floor() as usize;
    let section: Vec<(f64, f64)> = (0..=left)
        .rev()
        .map(|k| centre - k as f64 * STEP)
        .chain((1..=right).map(|k| centre + k as f64 * STEP))
        .map(|a| fit.value(a, v, D::S).map(|n| (a, n)))
        .collect::<Option<_>>()?;
    let m = resting_slope(&section, centre);
    let top = height_over(&section, centre, m);
    let contact = |side: &mut dyn Iterator<Item = &(f64, f64)>| {
        side.map(|&(a, n)| (n - m * (a - centre), a))
            .max_by(|p, q| p.0.total_cmp(&q.0))
    };
    let (g1, a1) = contact(&mut section.iter().filter(|p| p.0 < centre - 0.5 * STEP))?;
    let (g2, a2) = contact(&mut section.iter().filter(|p| p.0 > centre + 0.5 * STEP))?;
    let tol = 1e-6 * (1.0 + top.abs());
    let mut gradient = fit.zero();
    let slope = if top - g1 < tol && top - g2 < tol {
        fit.add(&mut gradient, a2, v, D::S, 1.0 / (a2 - a1));
        fit.add(&mut gradient, a1, v, D::S, -1.0 / (a2 - a1));
        (fit.value(a2, v, D::S)? - fit.value(a1, v, D::S)?) / (a2 - a1)
    } else {
        fit.add(&mut gradient, centre, v, D::A, 1.0);
        gradient += centre_gradient * fit.value(centre, v, D::AA)?;
        fit.value(centre, v, D::A)?
    };
    Some(Reading { slope, gradient })
}
