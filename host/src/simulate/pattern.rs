//! The projector's dot pattern: a grid of rays on the projector's slide, with the paper's nine
//! calibrated rays (Table 4) among them.
//!
//! A node (row, col) of the grid sits at slide coordinates s = origin + col·col_step + row·row_step
//! (tangents of the angles in the projector frame); its ray leaves the projector along
//! R_proj · normalise(s_x, s_y, −1) in the camera system. Ray ids are row·100 + col.
//!
//! The paper pattern is 20 rows × 22 columns. Table 4's rays "01".."23" are spaced about seven
//! dots apart on the real slide (they span the image), so label "ij" sits at the grid node
//! (3 + 7i, 3 + 7(j − 1)) with its exact Table 4 direction: ids 303, 310, 317, 1003, …, 1717
//! ([`TABLE4_IDS`]). The grid stays uniform around them.

use deltaz_shared::paper::TABLE4;
use nalgebra::{Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// Grid pitch of the paper's slide relative to Table 4's spacing.
const PAPER_SUBDIVISION: u16 = 7;
/// The grid row and column of Table 4's ray "01".
const PAPER_TABLE4_ORIGIN: (u16, u16) = (3, 3);

/// A ray's id is its grid node's row · `ID_STRIDE` + column.
pub const ID_STRIDE: u16 = 100;

/// The grid node (row, col) of Table 4's label "ij" = `[i, j]` in the paper pattern.
pub const fn table4_node([i, j]: [u16; 2]) -> (u16, u16) {
    (
        PAPER_TABLE4_ORIGIN.0 + PAPER_SUBDIVISION * i,
        PAPER_TABLE4_ORIGIN.1 + PAPER_SUBDIVISION * (j - 1),
    )
}

/// The ids (row·100 + col) of Table 4's nine rays in the paper pattern, in Table 4's order.
pub const TABLE4_IDS: [u16; 9] = {
    let mut ids = [0; 9];
    let mut k = 0;
    while k < 9 {
        let (row, col) = table4_node(TABLE4[k].0);
        ids[k] = row * 100 + col;
        k += 1;
    }
    ids
};

/// A dot pattern as a grid on the slide (see the module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PatternSpec {
    /// Rows of dots.
    pub rows: u16,
    /// Columns of dots (at most 100).
    pub cols: u16,
    /// Slide coordinates of node (0, 0).
    pub origin: [f64; 2],
    /// Slide step from one column to the next.
    pub col_step: [f64; 2],
    /// Slide step from one row to the next.
    pub row_step: [f64; 2],
    /// Whether Table 4's rays sit at their exact directions on nodes [`table4_node`] (the paper
    /// pattern).
    #[serde(default)]
    pub table4: bool,
    /// Radial distortion of the slide: s ↦ s (1 + k ρ²), ρ measured from the grid's centre.
    #[serde(default)]
    pub distortion: f64,
    /// Non-central rays: each ray passes through centre + offset, offset = this (mm per unit of
    /// slide coordinate) × (s − centre, 0) in the projector frame.
    #[serde(default)]
    pub noncentral_mm: f64,
}

/// One ray of the pattern, in the camera system.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PatternRay {
    /// Ray id.
    pub id: u16,
    /// Grid row of the node.
    pub row: u16,
    /// Grid column of the node.
    pub col: u16,
    /// Unit direction in the camera system.
    pub direction: Vector3<f64>,
    /// The ray passes through the projector centre + this offset (camera system, mm).
    pub offset: Vector3<f64>,
}

impl PatternSpec {
    /// The paper's 20 × 22 pattern, its grid fitted to Table 4's slide coordinates
    /// (ids 1..203 = Table 4, see the module docs).
    pub fn paper() -> Self {
        // Least-squares affine fit s = a + col·b + row·c over Table 4's nine rays.
        let mut n = Matrix3::<f64>::zeros();
        let mut rhs = [Vector3::<f64>::zeros(); 2];
        for ([i, j], d) in TABLE4 {
            let s = slide_of(&Vector3::from(d));
            let basis = Vector3::new(1.0, f64::from(j), f64::from(i));
            n += basis * basis.transpose();
            rhs[0] += basis * s.x;
            rhs[1] += basis * s.y;
        }
        let inv = n.try_inverse().expect("Table 4 spans a grid");
        let (fu, fv) = (inv * rhs[0], inv * rhs[1]);
        let (r0, c0) = PAPER_TABLE4_ORIGIN;
        let k = f64::from(PAPER_SUBDIVISION);
        let col_step = [fu.y / k, fv.y / k];
        let row_step = [fu.z / k, fv.z / k];
        // Table 4's "01" (row 0, col 1) sits at node (r0, c0).
        let at01 = [fu.x + fu.y, fv.x + fv.y];
        let origin = [
            at01[0] - f64::from(c0) * col_step[0] - f64::from(r0) * row_step[0],
            at01[1] - f64::from(c0) * col_step[1] - f64::from(r0) * row_step[1],
        ];
        Self {
            rows: 20,
            cols: 22,
            origin,
            col_step,
            row_step,
            table4: true,
            distortion: 0.0,
            noncentral_mm: 0.0,
        }
    }

    fn node(&self, row: u16, col: u16) -> Vector2<f64> {
        let (r, c) = (f64::from(row), f64::from(col));
        Vector2::new(
            self.origin[0] + c * self.col_step[0] + r * self.row_step[0],
            self.origin[1] + c * self.col_step[1] + r * self.row_step[1],
        )
    }

    /// The id of grid node (row, col): row·[`ID_STRIDE`] + col.
    pub fn id(&self, row: u16, col: u16) -> u16 {
        row * ID_STRIDE + col
    }

    /// Every ray in the camera system, sorted by id. `r_cam_proj` turns projector-frame vectors
    /// into camera-system vectors.
    pub fn rays(&self, r_cam_proj: &Matrix3<f64>) -> Vec<PatternRay> {
        let centre = (self.node(0, 0) + self.node(self.rows - 1, self.cols - 1)) / 2.0;
        let mut rays = Vec::with_capacity(usize::from(self.rows) * usize::from(self.cols));
        for row in 0..self.rows {
            for col in 0..self.cols {
                let id = self.id(row, col);
                let table = TABLE4
                    .iter()
                    .find(|(label, _)| self.table4 && table4_node(*label) == (row, col))
                    .map(|(_, d)| slide_of(&Vector3::from(*d)));
                let s = table.unwrap_or_else(|| self.node(row, col));
                let rho = s - centre;
                let s = s + rho * (self.distortion * rho.norm_squared());
                let direction = r_cam_proj * Vector3::new(s.x, s.y, -1.0).normalize();
                let offset = r_cam_proj * Vector3::new(rho.x, rho.y, 0.0) * self.noncentral_mm;
                rays.push(PatternRay {
                    id,
                    row,
                    col,
                    direction,
                    offset,
                });
            }
        }
        rays.sort_by_key(|r| r.id);
        rays
    }
}

/// Slide coordinates (tangents) of a direction pointing along −z: (l/−n, m/−n).
fn slide_of(d: &Vector3<f64>) -> Vector2<f64> {
    Vector2::new(d.x / -d.z, d.y / -d.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_pattern_ids_and_table4_directions() {
        let p = PatternSpec::paper();
        let rays = p.rays(&Matrix3::identity());
        assert_eq!(rays.len(), 440);
        // ids unique and all of the form row*100 + col within the grid
        let mut ids: Vec<u16> = rays.iter().map(|r| r.id).collect();
        ids.dedup();
        assert_eq!(ids.len(), 440);
        assert!(ids.iter().all(|id| id / 100 < 20 && id % 100 < 22));
        for (id, (_, d)) in TABLE4_IDS.into_iter().zip(TABLE4) {
            let ray = rays.iter().find(|r| r.id == id).unwrap();
            let expect = Vector3::from(d).normalize();
            assert!((ray.direction - expect).norm() < 1e-12, "ray {id}");
        }
        // The grid is uniform around the Table 4 rays: each lies within 0.4 pitch of its node
        // (Table 4 is not exactly affine), so neighbouring dots stay well apart.
        let pitch = Vector2::from(p.col_step).norm();
        for ray in rays.iter().filter(|r| TABLE4_IDS.contains(&r.id)) {
            let node = p.node(ray.row, ray.col);
            let miss = (slide_of(&ray.direction) - node).norm();
            assert!(
                miss < 0.4 * pitch,
                "ray {} misses its node by {miss}",
                ray.id
            );
        }
    }
}
