//! The per-level measurement: the levels, the symmetry line chained through them, and each
//! level's values with their gradients.

use super::{BackAnalysis, Posture, MIN_WIDTH};
use crate::fit::Fit;
use crate::scoliometer::resting_line;
use crate::spline::D;
use crate::support::Support;
use crate::symmetry::{coarse, symmetry_at, Symmetry};
use crate::SurfaceError;
use nalgebra::DVector;

/// A level and the run (a from, a to) of measured surface along it.
type Run = (f64, (f64, f64));
/// A coarse candidate: position, misfit, slope.
type Candidate = (f64, f64, f64);

/// The fitted surface with where it was measured.
pub(super) struct Measured<'a> {
    pub(super) fit: &'a Fit,
    pub(super) support: &'a Support,
    pub(super) posture: Posture,
}

/// A value with its gradient over the fit's unknowns.
pub(super) struct Var {
    pub(super) value: f64,
    pub(super) gradient: DVector<f64>,
}

impl Var {
    fn angle(slope: f64, gradient: DVector<f64>) -> Self {
        Self {
            value: slope.atan(),
            gradient: gradient / (1.0 + slope * slope),
        }
    }
}

/// One level's values.
pub(super) struct LevelVars {
    pub(super) v: f64,
    pub(super) x: Var,
    pub(super) depth: Var,
    pub(super) rotation: Var,
    pub(super) sagittal: Var,
    pub(super) skin: Option<Var>,
    pub(super) atr: Option<(Var, [f64; 2])>,
}

impl Measured<'_> {
    pub(super) fn value(&self, a: f64, v: f64, d: D) -> f64 {
        self.fit.value(a, v, d).unwrap_or(f64::NAN)
    }

    /// ∇ of value d at (a(c), v) where a moves with gradient `ga`.
    pub(super) fn moving(&self, a: f64, v: f64, d: D, slope: D, ga: &DVector<f64>) -> DVector<f64> {
        let mut g = ga * self.value(a, v, slope);
        self.fit.add(&mut g, a, v, d, 1.0);
        g
    }

    /// The levels: one dot spacing apart, where the trunk is at least MIN_WIDTH of its
    /// median width, with the run of measured surface at each.
    fn levels(&self, spacing: f64) -> Result<(Vec<Run>, f64), SurfaceError> {
        let (v0, v1) = self.support.rows().ok_or(SurfaceError::NoLevels)?;
        let count = ((v1 - v0) / spacing).floor() as usize;
        let runs: Vec<Run> = (1..count)
            .map(|k| v0 + k as f64 * spacing)
            .filter_map(|v| self.support.longest_run(v).map(|r| (v, r)))
            .collect();
        let mut widths: Vec<f64> = runs.iter().map(|(_, (lo, hi))| hi - lo).collect();
        widths.sort_by(f64::total_cmp);
        let median = *widths.get(widths.len() / 2).ok_or(SurfaceError::NoLevels)?;
        let wide = runs
            .into_iter()
            .filter(|(_, (lo, hi))| hi - lo >= MIN_WIDTH * median)
            .collect();
        Ok((wide, median))
    }

    pub(super) fn analyse(&self, spacing: f64) -> Result<BackAnalysis, SurfaceError> {
        let (runs, width) = self.levels(spacing)?;
        let found = self.symmetry_line(&runs, width);
        if found.len() < 3 {
            return Err(SurfaceError::NoLevels);
        }
        let w = width / 4.0;
        let length = found.last().map_or(0.0, |l| l.0) - found[0].0;
        let skin_d = 0.1 * length;
        let atr_half = width / 3.0;
        let levels: Vec<LevelVars> = found
            .iter()
            .map(|(v, s, run)| self.level(*v, s, *run, skin_d, atr_half))
            .collect();
        Ok(self.summarise(levels, w, skin_d, spacing))
    }

    /// The symmetry line: each level's symmetry point over a window of a quarter of the median
    /// width either side, searched for within a quarter of the width from the run's middle.
    /// The levels are chained (a trunk's section is nearly circular, and an arc is mirror
    /// symmetric about any of its normals): the coarse candidates of all levels are joined by
    /// the path of least Σ ln(misfit) + Σ (Δx / Δv / [`LEAN`])², then each level is refined
    /// within a knot of its path.
    fn symmetry_line(
        &self,
        runs: &[(f64, (f64, f64))],
        width: f64,
    ) -> Vec<(f64, Symmetry, (f64, f64))> {
        let w = width / 4.0;
        let margin = self.fit.grid.step;
        let searched: Vec<_> = runs
            .iter()
            .filter_map(|&(v, (lo, hi))| {
                let mid = 0.5 * (lo + hi);
                let range = (
                    (mid - width / 4.0).max(lo + w + margin),
                    (mid + width / 4.0).min(hi - w - margin),
                );
                let candidates = coarse(self.fit, v, w, range, (lo + margin, hi - margin));
                (range.0 < range.1 && !candidates.is_empty()).then_some((v, (lo, hi), candidates))
            })
            .collect();
        let path = chain(
            &searched
                .iter()
                .map(|(v, _, c)| (*v, c.as_slice()))
                .collect::<Vec<_>>(),
        );
        searched
            .iter()
            .zip(path)
            .filter_map(|((v, run, candidates), x)| {
                let near = (x - margin, x + margin);
                let s = symmetry_at(self.fit, *v, w, candidates, near, near)?;
                self.support
                    .covers(s.a - w - margin, s.a + w + margin, *v)
                    .then_some((*v, s, *run))
            })
            .collect()
    }

    fn level(
        &self,
        v: f64,
        s: &Symmetry,
        (lo, hi): (f64, f64),
        skin_d: f64,
        atr_half: f64,
    ) -> LevelVars {
        let (a, ga) = (s.a, &s.gradient);
        let x = Var {
            value: a,
            gradient: ga.clone(),
        };
        let depth = Var {
            value: self.value(a, v, D::S),
            gradient: self.moving(a, v, D::S, D::A, ga),
        };
        let rotation = Var {
            value: s.theta,
            gradient: s.theta_gradient.clone(),
        };
        let sagittal = Var::angle(self.value(a, v, D::V), self.moving(a, v, D::V, D::AV, ga));
        let skin = self.support.covers(a - skin_d, a + skin_d, v).then(|| {
            let g = self.moving(a + skin_d, v, D::S, D::A, ga)
                - self.moving(a - skin_d, v, D::S, D::A, ga);
            let rise = self.value(a + skin_d, v, D::S) - self.value(a - skin_d, v, D::S);
            Var::angle(rise / (2.0 * skin_d), g / (2.0 * skin_d))
        });
        let atr = (self.posture == Posture::ForwardBent)
            .then(|| {
                let window = ((a - atr_half).max(lo), (a + atr_half).min(hi));
                let r = resting_line(self.fit, v, a, ga, window)?;
                Some((Var::angle(r.slope, r.gradient), [window.0, window.1]))
            })
            .flatten();
        LevelVars {
            v,
            x,
            depth,
            rotation,
            sagittal,
            skin,
            atr,
        }
    }
}

/// The symmetry line's usual lean from the axis (lateral mm per mm along): steeper steps
/// between levels cost as much as a misfit e times larger.
const LEAN: f64 = 0.25;

/// The path through each level's coarse candidates (x, misfit, _) of least
/// Σ ln(misfit) + Σ ((x_k − x_{k−1}) / (v_k − v_{k−1}) / LEAN)² (dynamic programming).
fn chain(levels: &[(f64, &[Candidate])]) -> Vec<f64> {
    let cost = |c: &Candidate| c.1.max(1e-300).ln();
    let mut total: Vec<Vec<f64>> = Vec::with_capacity(levels.len());
    let mut from: Vec<Vec<usize>> = Vec::with_capacity(levels.len());
    for (k, (v, candidates)) in levels.iter().enumerate() {
        let row: Vec<(f64, usize)> = candidates
            .iter()
            .map(|c| match k {
                0 => (cost(c), 0),
                _ => {
                    let (pv, prev) = levels[k - 1];
                    let step = |j: usize| {
                        let lean = (c.0 - prev[j].0) / (v - pv) / LEAN;
                        total[k - 1][j] + lean * lean
                    };
                    let best = (0..prev.len())
                        .min_by(|&i, &j| step(i).total_cmp(&step(j)))
                        .unwrap_or(0);
                    (cost(c) + step(best), best)
                }
            })
            .collect();
        total.push(row.iter().map(|r| r.0).collect());
        from.push(row.iter().map(|r| r.1).collect());
    }
    let Some(last) = total.last() else {
        return vec![];
    };
    let mut j = (0..last.len())
        .min_by(|&a, &b| last[a].total_cmp(&last[b]))
        .unwrap_or(0);
    let mut path = vec![0.0; levels.len()];
    for k in (0..levels.len()).rev() {
        path[k] = levels[k].1[j].0;
        j = from[k][j];
    }
    path
}
