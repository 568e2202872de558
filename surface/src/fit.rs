//! The smooth surface n = s(a, v) of one subject's frames, registered onto the first, with its
//! covariance.
//!
//! Frame k's point p (analysis axes) is moved by its pose, q = c + R_k (p − c) + t_k (frame 0
//! stays), and should lie on the surface: r = q_n − s(q_a, q_v). The coefficients of s and the
//! poses are adjusted together by Gauss-Newton, each residual weighted by the inverse of its
//! variance jpᵀ C jp (jp = ∂r/∂p: a point's error across the surface counts, along it not),
//! with a thin-plate roughness penalty λ cᵀ P c. Several frames: frame 0 alone is fitted first
//! on one frame's grid, each other frame's pose registered on it ([`Fit::register`]), then all
//! are fitted together on the finer grid from those poses.
//!
//! Covariance: x̂ = N⁻¹ Σ w_i j_i e_i to first order (N the penalised normal matrix, e_i the
//! point's error across the surface: its own, variance 1/w_i, plus u_iᵀ δ of the calibration's
//! common share δ ~ N(0, Σ_c), u_i = G_iᵀ jp_i). A quantity with gradient g over x then has
//! var = Σ w_i y_i² + (Σ w_i y_i u_i)ᵀ Σ_c (Σ w_i y_i u_i), y_i = j_iᵀ N⁻¹ g: the sandwich,
//! which the penalty keeps below N⁻¹.

use crate::median;
use crate::spline::{Grid, Stencil, D};
use crate::support::Support;
use crate::SurfaceError;
use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, Vector3};
use nalgebra_sparse::factorization::CscCholesky;
use nalgebra_sparse::{CooMatrix, CscMatrix};

/// A point in the analysis axes with its covariance and its common-share sensitivity.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Sample {
    pub p: Vector3<f64>,
    pub cov: Matrix3<f64>,
    /// G_i (3 × k) in the analysis axes.
    pub common: DMatrix<f64>,
    pub frame: usize,
}

/// A frame's pose onto frame 0: q = centre + r (p − centre) + t.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Pose {
    pub r: Rotation3<f64>,
    pub t: Vector3<f64>,
}

impl Pose {
    pub(crate) fn identity() -> Self {
        Self {
            r: Rotation3::identity(),
            t: Vector3::zeros(),
        }
    }
}

/// A residual beyond this many times the residuals' robust spread may be wild ([`Fit::wild`]):
/// on the back model's scans the largest of a smooth back's were 3.8 times it where alone, 5.9
/// at the arm's crease (with neighbours as large); a point 5-30 mm off along the line of sight
/// left 6.7-19.
pub(crate) const WILD: f64 = 5.0;
/// ... and is, where its neighbours' residuals are under this share of it in RMS: 0.45 at the
/// arm's crease, 0.14-0.33 about a point 5-30 mm off.
pub(crate) const ALONE: f64 = 0.4;

/// One residual's linearisation.
#[derive(Debug, Clone)]
struct Row {
    stencil: Stencil,
    /// ∂r/∂(δω, t) of its frame's pose.
    pose: [f64; 6],
    frame: usize,
    /// 1 / variance.
    w: f64,
    /// u_i = G_iᵀ jp_i.
    u: DVector<f64>,
    r: f64,
    /// Where it lies on the surface, (a, v).
    at: [f64; 2],
    /// Its sample's index.
    sample: usize,
}

/// The fitted surface and poses, with what their covariance needs.
#[derive(Debug, Clone)]
pub(crate) struct Fit {
    pub grid: Grid,
    pub coeffs: Vec<f64>,
    pub poses: Vec<Pose>,
    /// Frame 0's centre of points, which the poses turn about.
    pub centre: Vector3<f64>,
    normal: CscCholesky<f64>,
    rows: Vec<Row>,
    common: DMatrix<f64>,
}

/// The unknowns of one Gauss-Newton step: the coefficients or not, and which frames' poses.
struct Unknowns {
    coeffs: bool,
    poses: Vec<usize>,
}

impl Unknowns {
    fn len(&self, grid: &Grid) -> usize {
        (if self.coeffs { grid.len() } else { 0 }) + 6 * self.poses.len()
    }
}

struct State<'a> {
    grid: Grid,
    coeffs: Vec<f64>,
    poses: Vec<Pose>,
    centre: Vector3<f64>,
    samples: &'a [Sample],
    penalty: CooMatrix<f64>,
    lambda: f64,
    /// While a frame is registered: where frame 0 measured the surface, the only place its
    /// points count (beyond it the surface is the penalty's extrapolation).
    registering_on: Option<&'a Support>,
}

impl State<'_> {
    /// The residual of sample i, None when its point falls off the grid.
    fn row(&self, i: usize) -> Option<Row> {
        let s = &self.samples[i];
        let pose = &self.poses[s.frame];
        let x = pose.r * (s.p - self.centre);
        let q = self.centre + x + pose.t;
        if s.frame > 0 && self.registering_on.is_some_and(|m| !m.contains(q.x, q.y)) {
            return None;
        }
        let stencil = self.grid.stencil(q.x, q.y, D::S)?;
        let sa = self.grid.stencil(q.x, q.y, D::A)?.apply(&self.coeffs);
        let sv = self.grid.stencil(q.x, q.y, D::V)?.apply(&self.coeffs);
        let grad = Vector3::new(-sa, -sv, 1.0);
        let jp = pose.r.inverse() * grad;
        let var = (jp.transpose() * s.cov * jp)[0].max(1e-12);
        let dw = x.cross(&grad);
        Some(Row {
            stencil,
            pose: [dw.x, dw.y, dw.z, grad.x, grad.y, grad.z],
            frame: s.frame,
            w: 1.0 / var,
            u: s.common.transpose() * jp,
            r: q.z - stencil.apply(&self.coeffs),
            at: [q.x, q.y],
            sample: i,
        })
    }

    /// The penalised normal equations over `which`, with only `frames`' samples (sparse).
    fn normal(&self, which: &Unknowns, frames: &[usize]) -> (CscMatrix<f64>, DVector<f64>) {
        let n = which.len(&self.grid);
        let m = if which.coeffs { self.grid.len() } else { 0 };
        let mut a = CooMatrix::new(n, n);
        let mut b = DVector::zeros(n);
        let mut idx: Vec<(usize, f64)> = Vec::with_capacity(22);
        for (i, s) in self.samples.iter().enumerate() {
            if !frames.contains(&s.frame) {
                continue;
            }
            let Some(row) = self.row(i) else { continue };
            idx.clear();
            if which.coeffs {
                let terms = row.stencil.index.iter().zip(&row.stencil.weight);
                idx.extend(terms.map(|(&i, &w)| (i, -w)));
            }
            if let Some(k) = which.poses.iter().position(|&f| f == s.frame) {
                idx.extend(
                    row.pose
                        .iter()
                        .enumerate()
                        .map(|(j, &d)| (m + 6 * k + j, d)),
                );
            }
            for &(i, di) in &idx {
                b[i] -= row.w * di * row.r;
                for &(j, dj) in &idx {
                    a.push(i, j, row.w * di * dj);
                }
            }
        }
        if which.coeffs {
            for (i, j, &p) in self.penalty.triplet_iter() {
                a.push(i, j, self.lambda * p);
                b[i] -= self.lambda * p * self.coeffs[j];
            }
        }
        (CscMatrix::from(&a), b)
    }

    /// One Gauss-Newton step over `which`; returns the largest change.
    fn step(&mut self, which: &Unknowns, frames: &[usize]) -> Result<f64, SurfaceError> {
        let (a, b) = self.normal(which, frames);
        let dx = CscCholesky::factor(&a)
            .map_err(|_| SurfaceError::Singular)?
            .solve(&b)
            .column(0)
            .into_owned();
        let m = if which.coeffs { self.grid.len() } else { 0 };
        for (c, d) in self.coeffs.iter_mut().zip(dx.iter().take(m)) {
            *c += d;
        }
        for (k, &f) in which.poses.iter().enumerate() {
            let d = dx.rows(m + 6 * k, 6);
            let pose = &mut self.poses[f];
            pose.r = Rotation3::new(Vector3::new(d[0], d[1], d[2])) * pose.r;
            pose.t += Vector3::new(d[3], d[4], d[5]);
        }
        Ok(dx.amax())
    }
}

/// Fits the surface on `grid` to the samples, frame k's moved by `poses[k]` (frame 0's the
/// identity) and adjusted with it; `lambda` weighs the roughness penalty relative to a sample
/// of weight 1, `common` is Σ_c of the calibration's common share.
pub(crate) fn fit(
    samples: &[Sample],
    poses: Vec<Pose>,
    grid: Grid,
    lambda: f64,
    common: DMatrix<f64>,
) -> Result<Fit, SurfaceError> {
    let n = samples.len() as f64;
    let (sum, count) = samples
        .iter()
        .filter(|s| s.frame == 0)
        .fold((Vector3::zeros(), 0.0), |(sum, n), s| (sum + s.p, n + 1.0));
    let centre = sum / count;
    let mean_weight = samples
        .iter()
        .map(|s| 1.0 / s.cov[(2, 2)].max(1e-12))
        .sum::<f64>()
        / n;
    let all: Vec<usize> = (0..poses.len()).collect();
    let mut state = State {
        grid,
        coeffs: vec![0.0; grid.len()],
        centre,
        samples,
        penalty: grid.penalty(),
        lambda: lambda * mean_weight,
        registering_on: None,
        poses,
    };
    let surface = Unknowns {
        coeffs: true,
        poses: vec![],
    };
    for _ in 0..3 {
        state.step(&surface, &all)?;
    }
    let joint = Unknowns {
        coeffs: true,
        poses: all[1..].to_vec(),
    };
    for _ in 0..3 {
        state.step(&joint, &all)?;
    }
    let (a, _) = state.normal(&joint, &all);
    let normal = CscCholesky::factor(&a).map_err(|_| SurfaceError::Singular)?;
    let rows: Vec<Row> = (0..samples.len()).filter_map(|i| state.row(i)).collect();
    Ok(Fit {
        grid,
        coeffs: state.coeffs,
        poses: state.poses,
        centre,
        normal,
        rows,
        common,
    })
}

impl Fit {
    /// The pose of `frame` onto this surface (frame 0's alone) by its samples among `samples`
    /// where frame 0 `measured` the surface: beyond, the surface is the penalty's
    /// extrapolation, and a trunk, nearly a cylinder, slid along it (three frames swayed by a
    /// degree and a few mm, one registered 22° and 470 mm off at 2 of 30 placements of the
    /// lattice on the back).
    pub fn register(
        &self,
        samples: &[Sample],
        frame: usize,
        measured: &Support,
    ) -> Result<Pose, SurfaceError> {
        let mut state = State {
            grid: self.grid,
            coeffs: self.coeffs.clone(),
            poses: vec![Pose::identity(); frame + 1],
            centre: self.centre,
            samples,
            // No penalty: the coefficients stay.
            penalty: CooMatrix::new(0, 0),
            lambda: 0.0,
            registering_on: Some(measured),
        };
        let pose = Unknowns {
            coeffs: false,
            poses: vec![frame],
        };
        for _ in 0..20 {
            if state.step(&pose, &[frame])? < 1e-7 {
                break;
            }
        }
        Ok(state.poses[frame])
    }

    /// The number of unknowns (coefficients, then 6 per frame after the first).
    pub fn unknowns(&self) -> usize {
        self.grid.len() + 6 * (self.poses.len() - 1)
    }

    /// The surface's value `d` at (a, v).
    pub fn value(&self, a: f64, v: f64, d: D) -> Option<f64> {
        Some(self.grid.stencil(a, v, d)?.apply(&self.coeffs))
    }

    /// Adds `weight` × the gradient of value `d` at (a, v) to `g`.
    pub fn add(&self, g: &mut DVector<f64>, a: f64, v: f64, d: D, weight: f64) {
        if let Some(s) = self.grid.stencil(a, v, d) {
            for (&i, &w) in s.index.iter().zip(&s.weight) {
                g[i] += weight * w;
            }
        }
    }

    /// A zero gradient.
    pub fn zero(&self) -> DVector<f64> {
        DVector::zeros(self.unknowns())
    }

    /// The gradient of frame k's pose component j (δω then t).
    pub fn pose_gradient(&self, frame: usize, j: usize) -> DVector<f64> {
        let mut g = self.zero();
        g[self.grid.len() + 6 * (frame - 1) + j] = 1.0;
        g
    }

    /// What the covariance of quantities with gradients `grads` is made of: √w_i y_i for each
    /// residual (n × k) and Σ w_i u_i y_iᵀ (k_c × k).
    fn spread(&self, grads: &[DVector<f64>]) -> (DMatrix<f64>, DMatrix<f64>) {
        let k = grads.len();
        // N⁻¹ g for every gradient, as the rows of z.
        let mut z = DMatrix::from_fn(k, self.unknowns(), |q, j| grads[q][j]);
        forward(self.normal.l(), &mut z);
        backward(self.normal.l(), &mut z);

        let mut y = DMatrix::zeros(self.rows.len(), k);
        let mut u = DMatrix::zeros(self.common.nrows(), k);
        for (i, row) in self.rows.iter().enumerate() {
            let sw = row.w.sqrt();
            for (c, d) in self.jacobian(row) {
                for q in 0..k {
                    y[(i, q)] += d * z[(q, c)];
                }
            }
            for q in 0..k {
                y[(i, q)] *= sw;
                for (j, uj) in row.u.iter().enumerate() {
                    u[(j, q)] += sw * uj * y[(i, q)];
                }
            }
        }
        (y, u)
    }

    /// The variances alone of the quantities whose gradients are `grads`.
    pub fn variances(&self, grads: &[DVector<f64>]) -> Vec<f64> {
        if grads.is_empty() {
            return vec![];
        }
        let (y, u) = self.spread(grads);
        let cu = &self.common * &u;
        (0..grads.len())
            .map(|q| y.column(q).norm_squared() + u.column(q).dot(&cu.column(q)))
            .collect()
    }

    /// The covariance of the quantities whose gradients are `grads`.
    pub fn covariance(&self, grads: &[DVector<f64>]) -> DMatrix<f64> {
        let (y, u) = self.spread(grads);
        y.transpose() * &y + u.transpose() * &self.common * &u
    }

    /// The σ of the quantities whose gradients are `grads`, each with an independent term
    /// (σ) of its own in `sampling` added in quadrature.
    pub fn sigmas(&self, grads: &[DVector<f64>], sampling: &[f64]) -> Vec<f64> {
        self.variances(grads)
            .iter()
            .zip(sampling)
            .map(|(v, s)| (v + s * s).max(0.0).sqrt())
            .collect()
    }

    /// The surface's misfit over the residuals that lie `inside` (a, v): the RMS (mm, across
    /// the surface) of what they hold beyond the points' own noise, whose share of residual i
    /// is (1 − h_i)/w_i by its leverage h_i = w_i j_iᵀ N⁻¹ j_i. Detail finer than the dots'
    /// spacing: the surface passes through it, and what it leaves out of the fit is there.
    pub fn misfit(&self, inside: impl Fn(f64, f64) -> bool) -> f64 {
        let rows: Vec<&Row> = self
            .rows
            .iter()
            .filter(|r| inside(r.at[0], r.at[1]))
            .collect();
        if rows.is_empty() {
            return 0.0;
        }
        let mut j = DMatrix::zeros(rows.len(), self.unknowns());
        for (k, row) in rows.iter().enumerate() {
            for (i, d) in self.jacobian(row) {
                j[(k, i)] += d;
            }
        }
        // j N⁻¹ j = |L⁻¹ j|² (N = L Lᵀ): half a solve.
        forward(self.normal.l(), &mut j);
        let leverage = j.map(|v| v * v).column_sum();
        let excess: f64 = rows
            .iter()
            .enumerate()
            .map(|(k, row)| {
                let h = row.w * leverage[k];
                row.r * row.r - (1.0 - h).max(0.0) / row.w
            })
            .sum();
        (excess / rows.len() as f64).max(0.0).sqrt()
    }

    /// A residual's derivatives over the unknowns (coefficients, then its frame's pose).
    fn jacobian<'a>(&self, row: &'a Row) -> impl Iterator<Item = (usize, f64)> + 'a {
        let pose = (row.frame > 0).then(|| self.grid.len() + 6 * (row.frame - 1));
        let coefficients = row.stencil.index.iter().zip(&row.stencil.weight);
        coefficients.map(|(&c, &w)| (c, -w)).chain(
            pose.into_iter()
                .flat_map(move |o| (0..6).map(move |j| (o + j, row.pose[j]))),
        )
    }

    /// The samples whose residual is wild, each with where it lies, (a, v), and the residual
    /// (mm): its normalised value beyond [`WILD`] times the normalised residuals' robust spread
    /// (1.4826 × their median magnitude), and its neighbours' within `radius` under [`ALONE`]
    /// of it in RMS (detail of the back the surface does not follow leaves large residuals side
    /// by side; a wild point stands alone).
    pub fn wild(&self, radius: f64) -> Vec<(usize, [f64; 2], f64)> {
        let z: Vec<f64> = self.rows.iter().map(|r| r.r.abs() * r.w.sqrt()).collect();
        let spread = 1.4826 * median(z.clone());
        // The RMS of the normalised residuals within `radius` of residual i, but its own.
        let near = |i: usize| {
            let at = self.rows[i].at;
            let around: Vec<f64> = (0..z.len())
                .filter(|&j| {
                    let b = self.rows[j].at;
                    j != i && (b[0] - at[0]).hypot(b[1] - at[1]) < radius
                })
                .map(|j| z[j] * z[j])
                .collect();
            (around.iter().sum::<f64>() / around.len().max(1) as f64).sqrt()
        };
        (0..z.len())
            .filter(|&i| z[i] > WILD * spread && near(i) < ALONE * z[i])
            .map(|i| (self.rows[i].sample, self.rows[i].at, self.rows[i].r))
            .collect()
    }

    /// The normalised residuals' RMS: about 1 when the points' σ and the surface are right.
    pub fn chi(&self) -> f64 {
        let n = self.rows.len().max(1) as f64;
        (self.rows.iter().map(|r| r.w * r.r * r.r).sum::<f64>() / n).sqrt()
    }
}

/// L⁻¹ applied to every row of `x` (k × n: column j holds unknown j's value in all k rows,
/// contiguous), for the factor L of N = L Lᵀ (lower triangular, each column's diagonal first).
/// L is walked once for all k rows; nalgebra-sparse's solve walks it once per right-hand side,
/// which with a back's few hundred gradients was a third of an analysis.
fn forward(l: &CscMatrix<f64>, x: &mut DMatrix<f64>) {
    let mut xj = DVector::zeros(x.nrows());
    for j in 0..l.ncols() {
        let col = l.col(j);
        let (rows, values) = (col.row_indices(), col.values());
        debug_assert_eq!(rows[0], j, "the factor's diagonal leads its column");
        x.column_mut(j).unscale_mut(values[0]);
        xj.copy_from(&x.column(j));
        for (&i, &v) in rows[1..].iter().zip(&values[1..]) {
            x.column_mut(i).axpy(-v, &xj, 1.0);
        }
    }
}

/// L⁻ᵀ applied to every row of `x`, as [`forward`].
fn backward(l: &CscMatrix<f64>, x: &mut DMatrix<f64>) {
    let mut xj = DVector::zeros(x.nrows());
    for j in (0..l.ncols()).rev() {
        let col = l.col(j);
        let (rows, values) = (col.row_indices(), col.values());
        xj.copy_from(&x.column(j));
        for (&i, &v) in rows[1..].iter().zip(&values[1..]) {
            xj.axpy(-v, &x.column(i), 1.0);
        }
        x.set_column(j, &xj.unscale(values[0]));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every row solved at once agrees with nalgebra-sparse's solve of each, on a banded matrix
    /// whose factor fills in.
    #[test]
    fn forward_and_backward_are_the_factors_solve() {
        let n = 40;
        let mut a = CooMatrix::new(n, n);
        for i in 0..n {
            // Diagonally dominant, so positive definite.
            a.push(i, i, 4.0 + 0.1 * i as f64);
            for (d, v) in [(1, -1.0), (5, 0.5)] {
                if i + d < n {
                    a.push(i, i + d, v);
                    a.push(i + d, i, v);
                }
            }
        }
        let factor = CscCholesky::factor(&CscMatrix::from(&a)).unwrap();
        let grads: Vec<DVector<f64>> = (0..7)
            .map(|q| DVector::from_fn(n, |j, _| (0.37 * (q * n + j) as f64).sin()))
            .collect();
        let each = factor.solve(&DMatrix::from_columns(&grads));
        let mut all = DMatrix::from_rows(&grads.iter().map(|g| g.transpose()).collect::<Vec<_>>());
        forward(factor.l(), &mut all);
        // Half a solve: |L⁻¹ g|² = gᵀ N⁻¹ g (the misfit's leverages).
        let halves = all.map(|v| v * v).column_sum();
        for (q, g) in grads.iter().enumerate() {
            let whole = g.dot(&each.column(q));
            assert!(
                (halves[q] - whole).abs() < 1e-12 * whole,
                "{q}: {} {whole}",
                halves[q]
            );
        }
        backward(factor.l(), &mut all);
        assert!((all.transpose() - &each).amax() < 1e-12 * each.amax());
    }
}
