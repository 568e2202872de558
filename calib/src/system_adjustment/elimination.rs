//! The normal equations of the whole-system adjustment with eliminated blocks: their
//! accumulation, the reduced system (the Schur complement, as the bundle eliminates its points,
//! [`crate::bundle::solver`]), the covariance of both parts and the redundancy numbers.
//!
//! The unknowns are the reduced (global) parameters g and blocks of local parameters b (a ray's 2
//! or 4, a field target's 3). Blocks come in kinds; every block of a kind is observed only
//! together with a fixed set of global parameters, the kind's rows (rays: the free inner
//! parameters, the plate poses and the centre; field targets: the free inner parameters and the
//! field poses). With the normal matrix in blocks U (global), V_b (block b) and W_b (its
//! coupling, kind rows × m):
//!
//! ```text
//! S = U − Σ_b W_b V_b⁻¹ W_bᵀ,   S Δg = g − Σ_b W_b V_b⁻¹ g_b,   Δb = V_b⁻¹ (g_b − W_bᵀ Δg)
//! Σ_gg = S⁻¹,   Σ_bg = −V_b⁻¹ W_bᵀ S⁻¹,   Σ_bb = V_b⁻¹ + V_b⁻¹ W_bᵀ S⁻¹ W_b V_b⁻¹
//! ```
//!
//! kind by kind as dense matrix products over the kind's rows (Y = W blockdiag(V⁻¹), S −= Y Wᵀ):
//! a field target is seen in most field images, so its coupling is dense in the field poses.

use super::SystemError;
use crate::dense::{cholesky, spd_inverse, times_transpose, transpose_times};
use nalgebra::{DMatrix, DVector, Matrix2, Vector2};
use rayon::prelude::*;

/// Observation groups with their own variance component: plate targets, dots, field targets.
pub(super) const GROUPS: usize = 3;

/// The columns of one observation that belong to an eliminated block.
pub(super) struct Local {
    /// The block's kind.
    pub kind: usize,
    /// The block within its kind.
    pub block: usize,
    /// ∂v/∂(block parameters), 2 × m.
    pub d: DMatrix<f64>,
}

/// One observation's linearisation: residual (mm), its global columns with their 2-vectors, its
/// block's columns if any, and its variance-component group.
pub(super) struct Linear {
    /// v (mm).
    pub value: Vector2<f64>,
    /// (global index, ∂v/∂g).
    pub global: Vec<(usize, Vector2<f64>)>,
    /// The block's columns.
    pub local: Option<Local>,
    /// Its group (< [`GROUPS`]).
    pub group: usize,
}

/// A kind of eliminated block: the global parameters its blocks are observed with and the blocks'
/// sizes.
pub(super) struct Kind {
    rows: Vec<usize>,
    row_of: Vec<Option<usize>>,
    offsets: Vec<usize>,
    sizes: Vec<usize>,
}

impl Kind {
    /// A kind whose blocks (of `sizes`) meet the global parameters `rows` (of `n`).
    pub fn new(n: usize, rows: Vec<usize>, sizes: Vec<usize>) -> Self {
        let mut row_of = vec![None; n];
        for (a, &r) in rows.iter().enumerate() {
            row_of[r] = Some(a);
        }
        let offsets = sizes
            .iter()
            .scan(0, |at, m| {
                let o = *at;
                *at += m;
                Some(o)
            })
            .collect();
        Self {
            rows,
            row_of,
            offsets,
            sizes,
        }
    }

    fn width(&self) -> usize {
        self.sizes.iter().sum()
    }
}

/// One kind's share of the normal equations.
pub(super) struct KindNormal {
    /// V_b per block.
    pub v: Vec<DMatrix<f64>>,
    /// The blocks' right-hand sides.
    pub g: Vec<DVector<f64>>,
    /// W of all blocks side by side (kind rows × Σ m).
    pub w: DMatrix<f64>,
}

/// The normal equations of one state.
pub(super) struct Normal {
    /// U.
    pub u: DMatrix<f64>,
    /// The global right-hand side.
    pub g: DVector<f64>,
    /// The eliminated blocks, kind by kind.
    pub kinds: Vec<KindNormal>,
    /// vᵀPv per group, and of the prior observations (control, inner orientation) last.
    pub cost: [f64; GROUPS + 1],
    /// The observations' linearisations.
    pub rows: Vec<Linear>,
}

impl Normal {
    /// The normal equations of `rows` weighted by 1/σ² of their group: U, g and vᵀPv summed
    /// row by row, each block's V, g and W from its own rows (in their order) on all cores.
    pub fn new(n: usize, kinds: &[Kind], rows: Vec<Linear>, sigma: &[f64; GROUPS]) -> Self {
        let weight = |row: &Linear| 1.0 / (sigma[row.group] * sigma[row.group]);
        let mut u = DMatrix::zeros(n, n);
        let mut g = DVector::zeros(n);
        let mut cost = [0.0; GROUPS + 1];
        // The rows of every block, kind by kind.
        let mut of_block: Vec<Vec<Vec<usize>>> = kinds
            .iter()
            .map(|k| vec![Vec::new(); k.sizes.len()])
            .collect();
        for (i, row) in rows.iter().enumerate() {
            let w = weight(row);
            cost[row.group] += w * row.value.norm_squared();
            for (ca, ja) in &row.global {
                g[*ca] -= w * ja.dot(&row.value);
                for (cb, jb) in &row.global {
                    u[(*ca, *cb)] += w * ja.dot(jb);
                }
            }
            if let Some(local) = &row.local {
                of_block[local.kind][local.block].push(i);
            }
        }
        let kinds = kinds
            .iter()
            .zip(&of_block)
            .map(|(k, of_block)| {
                let mut w = DMatrix::zeros(k.rows.len(), k.width());
                // W's columns block by block (column-major: each block's columns are one slice).
                let mut columns = Vec::with_capacity(k.sizes.len());
                let mut rest = w.as_mut_slice();
                for &m in &k.sizes {
                    let (these, more) = rest.split_at_mut(m * k.rows.len());
                    columns.push(these);
                    rest = more;
                }
                let (v, g): (Vec<_>, Vec<_>) = columns
                    .into_par_iter()
                    .zip(of_block)
                    .zip(&k.sizes)
                    .map(|((wb, block_rows), &m)| {
                        let mut v = DMatrix::zeros(m, m);
                        let mut g = DVector::zeros(m);
                        for &i in block_rows {
                            let row = &rows[i];
                            let (p, d) = (weight(row), &row.local.as_ref().expect("a block's").d);
                            v += d.transpose() * d * p;
                            g -= d.transpose() * row.value * p;
                            for (ca, ja) in &row.global {
                                // By construction every global column of a block's observation
                                // is a row of its kind.
                                let Some(ra) = k.row_of[*ca] else { continue };
                                let dw = d.transpose() * ja * p;
                                for (b, value) in dw.iter().enumerate() {
                                    wb[b * k.rows.len() + ra] += value;
                                }
                            }
                        }
                        (v, g)
                    })
                    .unzip();
                KindNormal { v, g, w }
            })
            .collect();
        Normal {
            u,
            g,
            kinds,
            cost,
            rows,
        }
    }

    /// A prior observation of global parameters `at`: weight matrix `p`, state minus observed
    /// value `d`.
    pub fn global_prior(&mut self, at: &[usize], p: &DMatrix<f64>, d: &DVector<f64>) {
        let pd = p * d;
        self.cost[GROUPS] += d.dot(&pd);
        for (a, &ga) in at.iter().enumerate() {
            self.g[ga] -= pd[a];
            for (b, &gb) in at.iter().enumerate() {
                self.u[(ga, gb)] += p[(a, b)];
            }
        }
    }

    /// A prior observation of every parameter of block `block` of `kind` with weight `p` each;
    /// state minus observed value `d`.
    pub fn local_prior(&mut self, kind: usize, block: usize, p: f64, d: &DVector<f64>) {
        let kn = &mut self.kinds[kind];
        self.cost[GROUPS] += p * d.norm_squared();
        for a in 0..d.len() {
            kn.v[block][(a, a)] += p;
        }
        kn.g[block] -= d * p;
    }

    /// The weighted sum of squares over all observations.
    pub fn total(&self) -> f64 {
        self.cost.iter().sum()
    }
}

/// The reduced system S Δg = b, the blocks' V⁻¹ and Y = W blockdiag(V⁻¹) per kind.
pub(super) struct Reduced {
    /// S.
    pub s: DMatrix<f64>,
    /// b.
    pub b: DVector<f64>,
    v_inv: Vec<Vec<DMatrix<f64>>>,
    y: Vec<DMatrix<f64>>,
}

/// Eliminates every block: V_b⁻¹ and Y_b = W_b V_b⁻¹ on all cores, b in block order, and
/// S −= Y Wᵀ by chunks of columns on all cores ([`times_transpose`]).
pub(super) fn reduce(normal: &Normal, kinds: &[Kind]) -> Result<Reduced, SystemError> {
    let mut s = normal.u.clone();
    let mut b = normal.g.clone();
    let mut v_inv = Vec::with_capacity(kinds.len());
    let mut ys = Vec::with_capacity(kinds.len());
    for (kind, kn) in kinds.iter().zip(&normal.kinds) {
        let eliminated: Vec<(DMatrix<f64>, DMatrix<f64>)> =
            kn.v.par_iter()
                .enumerate()
                .map(|(blk, v)| {
                    let (off, m) = (kind.offsets[blk], kind.sizes[blk]);
                    let vi = v.clone().try_inverse().ok_or(SystemError::Singular)?;
                    let yb = kn.w.columns(off, m) * &vi;
                    Ok((vi, yb))
                })
                .collect::<Result<_, _>>()?;
        let mut y = kn.w.clone();
        let mut yg = DVector::zeros(kind.rows.len());
        let mut inverses = Vec::with_capacity(kn.v.len());
        for (blk, (vi, yb)) in eliminated.into_iter().enumerate() {
            yg += &yb * &kn.g[blk];
            y.columns_mut(kind.offsets[blk], kind.sizes[blk])
                .copy_from(&yb);
            inverses.push(vi);
        }
        let ywt = times_transpose(&y, &kn.w);
        for (a, &ra) in kind.rows.iter().enumerate() {
            b[ra] -= yg[a];
            for (c, &rc) in kind.rows.iter().enumerate() {
                s[(ra, rc)] -= ywt[(a, c)];
            }
        }
        v_inv.push(inverses);
        ys.push(y);
    }
    Ok(Reduced { s, b, v_inv, y: ys })
}

impl Reduced {
    /// The blocks' steps from the global step: Δb = V_b⁻¹ (g_b − W_bᵀ Δg), kind by kind.
    pub fn back_substitute(
        &self,
        normal: &Normal,
        kinds: &[Kind],
        dg: &DVector<f64>,
    ) -> Vec<Vec<DVector<f64>>> {
        kinds
            .iter()
            .zip(&normal.kinds)
            .zip(&self.v_inv)
            .map(|((kind, kn), v_inv)| {
                let dg_rows =
                    DVector::from_iterator(kind.rows.len(), kind.rows.iter().map(|&r| dg[r]));
                v_inv
                    .iter()
                    .enumerate()
                    .map(|(blk, vi)| {
                        let w = kn.w.columns(kind.offsets[blk], kind.sizes[blk]);
                        vi * (&kn.g[blk] - w.transpose() * &dg_rows)
                    })
                    .collect()
            })
            .collect()
    }
}

/// The covariance (in units of the weights' σ): S⁻¹, per kind the blocks' covariance with the
/// kind's rows (Σ m × rows) and per block its own.
pub(super) struct Covariance {
    /// S⁻¹.
    pub s_inv: DMatrix<f64>,
    cross: Vec<DMatrix<f64>>,
    own: Vec<Vec<DMatrix<f64>>>,
}

/// The covariance of the reduced system and of every block.
pub(super) fn covariance(kinds: &[Kind], reduced: &Reduced) -> Result<Covariance, SystemError> {
    let s_inv = spd_inverse(&cholesky(reduced.s.clone()).ok_or(SystemError::Singular)?);
    let mut cross = Vec::with_capacity(kinds.len());
    let mut own = Vec::with_capacity(kinds.len());
    for ((kind, y), v_inv) in kinds.iter().zip(&reduced.y).zip(&reduced.v_inv) {
        let rows = &kind.rows;
        let sub = DMatrix::from_fn(rows.len(), rows.len(), |a, b| s_inv[(rows[a], rows[b])]);
        let c = -transpose_times(y, &sub);
        own.push(
            v_inv
                .par_iter()
                .enumerate()
                .map(|(blk, vi)| {
                    let (off, m) = (kind.offsets[blk], kind.sizes[blk]);
                    vi - c.rows(off, m) * y.columns(off, m)
                })
                .collect(),
        );
        cross.push(c);
    }
    Ok(Covariance { s_inv, cross, own })
}

impl Covariance {
    /// Block `block` of `kind`: its covariance and its covariance with the global parameters
    /// `at` (m × at.len(); each a row of the kind, or None for a parameter held fixed: zero).
    pub fn block(
        &self,
        kinds: &[Kind],
        kind: usize,
        block: usize,
        at: &[Option<usize>],
    ) -> (DMatrix<f64>, DMatrix<f64>) {
        let k = &kinds[kind];
        let (off, m) = (k.offsets[block], k.sizes[block]);
        let c = &self.cross[kind];
        let cross = DMatrix::from_fn(m, at.len(), |a, b| {
            at[b]
                .and_then(|g| k.row_of[g])
                .map_or(0.0, |r| c[(off + a, r)])
        });
        (self.own[kind][block].clone(), cross)
    }

    /// The sum of the redundancy numbers of each group's observations, 2 − tr(P A Σ Aᵀ) each
    /// (the observations' numbers on all cores, summed in their order).
    pub fn redundancy(
        &self,
        normal: &Normal,
        kinds: &[Kind],
        sigma: &[f64; GROUPS],
    ) -> [f64; GROUPS] {
        let numbers: Vec<f64> = normal
            .rows
            .par_iter()
            .map(|row| {
                let weight = 1.0 / (sigma[row.group] * sigma[row.group]);
                // q = A Σ Aᵀ over the observation's few non-zero columns.
                let mut q = Matrix2::zeros();
                for (ca, ja) in &row.global {
                    for (cb, jb) in &row.global {
                        q += ja * jb.transpose() * self.s_inv[(*ca, *cb)];
                    }
                }
                if let Some(Local { kind, block, d }) = &row.local {
                    let k = &kinds[*kind];
                    let (off, m) = (k.offsets[*block], k.sizes[*block]);
                    let mut cg = DMatrix::zeros(m, 2);
                    for (col, j) in &row.global {
                        if let Some(r) = k.row_of[*col] {
                            cg += self.cross[*kind].view((off, r), (m, 1)) * j.transpose();
                        }
                    }
                    let c = d * cg;
                    let o = d * &self.own[*kind][*block] * d.transpose();
                    q += Matrix2::from_fn(|i, j| c[(i, j)] + c[(j, i)] + o[(i, j)]);
                }
                2.0 - weight * q.trace()
            })
            .collect();
        let mut red = [0.0; GROUPS];
        for (row, number) in normal.rows.iter().zip(numbers) {
            red[row.group] += number;
        }
        red
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    /// The reduced solution, the covariance of every part and the redundancy numbers equal
    /// those of the full normal equations inverted densely, on a small problem with two kinds
    /// (blocks of 2, 4 and 3 parameters), global-only observations and priors on both parts.
    #[test]
    fn schur_complement_matches_the_dense_solution() {
        let mut rng = StdRng::seed_from_u64(9);
        let mut next = move || rng.random_range(-1.0..1.0);
        let n = 7;
        let kinds = [
            Kind::new(n, vec![0, 1, 2, 3], vec![2, 4]),
            Kind::new(n, vec![0, 4, 5, 6], vec![3, 3, 3]),
        ];
        let width: usize = kinds.iter().map(Kind::width).sum();
        let sigma = [0.7, 1.3, 0.4];
        let mut rows = Vec::new();
        let mut full_rows = Vec::new();
        for (k, kind) in kinds.iter().enumerate() {
            let base = n + kinds[..k].iter().map(Kind::width).sum::<usize>();
            for block in 0..kind.sizes.len() {
                let m = kind.sizes[block];
                for _ in 0..3 * m {
                    let mut global = Vec::new();
                    for &g in &kind.rows {
                        if next() > -0.5 {
                            global.push((g, Vector2::new(next(), next())));
                        }
                    }
                    let d = DMatrix::from_fn(2, m, |_, _| next());
                    let mut a = DMatrix::zeros(2, n + width);
                    for (g, j) in &global {
                        a.view_mut((0, *g), (2, 1)).copy_from(j);
                    }
                    a.view_mut((0, base + kind.offsets[block]), (2, m))
                        .copy_from(&d);
                    let group = k + 1;
                    full_rows.push((a, group));
                    rows.push(Linear {
                        value: Vector2::new(next(), next()),
                        global,
                        local: Some(Local { kind: k, block, d }),
                        group,
                    });
                }
            }
        }
        for _ in 0..3 * n {
            let mut global = Vec::new();
            for g in 0..n {
                if next() > 0.0 {
                    global.push((g, Vector2::new(next(), next())));
                }
            }
            let mut a = DMatrix::zeros(2, n + width);
            for (g, j) in &global {
                a.view_mut((0, *g), (2, 1)).copy_from(j);
            }
            full_rows.push((a, 0));
            rows.push(Linear {
                value: Vector2::new(next(), next()),
                global,
                local: None,
                group: 0,
            });
        }
        let values: Vec<Vector2<f64>> = rows.iter().map(|r| r.value).collect();
        let mut normal = Normal::new(n, &kinds, rows, &sigma);
        let p = DMatrix::from_row_slice(2, 2, &[4.0, 1.0, 1.0, 3.0]);
        let d = DVector::from_column_slice(&[0.2, -0.1]);
        normal.global_prior(&[1, 2], &p, &d);
        let dl = DVector::from_column_slice(&[0.3, 0.1, -0.2]);
        normal.local_prior(1, 0, 5.0, &dl);

        // The full normal equations.
        let mut full = DMatrix::zeros(n + width, n + width);
        let mut rhs = DVector::zeros(n + width);
        for ((a, group), v) in full_rows.iter().zip(&values) {
            let w = 1.0 / (sigma[*group] * sigma[*group]);
            full += a.transpose() * a * w;
            rhs -= a.transpose() * v * w;
        }
        let at = [1, 2];
        for (i, &gi) in at.iter().enumerate() {
            rhs[gi] -= (&p * &d)[i];
            for (j, &gj) in at.iter().enumerate() {
                full[(gi, gj)] += p[(i, j)];
            }
        }
        let local0 = n + kinds[0].width();
        for a in 0..3 {
            full[(local0 + a, local0 + a)] += 5.0;
            rhs[local0 + a] -= 5.0 * dl[a];
        }
        let inverse = full.clone().try_inverse().unwrap();
        let solution = &inverse * &rhs;

        let reduced = reduce(&normal, &kinds).unwrap();
        let dg = reduced.s.clone().cholesky().unwrap().solve(&reduced.b);
        let steps = reduced.back_substitute(&normal, &kinds, &dg);
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * (1.0 + b.abs());
        for g in 0..n {
            assert!(close(dg[g], solution[g]), "global {g}");
        }
        let cov = covariance(&kinds, &reduced).unwrap();
        let all: Vec<Option<usize>> = (0..n).map(Some).collect();
        for (k, kind) in kinds.iter().enumerate() {
            let base = n + kinds[..k].iter().map(Kind::width).sum::<usize>();
            for (block, step) in steps[k].iter().enumerate() {
                let (off, m) = (base + kind.offsets[block], kind.sizes[block]);
                for a in 0..m {
                    assert!(close(step[a], solution[off + a]));
                }
                let (own, cross) = cov.block(&kinds, k, block, &all);
                for a in 0..m {
                    for b in 0..m {
                        assert!(close(own[(a, b)], inverse[(off + a, off + b)]));
                    }
                    for g in 0..n {
                        // Zero where the global parameter is not a row of the kind.
                        let expect = if kind.row_of[g].is_some() {
                            inverse[(off + a, g)]
                        } else {
                            0.0
                        };
                        assert!(close(cross[(a, g)], expect), "kind {k} block {block}");
                    }
                }
            }
        }
        for a in 0..n {
            for b in 0..n {
                assert!(close(cov.s_inv[(a, b)], inverse[(a, b)]));
            }
        }
        let mut red = [0.0; GROUPS];
        for (a, group) in &full_rows {
            let w = 1.0 / (sigma[*group] * sigma[*group]);
            red[*group] += 2.0 - w * (a * &inverse * a.transpose()).trace();
        }
        let got = cov.redundancy(&normal, &kinds, &sigma);
        for g in 0..GROUPS {
            assert!(close(got[g], red[g]), "group {g}: {} vs {}", got[g], red[g]);
        }
    }
}
