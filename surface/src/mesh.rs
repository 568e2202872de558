//! A mesh over the projector lattice: the points of neighbouring rays make triangles, an
//! occlusion or a depth jump leaves a hole, and the back is the largest connected piece; a gap
//! of a dot or a few not measured is spanned ([`Mesh::gaps`]). Points without their rays are
//! meshed by the Delaunay triangulation of what the camera sees.

use crate::median;
use nalgebra::Vector3;
use std::collections::{BTreeSet, HashMap};

/// Triangles over a frame's points (indices into them).
#[derive(Debug, Clone, PartialEq)]
pub struct Mesh {
    /// The triangles.
    pub triangles: Vec<[usize; 3]>,
    /// The median length of [`Mesh::edges`] (mm): the dot spacing on the surface.
    pub spacing: f64,
    /// The edges whose lengths give the spacing: the lattice's, or each Delaunay triangle's
    /// two shorter ones (a lattice's triangles are half cells: their two shorter edges are its
    /// edges).
    pub edges: Vec<[usize; 2]>,
    /// The points the triangles index.
    pub points: Vec<Vector3<f64>>,
}

/// An edge longer than this many times the median is a jump between surfaces, not a piece
/// of one.
const JUMP: f64 = 2.5;
/// A triangle whose normal is further than this from the camera's line of sight (rad) spans
/// an occlusion (or a surface too oblique to measure well): at the lattice's resolution a
/// jump and a steep flank look alike, so both are left out.
const OBLIQUE: f64 = 60.0 * std::f64::consts::PI / 180.0;
/// An enclosed hole in a mesh bounded by at most this many edges is a gap in the sampling (a
/// dot or a few not measured, or a sparse patch of another scanner's points: one dot of a
/// lattice leaves a loop of 4, three in a row one of 8), not in the surface.
const GAP_EDGES: usize = 8;
/// Neighbouring triangles whose normals differ by more than this (rad) meet at a fold of two
/// surfaces (an arm against the trunk), not within one.
const CREASE: f64 = 45.0 * std::f64::consts::PI / 180.0;

impl Mesh {
    /// Each lattice cell makes two triangles where its four corners were measured (split along
    /// the shorter diagonal) and one where three were; the median lattice edge is the spacing
    /// (`Mesh::kept` leaves out jumps and oblique triangles).
    pub fn over_lattice(points: &[Vector3<f64>], rays: &[[i32; 2]]) -> Self {
        let node: HashMap<[i32; 2], usize> =
            rays.iter().enumerate().map(|(i, r)| (*r, i)).collect();
        let at = |i: i32, j: i32| node.get(&[i, j]).copied();
        let edges: Vec<[usize; 2]> = rays
            .iter()
            .enumerate()
            .flat_map(|(k, &[i, j])| {
                [at(i + 1, j), at(i, j + 1)]
                    .into_iter()
                    .flatten()
                    .map(move |n| [k, n])
            })
            .collect();
        // Every cell with a measured corner: a cell missing its first corner still has one
        // triangle.
        let cells: BTreeSet<[i32; 2]> = rays
            .iter()
            .flat_map(|&[i, j]| [[i, j], [i - 1, j], [i, j - 1], [i - 1, j - 1]])
            .collect();
        let mut candidates = Vec::new();
        for [i, j] in cells {
            let corners = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
            match corners {
                (Some(a), Some(b), Some(c), Some(d)) => {
                    if (points[a] - points[d]).norm() <= (points[b] - points[c]).norm() {
                        candidates.extend([[a, b, d], [a, d, c]]);
                    } else {
                        candidates.extend([[a, b, c], [b, d, c]]);
                    }
                }
                (Some(a), Some(b), Some(c), None) => candidates.push([a, b, c]),
                (Some(a), Some(b), None, Some(d)) => candidates.push([a, b, d]),
                (Some(a), None, Some(c), Some(d)) => candidates.push([a, d, c]),
                (None, Some(b), Some(c), Some(d)) => candidates.push([b, d, c]),
                _ => {}
            }
        }
        Self::kept(points, candidates, edges)
    }

    /// Points without their rays (a cloud from another scanner) make the Delaunay triangles of
    /// their directions from the camera (at the origin, looking along −z: every point has
    /// z < 0); the spacing is the median of the triangles' two shorter edges, a lattice's edges
    /// without its cells' diagonals. `Mesh::kept` leaves out the long triangles across holes
    /// and around the outline, and the oblique ones.
    pub fn over_directions(points: &[Vector3<f64>]) -> Self {
        let seen: Vec<delaunator::Point> = points
            .iter()
            .map(|p| delaunator::Point {
                x: p.x / -p.z,
                y: p.y / -p.z,
            })
            .collect();
        let candidates: Vec<[usize; 3]> = delaunator::triangulate(&seen)
            .triangles
            .chunks_exact(3)
            .map(|t| [t[0], t[1], t[2]])
            .collect();
        let edges = candidates
            .iter()
            .flat_map(|&[a, b, c]| {
                let mut e = [[a, b], [b, c], [c, a]];
                e.sort_by(|p, q| length(points, p).total_cmp(&length(points, q)));
                [e[0], e[1]]
            })
            .collect();
        Self::kept(points, candidates, edges)
    }

    /// The `candidates` without those with an edge beyond [`JUMP`] × the spacing (the median of
    /// `edges`) or seen more obliquely than [`OBLIQUE`] from the camera (at the origin).
    fn kept(points: &[Vector3<f64>], candidates: Vec<[usize; 3]>, edges: Vec<[usize; 2]>) -> Self {
        let spacing = median(edges.iter().map(|e| length(points, e)).collect());
        let facing = |t: &[usize; 3]| {
            let [a, b, c] = t.map(|k| points[k]);
            let normal = (b - a).cross(&(c - a));
            let sight = (a + b + c).normalize();
            normal.dot(&sight).abs() >= OBLIQUE.cos() * normal.norm()
        };
        let triangles = candidates
            .into_iter()
            .filter(|t| sides(points, t)[2] <= JUMP * spacing && facing(t))
            .collect();
        Self {
            triangles,
            spacing,
            edges,
            points: points.to_vec(),
        }
    }

    /// How irregularly the points of `triangles` lie: the RMS spread of each point's distance
    /// to its nearest neighbour along them, over their mean. On the back model: a lattice,
    /// 0.05; a grid whose points stray uniformly by up to 0.15 of its spacing, 0.13; by up to
    /// 0.3, 0.21; by up to 0.5, 0.40; points scattered at random, 0.55.
    pub fn irregularity(&self, triangles: &[[usize; 3]]) -> f64 {
        let mut nearest = vec![f64::INFINITY; self.points.len()];
        for t in triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let d = (self.points[a] - self.points[b]).norm();
                nearest[a] = nearest[a].min(d);
                nearest[b] = nearest[b].min(d);
            }
        }
        let meshed: Vec<f64> = nearest.into_iter().filter(|d| d.is_finite()).collect();
        let n = meshed.len().max(1) as f64;
        let mean = meshed.iter().sum::<f64>() / n;
        let spread = (meshed.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / n).sqrt();
        if mean > 0.0 {
            spread / mean
        } else {
            0.0
        }
    }

    /// The smooth pieces of the mesh, largest first (by points; of equal ones, that of the
    /// first triangle first): its triangles connected across shared edges where the surface folds
    /// by less than `CREASE` (an arm touching the trunk meets it at a fold, a floor a wall).
    pub fn pieces(&self) -> Vec<Piece> {
        let t = &self.triangles;
        let mut parent: Vec<usize> = (0..t.len()).collect();
        fn root(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        let normal = |k: usize| {
            let [a, b, c] = t[k].map(|i| self.points[i]);
            (b - a).cross(&(c - a)).normalize()
        };
        let mut by_edge: HashMap<(usize, usize), usize> = HashMap::new();
        for (k, tri) in t.iter().enumerate() {
            for e in 0..3 {
                let (a, b) = (tri[e], tri[(e + 1) % 3]);
                let key = (a.min(b), a.max(b));
                match by_edge.get(&key) {
                    Some(&other) if normal(k).dot(&normal(other)) >= CREASE.cos() => {
                        let (ra, rb) = (root(&mut parent, k), root(&mut parent, other));
                        parent[ra] = rb;
                    }
                    Some(_) => {}
                    None => {
                        by_edge.insert(key, k);
                    }
                }
            }
        }
        let mut members: HashMap<usize, Vec<usize>> = HashMap::new();
        for k in 0..t.len() {
            members.entry(root(&mut parent, k)).or_default().push(k);
        }
        let mut pieces: Vec<(usize, Piece)> = members
            .into_values()
            .map(|tris| {
                let mut points: Vec<usize> = tris.iter().flat_map(|&k| t[k]).collect();
                points.sort_unstable();
                points.dedup();
                let triangles = tris.iter().map(|&k| t[k]).collect();
                (tris[0], Piece { points, triangles })
            })
            .collect();
        pieces.sort_by_key(|(first, p)| (std::cmp::Reverse(p.points.len()), *first));
        pieces.into_iter().map(|(_, p)| p).collect()
    }

    /// The dot spacing over `points` (sorted indices, as a [`Piece`]'s): the median length of
    /// the [`Mesh::edges`] between them.
    pub fn spacing_over(&self, points: &[usize]) -> f64 {
        let within = |k: &usize| points.binary_search(k).is_ok();
        let lengths = self
            .edges
            .iter()
            .filter(|e| e.iter().all(within))
            .map(|e| length(&self.points, e))
            .collect();
        median(lengths)
    }
}

/// A smooth connected piece of a mesh ([`Mesh::pieces`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Piece {
    /// Its points (indices into the mesh's), sorted.
    pub points: Vec<usize>,
    /// Its triangles.
    pub triangles: Vec<[usize; 3]>,
}

impl Mesh {
    /// The gaps `triangles` enclose (`GAP_EDGES`), each as triangles (a fan over its loop):
    /// the surface spans them. The triangles turn alike (a lattice's cells and the Delaunay
    /// triangles do), so the boundary's edges, each in its triangle's turn, run in loops: the
    /// outline one way round and every hole the other.
    pub fn gaps(triangles: &[[usize; 3]]) -> Vec<[usize; 3]> {
        // Each edge a → b of a triangle, with its third corner.
        let third: HashMap<(usize, usize), usize> = triangles
            .iter()
            .flat_map(|&[a, b, c]| [((a, b), c), ((b, c), a), ((c, a), b)])
            .collect();
        let boundary: BTreeSet<(usize, usize)> = third
            .keys()
            .filter(|&&(a, b)| !third.contains_key(&(b, a)))
            .copied()
            .collect();
        // The boundary edge after a → b: round b through its triangles to the next edge out of
        // b that no triangle shares.
        let after = |(a, b): (usize, usize)| {
            let mut c = third[&(a, b)];
            for _ in 0..triangles.len() {
                match third.get(&(c, b)) {
                    Some(&d) => c = d,
                    None => break,
                }
            }
            (b, c)
        };
        let mut walked = BTreeSet::new();
        let mut loops: Vec<Vec<usize>> = Vec::new();
        for &start in &boundary {
            let mut corners = Vec::new();
            let mut edge = start;
            while walked.insert(edge) {
                corners.push(edge.0);
                edge = after(edge);
            }
            if edge == start && corners.len() >= 3 {
                loops.push(corners);
            }
        }
        // The outline is the longest loop; a small one touching it is a notch pinched off it.
        let outline: BTreeSet<usize> = loops
            .iter()
            .max_by_key(|l| l.len())
            .map(|l| l.iter().copied().collect())
            .unwrap_or_default();
        let gaps = loops
            .iter()
            .filter(|l| l.len() <= GAP_EDGES && l.iter().all(|c| !outline.contains(c)));
        gaps.flat_map(|l| (1..l.len() - 1).map(|k| [l[0], l[k], l[k + 1]]))
            .collect()
    }

    /// The points on the rim of `triangles`: on an edge no other triangle shares (whichever
    /// way they turn: a gap's fan turns against the triangles about it).
    pub fn rim(triangles: &[[usize; 3]]) -> BTreeSet<usize> {
        let mut uses: HashMap<[usize; 2], usize> = HashMap::new();
        for t in triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *uses.entry([a.min(b), a.max(b)]).or_default() += 1;
            }
        }
        uses.into_iter()
            .filter(|&(_, n)| n == 1)
            .flat_map(|(edge, _)| edge)
            .collect()
    }
}

/// The length of edge `e`.
fn length(points: &[Vector3<f64>], e: &[usize; 2]) -> f64 {
    (points[e[0]] - points[e[1]]).norm()
}

/// The lengths of triangle `t`'s edges, shortest first.
fn sides(points: &[Vector3<f64>], t: &[usize; 3]) -> [f64; 3] {
    let e = |a: usize, b: usize| length(points, &[t[a], t[b]]);
    let mut s = [e(0, 1), e(1, 2), e(2, 0)];
    s.sort_by(f64::total_cmp);
    s
}
