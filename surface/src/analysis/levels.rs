//! The per-level measurement: the levels, the symmetry line chained through them, and each
//! level's values with their gradients.

use super::{BackAnalysis, Posture, MIN_WIDTH};
use crate::fit::Fit;
use crate::median;
use crate::scoliometer::resting_line;
use crate::spline::D;
use crate::support::Support;
use crate::symmetry::{asymmetry, coarse, symmetry_at, Candidate, Symmetry};
use crate::SurfaceError;
use nalgebra::DVector;

/// A level and the run (a from, a to) of measured surface along it.
type Run = (f64, (f64, f64));

/// A level of the symmetry line: its symmetry point, a rival's where the line is ambiguous
/// there, the run (a from, a to) of measured surface along it, and the section's asymmetry
/// across the search against its noise ([`asymmetry`]).
struct Found {
    v: f64,
    symmetry: Symmetry,
    rival: Option<Symmetry>,
    run: (f64, f64),
    window: f64,
    asymmetry: f64,
}

/// A level's coarse search: its run, its candidates and the symmetry window's half-width.
struct Searched {
    v: f64,
    run: (f64, f64),
    candidates: Vec<Candidate>,
    window: f64,
    /// Whether the window cut the range short at an end where the misfit still falls toward
    /// it: a minimum may lie beyond, which a narrower window would reach.
    cut: bool,
}

impl Searched {
    /// Whether candidate j ends the searched range (the misfit may fall beyond it).
    fn at_end(&self, j: usize) -> bool {
        j == 0 || j + 1 == self.candidates.len()
    }
}

/// The fitted surface with where it was measured.
pub(super) struct Measured<'a> {
    pub(super) fit: &'a Fit,
    /// The fit of one frame's points, whose misfit gives the sampling terms.
    pub(super) sampled: &'a Fit,
    pub(super) support: &'a Support,
    pub(super) posture: Posture,
    /// The trunk's radius about its axis (mm): its half-width.
    pub(super) radius: f64,
}

/// A value with its gradient over the fit's unknowns, its sampling term (σ of what the
/// detail between the dots moves it by: [`Sampling`]), its registration term: what the
/// frames' registration moves it by, one error shared by every value that turns with the
/// surface (the σ of its share, signed, so that the terms of values combined add, not in
/// quadrature), and its rival: the value where the symmetry line may as well lie elsewhere
/// ([`Var::or`]).
#[derive(Clone)]
pub(super) struct Var {
    pub(super) value: f64,
    pub(super) gradient: DVector<f64>,
    pub(super) sampling: f64,
    pub(super) registration: f64,
    pub(super) rival: Option<f64>,
}

impl Var {
    /// A value without a registration term or a rival.
    pub(super) fn new(value: f64, gradient: DVector<f64>, sampling: f64) -> Self {
        Self {
            value,
            gradient,
            sampling,
            registration: 0.0,
            rival: None,
        }
    }

    /// This value turning with the surface: it holds the frames' registration, `registered`.
    fn turning(self, registered: f64) -> Self {
        Self {
            registration: registered,
            ..self
        }
    }

    /// The value's σ beside the fit's: its spread and registration terms.
    pub(super) fn own(&self) -> f64 {
        self.spread().hypot(self.registration)
    }

    /// σ of its sampling term and its rival's: the value is one of two, so their
    /// half-difference, in quadrature.
    pub(super) fn spread(&self) -> f64 {
        let either = self.rival.map_or(0.0, |rival| 0.5 * (self.value - rival));
        self.sampling.hypot(either)
    }

    /// atan of this slope.
    fn atan(self) -> Self {
        let d = 1.0 / (1.0 + self.value * self.value);
        Self {
            value: self.value.atan(),
            gradient: self.gradient * d,
            sampling: self.sampling * d,
            registration: self.registration * d,
            rival: self.rival.map(f64::atan),
        }
    }

    /// This value where it may as well be `rival`'s (the symmetry line ambiguous): its
    /// spread holds the two's half-difference ([`Var::spread`]).
    fn or(self, rival: &Var) -> Self {
        Self {
            rival: Some(rival.value),
            ..self
        }
    }

    /// Σ c_k var_k over distinct vars, their spreads independent, their registration one; a
    /// sum has no rival (its terms' are in its spread).
    pub(super) fn sum(terms: &[(&Var, f64)]) -> Self {
        let mut gradient = DVector::zeros(terms[0].0.gradient.len());
        for (var, c) in terms {
            gradient.axpy(*c, &var.gradient, 1.0);
        }
        Self {
            value: terms.iter().map(|(var, c)| c * var.value).sum(),
            gradient,
            sampling: terms
                .iter()
                .map(|(var, c)| (c * var.spread()).powi(2))
                .sum::<f64>()
                .sqrt(),
            registration: terms.iter().map(|(var, c)| c * var.registration).sum(),
            rival: None,
        }
    }
}

/// The sampling terms: surface detail between the dots (the spinous groove, the paraspinal
/// muscles), which the lattice samples unevenly about the symmetry line, moves the line and
/// its rotation by errors the points' noise does not hold, larger where the surface departs
/// more from its fit between the dots. Each level's symmetry point gets σ = [`K_LINE`] × the
/// misfit along the line ([`Measured::misfit_along`]) and its rotation [`K_ROTATION`] ×
/// misfit / window (rad), its depth [`K_DEPTH`] × misfit, independent from level to level;
/// every value measured at the symmetry point carries the line's term through its derivative
/// along the section.
/// Several frames share one frame's terms, from the misfit of frame 0's points alone
/// (`sampled`): the frames of a scan sample the back nearly where the first does (a subject
/// sways by a few mm, a fraction of a dot cell), so the detail between the dots moves each
/// alike, and their errors do not average out (three swayed frames err 0.58 mm where one errs
/// 0.61; with the combined fit's misfit, on its finer grid, the line's error/σ was 1.26).
/// Where the frames fall far apart on the cell the terms overstate.
/// Several frames' rotations also hold the frames' registration (`registered`): the surface,
/// fitted to all, turns by 1 / frames of each frame's turn about the trunk's axis (misfit /
/// radius, the sway's term), every level alike ([`Var::registration`]), and the skin angle
/// with it. Without it, three swayed frames through the image path read the rotation at
/// error/σ 1.29 (its common error across the levels about a third of the frames' turn errors
/// summed), now 1.08; simulated 1.04 → 0.88. Held per level apart, the RMS rotation read
/// 1.62 (simulated 1.19), now 0.91 (0.86); the skin angle 1.12 → 0.99. Standing only: bent
/// forward a frame's turn about the trunk's axis errs about a third of misfit / radius (0.09°
/// RMS over 16 placements of the lattice, error/σ 0.31), and three swayed frames read the
/// rotation at error/σ 0.74 (the scoliometer, without the term, 1.02-1.08).
/// Calibrated by Monte Carlo (the host's back_accuracy and back_image_path tests: nine backs at
/// 20 mm spacing, one frame and three swayed, each draw placed anew on the lattice): the
/// symmetry line's RMS of error/σ lies within 0.86-1.2 on each (1.05-1.45
/// without). The noiseless error is 0.2-0.5 mm RMS at 20 mm, 0.05-0.13 at 15 and 0.02-0.04 at
/// 10, where the misfit is 0.8-0.95, 0.4-0.5 and 0.16-0.21 mm.
#[derive(Clone, Copy)]
pub(super) struct Sampling {
    /// σ of the symmetry point across (mm).
    pub(super) line: f64,
    /// σ of the rotation (rad).
    pub(super) turn: f64,
    /// σ of the depth at the symmetry point (mm).
    pub(super) depth: f64,
    /// σ of the surface's turn about the trunk's axis from the frames' registration (rad),
    /// shared by every level.
    pub(super) registered: f64,
}

/// The line's sampling term per mm of misfit.
const K_LINE: f64 = 0.42;
/// The rotation's, per mm of misfit over the window's half-width.
const K_ROTATION: f64 = 0.1;
/// The depth's at the symmetry point, per mm of misfit: the spinous groove's bottom lies
/// between the dots, and the fit's depth there moves with where they fall on it. Without it
/// the trunk inclination (through the line's two ends) erred by 1.22-1.56 times its σ on the
/// back model at 20 mm (0.03° RMS of its 0.05° with a noiseless scan).
const K_DEPTH: f64 = 0.2;

/// One level's values.
pub(super) struct LevelVars {
    pub(super) v: f64,
    pub(super) x: Var,
    pub(super) depth: Var,
    pub(super) rotation: Var,
    pub(super) sagittal: Var,
    pub(super) skin: Option<Var>,
    pub(super) atr: Option<(Var, [f64; 2])>,
    /// The rival symmetry point where the line is ambiguous.
    pub(super) rival_x: Option<f64>,
}

impl LevelVars {
    /// This level's values where the symmetry point may as well be `rival`'s ([`Var::or`]).
    fn or(self, rival: LevelVars) -> Self {
        // A value the rival's level lacks (its window not measured) stays as it is.
        let or = |p: Var, q: Option<&Var>| match q {
            Some(q) => p.or(q),
            None => p,
        };
        Self {
            x: self.x.or(&rival.x),
            depth: self.depth.or(&rival.depth),
            rotation: self.rotation.or(&rival.rotation),
            sagittal: self.sagittal.or(&rival.sagittal),
            skin: self.skin.map(|p| or(p, rival.skin.as_ref())),
            atr: self
                .atr
                .map(|(p, w)| (or(p, rival.atr.as_ref().map(|a| &a.0)), w)),
            rival_x: Some(rival.x.value),
            ..self
        }
    }
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

    /// The levels: one dot spacing apart ([`Support::levels`]), where the trunk is at least
    /// MIN_WIDTH of its median width, with the run of measured surface at each. (Each level
    /// on a row's edge took the row above or below by rounding, and the top level was kept or
    /// not: five of 30 draws of a simulated back changed their levels for a sub-nanometre
    /// change of the dots.)
    fn levels(&self, spacing: f64) -> Result<(Vec<Run>, f64), SurfaceError> {
        let runs: Vec<Run> = self
            .support
            .levels(spacing)
            .into_iter()
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
        let found = self.symmetry_line(&runs, width, spacing);
        if found.len() < 3 {
            return Err(SurfaceError::NoLevels);
        }
        let w = width / 4.0;
        let length = found.last().map_or(0.0, |l| l.v) - found[0].v;
        let skin_d = 0.1 * length;
        let atr_half = width / 3.0;
        let line: Vec<(f64, f64)> = found.iter().map(|f| (f.v, f.symmetry.a)).collect();
        let misfit = self.misfit_along(&line, w, spacing);
        // Several frames: each other frame's registration turns it about the trunk's axis by
        // misfit / radius (the sway's term), and the surface, fitted to all, by 1 / frames of
        // each.
        let frames = self.fit.poses.len() as f64;
        let sampling = Sampling {
            line: K_LINE * misfit,
            turn: K_ROTATION * misfit / w,
            depth: K_DEPTH * misfit,
            registered: misfit / self.radius * (frames - 1.0).sqrt() / frames,
        };
        let levels: Vec<LevelVars> = found
            .iter()
            .map(|f| {
                // The rotation's sampling term is over its level's window (narrowed at a waist).
                let sampling = Sampling {
                    turn: sampling.turn * w / f.window,
                    ..sampling
                };
                let at = |s: &Symmetry| self.level(f.v, s, f.run, skin_d, atr_half, sampling);
                let level = at(&f.symmetry);
                match &f.rival {
                    Some(rival) => level.or(at(rival)),
                    None => level,
                }
            })
            .collect();
        let left_out = runs
            .iter()
            .map(|r| r.0)
            .filter(|v| found.iter().all(|f| f.v != *v))
            .collect();
        Ok(BackAnalysis {
            asymmetry_over_noise: median(found.iter().map(|f| f.asymmetry).collect()),
            ..self.summarise(levels, left_out, w, skin_d, spacing, misfit)
        })
    }

    /// The misfit of one frame's surface (`sampled`) within `window` of the symmetry line
    /// `line` ((v, a) per level; half a spacing beyond its ends), as on a grid one spacing
    /// apart (a coarser grid, where the coefficients' count bounds it, scaled by the square of
    /// the steps' ratio).
    fn misfit_along(&self, line: &[(f64, f64)], window: f64, spacing: f64) -> f64 {
        let x = |v: f64| {
            let k = line.partition_point(|l| l.0 < v).clamp(1, line.len() - 1);
            let (p, q) = (line[k - 1], line[k]);
            let f = ((v - p.0) / (q.0 - p.0)).clamp(0.0, 1.0);
            (1.0 - f) * p.1 + f * q.1
        };
        let (lo, hi) = (
            line[0].0 - spacing / 2.0,
            line[line.len() - 1].0 + spacing / 2.0,
        );
        let on_a_spacing = (spacing / self.sampled.grid.step).powi(2);
        on_a_spacing
            * self
                .sampled
                .misfit(|a, v| (lo..=hi).contains(&v) && (a - x(v)).abs() < window)
    }

    /// The symmetry line: each level's symmetry point over a window of a quarter of the median
    /// width either side, searched for within a quarter of the width from the run's middle.
    /// The levels are chained (a trunk's section is nearly circular, and an arc is mirror
    /// symmetric about any of its normals): the coarse candidates of all levels are joined by
    /// the path of least Σ ln(misfit) + Σ (Δx / Δv / [`LEAN`])², then each level is refined
    /// within a knot of its path, and of its rival's where the line is ambiguous ([`chain`]),
    /// each on its side of their midpoint (refined across it, both took one point, and the
    /// level's σ lost the other axis: on a real back 20.1 ± 0.6° where its mirror image read
    /// 25.2°, now 25.2 ± 2.5°).
    /// A level whose path ends its searched range is left out: its symmetry point may lie
    /// beyond, where the window does not fit the measured run. So is a level the path passes by
    /// ([`SKIP`]): one whose run the trunk's outline cuts short, seen through a turned lattice,
    /// holds candidates far from the line only. A level these leave alone (`spacing` apart) is
    /// left out after them ([`chained`]).
    /// Standing, a level whose path ends its range is first searched again with a quarter of
    /// its own run for its window where that is narrower: at a waist, where the measured
    /// surface ends within a window and a knot of the spine (on the real backs standing square,
    /// 17 levels left out where there were 33, most of them lumbar). So is a level whose window
    /// cut its range short where the misfit still falls toward the cut ([`Searched::cut`]),
    /// whatever the path: the path may take a false axis within the range where the true one
    /// lies beyond it. Without it, one real back (patient 10), on one of 32 lattice placements,
    /// put its line over 14 lower levels on a second axis 45 mm aside, σ 1-2 mm, no rival
    /// flagged, its largest rotation 19.8 ± 0.3° where the others read 25.2-25.4° (and with the
    /// levels placed half a row higher, its line changed between placements by 14.5 σ RMS; now
    /// 0.4). With it, one placement of the 32 takes that axis over 11 levels, each flagged with
    /// its rival (σ 19-26 mm), and the largest rotation, 19.9°, holds them: ± 2.7°
    /// ([`super::selection::ambiguity`]).
    fn symmetry_line(&self, runs: &[(f64, (f64, f64))], width: f64, spacing: f64) -> Vec<Found> {
        let w = width / 4.0;
        let margin = self.fit.grid.step;
        let standing = self.posture == Posture::Standing;
        let search = |v: f64, (lo, hi): (f64, f64), w: f64| {
            let mid = 0.5 * (lo + hi);
            let wanted = (mid - width / 4.0, mid + width / 4.0);
            let range = (wanted.0.max(lo + w + margin), wanted.1.min(hi - w - margin));
            let run = (lo + margin, hi - margin);
            let candidates = coarse(self.fit, v, w, range, run, standing);
            let n = candidates.len();
            let falls = |end: usize, next: usize| candidates[end].1 < candidates[next].1;
            let cut = n > 1
                && ((range.0 > wanted.0 && falls(0, 1))
                    || (range.1 < wanted.1 && falls(n - 1, n - 2)));
            (range.0 < range.1 && n > 0).then_some(Searched {
                v,
                run: (lo, hi),
                candidates,
                window: w,
                cut,
            })
        };
        let links = |s: &[Searched]| {
            let levels: Vec<_> = s.iter().map(|s| (s.v, s.candidates.as_slice())).collect();
            chain(&levels, margin)
        };
        let mut searched: Vec<Searched> = runs
            .iter()
            .filter_map(|&(v, run)| search(v, run, w))
            .collect();
        let mut path = links(&searched);
        // Standing, a waist's level whose path ends its range: searched again, narrower.
        let mut narrowed = false;
        for (s, link) in searched.iter_mut().zip(&path) {
            let narrow = w.min((s.run.1 - s.run.0) / 4.0);
            let ends = link.as_ref().is_some_and(|l| s.at_end(l.chosen));
            if standing && narrow < w && (ends || s.cut) {
                if let Some(again) = search(s.v, s.run, narrow) {
                    *s = again;
                    narrowed = true;
                }
            }
        }
        if narrowed {
            path = links(&searched);
        }
        let found = searched
            .iter()
            .zip(path)
            .filter_map(|(level, link)| {
                let (v, w, candidates) = (level.v, level.window, &level.candidates);
                let link = link.filter(|l| !level.at_end(l.chosen))?;
                // Within a knot of candidate j, on its side of the midpoint to `other`'s.
                let refined = |j: usize, other: Option<usize>| {
                    let x = candidates[j].0;
                    let mut near = (x - margin, x + margin);
                    if let Some(mid) = other.map(|o| 0.5 * (x + candidates[o].0)) {
                        near = if mid > x {
                            (near.0, near.1.min(mid))
                        } else {
                            (near.0.max(mid), near.1)
                        };
                    }
                    let s = symmetry_at(self.fit, v, w, candidates, near, near)?;
                    self.support
                        .covers(s.a - w - margin, s.a + w + margin, v)
                        .then_some(s)
                };
                let rival = match link.rival {
                    Some(j) if level.at_end(j) => return None,
                    Some(j) => Some(refined(j, Some(link.chosen))?),
                    None => None,
                };
                let symmetry = refined(link.chosen, link.rival)?;
                Some(Found {
                    v,
                    asymmetry: asymmetry(self.fit, v, symmetry.a, w, candidates)?,
                    symmetry,
                    rival,
                    run: level.run,
                    window: w,
                })
            })
            .collect();
        chained(found, spacing)
    }

    fn level(
        &self,
        v: f64,
        s: &Symmetry,
        (lo, hi): (f64, f64),
        skin_d: f64,
        atr_half: f64,
        sampling: Sampling,
    ) -> LevelVars {
        let (a, ga) = (s.a, &s.gradient);
        let line = sampling.line;
        let x = Var::new(a, ga.clone(), line);
        let depth = Var::new(
            self.value(a, v, D::S),
            self.moving(a, v, D::S, D::A, ga),
            (self.value(a, v, D::A) * line).hypot(sampling.depth),
        );
        let rotation =
            Var::new(s.theta, s.theta_gradient.clone(), sampling.turn).turning(sampling.registered);
        let sagittal = Var::new(
            self.value(a, v, D::V),
            self.moving(a, v, D::V, D::AV, ga),
            (self.value(a, v, D::AV) * line).abs(),
        )
        .atan();
        let skin = self.support.covers(a - skin_d, a + skin_d, v).then(|| {
            let g = self.moving(a + skin_d, v, D::S, D::A, ga)
                - self.moving(a - skin_d, v, D::S, D::A, ga);
            let rise = self.value(a + skin_d, v, D::S) - self.value(a - skin_d, v, D::S);
            let turn = self.value(a + skin_d, v, D::A) - self.value(a - skin_d, v, D::A);
            Var::new(
                rise / (2.0 * skin_d),
                g / (2.0 * skin_d),
                (turn * line / (2.0 * skin_d)).abs(),
            )
            .atan()
            .turning(sampling.registered)
        });
        // The scoliometer rests on the back over a third of its width: where the window sits
        // moves its reading little (its RMS of error/σ is 0.9-1.06 without a sampling term).
        let atr = (self.posture == Posture::ForwardBent)
            .then(|| {
                let window = ((a - atr_half).max(lo), (a + atr_half).min(hi));
                let r = resting_line(self.fit, v, a, ga, window)?;
                let slope = Var::new(r.slope, r.gradient, 0.0);
                Some((slope.atan(), [window.0, window.1]))
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
            rival_x: None,
        }
    }
}

/// The levels chained to the line: a level with no other within 1.5 spacings (its neighbours
/// left out, or beyond the ends) has nothing to hold its symmetry point to the line, and is
/// left out, and so are two such levels at either end of the line (held to it from one side
/// only, across a gap). On the real forward-bent backs such a lone level at the line's end,
/// across a level left out, took a point 28 mm aside, and the largest scoliometer reading of
/// one back was −11.2 ± 0.6° on one lattice placement and +4.9 ± 2.1° on another (−4.0 to
/// −5.7° without it); a pair across two levels left out, 25 mm aside, read −12.0 ± 0.6° on
/// one placement where the others read −4.0 to −6.8°, and another back's thoracic pair
/// +15.2 ± 4.7° where the others read −9.0 to −9.7° (r(scoliometer, Cobb) 0.57-0.58 on the two
/// placements; 0.64-0.69 without the pairs).
fn chained(found: Vec<Found>, spacing: f64) -> Vec<Found> {
    // The stretches: levels each within 1.5 spacings of the last.
    let stretches: Vec<usize> = found
        .chunk_by(|p, q| q.v - p.v < 1.5 * spacing)
        .map(<[Found]>::len)
        .collect();
    let n = stretches.len();
    let held = stretches.iter().enumerate().flat_map(|(k, &len)| {
        let inner = k > 0 && k + 1 < n;
        std::iter::repeat_n(len > 2 || (len == 2 && inner), len)
    });
    found
        .into_iter()
        .zip(held)
        .filter_map(|(f, keep)| keep.then_some(f))
        .collect()
}

/// The symmetry line's usual lean from the axis (lateral mm per mm along): steeper steps
/// between levels cost as much as a misfit e times larger.
const LEAN: f64 = 0.25;

/// What leaving a level out of the path costs beyond its best candidate's ln(misfit), or
/// beyond the levels' median best where its own is worse: a level whose candidates all lie far
/// from its neighbours' line (a run cut short by the trunk's outline, a hole) is left out
/// instead of bending the line through the levels about it. 15 nats, the cost of a step of
/// about four [`LEAN`]s: on the real backs the fewest levels a scan keeps are as many as
/// without it (with 9 nats, up to three fewer). A level far less symmetric than the line's
/// others costs no more to leave out than a typical one: on the back model bent forward with a
/// dot missed by its top, two levels whose run a notch cut short (the line's neighbourhood out
/// of their search) held a false axis 39 mm aside, misfit e⁷ worse than the line's, and the
/// path left out a sound level between them and the line to keep them (line 2.4 mm RMS off
/// over 30 draws, error/σ 3.6; now 0.7 mm, 1.2).
const SKIP: f64 = 15.0;

/// What a rival path may cost beyond the chosen one for the symmetry line to be ambiguous
/// where they part. On the real forward-bent backs, where a section is a convex arc with two
/// mirror axes, where the lattice falls moves the difference between the two paths by about
/// ±5 nats (one patient's stretch of 17 levels: +3.4, −7.6 and +2.0 nats on three placements),
/// and the chain takes either; on the simulated backs no rival comes within 13 nats (of 4,553
/// levels, one under 20).
const AMBIGUOUS: f64 = 10.0;

/// A level's place on the chain: the candidate the path takes, and where a path more than
/// `apart` away there costs at most [`AMBIGUOUS`] more, that path's candidate.
struct Link {
    chosen: usize,
    rival: Option<usize>,
}

/// The path through each level's coarse candidates (x, misfit, _) of least
/// Σ ln(misfit) + Σ ((x_k − x_j) / (v_k − v_j) / LEAN)² over the levels it keeps (j the kept
/// level before k), a level left out costing [`SKIP`] more than its best candidate or the
/// levels' median best, the less of the two (dynamic programming), with the rival at each
/// level: of the least paths through each candidate (the two passes' min-marginals), the least
/// at a local minimum over the level's candidates more than `apart` from the path's, if it is
/// within [`AMBIGUOUS`] of the path (a second mirror axis the chain cannot tell from the
/// first). `None` where a level is left out.
fn chain(levels: &[(f64, &[Candidate])], apart: f64) -> Vec<Option<Link>> {
    let ahead = Pass::run(levels.iter().copied());
    let behind = Pass::run(levels.iter().rev().copied());
    let n = levels.len();
    ahead
        .path()
        .into_iter()
        .enumerate()
        .map(|(k, chosen)| {
            let chosen = chosen?;
            let c = levels[k].1;
            // The least path through each candidate: the passes' paths that end there, the
            // candidate's own cost counted once.
            let through: Vec<f64> = (0..c.len())
                .map(|j| ahead.total[k][j] + behind.total[n - 1 - k][j] - cost(&c[j]))
                .collect();
            let local = |j: usize| {
                (j == 0 || through[j] <= through[j - 1])
                    && through.get(j + 1).is_none_or(|t| through[j] <= *t)
            };
            let rival = (0..c.len())
                .filter(|&j| local(j) && (c[j].0 - c[chosen].0).abs() > apart)
                .min_by(|&p, &q| through[p].total_cmp(&through[q]))
                .filter(|&j| through[j] - ahead.least <= AMBIGUOUS);
            Some(Link { chosen, rival })
        })
        .collect()
}

/// A candidate's cost on the chain: the log of its misfit.
fn cost(c: &Candidate) -> f64 {
    c.1.max(1e-300).ln()
}

/// One pass of the chain's dynamic programming over the levels in the order given.
struct Pass {
    /// `total[k][i]`: the least cost of a path whose last kept level is k at candidate i.
    total: Vec<Vec<f64>>,
    /// The kept level and candidate before it.
    from: Vec<Vec<Option<(usize, usize)>>>,
    /// The least cost of a whole path, and its last kept level and candidate.
    least: f64,
    last: Option<(usize, usize)>,
}

impl Pass {
    fn run<'a>(levels: impl Iterator<Item = (f64, &'a [Candidate])>) -> Self {
        let levels: Vec<_> = levels.collect();
        let best: Vec<f64> = levels
            .iter()
            .map(|(_, c)| c.iter().map(cost).fold(f64::INFINITY, f64::min))
            .collect();
        let typical = median(best.clone());
        // skipped[k]: the cost of leaving out every level before k.
        let mut skipped = vec![0.0];
        for b in &best {
            skipped.push(skipped[skipped.len() - 1] + b.min(typical) + SKIP);
        }
        // The cost of leaving out the levels between j and k.
        let between = |j: usize, k: usize| skipped[k] - skipped[j + 1];
        let mut total: Vec<Vec<f64>> = Vec::with_capacity(levels.len());
        let mut from: Vec<Vec<Option<(usize, usize)>>> = Vec::with_capacity(levels.len());
        for (k, (v, candidates)) in levels.iter().enumerate() {
            let row: Vec<(f64, Option<(usize, usize)>)> = candidates
                .iter()
                .map(|c| {
                    let mut best = (skipped[k], None);
                    for (j, (pv, prev)) in levels[..k].iter().enumerate() {
                        for (i, p) in prev.iter().enumerate() {
                            let lean = (c.0 - p.0) / (v - pv) / LEAN;
                            let step = total[j][i] + between(j, k) + lean * lean;
                            if step < best.0 {
                                best = (step, Some((j, i)));
                            }
                        }
                    }
                    (cost(c) + best.0, best.1)
                })
                .collect();
            total.push(row.iter().map(|r| r.0).collect());
            from.push(row.iter().map(|r| r.1).collect());
        }
        let n = levels.len();
        let mut last = None;
        let mut least = skipped[n];
        for (k, row) in total.iter().enumerate() {
            for (i, t) in row.iter().enumerate() {
                let end = t + between(k, n);
                if end < least {
                    least = end;
                    last = Some((k, i));
                }
            }
        }
        Self {
            total,
            from,
            least,
            last,
        }
    }

    /// The least path: its candidate at each level, `None` where it is left out.
    fn path(&self) -> Vec<Option<usize>> {
        let mut path = vec![None; self.total.len()];
        let mut last = self.last;
        while let Some((k, i)) = last {
            path[k] = Some(i);
            last = self.from[k][i];
        }
        path
    }
}
