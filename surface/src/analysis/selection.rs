//! The largest of several values and what choosing it adds to its σ.
//!
//! The largest rotation, lateral deviation or scoliometer reading is the value of one level,
//! and the largest asymmetry that of one cell of the map; but which one it is depends on the
//! noise. Where other values lie within the noise of it (a straight back's flat profile, a
//! double curve's two lobes alike, the many cells of a nearly flat map), the largest of several
//! noisy values leans away from the truth by the largest of their errors, not by its own: on a
//! straight back (20 mm, 30 draws) the largest rotation was 0.54° too large on average, 2.1 of
//! its level's σ. So its σ holds, in quadrature with its own, the expected largest error of
//! the values that compete with it, E[max_k s_k ε_k]: those whose magnitude lies within
//! [`COMPETING`] σ (of their difference) of the largest, s_k their signs, ε their errors drawn
//! jointly from the covariance the points' noise and the calibration's share give them
//! ([`DRAWS`] draws from a fixed seed: an analysis repeated gives the same σ). The sampling
//! terms (what the lattice makes of the detail between the dots, [`super::levels`]) fall alike
//! on neighbouring values, which are the ones that compete: they move the largest with its
//! rivals instead of choosing among them, and stay its own. A lone peak competes with nothing
//! and keeps its own σ; a value read with a large σ competes from far below, since its truth
//! may be the largest: on a real back bent forward (patient 4 of the real backs, 15 mm) two
//! levels read −1.3 ± 6.9° and 1.4 ± 7.4°, and the largest reading, −4.4°, is ± 5.3° (± 0.5°
//! its own).
//!
//! On the back model (20 mm, 30 draws; RMS error/σ before → with the choice's term): on a
//! straight back the largest rotation 2.10 → 1.09, the largest scoliometer reading 2.12 → 1.04,
//! the largest lateral deviation 1.62 → 1.04; on four curves 0.78-1.16 → 0.75-1.10, 0.83-1.05 →
//! 0.77-1.02 and 0.59-0.90 → 0.45-0.82 (a curve's deviation already held more than its error).
//! Through the whole image path, a straight back's largest asymmetry 2.12 → 1.08 standing and
//! 2.05 → 1.01 bent forward.
//!
//! Where the symmetry line is ambiguous, the largest also lies anywhere in the range its
//! levels' rivals give it ([`ambiguity`]).

use nalgebra::{DMatrix, DVector, SymmetricEigen};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// How many σ of their difference below the largest a value still competes with it.
const COMPETING: f64 = 2.0;
/// Draws of the competitors' errors.
const DRAWS: usize = 2000;

/// The index of the value of largest magnitude among `values` (σ `sigma`), and the σ its
/// choice adds (module docs); `covariance` gives the covariance of the values at some indices.
pub(super) fn largest(
    values: &[f64],
    sigma: &[f64],
    covariance: impl Fn(&[usize]) -> DMatrix<f64>,
) -> Option<(usize, f64)> {
    let j = (0..values.len()).max_by(|&p, &q| values[p].abs().total_cmp(&values[q].abs()))?;
    let top = values[j].abs();
    // σ of a difference is at most the sum of the two σ: the competitors are among these.
    let near: Vec<usize> = (0..values.len())
        .filter(|&k| k == j || top - values[k].abs() < COMPETING * (sigma[j] + sigma[k]))
        .collect();
    if near.len() < 2 {
        return Some((j, 0.0));
    }
    let c = covariance(&near);
    let sign = |k: usize| values[near[k]].signum();
    let at = near
        .iter()
        .position(|&k| k == j)
        .expect("the largest is among the near");
    let competing: Vec<usize> = (0..near.len())
        .filter(|&k| {
            let difference = c[(at, at)] + c[(k, k)] - 2.0 * sign(at) * sign(k) * c[(at, k)];
            k == at || top - values[near[k]].abs() < COMPETING * difference.max(0.0).sqrt()
        })
        .collect();
    if competing.len() < 2 {
        return Some((j, 0.0));
    }
    let c = DMatrix::from_fn(competing.len(), competing.len(), |p, q| {
        c[(competing[p], competing[q])] * sign(competing[p]) * sign(competing[q])
    });
    Some((j, expected_largest(c)))
}

/// Half the range of the largest magnitude among `values` where each that has a rival
/// (`rivals`, the symmetry line ambiguous there: [`super::levels::Var::or`]) may as well be
/// it: the largest read lies in that range, one of its ends or between, whichever axis each
/// ambiguous level takes. This, not the largest's own level's rival, is what the line's
/// ambiguity adds to its σ. On the real backs (15 mm, 32 lattice placements each): patient 10
/// standing, on one placement the line followed a second axis over 11 levels, each flagged
/// (σ 19-26 mm), and the largest rotation, 19.9° on one of them, was ± 0.9° (its own rival
/// reading near it) where the other placements read 24.8-25.4°; with every level at its
/// rival it reads 25.2°, and the largest is now 19.9 ± 2.7°. Where the largest level is
/// ambiguous but a clear one reads nearly as much, its own rival overstated the σ: the same
/// back on the aligned lattice 25.3 ± 2.1° (now ± 0.5°), and patient 5 bent forward, its scan
/// mirrored, −24.7 ± 9.0° (now ± 0.7°; unmirrored +24.4 ± 0.8°). Over the 32 placements,
/// the RMS of each largest's departure from its back's median, over its σ, went from 1.59 to
/// 1.56 standing and 1.09 to 1.08 bent forward (patient 10: 1.13 to 0.55 and 1.60 to 1.35).
pub(super) fn ambiguity(values: &[f64], rivals: &[Option<f64>]) -> f64 {
    let either = values.iter().zip(rivals).map(|(v, r)| {
        let r = r.unwrap_or(*v);
        (v.abs().min(r.abs()), v.abs().max(r.abs()))
    });
    let (least, most) = either.fold((0.0, 0.0), |(a, b), (l, m)| (l.max(a), m.max(b)));
    0.5 * (most - least)
}

/// E[max_k ε_k] for ε ~ N(0, c), by Monte Carlo.
fn expected_largest(c: DMatrix<f64>) -> f64 {
    let eigen = SymmetricEigen::new(c);
    let root =
        &eigen.eigenvectors * DMatrix::from_diagonal(&eigen.eigenvalues.map(|l| l.max(0.0).sqrt()));
    let mut rng = ChaCha8Rng::seed_from_u64(18);
    let n = root.ncols();
    let sum: f64 = (0..DRAWS)
        .map(|_| {
            let z = DVector::from_fn(n, |_, _| StandardNormal.sample(&mut rng));
            (&root * z).max()
        })
        .sum();
    sum / DRAWS as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Independent values of σ 1 at `values`.
    fn independent(values: &[f64]) -> Option<(usize, f64)> {
        largest(values, &vec![1.0; values.len()], |at| {
            DMatrix::identity(at.len(), at.len())
        })
    }

    #[test]
    fn a_flat_profile_adds_the_largest_of_its_noise() {
        // E[max] of 10 independent standard normals is 1.5388; the draws' own error is 0.013.
        let (_, added) = independent(&[0.0; 10]).unwrap();
        assert!((added - 1.5388).abs() < 0.05, "{added}");
        // Two of opposite sign compete alike: E[max] of two is 1/√π.
        let (j, added) = independent(&[1.0, -1.2]).unwrap();
        assert_eq!(j, 1);
        assert!((added - 0.5642).abs() < 0.04, "{added}");
    }

    #[test]
    fn a_lone_peak_or_rivals_moving_together_add_nothing() {
        assert_eq!(independent(&[10.0, 1.0, -0.5]), Some((0, 0.0)));
        // Within the noise but their errors one: what moves one moves the other alike.
        let (_, added) = largest(&[3.0, 2.9, 2.8], &[1.0; 3], |at| {
            DMatrix::from_element(at.len(), at.len(), 1.0)
        })
        .unwrap();
        assert!(added.abs() < 0.07, "{added}");
        assert_eq!(independent(&[]), None);
    }

    #[test]
    fn ambiguous_levels_widen_the_largest_by_their_range() {
        // A clear 19.9 above levels reading little whose rivals read more: 19.9 to 25.3.
        let values = [19.9, 19.5, 5.0, -3.0];
        let half = ambiguity(&values, &[None, None, Some(25.3), Some(-24.0)]);
        assert!((half - 2.7).abs() < 1e-12, "{half}");
        // The largest ambiguous, its rival reading little: 19.5 to 19.9, either sign.
        let half = ambiguity(&values, &[Some(-2.0), None, None, None]);
        assert!((half - 0.2).abs() < 1e-12, "{half}");
        // Two ambiguous, each the largest on one axis: 5 to 26.
        let half = ambiguity(&[5.0, 3.0], &[Some(26.0), Some(-5.5)]);
        assert!((half - 10.5).abs() < 1e-12, "{half}");
        assert_eq!(ambiguity(&values, &[None; 4]), 0.0);
    }
}
