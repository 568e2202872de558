//! A mesh over the projector lattice: the points of neighbouring rays make triangles, an
//! occlusion or a depth jump leaves a hole, and the back is the largest connected piece.

use nalgebra::Vector3;
use std::collections::HashMap;

/// Triangles over a frame's points (indices into them).
#[derive(Debug, Clone, PartialEq)]
pub struct Mesh {
    /// The triangles.
    pub triangles: Vec<[usize; 3]>,
    /// The median length of the lattice's edges (mm): the dot spacing on the surface.
    pub spacing: f64,
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
/// Neighbouring triangles whose normals differ by more than this (rad) meet at a fold of two
/// surfaces (an arm against the trunk), not within one.
const CREASE: f64 = 45.0 * std::f64::consts::PI / 180.0;

impl Mesh {
    /// Each lattice cell whose corners were measured makes two triangles (split along the
    /// shorter diagonal); triangles with an edge beyond [`JUMP`] × the median edge or seen
    /// more obliquely than [`OBLIQUE`] from the camera (at the origin) are left out.
    pub fn over_lattice(points: &[Vector3<f64>], rays: &[[i32; 2]]) -> Self {
        let node: HashMap<[i32; 2], usize> =
            rays.iter().enumerate().map(|(i, r)| (*r, i)).collect();
        let at = |i: i32, j: i32| node.get(&[i, j]).copied();
        let mut edges: Vec<f64> = Vec::new();
        for (k, &[i, j]) in rays.iter().enumerate() {
            for n in [at(i + 1, j), at(i, j + 1)].into_iter().flatten() {
                edges.push((points[n] - points[k]).norm());
            }
        }
        edges.sort_by(f64::total_cmp);
        let spacing = edges.get(edges.len() / 2).copied().unwrap_or(0.0);
        let longest = |t: &[usize; 3]| {
            let e = |a: usize, b: usize| (points[t[a]] - points[t[b]]).norm();
            e(0, 1).max(e(1, 2)).max(e(2, 0))
        };
        let mut triangles = Vec::new();
        for &[i, j] in rays {
            let corners = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
            let candidates = match corners {
                (Some(a), Some(b), Some(c), Some(d)) => {
                    if (points[a] - points[d]).norm() <= (points[b] - points[c]).norm() {
                        vec![[a, b, d], [a, d, c]]
                    } else {
                        vec![[a, b, c], [b, d, c]]
                    }
                }
                (Some(a), Some(b), Some(c), None) => vec![[a, b, c]],
                (Some(a), Some(b), None, Some(d)) => vec![[a, b, d]],
                (Some(a), None, Some(c), Some(d)) => vec![[a, d, c]],
                (None, Some(b), Some(c), Some(d)) => vec![[b, d, c]],
                _ => vec![],
            };
            let facing = |t: &[usize; 3]| {
                let [a, b, c] = t.map(|k| points[k]);
                let normal = (b - a).cross(&(c - a));
                let sight = (a + b + c).normalize();
                normal.dot(&sight).abs() >= OBLIQUE.cos() * normal.norm()
            };
            let kept = candidates
                .into_iter()
                .filter(|t| longest(t) <= JUMP * spacing && facing(t));
            triangles.extend(kept);
        }
        Self {
            triangles,
            spacing,
            points: points.to_vec(),
        }
    }

    /// The points of the largest smooth piece (by points), sorted, and its triangles: the
    /// triangles connected across shared edges where the surface folds by less than
    /// [`CREASE`] (an arm touching the trunk meets it at a fold).
    pub fn largest_piece(&self) -> (Vec<usize>, Vec<[usize; 3]>) {
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
        let vertices = |tris: &[usize]| {
            let mut v: Vec<usize> = tris.iter().flat_map(|&k| t[k]).collect();
            v.sort_unstable();
            v.dedup();
            v
        };
        let Some(best) = members
            .values()
            .max_by_key(|tris| (vertices(tris).len(), std::cmp::Reverse(tris[0])))
        else {
            return (vec![], vec![]);
        };
        let kept = vertices(best);
        (kept, best.iter().map(|&k| t[k]).collect())
    }
}
