//! Dense linear algebra the adjustments share.

use nalgebra::{linalg::Cholesky, DMatrix, Dyn};

/// The inverse of a symmetric positive-definite matrix A from its Cholesky factor (A = L Lᵀ):
/// A⁻¹ = L⁻ᵀ L⁻¹, with L⁻¹ by column-oriented forward substitution (column j of L⁻¹ is zero
/// above row j: n³/6 operations) and the product by the blocked matrix multiplication. For the
/// reduced normal matrix of a large network (n ≈ 1,200) it is several times faster than solving
/// A X = I column by column.
pub fn spd_inverse(chol: &Cholesky<f64, Dyn>) -> DMatrix<f64> {
    let l = chol.l_dirty();
    let n = l.nrows();
    let l = l.as_slice();
    let mut l_inv = DMatrix::zeros(n, n);
    for (j, x) in l_inv.as_mut_slice().chunks_exact_mut(n.max(1)).enumerate() {
        x[j] = 1.0;
        for k in j..n {
            let column = &l[k * n..(k + 1) * n];
            let xk = x[k] / column[k];
            x[k] = xk;
            for (xi, lik) in x[k + 1..].iter_mut().zip(&column[k + 1..]) {
                *xi -= xk * lik;
            }
        }
    }
    l_inv.transpose() * &l_inv
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A⁻¹ A = I for a well-conditioned symmetric positive-definite matrix.
    #[test]
    fn inverts_a_positive_definite_matrix() {
        let n = 40;
        let b = DMatrix::from_fn(n, n, |i, j| ((i * 7 + j * 13) % 17) as f64 / 17.0 - 0.5);
        let a = &b * b.transpose() + DMatrix::identity(n, n);
        let inverse = spd_inverse(&a.clone().cholesky().unwrap());
        let error = (inverse * a - DMatrix::identity(n, n)).amax();
        assert!(error < 1e-12, "{error}");
    }
}
