//! Circle-grid boards (OpenCV's symmetric and asymmetric circle grids): find the board among
//! the measured targets and label every circle by its grid position.
//!
//! # Convention (OpenCV's)
//! `circles:COLSxROWS[:SPACING]` is a symmetric grid of COLS circles per row and ROWS rows,
//! circle (row i, column j) at (j s, i s, 0). `acircles:COLSxROWS[:SPACING]` is an asymmetric
//! grid: COLS circles per row, ROWS rows, each row shifted by half a pitch against the one before,
//! circle (i, j) at ((2 j + i mod 2) s, i s, 0) (OpenCV's `calcBoardCornerPositions`; the pitch
//! along a row is 2 s). The default spacing s is 1 (board units).
//!
//! # Order
//! Circles are named `rIcJ` and listed row-major (OpenCV's index i · COLS + j). A grid is
//! symmetric under some rotations and reflections, so the labelling is fixed by the image, as
//! OpenCV's `findCirclesGrid` fixes it:
//! 1. the board is seen from its front: turning from the column direction (+j) to the row
//!    direction (+i) is clockwise in the image, as from +col to +row (the board's x × y points
//!    away from the camera). This alone fixes an asymmetric grid with an odd number of rows,
//!    whose only symmetry is a reflection (OpenCV's "clockwise" test on its outside corners);
//! 2. of the rotations left, the one whose column direction points most along +col, then the
//!    one whose row direction points along +row ("row 0 at the top, column 0 at the left" for a
//!    board held about upright).
//!
//! # Method
//! The targets of similar size are walked as a lattice ([`super::grid::walk_grid`]) from the
//! most regular one (four nearest neighbours in two opposite pairs), so blobs off the lattice are
//! never labelled. The walked lattice is then placed on the board: every rotation or reflection
//! and offset for which the walked circles fall on board positions, the most of them winning.
//! When part of the board is cut off by the image border, several offsets fit; the one whose
//! missing circles are all predicted (by the plane homography of the found ones) outside the
//! image is taken, and an ambiguous placement is an error rather than a guess.
//!
//! # Geometry
//! The lattice found must be the declared board: every walked circle on it, at most a tenth of
//! its circles predicted inside the image missing and none of its edge rows and columns missing
//! where in view. A board of another kind (a symmetric grid's diagonals fit an asymmetric
//! board) or size is refused, and the error says what the lattice is ("the 49 circles found
//! form a circles:7x7 grid").

use super::grid::walk_grid;
use anyhow::{bail, Context, Result};
use nalgebra::{DMatrix, Matrix3, Vector2, Vector3};

/// The kind of circle grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GridKind {
    /// Rows of COLS circles at pitch s, rows s apart.
    Symmetric,
    /// Rows of COLS circles at pitch 2 s, rows s apart, alternate rows shifted by s.
    Asymmetric,
}

/// A circle-grid board.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Board {
    /// Symmetric or asymmetric.
    pub kind: GridKind,
    /// Circles per row (OpenCV's patternSize.width).
    pub cols: usize,
    /// Rows (OpenCV's patternSize.height).
    pub rows: usize,
    /// The spacing s (mm; 1 when not given).
    pub spacing: f64,
}

impl std::str::FromStr for Board {
    type Err = anyhow::Error;

    /// `circles:COLSxROWS[:SPACING]` or `acircles:COLSxROWS[:SPACING]`.
    fn from_str(s: &str) -> Result<Self> {
        let usage = || {
            format!("board {s:?}: expected circles:COLSxROWS[:SPACING_MM] or acircles:COLSxROWS[:SPACING_MM]")
        };
        let mut parts = s.split(':');
        let kind = match parts.next() {
            Some("circles") => GridKind::Symmetric,
            Some("acircles") => GridKind::Asymmetric,
            _ => bail!(usage()),
        };
        let (cols, rows) = parts
            .next()
            .and_then(|d| d.split_once('x'))
            .with_context(usage)?;
        let cols: usize = cols.parse().ok().with_context(usage)?;
        let rows: usize = rows.parse().ok().with_context(usage)?;
        let spacing = match parts.next() {
            Some(v) => v.parse::<f64>().ok().with_context(usage)?,
            None => 1.0,
        };
        if parts.next().is_some() || cols < 2 || rows < 2 || !spacing.is_finite() || spacing <= 0.0
        {
            bail!(usage());
        }
        Ok(Board {
            kind,
            cols,
            rows,
            spacing,
        })
    }
}

/// One labelled circle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoardPoint {
    /// Row (0-based).
    pub row: usize,
    /// Column (0-based).
    pub col: usize,
    /// Index of the target it was found as.
    pub target: usize,
}

impl Board {
    /// The circle's position on the board in lattice units (x = col pitch units, y = rows).
    fn lattice(&self, row: usize, col: usize) -> (i64, i64) {
        match self.kind {
            GridKind::Symmetric => (col as i64, row as i64),
            GridKind::Asymmetric => ((2 * col + row % 2) as i64, row as i64),
        }
    }

    /// The board position (row, col) at a lattice point, if there is a circle.
    fn at(&self, x: i64, y: i64) -> Option<(usize, usize)> {
        if y < 0 || y >= self.rows as i64 || x < 0 {
            return None;
        }
        let (row, x) = (y as usize, x as usize);
        let col = match self.kind {
            GridKind::Symmetric => x,
            GridKind::Asymmetric => {
                if x < row % 2 || (x - row % 2) % 2 != 0 {
                    return None;
                }
                (x - row % 2) / 2
            }
        };
        (col < self.cols).then_some((row, col))
    }

    /// The circle's point name, `rIcJ`.
    pub fn name(row: usize, col: usize) -> String {
        format!("r{row}c{col}")
    }

    /// The circle's board coordinates (X, Y, Z = 0) in the spacing's unit.
    pub fn position(&self, row: usize, col: usize) -> Vector3<f64> {
        let (x, y) = self.lattice(row, col);
        Vector3::new(x as f64 * self.spacing, y as f64 * self.spacing, 0.0)
    }

    /// All circles in OpenCV's order, as (row, col).
    pub fn circles(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        (0..self.rows).flat_map(move |r| (0..self.cols).map(move |c| (r, c)))
    }

    /// Find the board among target centres (`radii`: their sizes, any consistent measure) in
    /// an image `width × height`; the labelled circles in OpenCV's order (cut-off ones absent).
    /// A lattice of circles that is not this board (another kind or size) is refused, the
    /// error naming what was found.
    pub fn find(
        &self,
        centres: &[Vector2<f64>],
        radii: &[f64],
        width: usize,
        height: usize,
    ) -> Result<Vec<BoardPoint>> {
        let needed = (self.cols * self.rows).div_ceil(2).max(4);
        let seeds = regular_seeds(centres);
        let mut best: Option<Vec<BoardPoint>> = None;
        // The largest lattice walked: its size and what it is.
        let mut largest: Option<(usize, String)> = None;
        let mut tried = 0;
        for &seed in &seeds {
            if best
                .as_ref()
                .is_some_and(|b| b.len() == self.cols * self.rows)
                || tried >= 12
            {
                break;
            }
            // Targets of about the seed's size only: other blobs never enter the walk.
            let similar: Vec<usize> = (0..centres.len())
                .filter(|&k| (radii[k] / radii[seed] - 1.0).abs() < 0.5)
                .collect();
            let Some(start) = similar.iter().position(|&k| k == seed) else {
                continue;
            };
            tried += 1;
            let dots: Vec<Vector2<f64>> = similar.iter().map(|&k| centres[k]).collect();
            let Some((a, b)) = seed_steps(&dots, start) else {
                continue;
            };
            let labels = walk_grid(&dots, start, (1000, 1000), a, b, (2000, 2000));
            // Walk nodes (p along a, q along b).
            let nodes: Vec<(usize, (i64, i64))> = labels
                .iter()
                .enumerate()
                .filter_map(|(k, l)| {
                    let (r, c) = l.as_ref()?;
                    Some((similar[k], (i64::from(*c) - 1000, i64::from(*r) - 1000)))
                })
                .collect();
            if largest.as_ref().is_none_or(|(n, _)| nodes.len() > *n) {
                largest = Some((nodes.len(), lattice_kind(&nodes, a, b)));
            }
            // Walk nodes to lattice units: the asymmetric grid's nearest neighbours are the
            // diagonals (±1, ±1).
            let walked: Vec<(usize, (i64, i64))> = nodes
                .iter()
                .map(|&(k, (p, q))| {
                    let at = match self.kind {
                        GridKind::Symmetric => (p, q),
                        GridKind::Asymmetric => (p + q, p - q),
                    };
                    (k, at)
                })
                .collect();
            if walked.len() < needed {
                continue;
            }
            if let Some(found) = self.place(&walked, centres, width, height)? {
                if best.as_ref().is_none_or(|b| found.len() > b.len()) {
                    best = Some(found);
                }
            }
        }
        match best {
            Some(b) if b.len() >= needed => Ok(b),
            _ => {
                let found = match largest {
                    Some((n, kind)) if n >= 4 => format!(": the {n} circles found form {kind}"),
                    _ => String::new(),
                };
                bail!(
                    "no {self} board ({} × {} {} circle grid) among {} targets{found}",
                    self.cols,
                    self.rows,
                    match self.kind {
                        GridKind::Symmetric => "symmetric",
                        GridKind::Asymmetric => "asymmetric",
                    },
                    centres.len()
                )
            }
        }
    }

    /// Place the walked lattice on the board (see the module's doc).
    fn place(
        &self,
        walked: &[(usize, (i64, i64))],
        centres: &[Vector2<f64>],
        width: usize,
        height: usize,
    ) -> Result<Option<Vec<BoardPoint>>> {
        let (bw, bh) = match self.kind {
            GridKind::Symmetric => (self.cols as i64, self.rows as i64),
            GridKind::Asymmetric => (2 * self.cols as i64 - 1, self.rows as i64),
        };
        // The labelled points of every placement.
        let mut candidates: Vec<Vec<BoardPoint>> = Vec::new();
        for transform in &DIHEDRAL {
            let moved: Vec<(usize, (i64, i64))> = walked
                .iter()
                .map(|&(k, (x, y))| {
                    (
                        k,
                        (
                            transform[0] * x + transform[1] * y,
                            transform[2] * x + transform[3] * y,
                        ),
                    )
                })
                .collect();
            let (minx, miny) = moved
                .iter()
                .fold((i64::MAX, i64::MAX), |(a, b), (_, (x, y))| {
                    (a.min(*x), b.min(*y))
                });
            let (maxx, maxy) = moved
                .iter()
                .fold((i64::MIN, i64::MIN), |(a, b), (_, (x, y))| {
                    (a.max(*x), b.max(*y))
                });
            // Offsets putting the walked lattice's box at least half on the board.
            for ox in (-maxx)..=(bw - 1 - minx) {
                for oy in (-maxy)..=(bh - 1 - miny) {
                    let points: Vec<BoardPoint> = moved
                        .iter()
                        .filter_map(|&(k, (x, y))| {
                            self.at(x + ox, y + oy).map(|(row, col)| BoardPoint {
                                row,
                                col,
                                target: k,
                            })
                        })
                        .collect();
                    // The board's geometry: every circle of the lattice on it.
                    if points.len() == walked.len() {
                        candidates.push(points);
                    }
                }
            }
        }
        // ... and the board's circles in view found: those missing are cut off by the border
        // (predicted outside the image), but for a few (a glare, a covered circle).
        candidates.retain(|c| self.fills_view(c, centres, width, height));
        // Of the placements, those with the fewest missing circles predicted inside the image.
        let missing: Vec<usize> = candidates
            .iter()
            .map(|c| self.missing_inside(c, centres, width, height).len())
            .collect();
        let fewest = missing.iter().copied().min().unwrap_or(0);
        let mut kept = missing.iter();
        candidates.retain(|_| kept.next() == Some(&fewest));
        // The board's symmetries give equal placements: the image's orientation picks one (see
        // the module's doc), by the board's directions at the same place for every placement:
        // the board point under the centroid of the circles. Greater is preferred.
        let oriented = |points: &[BoardPoint]| -> Option<Orientation> {
            let h = self.homography(points, centres)?;
            let inverse = h.try_inverse()?;
            let at = |x: f64, y: f64| {
                let v = h * Vector3::new(x, y, 1.0);
                Vector2::new(v.x / v.z, v.y / v.z)
            };
            let m = points
                .iter()
                .map(|p| centres[p.target])
                .sum::<Vector2<f64>>()
                / points.len() as f64;
            let b = inverse * Vector3::new(m.x, m.y, 1.0);
            let (x0, y0) = (b.x / b.z, b.y / b.z);
            let col_dir = (at(x0 + 1.0, y0) - m).normalize();
            let row_dir = (at(x0, y0 + 1.0) - m).normalize();
            // Seen from the front; the column direction (to 1e-3); the row direction's sense.
            Some((
                col_dir.perp(&row_dir) > 0.0,
                (1e3 * col_dir.x).round() as i64,
                row_dir.y > 0.0,
            ))
        };
        let mut scored: Vec<(Option<Orientation>, Vec<BoardPoint>)> =
            candidates.into_iter().map(|c| (oriented(&c), c)).collect();
        scored.sort_by_key(|s| std::cmp::Reverse(s.0));
        let Some((score, mut points)) = scored.first().cloned() else {
            return Ok(None);
        };
        // A different labelling with the same score: the placement is ambiguous.
        if scored
            .iter()
            .skip(1)
            .any(|(s, p)| *s == score && !same_labels(p, &points))
        {
            bail!(
                "the {}x{} circle grid is cut off so that its position on the board is ambiguous",
                self.cols,
                self.rows
            );
        }
        points.sort_by_key(|p| (p.row, p.col));
        Ok(Some(points))
    }

    /// The plane homography board lattice (x, y) → image of labelled points (DLT, normalised).
    fn homography(&self, points: &[BoardPoint], centres: &[Vector2<f64>]) -> Option<Matrix3<f64>> {
        let pairs: Vec<(Vector2<f64>, Vector2<f64>)> = points
            .iter()
            .map(|p| {
                let (x, y) = self.lattice(p.row, p.col);
                (Vector2::new(x as f64, y as f64), centres[p.target])
            })
            .collect();
        homography(&pairs)
    }

    /// The board circles (row, col) not in `points` that are predicted inside the image
    /// (farther than half a pitch from its border); all of them when the homography fails.
    fn missing_inside(
        &self,
        points: &[BoardPoint],
        centres: &[Vector2<f64>],
        width: usize,
        height: usize,
    ) -> Vec<(usize, usize)> {
        let missing = self
            .circles()
            .filter(|&(r, c)| !points.iter().any(|p| p.row == r && p.col == c));
        let Some(h) = self.homography(points, centres) else {
            return missing.collect();
        };
        let at = |c: f64, r: f64| {
            let v = h * Vector3::new(c, r, 1.0);
            Vector2::new(v.x / v.z, v.y / v.z)
        };
        let pitch = (at(1.0, 0.0) - at(0.0, 0.0))
            .norm()
            .min((at(0.0, 1.0) - at(0.0, 0.0)).norm());
        let margin = 0.5 * pitch;
        missing
            .filter(|&(r, c)| {
                let (x, y) = self.lattice(r, c);
                let p = at(x as f64, y as f64);
                p.x >= margin
                    && p.y >= margin
                    && p.x <= width as f64 - 1.0 - margin
                    && p.y <= height as f64 - 1.0 - margin
            })
            .collect()
    }

    /// Whether a placement shows the whole board within the image: at most a tenth of the
    /// circles predicted inside the image are missing (a detection loses a few, to glare or a
    /// cover; a board declared larger than the one in view, or a grid of another kind laid on
    /// it, leaves rows or a good share empty), and none of the board's four edge rows and
    /// columns is missing where it is in view (a board declared one row too long).
    fn fills_view(
        &self,
        points: &[BoardPoint],
        centres: &[Vector2<f64>],
        width: usize,
        height: usize,
    ) -> bool {
        let missing = self.missing_inside(points, centres, width, height);
        if 10 * missing.len() > points.len() + missing.len() {
            return false;
        }
        let edges: [&dyn Fn(usize, usize) -> bool; 4] = [
            &|r, _| r == 0,
            &|r, _| r == self.rows - 1,
            &|_, c| c == 0,
            &|_, c| c == self.cols - 1,
        ];
        edges.iter().all(|on_edge| {
            let shown = missing.iter().any(|&(r, c)| on_edge(r, c));
            !shown || points.iter().any(|p| on_edge(p.row, p.col))
        })
    }
}

impl std::fmt::Display for Board {
    /// The spec: `circles:COLSxROWS` or `acircles:COLSxROWS` (with `:SPACING` when not 1).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let kind = match self.kind {
            GridKind::Symmetric => "circles",
            GridKind::Asymmetric => "acircles",
        };
        write!(f, "{kind}:{}x{}", self.cols, self.rows)?;
        if self.spacing != 1.0 {
            write!(f, ":{}", self.spacing)?;
        }
        Ok(())
    }
}

/// What a walked lattice is (walk nodes (p, q) along the image steps `a`, `b`): "a circles:7x7
/// grid" when it fills a rectangle of nodes (the columns along the step nearer the image's
/// rows), "an acircles:4x11 grid" when its diagonals (p + q, p − q) fill an asymmetric grid,
/// otherwise its extent.
fn lattice_kind(nodes: &[(usize, (i64, i64))], a: Vector2<f64>, b: Vector2<f64>) -> String {
    let extent = |f: &dyn Fn(i64, i64) -> (i64, i64)| {
        let (mut lo, mut hi) = ((i64::MAX, i64::MAX), (i64::MIN, i64::MIN));
        for &(_, (p, q)) in nodes {
            let (x, y) = f(p, q);
            lo = (lo.0.min(x), lo.1.min(y));
            hi = (hi.0.max(x), hi.1.max(y));
        }
        ((hi.0 - lo.0 + 1) as usize, (hi.1 - lo.1 + 1) as usize)
    };
    let n = nodes.len();
    let (w, h) = extent(&|p, q| (p, q));
    if n == w * h {
        // OpenCV's columns run along the board's more nearly horizontal direction.
        let (cols, rows) = if a.x.abs() / a.norm() >= b.x.abs() / b.norm() {
            (w, h)
        } else {
            (h, w)
        };
        return format!("a circles:{cols}x{rows} grid");
    }
    let (x, y) = extent(&|p, q| (p + q, p - q));
    if x % 2 == 0 && n == x / 2 * y {
        return format!("an acircles:{}x{y} grid", x / 2);
    }
    if y % 2 == 0 && n == y / 2 * x {
        return format!("an acircles:{}x{x} grid", y / 2);
    }
    format!("a lattice of {w} × {h} steps with gaps (not a whole grid)")
}

/// How a placement of the board faces the image, greater preferred (see the module's doc): seen
/// from its front, its column direction's x component (in thousandths), its row direction
/// pointing down the image.
type Orientation = (bool, i64, bool);

/// The 8 rotations and reflections of the integer lattice, as [a, b, c, d]: (x, y) ↦
/// (a x + b y, c x + d y).
const DIHEDRAL: [[i64; 4]; 8] = [
    [1, 0, 0, 1],
    [0, -1, 1, 0],
    [-1, 0, 0, -1],
    [0, 1, -1, 0],
    [-1, 0, 0, 1],
    [1, 0, 0, -1],
    [0, 1, 1, 0],
    [0, -1, -1, 0],
];

fn same_labels(a: &[BoardPoint], b: &[BoardPoint]) -> bool {
    a.len() == b.len()
        && a.iter().all(|p| {
            b.iter()
                .any(|q| q.target == p.target && q.row == p.row && q.col == p.col)
        })
}

/// Targets ordered by how regular their neighbourhood is: the four nearest neighbours in two
/// opposite pairs of about equal length (best first).
fn regular_seeds(centres: &[Vector2<f64>]) -> Vec<usize> {
    let mut scored: Vec<(f64, usize)> = (0..centres.len())
        .filter_map(|k| {
            let near = nearest_four(centres, k)?;
            let len = near[0].norm();
            // Each neighbour's opposite: the one closest to its negative.
            let misfit: f64 = near
                .iter()
                .map(|v| {
                    near.iter()
                        .map(|w| (v + w).norm())
                        .fold(f64::INFINITY, f64::min)
                })
                .sum::<f64>()
                + near.iter().map(|v| (v.norm() - len).abs()).sum::<f64>();
            Some((misfit / len, k))
        })
        .collect();
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    scored.into_iter().map(|s| s.1).collect()
}

fn nearest_four(centres: &[Vector2<f64>], k: usize) -> Option<[Vector2<f64>; 4]> {
    let mut near: Vec<Vector2<f64>> = centres
        .iter()
        .enumerate()
        .filter(|&(j, _)| j != k)
        .map(|(_, c)| c - centres[k])
        .collect();
    if near.len() < 4 {
        return None;
    }
    near.select_nth_unstable_by(3, |a, b| a.norm_squared().total_cmp(&b.norm_squared()));
    Some([near[0], near[1], near[2], near[3]])
}

/// The seed's two lattice steps: the nearest neighbour and the most nearly perpendicular of
/// the other three nearest.
fn seed_steps(dots: &[Vector2<f64>], seed: usize) -> Option<(Vector2<f64>, Vector2<f64>)> {
    let mut near = nearest_four(dots, seed)?;
    near.sort_by(|a, b| a.norm_squared().total_cmp(&b.norm_squared()));
    let a = near[0];
    let b = near[1..]
        .iter()
        .copied()
        .max_by(|u, v| a.perp(u).abs().total_cmp(&a.perp(v).abs()))?;
    Some((a, b))
}

/// The plane homography from (x, y) to (u, v) by the normalised DLT; `None` with fewer than 4
/// pairs or a degenerate configuration.
pub fn homography(pairs: &[(Vector2<f64>, Vector2<f64>)]) -> Option<Matrix3<f64>> {
    if pairs.len() < 4 {
        return None;
    }
    let normaliser = |pts: &mut dyn Iterator<Item = Vector2<f64>>| {
        let v: Vec<Vector2<f64>> = pts.collect();
        let mean = v.iter().sum::<Vector2<f64>>() / v.len() as f64;
        let spread = v.iter().map(|p| (p - mean).norm()).sum::<f64>() / v.len() as f64;
        let s = std::f64::consts::SQRT_2 / spread.max(1e-12);
        Matrix3::new(s, 0.0, -s * mean.x, 0.0, s, -s * mean.y, 0.0, 0.0, 1.0)
    };
    let tx = normaliser(&mut pairs.iter().map(|p| p.0));
    let tu = normaliser(&mut pairs.iter().map(|p| p.1));
    let mut a = DMatrix::<f64>::zeros(2 * pairs.len(), 9);
    for (k, (x, u)) in pairs.iter().enumerate() {
        let x = tx * Vector3::new(x.x, x.y, 1.0);
        let u = tu * Vector3::new(u.x, u.y, 1.0);
        let r = 2 * k;
        for j in 0..3 {
            a[(r, 3 + j)] = -u.z * x[j];
            a[(r, 6 + j)] = u.y * x[j];
            a[(r + 1, j)] = u.z * x[j];
            a[(r + 1, 6 + j)] = -u.x * x[j];
        }
    }
    let svd = (a.transpose() * &a).symmetric_eigen();
    let (min, _) = svd
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let h = svd.eigenvectors.column(min);
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let h = tu.try_inverse()? * hn * tx;
    (h[(2, 2)].abs() > 1e-15).then(|| h / h[(2, 2)])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic board seen through a homography, with clutter, whole or with part cut off by
    /// the image border, upright or turned about the image centre: every circle labelled with
    /// its own (row, col), clutter never. (Turned only the asymmetric board of odd rows, whose
    /// labels no rotation changes: its one symmetry is a reflection.)
    #[test]
    fn labels_synthetic_boards() {
        for (spec, cut, turn) in [
            ("circles:7x5:20", 0.0, 0.0),
            ("acircles:4x11:10", 0.0, 0.0),
            ("circles:7x5:20", 150.0, 0.0),
            ("circles:5x4:20", 135.0, 0.0),
            ("acircles:4x11:10", 150.0, 0.0),
            ("acircles:4x10:10", 150.0, 0.0),
            ("acircles:4x11:10", 0.0, 170.0),
            ("acircles:4x11:10", 0.0, 100.0),
        ] {
            let board: Board = spec.parse().unwrap();
            let (sin, cos) = f64::to_radians(turn).sin_cos();
            let about_centre = Matrix3::new(1.0, 0.0, 320.0, 0.0, 1.0, 240.0, 0.0, 0.0, 1.0)
                * Matrix3::new(cos, -sin, 0.0, sin, cos, 0.0, 0.0, 0.0, 1.0)
                * Matrix3::new(1.0, 0.0, -320.0, 0.0, 1.0, -240.0, 0.0, 0.0, 1.0);
            let h = about_centre
                * Matrix3::new(1.1, 0.15, 120.0, -0.1, 0.95, 90.0, 0.0004, -0.0002, 1.0);
            let scale = 20.0 / board.spacing;
            let mut centres = Vec::new();
            let mut truth = Vec::new();
            for (r, c) in board.circles() {
                let p = board.position(r, c) * scale;
                let v = h * Vector3::new(p.x, p.y, 1.0);
                // The image's left border at `cut`: the circles left of it are cut off.
                let img = Vector2::new(v.x / v.z - cut, v.y / v.z);
                if img.x >= 0.0 {
                    truth.push((r, c, centres.len()));
                    centres.push(img);
                }
            }
            // Clutter: two blobs off the lattice, one far away.
            centres.push(Vector2::new(130.0, 300.0));
            centres.push(Vector2::new(400.0, 20.0));
            let radii = vec![3.0; centres.len()];
            let case = format!("{spec} cut {cut} turned {turn}°");
            let found = board.find(&centres, &radii, 640, 480).expect(&case);
            assert_eq!(found.len(), truth.len(), "{case}");
            for p in &found {
                let t = truth.iter().find(|t| t.2 == p.target).unwrap();
                assert_eq!((p.row, p.col), (t.0, t.1), "{case}");
            }
        }
    }

    #[test]
    fn parses_specs() {
        let b: Board = "acircles:4x11:15.5".parse().unwrap();
        assert_eq!(
            (b.kind, b.cols, b.rows, b.spacing),
            (GridKind::Asymmetric, 4, 11, 15.5)
        );
        assert_eq!(b.position(1, 2), Vector3::new(5.0 * 15.5, 15.5, 0.0));
        for bad in [
            "circles",
            "circles:7",
            "squares:7x7",
            "circles:7x7:-1",
            "circles:1x7",
        ] {
            assert!(bad.parse::<Board>().is_err(), "{bad}");
        }
    }
}
