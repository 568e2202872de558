//! Epipolar segments in the refined image (the pinhole image of a projector ray between two
//! depths: a straight segment) and the distances [`crate::identify`] measures with them.

use crate::{lit, sqrt};
use nalgebra::{RealField, Vector2};

/// One ray's epipolar segment in refined pixel positions (see [`crate::identify`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpipolarSegment<T: RealField> {
    /// The ray id.
    pub id: u16,
    /// Its ends (col, row) in the refined image: the ray at the near and at the far depth.
    pub points: [Vector2<T>; 2],
}

impl<T: RealField + Copy> EpipolarSegment<T> {
    /// Distance (pixels) from a refined pixel position to the segment.
    pub fn distance(&self, p: Vector2<T>) -> T {
        sqrt(self.distance_squared(p))
    }

    /// The square of [`Self::distance`] (no square root: a search compares squares).
    pub(crate) fn distance_squared(&self, p: Vector2<T>) -> T {
        let [a, b] = self.points;
        point_segment_distance_squared(p, a, b)
    }

    /// Whether the segment passes within `reach` of the square [lo, lo + side]² (it meets the
    /// square grown by `reach` on every side; a little generous at the corners): the
    /// Liang-Barsky clip of the segment to that square leaves something.
    pub(crate) fn meets(&self, lo: Vector2<T>, side: T, reach: T) -> bool {
        let [a, b] = self.points;
        let d = b - a;
        let (mut t0, mut t1) = (T::zero(), T::one());
        for axis in 0..2 {
            let low = lo[axis] - reach;
            let high = lo[axis] + side + reach;
            for (p, q) in [(-d[axis], a[axis] - low), (d[axis], high - a[axis])] {
                if p == T::zero() {
                    if q < T::zero() {
                        return false;
                    }
                    continue;
                }
                let r = q / p;
                if p < T::zero() {
                    if r > t1 {
                        return false;
                    }
                    t0 = t0.max(r);
                } else {
                    if r < t0 {
                        return false;
                    }
                    t1 = t1.min(r);
                }
            }
        }
        true
    }
}

fn point_segment_distance<T: RealField + Copy>(p: Vector2<T>, a: Vector2<T>, b: Vector2<T>) -> T {
    sqrt(point_segment_distance_squared(p, a, b))
}

fn point_segment_distance_squared<T: RealField + Copy>(
    p: Vector2<T>,
    a: Vector2<T>,
    b: Vector2<T>,
) -> T {
    let ab = b - a;
    let len2 = ab.norm_squared();
    let t = if len2 > T::zero() {
        ((p - a).dot(&ab) / len2).clamp(T::zero(), T::one())
    } else {
        T::zero()
    };
    (a + ab * t - p).norm_squared()
}

/// The smallest distance between two polylines (segments that do not cross: the smallest
/// vertex-to-piece distance; crossing pieces: zero).
pub(crate) fn segments_distance<T: RealField + Copy>(
    a: &EpipolarSegment<T>,
    b: &EpipolarSegment<T>,
) -> T {
    let mut best = T::max_value().unwrap_or_else(|| lit(f64::MAX));
    for pa in a.points.windows(2) {
        for pb in b.points.windows(2) {
            if pieces_cross(pa[0], pa[1], pb[0], pb[1]) {
                return T::zero();
            }
            best = best
                .min(point_segment_distance(pa[0], pb[0], pb[1]))
                .min(point_segment_distance(pa[1], pb[0], pb[1]))
                .min(point_segment_distance(pb[0], pa[0], pa[1]))
                .min(point_segment_distance(pb[1], pa[0], pa[1]));
        }
    }
    best
}

fn pieces_cross<T: RealField + Copy>(
    a0: Vector2<T>,
    a1: Vector2<T>,
    b0: Vector2<T>,
    b1: Vector2<T>,
) -> bool {
    let cross = |o: Vector2<T>, p: Vector2<T>, q: Vector2<T>| (p - o).perp(&(q - o));
    let (d1, d2) = (cross(b0, b1, a0), cross(b0, b1, a1));
    let (d3, d4) = (cross(a0, a1, b0), cross(a0, a1, b1));
    d1 * d2 < T::zero() && d3 * d4 < T::zero()
}
