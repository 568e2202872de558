//! Levenberg-Marquardt on the bundle, with the points eliminated by the Schur complement.
//!
//! Normal equations, camera part c and points p (weights P: 1 for image observations,
//! (σ_image/σ_control)² for control):
//!
//! ```text
//! [ U   W ] [Δc]   [g_c]        U = J_cᵀ P J_c,  W = J_cᵀ P J_p,  V = J_pᵀ P J_p (3 × 3 blocks)
//! [ Wᵀ  V ] [Δp] = [g_p]        g = −Jᵀ P v
//! S = U − Σ_p W_p V_p⁻¹ W_pᵀ,   S Δc = g_c − Σ_p W_p V_p⁻¹ g_p,   Δp = V_p⁻¹ (g_p − W_pᵀ Δc)
//! ```
//!
//! Damping: the diagonals of U and V are multiplied by (1 + μ). After convergence, S⁻¹ σ0² is the
//! covariance of the camera parameters (σ0² = vᵀPv / redundancy).
//!
//! On all cores, and the same to the bit on any number of them: the points are linearised and
//! eliminated in parallel, U and the right-hand sides summed in point order, S by dense products
//! over groups of points in chunks of columns, each summing the groups in order; the Cholesky
//! factor and S⁻¹ by [`crate::dense`].

use super::problem::Problem;
use crate::dense::{cholesky, spd_inverse, PRODUCT_COLUMNS};
use crate::residual::{image_residual, INNER, POSE};
use nalgebra::{DMatrix, DVector, Matrix3, MatrixXx3, Vector2, Vector3};
use rayon::prelude::*;

/// Why the adjustment failed.
#[derive(Debug, Clone, PartialEq)]
pub enum SolveError {
    /// The normal equations are singular: the configuration does not determine the parameters.
    Singular,
    /// A point ended up behind a camera.
    BehindCamera {
        /// Image label.
        image: String,
        /// Point label.
        point: String,
    },
    /// More unknowns than observations.
    NoRedundancy,
}

impl std::fmt::Display for SolveError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SolveError::Singular => {
                f.write_str("the normal equations are singular (weak or insufficient geometry)")
            }
            SolveError::BehindCamera { image, point } => {
                write!(
                    f,
                    "point {point:?} lies behind the camera of image {image:?}"
                )
            }
            SolveError::NoRedundancy => {
                f.write_str("no redundancy: more unknowns than observations")
            }
        }
    }
}

impl std::error::Error for SolveError {}

/// The outcome of one adjustment.
#[derive(Debug, Clone)]
pub struct Solution {
    /// LM iterations.
    pub iterations: usize,
    /// vᵀPv at the solution (mm²).
    pub cost: f64,
    /// Redundancy (observation equations − unknowns).
    pub redundancy: usize,
    /// A posteriori σ0 (mm).
    pub sigma0: f64,
    /// Covariance of the camera states (σ0² S⁻¹).
    pub camera_covariance: DMatrix<f64>,
}

/// Stopping rules.
#[derive(Debug, Clone, Copy)]
pub struct SolverOptions {
    /// Maximum LM iterations.
    pub max_iterations: usize,
    /// Stop when the relative decrease of the cost falls below this.
    pub tolerance: f64,
}

impl Default for SolverOptions {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            tolerance: 1e-12,
        }
    }
}

/// The state indices of each image's inner + pose parameters (the rows its observations touch).
struct Layout {
    inner: Vec<(usize, usize)>,
    poses: Vec<Vec<(usize, usize)>>,
    camera: usize,
}

impl Layout {
    fn new(problem: &Problem) -> Self {
        let inner = (0..INNER)
            .filter_map(|k| problem.state_index_inner(k).map(|s| (k, s)))
            .collect();
        let poses = (0..problem.images.len())
            .map(|i| {
                (0..POSE)
                    .filter_map(|k| problem.state_index_pose(i, k).map(|s| (k, s)))
                    .collect()
            })
            .collect();
        Self {
            inner,
            poses,
            camera: problem.num_states_camera(),
        }
    }
}

/// One point's blocks of the normal equations.
struct PointBlock {
    /// The camera states its observations touch.
    rows: Vec<usize>,
    /// W_p restricted to `rows` (rows × 3).
    w: DMatrix<f64>,
    /// V_p.
    v: Matrix3<f64>,
    /// g_p.
    g: Vector3<f64>,
}

/// The assembled (undamped) normal equations.
struct Normal {
    u: DMatrix<f64>,
    g_c: DVector<f64>,
    points: Vec<PointBlock>,
    cost: f64,
}

/// The reduced camera system S Δc = b and the damped V_p⁻¹.
struct Reduced {
    s: DMatrix<f64>,
    b: DVector<f64>,
    v_inv: Vec<Matrix3<f64>>,
}

/// vᵀPv of the current state.
pub fn cost(problem: &Problem) -> f64 {
    let mut total = 0.0;
    for o in problem.observations.iter().filter(|o| o.active) {
        let r = image_residual(
            &problem.inner,
            &o.photo,
            &problem.poses[o.image],
            &problem.xyz[o.point],
        );
        total += r.value.norm_squared();
    }
    for (x, c) in problem.xyz.iter().zip(&problem.control) {
        if let Some(c) = c {
            total += problem.control_weight(c) * (x - c.xyz).norm_squared();
        }
    }
    total
}

/// One observation's share of U and g_c: its residual and its camera Jacobian compacted to
/// (slot in the point's rows, state index, column).
struct CameraColumns {
    value: Vector2<f64>,
    cols: Vec<(usize, usize, Vector2<f64>)>,
}

/// One point linearised: its block, its observations' camera columns, and its terms of vᵀPv in
/// order (each observation's, then its control's).
struct PointLinear {
    block: PointBlock,
    observations: Vec<CameraColumns>,
    costs: Vec<f64>,
}

/// Linearises the observations of point `j` (indices `obs`).
fn linearise_point(
    problem: &Problem,
    layout: &Layout,
    j: usize,
    obs: &[usize],
) -> Result<PointLinear, SolveError> {
    let mut rows: Vec<usize> = layout.inner.iter().map(|(_, s)| *s).collect();
    for &n in obs {
        rows.extend(
            layout.poses[problem.observations[n].image]
                .iter()
                .map(|(_, s)| *s),
        );
    }
    let mut w = DMatrix::zeros(rows.len(), 3);
    let mut v = Matrix3::zeros();
    let mut g_p = Vector3::zeros();
    let mut offset = layout.inner.len();
    let mut observations = Vec::with_capacity(obs.len());
    let mut costs = Vec::with_capacity(obs.len() + 1);
    for &n in obs {
        let o = &problem.observations[n];
        let r = image_residual(
            &problem.inner,
            &o.photo,
            &problem.poses[o.image],
            &problem.xyz[j],
        );
        if r.z_cam >= 0.0 {
            return Err(SolveError::BehindCamera {
                image: problem.images[o.image].clone(),
                point: problem.points[j].clone(),
            });
        }
        costs.push(r.value.norm_squared());
        let mut cols: Vec<(usize, usize, Vector2<f64>)> = Vec::new();
        for (slot, (k, s)) in layout.inner.iter().enumerate() {
            cols.push((slot, *s, r.d_inner.column(*k).into_owned()));
        }
        for (slot, (k, s)) in layout.poses[o.image].iter().enumerate() {
            cols.push((offset + slot, *s, r.d_pose.column(*k).into_owned()));
        }
        offset += layout.poses[o.image].len();
        for (slot, _, ja) in &cols {
            let row = ja.transpose() * r.d_point;
            for k in 0..3 {
                w[(*slot, k)] += row[k];
            }
        }
        v += r.d_point.transpose() * r.d_point;
        g_p -= r.d_point.transpose() * r.value;
        observations.push(CameraColumns {
            value: r.value,
            cols,
        });
    }
    if let Some(c) = &problem.control[j] {
        let weight = problem.control_weight(c);
        let d = problem.xyz[j] - c.xyz;
        costs.push(weight * d.norm_squared());
        v += Matrix3::identity() * weight;
        g_p -= d * weight;
    }
    Ok(PointLinear {
        block: PointBlock { rows, w, v, g: g_p },
        observations,
        costs,
    })
}

/// The normal equations: the points linearised on all cores, then U, g_c and vᵀPv summed in
/// point order (the same sums on any number of cores).
fn assemble(problem: &Problem, layout: &Layout) -> Result<Normal, SolveError> {
    let m = layout.camera;
    let mut u = DMatrix::zeros(m, m);
    let mut g_c = DVector::zeros(m);
    let mut by_point: Vec<Vec<usize>> = vec![Vec::new(); problem.xyz.len()];
    for (n, o) in problem.observations.iter().enumerate() {
        if o.active {
            by_point[o.point].push(n);
        }
    }
    let linear: Vec<Result<PointLinear, SolveError>> = by_point
        .par_iter()
        .enumerate()
        .map(|(j, obs)| linearise_point(problem, layout, j, obs))
        .collect();
    // The first error in point order, as on one core.
    let linear: Vec<PointLinear> = linear.into_iter().collect::<Result<_, _>>()?;
    let mut points = Vec::with_capacity(linear.len());
    let mut total = 0.0;
    for point in linear {
        for CameraColumns { value, cols } in &point.observations {
            for (a, (_, sa, ja)) in cols.iter().enumerate() {
                g_c[*sa] -= ja.dot(value);
                for (_, sb, jb) in &cols[a..] {
                    let value = ja.dot(jb);
                    u[(*sa, *sb)] += value;
                    if sa != sb {
                        u[(*sb, *sa)] += value;
                    }
                }
            }
        }
        for cost in &point.costs {
            total += cost;
        }
        points.push(point.block);
    }
    Ok(Normal {
        u,
        g_c,
        points,
        cost: total,
    })
}

/// Points eliminated together in one dense matrix product.
const GROUP_POINTS: usize = 32;

/// A group of points' Y and W side by side over the union of their rows: Y_g W_gᵀ =
/// Σ_p Y_p W_pᵀ of the group's points p.
struct Group {
    /// The camera states the group's points touch, ascending.
    rows: Vec<usize>,
    /// rows × 3 (points): the points' Y.
    y: DMatrix<f64>,
    /// rows × 3 (points): the points' W.
    w: DMatrix<f64>,
}

impl Group {
    fn new(points: &[PointBlock], ys: &[MatrixXx3<f64>]) -> Self {
        let mut rows: Vec<usize> = points.iter().flat_map(|p| p.rows.iter().copied()).collect();
        rows.sort_unstable();
        rows.dedup();
        let mut y = DMatrix::zeros(rows.len(), 3 * points.len());
        let mut w = DMatrix::zeros(rows.len(), 3 * points.len());
        for (i, (p, yp)) in points.iter().zip(ys).enumerate() {
            for (a, r) in p.rows.iter().enumerate() {
                let at = rows.partition_point(|x| x < r);
                for k in 0..3 {
                    y[(at, 3 * i + k)] += yp[(a, k)];
                    w[(at, 3 * i + k)] += p.w[(a, k)];
                }
            }
        }
        Self { rows, y, w }
    }
}

/// The reduced camera system S (and its right-hand side) for damping μ: V_p⁻¹ and
/// Y_p = W_p V_p⁻¹ of the points on all cores; then S = U − Σ_p Y_p W_pᵀ by groups of
/// [`GROUP_POINTS`] points, each one dense product Y_g W_gᵀ over the rows its points touch,
/// the lower triangle in chunks of [`PRODUCT_COLUMNS`] columns on all cores, each chunk
/// subtracting the groups in order (the same sums on any number of cores).
fn reduce(normal: &Normal, mu: f64) -> Result<Reduced, SolveError> {
    let mut s = normal.u.clone();
    for k in 0..s.nrows() {
        s[(k, k)] *= 1.0 + mu;
    }
    let (v_inv, ys): (Vec<Matrix3<f64>>, Vec<MatrixXx3<f64>>) = normal
        .points
        .par_iter()
        .map(|PointBlock { w, v, .. }| {
            let mut vd = *v;
            for k in 0..3 {
                vd[(k, k)] *= 1.0 + mu;
            }
            let vi = vd.try_inverse().ok_or(SolveError::Singular)?;
            Ok((vi, w * vi)) // Y: rows × 3
        })
        .collect::<Result<Vec<_>, _>>()?
        .into_iter()
        .unzip();
    let mut b = normal.g_c.clone();
    for (PointBlock { rows, g: g_p, .. }, y) in normal.points.iter().zip(&ys) {
        let yg = y * g_p;
        for (a, &ra) in rows.iter().enumerate() {
            b[ra] -= yg[a];
        }
    }
    let groups: Vec<Group> = normal
        .points
        .par_chunks(GROUP_POINTS)
        .zip(ys.par_chunks(GROUP_POINTS))
        .map(|(points, ys)| Group::new(points, ys))
        .collect();
    let m = s.nrows();
    s.as_mut_slice()
        .par_chunks_mut((PRODUCT_COLUMNS * m).max(1))
        .enumerate()
        .for_each(|(chunk, columns)| {
            let first = chunk * PRODUCT_COLUMNS;
            let last = first + columns.len() / m.max(1);
            for group in &groups {
                let lo = group.rows.partition_point(|&r| r < first);
                let hi = group.rows.partition_point(|&r| r < last);
                if lo == hi {
                    continue;
                }
                // Y_g times the chunk's rows of W_g, transposed: the chunk's columns.
                let piece = &group.y * group.w.rows(lo, hi - lo).transpose();
                for (c, &rc) in group.rows[lo..hi].iter().enumerate() {
                    let to = &mut columns[(rc - first) * m..(rc - first + 1) * m];
                    // The lower triangle: the rows from rc on.
                    for (a, &ra) in group.rows.iter().enumerate().skip(lo + c) {
                        to[ra] -= piece[(a, c)];
                    }
                }
            }
        });
    s.fill_upper_triangle_with_lower_triangle();
    Ok(Reduced { s, b, v_inv })
}

/// Runs LM to convergence from the problem's current values; updates them in place.
pub fn solve(problem: &mut Problem, options: &SolverOptions) -> Result<Solution, SolveError> {
    let layout = Layout::new(problem);
    let active = problem.observations.iter().filter(|o| o.active).count();
    let controls = problem.control.iter().filter(|c| c.is_some()).count();
    let equations = 2 * active + 3 * controls;
    let unknowns = layout.camera + 3 * problem.xyz.len();
    if equations <= unknowns {
        return Err(SolveError::NoRedundancy);
    }
    let mut mu = 1e-6;
    let mut iterations = 0;
    let mut normal = assemble(problem, &layout)?;
    while iterations < options.max_iterations {
        iterations += 1;
        let Reduced { s, b, v_inv } = reduce(&normal, mu)?;
        let Some(chol) = cholesky(s) else {
            mu *= 10.0;
            if mu > 1e8 {
                return Err(SolveError::Singular);
            }
            continue;
        };
        let dc = chol.solve(&b);
        let dp: Vec<Vector3<f64>> = normal
            .points
            .par_iter()
            .zip(&v_inv)
            .map(
                |(
                    PointBlock {
                        rows, w, g: g_p, ..
                    },
                    vi,
                )| {
                    let wdc = w.transpose()
                        * DVector::from_iterator(rows.len(), rows.iter().map(|r| dc[*r]));
                    vi * (g_p - Vector3::new(wdc[0], wdc[1], wdc[2]))
                },
            )
            .collect();
        let mut trial = problem.clone();
        trial.apply(dc.as_slice(), &dp);
        let trial_normal = assemble(&trial, &layout);
        match trial_normal {
            Ok(tn) if tn.cost <= normal.cost => {
                let decrease = (normal.cost - tn.cost) / normal.cost.max(f64::MIN_POSITIVE);
                *problem = trial;
                normal = tn;
                mu = (mu / 3.0).max(1e-12);
                if decrease < options.tolerance {
                    break;
                }
            }
            _ => {
                mu *= 4.0;
                if mu > 1e8 {
                    break; // no further descent: converged to machine precision
                }
            }
        }
    }
    let s = reduce(&normal, 0.0)?.s;
    let inverse = spd_inverse(&cholesky(s).ok_or(SolveError::Singular)?);
    let redundancy = equations - unknowns;
    let sigma0 = (normal.cost / redundancy as f64).sqrt();
    Ok(Solution {
        iterations,
        cost: normal.cost,
        redundancy,
        sigma0,
        camera_covariance: inverse * (sigma0 * sigma0),
    })
}
