//! A uniform bicubic B-spline over a rectangle of the analysis plane (a across, v along the
//! trunk), the smooth surface n = s(a, v) is fitted as.

use nalgebra_sparse::CooMatrix;

/// The knot grid: `step` apart from `origin`, `cells` cells each way, `cells + 3` coefficients.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Grid {
    pub origin: [f64; 2],
    pub step: f64,
    pub cells: [usize; 2],
}

/// Which value of the surface: s, ∂s/∂a, ∂s/∂v, ∂²s/∂a², ∂²s/∂a∂v.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum D {
    S,
    A,
    V,
    AA,
    AV,
}

impl D {
    /// The orders of differentiation along a and v.
    fn orders(self) -> (usize, usize) {
        match self {
            D::S => (0, 0),
            D::A => (1, 0),
            D::V => (0, 1),
            D::AA => (2, 0),
            D::AV => (1, 1),
        }
    }
}

/// A value of the surface as a linear form in the coefficients.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Stencil {
    pub index: [usize; 16],
    pub weight: [f64; 16],
}

impl Stencil {
    pub fn apply(&self, c: &[f64]) -> f64 {
        self.index
            .iter()
            .zip(&self.weight)
            .map(|(&i, w)| c[i] * w)
            .sum()
    }
}

/// The uniform cubic B-spline's four basis functions at t in [0, 1] and their 1st and 2nd
/// derivatives (per unit t).
fn basis(t: f64) -> [[f64; 4]; 3] {
    let s = 1.0 - t;
    [
        [
            s * s * s / 6.0,
            (3.0 * t * t * t - 6.0 * t * t + 4.0) / 6.0,
            (-3.0 * t * t * t + 3.0 * t * t + 3.0 * t + 1.0) / 6.0,
            t * t * t / 6.0,
        ],
        [
            -s * s / 2.0,
            (3.0 * t * t - 4.0 * t) / 2.0,
            (-3.0 * t * t + 2.0 * t + 1.0) / 2.0,
            t * t / 2.0,
        ],
        [s, 3.0 * t - 2.0, -3.0 * t + 1.0, t],
    ]
}

impl Grid {
    /// A grid covering [lo, hi] with knots `step` apart.
    pub fn covering(lo: [f64; 2], hi: [f64; 2], step: f64) -> Self {
        let cells = [0, 1].map(|k| (((hi[k] - lo[k]) / step).ceil() as usize).max(1));
        Self {
            origin: lo,
            step,
            cells,
        }
    }

    /// The number of coefficients.
    pub fn len(&self) -> usize {
        (self.cells[0] + 3) * (self.cells[1] + 3)
    }

    fn span(&self, x: f64, axis: usize) -> Option<(usize, f64)> {
        let u = (x - self.origin[axis]) / self.step;
        let n = self.cells[axis];
        if !(0.0..=n as f64).contains(&u) {
            return None;
        }
        let i = (u.floor() as usize).min(n - 1);
        Some((i, u - i as f64))
    }

    /// The stencil of value `d` at (a, v); None outside the grid.
    pub fn stencil(&self, a: f64, v: f64, d: D) -> Option<Stencil> {
        let (ia, ta) = self.span(a, 0)?;
        let (iv, tv) = self.span(v, 1)?;
        let (oa, ov) = d.orders();
        let ba = basis(ta)[oa].map(|b| b / self.step.powi(oa as i32));
        let bv = basis(tv)[ov].map(|b| b / self.step.powi(ov as i32));
        let row = self.cells[0] + 3;
        let mut s = Stencil {
            index: [0; 16],
            weight: [0.0; 16],
        };
        for (q, wv) in bv.iter().enumerate() {
            for (p, wa) in ba.iter().enumerate() {
                s.index[4 * q + p] = (ia + p) + row * (iv + q);
                s.weight[4 * q + p] = wa * wv;
            }
        }
        Some(s)
    }

    /// The roughness penalty: the squared second differences of the coefficients, the
    /// thin-plate energy's discrete form (∂²/∂a², 2 ∂²/∂a∂v, ∂²/∂v²).
    pub fn penalty(&self) -> CooMatrix<f64> {
        let [na, nv] = self.cells.map(|c| c + 3);
        let id = |i: usize, j: usize| i + na * j;
        let mut p = CooMatrix::new(self.len(), self.len());
        let mut add = |terms: &[(usize, f64)]| {
            for &(i, wi) in terms {
                for &(j, wj) in terms {
                    p.push(i, j, wi * wj);
                }
            }
        };
        let r2 = std::f64::consts::SQRT_2;
        for j in 0..nv {
            for i in 0..na {
                if i + 2 < na {
                    add(&[(id(i, j), 1.0), (id(i + 1, j), -2.0), (id(i + 2, j), 1.0)]);
                }
                if j + 2 < nv {
                    add(&[(id(i, j), 1.0), (id(i, j + 1), -2.0), (id(i, j + 2), 1.0)]);
                }
                if i + 1 < na && j + 1 < nv {
                    add(&[
                        (id(i, j), r2),
                        (id(i + 1, j), -r2),
                        (id(i, j + 1), -r2),
                        (id(i + 1, j + 1), r2),
                    ]);
                }
            }
        }
        p
    }
}
