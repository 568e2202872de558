//! The indices along the symmetry line (deviation, imbalance, inclination, kyphosis,
//! lordosis, their largest and RMS values) and the maps. The σ are propagated from the fit
//! twice: the levels' values first, then the indices, whose largest and RMS values need the
//! levels' σ (what choosing the largest and the noise's share of an RMS add).

use super::levels::{LevelVars, Measured, Var};
use super::{selection, Axes, BackAnalysis, Level, Map, Posture};
use crate::spline::D;
use nalgebra::DVector;

impl Measured<'_> {
    pub(super) fn summarise(
        &self,
        levels: Vec<LevelVars>,
        left_out: Vec<f64>,
        window: f64,
        skin_d: f64,
        spacing: f64,
        misfit: f64,
    ) -> BackAnalysis {
        let n = levels.len();
        let (first, last) = (&levels[0], &levels[n - 1]);
        let span = last.v - first.v;
        let deviation: Vec<Var> = levels
            .iter()
            .enumerate()
            .map(|(k, l)| {
                if k == 0 || k + 1 == n {
                    // The ends lie on the line through them: nought, with no uncertainty.
                    Var::sum(&[(&l.x, 0.0)])
                } else {
                    let f = (l.v - first.v) / span;
                    Var::sum(&[(&l.x, 1.0), (&first.x, f - 1.0), (&last.x, -f)])
                }
            })
            .collect();
        let rotations: Vec<&Var> = levels.iter().map(|l| &l.rotation).collect();
        let deviations: Vec<&Var> = deviation.iter().collect();
        let imbalance = Var::sum(&[(&last.x, 1.0), (&first.x, -1.0)]);
        let rise = last.depth.value - first.depth.value;
        let c = span / (span * span + rise * rise);
        let inclination = Var {
            value: rise.atan2(span),
            ..Var::sum(&[(&last.depth, c), (&first.depth, -c)])
        };
        let (kyphosis, lordosis) = match self.posture {
            Posture::Standing => sagittal_angles(&levels),
            Posture::ForwardBent => (None, None),
        };
        let atrs: Vec<&Var> = levels
            .iter()
            .filter_map(|l| l.atr.as_ref().map(|a| &a.0))
            .collect();
        // The levels' σ in one propagation: x, depth, rotation, sagittal, deviation, skin, atr.
        let mut grads: Vec<DVector<f64>> = Vec::new();
        let mut sampling: Vec<f64> = Vec::new();
        let mut slot = |var: &Var| {
            grads.push(var.gradient.clone());
            sampling.push(var.own());
            grads.len() - 1
        };
        let per_level: Vec<[Option<usize>; 7]> = levels
            .iter()
            .zip(&deviation)
            .map(|(l, d)| {
                [
                    Some(slot(&l.x)),
                    Some(slot(&l.depth)),
                    Some(slot(&l.rotation)),
                    Some(slot(&l.sagittal)),
                    Some(slot(d)),
                    l.skin.as_ref().map(&mut slot),
                    l.atr.as_ref().map(|a| slot(&a.0)),
                ]
            })
            .collect();
        let sigma = self.fit.sigmas(&grads, &sampling);
        // Each level's σ of the value in `field` (where the level has one).
        let of = |field: usize| -> Vec<f64> {
            per_level
                .iter()
                .filter_map(|k| k[field])
                .map(|k| sigma[k])
                .collect()
        };
        let (rot_sigma, dev_sigma) = (of(2), of(4));
        let rot_max = self.largest(&rotations, &rot_sigma);
        let rot_rms = self.rms(&rotations, &rot_sigma);
        let dev_max = self.largest(&deviations, &dev_sigma);
        let dev_rms = self.rms(&deviations, &dev_sigma);
        let atr_max = (!atrs.is_empty()).then(|| self.largest(&atrs, &of(6)));
        let scalars = [
            Some(&rot_max),
            Some(&rot_rms),
            Some(&dev_max),
            Some(&dev_rms),
            Some(&imbalance),
            Some(&inclination),
            kyphosis.as_ref(),
            lordosis.as_ref(),
            atr_max.as_ref(),
        ];
        // The indices' σ, in a second propagation.
        let present: Vec<&Var> = scalars.iter().flatten().copied().collect();
        let mut present_sigma = self.sigmas(&present).into_iter();
        let scalar_sigma: Vec<Option<f64>> = scalars
            .iter()
            .map(|v| v.and_then(|_| present_sigma.next()))
            .collect();
        let sd = |k: Option<usize>| k.map(|k| sigma[k]);
        let deg = f64::to_degrees;
        let out_levels = levels
            .iter()
            .zip(&deviation)
            .zip(&per_level)
            .map(|((l, d), k)| Level {
                y: l.v,
                symmetry_x: l.x.value,
                symmetry_x_sigma: sigma[k[0].unwrap_or(0)],
                depth_mm: l.depth.value,
                depth_sigma_mm: sigma[k[1].unwrap_or(0)],
                rotation_deg: deg(l.rotation.value),
                rotation_sigma_deg: deg(sigma[k[2].unwrap_or(0)]),
                sagittal_slope_deg: deg(l.sagittal.value),
                sagittal_slope_sigma_deg: deg(sigma[k[3].unwrap_or(0)]),
                lateral_deviation_mm: d.value,
                lateral_deviation_sigma_mm: sigma[k[4].unwrap_or(0)],
                skin_angle_deg: l.skin.as_ref().map(|s| deg(s.value)),
                skin_angle_sigma_deg: sd(k[5]).map(deg),
                atr_deg: l.atr.as_ref().map(|a| deg(a.0.value)),
                atr_sigma_deg: sd(k[6]).map(deg),
                atr_window: l.atr.as_ref().map(|a| a.1),
                symmetry_x_rival: l.rival_x,
            })
            .collect();
        let s = |i: usize| scalar_sigma[i].unwrap_or(f64::NAN);
        let (asymmetry, topography, cells) = self.maps(&levels);
        let asymmetry_max = self.largest_inside(&asymmetry, &cells, &levels);
        BackAnalysis {
            posture: self.posture,
            frames: 1,
            points: 0,
            calibration: None,
            spacing_mm: spacing,
            irregularity: 0.0,
            wild: Vec::new(),
            planes_left_out: Vec::new(),
            points_apart: 0,
            axes: Axes {
                across: [1.0, 0.0, 0.0],
                axis: [0.0, 1.0, 0.0],
                up: [0.0, 0.0, 1.0],
            },
            symmetry_window_mm: window,
            skin_angle_distance_mm: skin_d,
            fit_chi: self.fit.chi(),
            misfit_mm: misfit,
            asymmetry_over_noise: f64::NAN,
            levels: out_levels,
            levels_left_out: left_out,
            rotation_max_deg: deg(rot_max.value),
            rotation_max_deg_sigma: deg(s(0)),
            rotation_rms_deg: deg(rot_rms.value),
            rotation_rms_deg_sigma: deg(s(1)),
            lateral_deviation_max_mm: dev_max.value,
            lateral_deviation_max_mm_sigma: s(2),
            lateral_deviation_rms_mm: dev_rms.value,
            lateral_deviation_rms_mm_sigma: s(3),
            trunk_imbalance_mm: imbalance.value,
            trunk_imbalance_mm_sigma: s(4),
            trunk_inclination_deg: deg(inclination.value),
            trunk_inclination_deg_sigma: deg(s(5)),
            kyphosis_deg: kyphosis.as_ref().map(|k| deg(k.value)),
            kyphosis_deg_sigma: scalar_sigma[6].map(deg),
            lordosis_deg: lordosis.as_ref().map(|k| deg(k.value)),
            lordosis_deg_sigma: scalar_sigma[7].map(deg),
            atr_max_deg: atr_max.as_ref().map(|a| deg(a.value)),
            atr_max_deg_sigma: scalar_sigma[8].map(deg),
            asymmetry_max_mm: asymmetry_max.map(|m| m.0),
            asymmetry_max_mm_sigma: asymmetry_max.map(|m| m.1),
            asymmetry_max_at: asymmetry_max.map(|m| m.2),
            sway: vec![],
            asymmetry,
            topography,
        }
    }

    /// The mirror-asymmetry map (with σ) and the topography, one dot spacing apart across, at
    /// the levels, with the gradients of the asymmetry map's measured cells in its order.
    fn maps(&self, levels: &[LevelVars]) -> (Map, Map, Vec<DVector<f64>>) {
        let step = self.fit.grid.step;
        let (lo, hi) = levels
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), l| {
                let r = self
                    .support
                    .longest_run(l.v)
                    .unwrap_or((l.x.value, l.x.value));
                (lo.min(r.0), hi.max(r.1))
            });
        let a: Vec<f64> = (0..=((hi - lo) / step).floor() as usize)
            .map(|i| lo + i as f64 * step)
            .collect();
        let mut asym = Vec::new();
        let mut grads = Vec::new();
        let mut sampling = Vec::new();
        let mut depth = Vec::new();
        for l in levels {
            for &x in &a {
                let on = self.support.contains(x, l.v);
                depth.push(on.then(|| self.value(x, l.v, D::S)));
                let mirror = 2.0 * l.x.value - x;
                if on && self.support.contains(mirror, l.v) {
                    let g = self.moving(x, l.v, D::S, D::A, &DVector::zeros(self.fit.unknowns()))
                        - self.moving(mirror, l.v, D::S, D::A, &(&l.x.gradient * 2.0));
                    asym.push(Some(
                        self.value(x, l.v, D::S) - self.value(mirror, l.v, D::S),
                    ));
                    grads.push(g);
                    sampling.push(2.0 * self.value(mirror, l.v, D::A) * l.x.spread());
                } else {
                    asym.push(None);
                }
            }
        }
        let mut sigma = self.fit.sigmas(&grads, &sampling).into_iter();
        let sigmas = asym.iter().map(|x| x.and_then(|_| sigma.next())).collect();
        let v: Vec<f64> = levels.iter().map(|l| l.v).collect();
        let cells = depth.len();
        (
            Map {
                a: a.clone(),
                v: v.clone(),
                values: asym,
                sigmas,
            },
            Map {
                a,
                v,
                values: depth,
                sigmas: vec![None; cells],
            },
            grads,
        )
    }

    /// The asymmetry map's value of largest magnitude (signed) on the +a side of the symmetry
    /// line (the map is odd about the line: its other side holds the same values negated)
    /// with its σ (what choosing it among the cells adds included: [`selection`]) and its
    /// cell (a, v), where the cell and its mirror image lie a grid step or more inside the
    /// measured surface (at its edges the fit ends). `cells`: the gradients of the map's
    /// measured cells.
    fn largest_inside(
        &self,
        map: &Map,
        cells: &[DVector<f64>],
        levels: &[LevelVars],
    ) -> Option<(f64, f64, [f64; 2])> {
        let na = map.a.len();
        let step = self.fit.grid.step;
        // (map index, gradient, value, σ) of the cells inside.
        let inside: Vec<(usize, &DVector<f64>, f64, f64)> = map
            .values
            .iter()
            .zip(&map.sigmas)
            .enumerate()
            .filter_map(|(k, (v, s))| Some((k, v.as_ref()?, s.as_ref()?)))
            .zip(cells)
            .filter(|((k, _, _), _)| {
                let (a, l) = (map.a[k % na], &levels[k / na]);
                let mirror = 2.0 * l.x.value - a;
                a > l.x.value && self.support.covers(mirror - step, a + step, l.v)
            })
            .map(|((k, v, s), cell)| (k, cell, *v, *s))
            .collect();
        let values: Vec<f64> = inside.iter().map(|c| c.2).collect();
        let sigma: Vec<f64> = inside.iter().map(|c| c.3).collect();
        let (j, added) = selection::largest(&values, &sigma, |at| {
            let grads: Vec<DVector<f64>> = at.iter().map(|&i| inside[i].1.clone()).collect();
            self.fit.covariance(&grads)
        })?;
        let k = inside[j].0;
        Some((
            values[j],
            sigma[j].hypot(added),
            [map.a[k % na], levels[k / na].v],
        ))
    }

    /// The σ of each of `vars`.
    fn sigmas(&self, vars: &[&Var]) -> Vec<f64> {
        let grads: Vec<DVector<f64>> = vars.iter().map(|v| v.gradient.clone()).collect();
        let sampling: Vec<f64> = vars.iter().map(|v| v.own()).collect();
        self.fit.sigmas(&grads, &sampling)
    }

    /// The value of largest magnitude (signed) with its gradient, its sampling term holding
    /// what choosing it among the levels adds ([`selection`]); `sigma`: each value's σ.
    /// Where the line is ambiguous, that term also holds [`selection::ambiguity`], in place
    /// of its level's rival.
    fn largest(&self, vars: &[&Var], sigma: &[f64]) -> Var {
        let values: Vec<f64> = vars.iter().map(|v| v.value).collect();
        let (j, added) = selection::largest(&values, sigma, |at| {
            let g: Vec<DVector<f64>> = at.iter().map(|&k| vars[k].gradient.clone()).collect();
            self.fit.covariance(&g)
        })
        .expect("at least one level");
        let rivals: Vec<Option<f64>> = vars.iter().map(|v| v.rival).collect();
        let ambiguity = selection::ambiguity(&values, &rivals);
        Var {
            sampling: vars[j].sampling.hypot(added).hypot(ambiguity),
            rival: None,
            ..vars[j].clone()
        }
    }

    /// The RMS with its gradient. The values' noise adds to their mean square (its expectation
    /// is the truth's plus the mean of their variances), so the RMS leans away from the
    /// truth's by rms − √(rms² − mean σ²): its sampling term holds that in quadrature. On a
    /// straight back, whose profile is mostly noise, the RMS rotation was 0.26° off (20 mm, 30
    /// draws), 3.3 times the σ its gradient gives. `sigma`: each value's σ.
    fn rms(&self, vars: &[&Var], sigma: &[f64]) -> Var {
        let n = vars.len() as f64;
        let value = (vars.iter().map(|v| v.value * v.value).sum::<f64>() / n).sqrt();
        // d rms / d v_k = v_k / (n rms); all zero where every value is.
        let c = if value > 0.0 { 1.0 / (n * value) } else { 0.0 };
        let terms: Vec<(&Var, f64)> = vars.iter().map(|v| (*v, v.value * c)).collect();
        let noise = sigma.iter().map(|s| s * s).sum::<f64>() / n;
        let sum = Var::sum(&terms);
        Var {
            value,
            sampling: sum
                .sampling
                .hypot(value - (value * value - noise).max(0.0).sqrt()),
            ..sum
        }
    }
}

/// Kyphosis and lordosis from the sagittal slopes (module docs).
fn sagittal_angles(levels: &[LevelVars]) -> (Option<Var>, Option<Var>) {
    let slope = |i: usize| levels[i].sagittal.value;
    let Some(itl) = (0..levels.len()).max_by(|&i, &j| slope(i).total_cmp(&slope(j))) else {
        return (None, None);
    };
    let least =
        |range: std::ops::Range<usize>| range.min_by(|&i, &j| slope(i).total_cmp(&slope(j)));
    let angle = |other: Option<usize>| {
        other.map(|o| Var::sum(&[(&levels[itl].sagittal, 1.0), (&levels[o].sagittal, -1.0)]))
    };
    // Levels run bottom to top: the cervico-thoracic inflection is above the thoraco-lumbar.
    (angle(least(itl + 1..levels.len())), angle(least(0..itl)))
}
