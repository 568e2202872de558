//! The paper's published figures (Tables 1-4), in one place for the simulator, the tests and the
//! firmware's boot smoke. Values as printed; see the errata for how each was checked.

use crate::camera::{InnerOrientation, PixelGrid};
use crate::collinearity::ExteriorOrientation;
use nalgebra::Vector3;

/// Section 3.1 / 6.2.1: the Kodak DC40's 768 × 512 raster in "equivalent" 0.045 mm pixels,
/// the photo origin at pixel (378, 252).
pub const DC40_GRID: PixelGrid<f64> = PixelGrid {
    pixel_size: 0.045,
    width: 768,
    height: 512,
    origin_col: 378.0,
    origin_row: 252.0,
};

/// Table 1: the calibrated inner orientation (f, cx, cy in mm, k1 in mm⁻²).
pub const TABLE1_INNER: InnerOrientation<f64> = InnerOrientation {
    f: 46.981,
    cx: -0.133,
    cy: 0.208,
    k1: 0.000063,
    k2: 0.0,
    k3: 0.0,
    p1: 0.0,
    p2: 0.0,
};

/// Table 2: the camera's exterior orientation [κ, φ, ω, X0, Y0, Z0] (rad, mm) for each
/// projection plane, in the plate's frame. The 1st plane's κ is as printed (0.013301; the errata
/// suspect 0.01329).
pub const TABLE2: [[f64; 6]; 3] = [
    [0.013301, 0.01418, -0.02600, 375.121, 364.541, 1842.675],
    [0.01321, 0.00983, -0.02641, 369.765, 365.590, 1741.494],
    [0.01274, 0.01590, -0.02787, 382.264, 368.888, 1639.377],
];

/// Table 3: the projector's perspective centre in the global (1st plane's) frame, mm.
pub const TABLE3_GLOBAL: [f64; 3] = [-114.601, 383.502, 1905.981];

/// Table 3: the projector's perspective centre in the camera system, mm.
pub const TABLE3_CAMERA: [f64; 3] = [-490.304, 23.837, 56.8250];

/// Table 4: direction cosines (l, m, n) of the nine calibrated rays in the global frame, by
/// label "ij" as `[i, j]` (row i = 0..2, column j = 1..3 of the paper's 3 × 3 set).
pub const TABLE4: [([u16; 2], [f64; 3]); 9] = [
    ([0, 1], [0.09159, -0.17179, -0.98087]),
    ([0, 2], [0.24040, -0.16860, -0.95592]),
    ([0, 3], [0.38490, -0.16341, -0.90838]),
    ([1, 1], [0.09012, -0.02403, -0.99564]),
    ([1, 2], [0.23928, -0.01954, -0.97075]),
    ([1, 3], [0.38453, -0.01461, -0.92300]),
    ([2, 1], [0.08562, 0.12279, -0.98873]),
    ([2, 2], [0.23365, 0.12957, -0.96365]),
    ([2, 3], [0.37689, 0.13301, -0.91666]),
];

/// Table 2's row `plane` (0, 1, 2) as an exterior orientation.
pub fn table2_exterior(plane: usize) -> ExteriorOrientation<f64> {
    let [kappa, phi, omega, x0, y0, z0] = TABLE2[plane];
    ExteriorOrientation {
        kappa,
        phi,
        omega,
        centre: Vector3::new(x0, y0, z0),
    }
}

/// Table 4's ray `k` as a unit vector (the printed cosines normalised).
#[inline]
pub fn table4_direction(k: usize) -> Vector3<f64> {
    Vector3::from(TABLE4[k].1).normalize()
}
