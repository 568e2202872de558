//! Where the surface was measured: the union of the frames' triangles projected on the
//! analysis plane (a, v), rasterised; holes stay holes.

use nalgebra::Vector3;

/// How near an edge a point counts as on it, in cells (or, for the levels' count, in
/// spacings). The levels lie a whole number of rows apart from the first measured row's lower
/// edge, and so on row edges: without it, which row a level's run came from, and whether the
/// top level was kept, hung on rounding.
const EDGE: f64 = 1e-9;

/// A mask of cells `cell` mm square from `origin`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Support {
    origin: [f64; 2],
    cell: f64,
    size: [usize; 2],
    mask: Vec<bool>,
}

impl Support {
    /// An empty mask over [lo, hi].
    pub fn new(lo: [f64; 2], hi: [f64; 2], cell: f64) -> Self {
        let size = [0, 1].map(|k| ((hi[k] - lo[k]) / cell).ceil() as usize + 1);
        Self {
            origin: lo,
            cell,
            size,
            mask: vec![false; size[0] * size[1]],
        }
    }

    /// Marks the cells whose centres the triangle (a, v of its corners) covers.
    pub fn fill(&mut self, t: [Vector3<f64>; 3]) {
        let lo = [0, 1].map(|k| t.iter().map(|p| p[k]).fold(f64::INFINITY, f64::min));
        let hi = [0, 1].map(|k| t.iter().map(|p| p[k]).fold(f64::NEG_INFINITY, f64::max));
        let cell = |x: f64, k: usize| ((x - self.origin[k]) / self.cell).floor();
        let (e1, e2) = (t[1] - t[0], t[2] - t[0]);
        let det = e1.x * e2.y - e1.y * e2.x;
        if det.abs() < 1e-12 {
            return;
        }
        let (i0, i1) = (cell(lo[0], 0).max(0.0) as usize, cell(hi[0], 0) as usize);
        let (j0, j1) = (cell(lo[1], 1).max(0.0) as usize, cell(hi[1], 1) as usize);
        for j in j0..=j1.min(self.size[1] - 1) {
            for i in i0..=i1.min(self.size[0] - 1) {
                let (a, v) = self.centre(i, j);
                let (da, dv) = (a - t[0].x, v - t[0].y);
                let u = (da * e2.y - dv * e2.x) / det;
                let w = (e1.x * dv - e1.y * da) / det;
                if u >= 0.0 && w >= 0.0 && u + w <= 1.0 {
                    self.mask[i + self.size[0] * j] = true;
                }
            }
        }
    }

    fn centre(&self, i: usize, j: usize) -> (f64, f64) {
        (
            self.origin[0] + (i as f64 + 0.5) * self.cell,
            self.origin[1] + (j as f64 + 0.5) * self.cell,
        )
    }

    /// The cell holding (a, v); on a cell's edge (to rounding: [`EDGE`]), the cell above it or
    /// to its right.
    fn index(&self, a: f64, v: f64) -> Option<(usize, usize)> {
        let i = ((a - self.origin[0]) / self.cell + EDGE).floor();
        let j = ((v - self.origin[1]) / self.cell + EDGE).floor();
        let inside = i >= 0.0 && j >= 0.0;
        let (i, j) = (i as usize, j as usize);
        (inside && i < self.size[0] && j < self.size[1]).then_some((i, j))
    }

    /// Whether (a, v) was measured.
    pub fn contains(&self, a: f64, v: f64) -> bool {
        self.index(a, v)
            .is_some_and(|(i, j)| self.mask[i + self.size[0] * j])
    }

    /// Whether the whole segment from (a0, v) to (a1, v) was measured.
    pub fn covers(&self, a0: f64, a1: f64, v: f64) -> bool {
        let n = ((a1 - a0).abs() / (0.5 * self.cell)).ceil() as usize + 1;
        (0..=n).all(|k| self.contains(a0 + (a1 - a0) * k as f64 / n as f64, v))
    }

    /// The longest measured run along a at level v (a from, a to).
    pub fn longest_run(&self, v: f64) -> Option<(f64, f64)> {
        let (_, j) = self.index(self.origin[0], v)?;
        let row = &self.mask[self.size[0] * j..self.size[0] * (j + 1)];
        let mut best: Option<(usize, usize)> = None;
        let mut start = None;
        for (i, &m) in row.iter().chain([&false]).enumerate() {
            match (m, start) {
                (true, None) => start = Some(i),
                (false, Some(s)) => {
                    if best.is_none_or(|(b0, b1)| i - s > b1 - b0) {
                        best = Some((s, i));
                    }
                    start = None;
                }
                _ => {}
            }
        }
        best.map(|(i0, i1)| {
            let a = |i: usize| self.origin[0] + i as f64 * self.cell;
            (a(i0), a(i1))
        })
    }

    /// The levels `spacing` apart from the first measured row's lower edge, a spacing inside
    /// both ends of the measured rows. For one frame the spacing is four rows, so each level
    /// lies on a row's edge and takes the row above it ([`EDGE`]).
    pub fn levels(&self, spacing: f64) -> Vec<f64> {
        let Some((v0, v1)) = self.rows() else {
            return Vec::new();
        };
        let count = ((v1 - v0) / spacing + EDGE).floor() as usize;
        (1..count).map(|k| v0 + k as f64 * spacing).collect()
    }

    /// The range of v over which the mask holds anything.
    fn rows(&self) -> Option<(f64, f64)> {
        let filled =
            |j: &usize| self.mask[self.size[0] * j..self.size[0] * (j + 1)].contains(&true);
        let first = (0..self.size[1]).find(filled)?;
        let last = (0..self.size[1]).rev().find(filled)?;
        let v = |j: usize| self.origin[1] + j as f64 * self.cell;
        Some((v(first), v(last + 1)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A level on a row's edge takes the row above, whatever the rounding: 0.3 / 0.1 is
    /// 2.9999999999999996, and without [`EDGE`] the level at 0.3 found row 2's run, not row 3's.
    #[test]
    fn a_level_on_a_row_edge_takes_the_row_above() {
        let mut support = Support::new([0.0, 0.0], [1.0, 1.0], 0.1);
        // Row 3 (v 0.3 to 0.4), columns 2 to 5: a triangle pair covering their centres.
        let p = |a: f64, v: f64| Vector3::new(a, v, 0.0);
        support.fill([p(0.2, 0.3), p(0.6, 0.3), p(0.6, 0.4)]);
        support.fill([p(0.2, 0.3), p(0.6, 0.4), p(0.2, 0.4)]);
        let (lo, hi) = support.longest_run(0.3).expect("row 3 is measured");
        assert!(
            (lo - 0.2).abs() < 1e-12 && (hi - 0.6).abs() < 1e-12,
            "{lo} {hi}"
        );
        assert!(support.contains(0.25, 0.3) && !support.contains(0.25, 0.3 - 1e-6));
    }
}
