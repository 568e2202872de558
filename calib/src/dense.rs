//! Dense linear algebra the adjustments share, on all cores and deterministic: the work is cut
//! into pieces that do not depend on the number of threads (columns of the result, in chunks
//! of fixed width), and every sum runs in the same order as on one thread, so the results are
//! the same to the bit on any number of cores.

use nalgebra::{linalg::Cholesky, DMatrix, Dyn};
use rayon::prelude::*;

/// Columns per panel of the Cholesky factor.
pub const CHUNK_COLUMNS: usize = 16;

/// Columns per piece of a matrix product (wide enough that packing the other factor for each
/// piece costs little beside the product).
pub const PRODUCT_COLUMNS: usize = 128;

/// The Cholesky factor A = L Lᵀ of a symmetric positive-definite matrix (its lower triangle is
/// read), `None` when a pivot is not positive. The same operations in the same order as
/// nalgebra's `cholesky` (column j less L_jk times column k, for k = 0, 1, …, j − 1, then divided
/// by the square root of its pivot), so the same factor to the bit, but right-looking by
/// panels of [`CHUNK_COLUMNS`] columns: once a panel is factored, the columns right of it are
/// updated by it on all cores.
pub fn cholesky(mut a: DMatrix<f64>) -> Option<Cholesky<f64, Dyn>> {
    let n = a.nrows();
    assert_eq!(n, a.ncols(), "a square matrix");
    let data = a.as_mut_slice();
    let mut p0 = 0;
    while p0 < n {
        let p1 = (p0 + CHUNK_COLUMNS).min(n);
        let (panel, right) = data[p0 * n..].split_at_mut((p1 - p0) * n);
        // The panel, left-looking within it (the columns before it are applied already).
        for j in p0..p1 {
            let (before, column) = panel.split_at_mut((j - p0) * n);
            let column = &mut column[..n];
            for k in p0..j {
                let col_k = &before[(k - p0) * n..(k - p0 + 1) * n];
                let factor = col_k[j];
                for (y, x) in column[j..].iter_mut().zip(&col_k[j..]) {
                    *y -= factor * x;
                }
            }
            let diag = column[j];
            if diag.is_nan() || diag <= 0.0 {
                return None;
            }
            let denom = diag.sqrt();
            column[j] = denom;
            for y in &mut column[j + 1..] {
                *y /= denom;
            }
        }
        // The columns right of the panel, less the panel's share, in order k = p0..p1.
        let panel: &[f64] = panel;
        right
            .par_chunks_mut(CHUNK_COLUMNS * n)
            .enumerate()
            .for_each(|(c, columns)| {
                for (i, column) in columns.chunks_exact_mut(n).enumerate() {
                    let j = p1 + c * CHUNK_COLUMNS + i;
                    for k in p0..p1 {
                        let col_k = &panel[(k - p0) * n..(k - p0 + 1) * n];
                        let factor = col_k[j];
                        for (y, x) in column[j..].iter_mut().zip(&col_k[j..]) {
                            *y -= factor * x;
                        }
                    }
                }
            });
        p0 = p1;
    }
    Some(Cholesky::pack_dirty(a))
}

/// The inverse of a symmetric positive-definite matrix A from its Cholesky factor (A = L Lᵀ):
/// A⁻¹ = L⁻ᵀ L⁻¹, with L⁻¹ by column-oriented forward substitution (column j of L⁻¹ is zero
/// above row j: n³/6 operations; the columns on all cores) and the product by the blocked
/// matrix multiplication ([`transpose_times`]). For the reduced normal matrix of a large
/// network (n ≈ 1,200) it is several times faster than solving A X = I column by column.
pub fn spd_inverse(chol: &Cholesky<f64, Dyn>) -> DMatrix<f64> {
    let l = chol.l_dirty();
    let n = l.nrows();
    let l = l.as_slice();
    let mut l_inv = DMatrix::zeros(n, n);
    l_inv
        .as_mut_slice()
        .par_chunks_exact_mut(n.max(1))
        .enumerate()
        .for_each(|(j, x)| {
            x[j] = 1.0;
            for k in j..n {
                let column = &l[k * n..(k + 1) * n];
                let xk = x[k] / column[k];
                x[k] = xk;
                for (xi, lik) in x[k + 1..].iter_mut().zip(&column[k + 1..]) {
                    *xi -= xk * lik;
                }
            }
        });
    transpose_times(&l_inv, &l_inv)
}

/// Aᵀ B by the blocked matrix multiplication, [`PRODUCT_COLUMNS`] columns of B at a time on all
/// cores (the whole product's columns to rounding: a piece may group its sums otherwise).
pub fn transpose_times(a: &DMatrix<f64>, b: &DMatrix<f64>) -> DMatrix<f64> {
    let at = a.transpose();
    by_column_blocks(at.nrows(), b.ncols(), |first, width| {
        &at * b.columns(first, width)
    })
}

/// A Bᵀ by the blocked matrix multiplication, [`PRODUCT_COLUMNS`] rows of B at a time on all
/// cores (the whole product's columns to rounding: a piece may group its sums otherwise).
pub fn times_transpose(a: &DMatrix<f64>, b: &DMatrix<f64>) -> DMatrix<f64> {
    by_column_blocks(a.nrows(), b.nrows(), |first, width| {
        a * b.rows(first, width).transpose()
    })
}

/// A `rows` × `cols` product assembled from its blocks of [`PRODUCT_COLUMNS`] columns,
/// `piece(first, width)` each, on all cores.
fn by_column_blocks(
    rows: usize,
    cols: usize,
    piece: impl Fn(usize, usize) -> DMatrix<f64> + Sync,
) -> DMatrix<f64> {
    let mut product = DMatrix::zeros(rows, cols);
    product
        .as_mut_slice()
        .par_chunks_mut((PRODUCT_COLUMNS * rows).max(1))
        .enumerate()
        .for_each(|(c, out)| {
            let width = out.len() / rows.max(1);
            out.copy_from_slice(piece(c * PRODUCT_COLUMNS, width).as_slice());
        });
    product
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A well-conditioned symmetric positive-definite matrix of size n.
    fn spd(n: usize) -> DMatrix<f64> {
        let b = DMatrix::from_fn(n, n, |i, j| ((i * 7 + j * 13) % 17) as f64 / 17.0 - 0.5);
        &b * b.transpose() + DMatrix::identity(n, n)
    }

    /// A⁻¹ A = I for a well-conditioned symmetric positive-definite matrix.
    #[test]
    fn inverts_a_positive_definite_matrix() {
        let n = 40;
        let a = spd(n);
        let inverse = spd_inverse(&cholesky(a.clone()).unwrap());
        let error = (inverse * a - DMatrix::identity(n, n)).amax();
        assert!(error < 1e-12, "{error}");
    }

    /// The panel factorisation gives nalgebra's factor to the bit (sizes below, at and above a
    /// panel, and not a multiple of it), refuses a matrix that is not positive definite, and
    /// Aᵀ B and A Bᵀ by pieces equal the whole products to rounding.
    #[test]
    fn cholesky_is_nalgebras_to_the_bit() {
        for n in [
            1,
            5,
            CHUNK_COLUMNS,
            3 * CHUNK_COLUMNS + 7,
            PRODUCT_COLUMNS + 22,
        ] {
            let a = spd(n);
            let ours = cholesky(a.clone()).unwrap().unpack_dirty();
            let theirs = a.clone().cholesky().unwrap().unpack_dirty();
            assert_eq!(ours.lower_triangle(), theirs.lower_triangle(), "n = {n}");
            let b = DMatrix::from_fn(n, n + 3, |i, j| ((i * 5 + j * 3) % 11) as f64 - 5.0);
            // The pieces may sum in another grouping than the whole product (nalgebra
            // multiplies small matrices by its own loops): equal to rounding.
            let close = |x: DMatrix<f64>, y: DMatrix<f64>| (x - &y).amax() <= 1e-14 * y.amax();
            assert!(
                close(transpose_times(&a, &b), a.transpose() * &b),
                "n = {n}"
            );
            let bt = b.transpose();
            assert!(close(times_transpose(&a, &bt), &a * b), "n = {n}");
        }
        let mut indefinite = spd(20);
        indefinite[(12, 12)] = -1.0;
        assert!(cholesky(indefinite).is_none());
    }
}
