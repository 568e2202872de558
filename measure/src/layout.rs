//! Control targets identified by their known layout, matched from a few distinct targets.
//!
//! # The choice
//! Coded targets need a larger target and a decoder per code; the calibration field and the
//! plate already carry a known 3D layout (the control file). So a handful of the control
//! targets are made *distinct* — drawn with a larger radius (the simulator uses 1.8×) — and the
//! rest are found from them:
//! 1. The largest blobs of the image (those rejected by the shape tests too: a projected dot
//!    falling on a target merges with it) are the candidates for the distinct targets.
//! 2. Every assignment of four candidates to four distinct targets gives a plane homography
//!    (the distinct targets are coplanar); one that crowds the layout together (from nearly
//!    collinear candidates) is dropped. It scores the distinct targets that land on a candidate
//!    (within 2 tolerances), then the other control points of that plane that land on a blob.
//! 3. Every assignment with the most distinct targets explained gives a start pose by space
//!    resection (planar homography decomposition, [`deltaz_calib::resection::resect`]) from the
//!    plane's matched points and the four candidates; every control point is projected
//!    through the camera and matched to the one blob within the tolerance (none if two are);
//!    the pose is resected again from those matches (Gauss-Newton from the previous pose,
//!    dropping points beyond 3× the median residual), the tolerance shrinks to 8× the
//!    residual RMS (at least 1.5 px, so neighbouring dots stay out) and the matching is
//!    repeated until the labels settle.
//! 4. Among the labellings whose residual RMS is within 3× (+ 0.3 px) of the best-fitting one
//!    (of at least six points), the one with the most matches wins; a different labelling with
//!    as many matches is reported as ambiguous. The residual decides between a labelling and
//!    its mirror image: a plate with raised points flipped over fits a mirrored layout with a
//!    few pixels of residual, the right labelling with the centroid noise. A best labelling
//!    with a residual RMS above a quarter of the tolerance is an error, never a guess.
//!
//! # Target requirements
//! - At least four distinct targets in one plane (one height level of the control), all of them
//!   markedly larger in the image than every other blob (projected dots and the dot pattern's
//!   marker included), and at least four of them visible in every image.
//! - The distinct targets must not be placed symmetrically under a rotation of their plane
//!   (that would leave the assignment open). A reflection symmetry (as the default rule's pick on
//!   the paper plate has) is resolved by step 4 only where control points stand off that plane
//!   (the plate's raised points).
//! - The control points must be farther apart in the image than twice the tolerance, and the
//!   approximate inner orientation good enough to project them within the tolerance (8 pixels by
//!   default; the paper camera's k1 moves the corners by 7 pixels before calibration).
//!
//! [`crate::target_field::distinct_targets`] picks them from a control layout by a fixed rule (the simulator renders
//! those larger), so a layout file alone says which targets must be made distinct.

use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::{Camera, ExteriorOrientation};
use nalgebra::{SMatrix, SVector, Vector2, Vector3};
use std::fmt;

use crate::target_field::{distinct_targets, DISTINCT_COUNT};

/// Matches a labelling needs before its residual sets the bar for the others.
const MIN_FIT_POINTS: usize = 6;

/// At most this many assignments are refined by resection.
const MAX_REFINED: usize = 2000;

/// A known control layout with its distinct targets.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    /// Every control point: label and coordinates (mm).
    pub points: Vec<(String, Vector3<f64>)>,
    /// Indices (into `points`) of the distinct targets, all on the plane Z = `level`.
    pub distinct: Vec<usize>,
    /// The Z of the distinct targets' plane.
    pub level: f64,
}

/// Why a layout or an image could not be matched.
#[derive(Debug, Clone, PartialEq)]
pub enum LayoutError {
    /// A distinct label is not among the control points.
    UnknownDistinct(String),
    /// Fewer than four distinct targets, or not all on one level.
    DistinctNotCoplanar,
    /// Fewer than four large blobs in the image.
    TooFewCandidates(usize),
    /// No assignment of the distinct targets explained the image.
    NoMatch,
    /// Two different labellings explain the image equally well.
    Ambiguous {
        /// Matches of the best labelling.
        matched: usize,
        /// Its residual RMS (px).
        rms: f64,
        /// The runner-up's residual RMS (px).
        runner_up_rms: f64,
    },
}

impl fmt::Display for LayoutError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LayoutError::UnknownDistinct(l) => {
                write!(f, "distinct target {l:?} is not in the control file")
            }
            LayoutError::DistinctNotCoplanar => f.write_str(
                "need at least 4 distinct targets, all at one Z (within 1 mm) of the control",
            ),
            LayoutError::TooFewCandidates(n) => write!(
                f,
                "only {n} large blobs: at least 4 distinct targets must be visible"
            ),
            LayoutError::NoMatch => f.write_str(
                "no assignment of the distinct targets explains the image (are they visible and larger than every other blob?)",
            ),
            LayoutError::Ambiguous {
                matched,
                rms,
                runner_up_rms,
            } => write!(
                f,
                "ambiguous layout match: two labellings with {matched} targets each fit with {rms:.2} and {runner_up_rms:.2} px RMS (are the distinct targets placed symmetrically?)"
            ),
        }
    }
}

impl std::error::Error for LayoutError {}

impl Layout {
    /// A layout whose distinct targets are `distinct` (labels).
    pub fn new(
        points: Vec<(String, Vector3<f64>)>,
        distinct: &[String],
    ) -> Result<Self, LayoutError> {
        let distinct = distinct
            .iter()
            .map(|l| {
                points
                    .iter()
                    .position(|(p, _)| p == l)
                    .ok_or_else(|| LayoutError::UnknownDistinct(l.clone()))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let Some(&first) = distinct.first() else {
            return Err(LayoutError::DistinctNotCoplanar);
        };
        let level = points[first].1.z;
        if distinct.len() < 4
            || distinct
                .iter()
                .any(|&k| (points[k].1.z - level).abs() > 1.0)
        {
            return Err(LayoutError::DistinctNotCoplanar);
        }
        Ok(Self {
            points,
            distinct,
            level,
        })
    }

    /// A layout with the distinct targets of [`distinct_targets`].
    pub fn with_default_distinct(points: Vec<(String, Vector3<f64>)>) -> Result<Self, LayoutError> {
        let distinct = distinct_targets(&points, DISTINCT_COUNT);
        Self::new(points, &distinct)
    }
}

/// A blob of the image: its centre (pixels) and its size (pixels above the threshold).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Blob {
    /// Centre (col, row).
    pub centre: Vector2<f64>,
    /// Area (pixels).
    pub area: f64,
}

/// The result of matching an image.
#[derive(Debug, Clone, PartialEq)]
pub struct LayoutMatch {
    /// For every blob, the index of its control point in the layout, if matched.
    pub labels: Vec<Option<usize>>,
    /// The camera pose from the final resection.
    pub exterior: ExteriorOrientation<f64>,
    /// Residual RMS (px) of the matched points under that pose and the given inner orientation.
    pub rms_px: f64,
    /// Control points projected into the image by the final pose.
    pub expected: usize,
    /// Control points matched.
    pub matched: usize,
}

/// Spatial buckets of the blob centres for nearest-blob queries.
struct Buckets {
    cell: f64,
    map: std::collections::HashMap<(i64, i64), Vec<usize>>,
}

impl Buckets {
    fn new(blobs: &[Blob], cell: f64) -> Self {
        let mut map = std::collections::HashMap::<(i64, i64), Vec<usize>>::new();
        for (k, b) in blobs.iter().enumerate() {
            map.entry(Self::key(b.centre, cell)).or_default().push(k);
        }
        Self { cell, map }
    }

    fn key(p: Vector2<f64>, cell: f64) -> (i64, i64) {
        ((p.x / cell).floor() as i64, (p.y / cell).floor() as i64)
    }

    /// The only blob within `tol` (≤ the cell size) of `p`: `None` if none or two.
    fn unique_within(&self, blobs: &[Blob], p: Vector2<f64>, tol: f64) -> Option<usize> {
        if !(p.x.is_finite() && p.y.is_finite()) {
            return None;
        }
        let (cx, cy) = Self::key(p, self.cell);
        let mut found = None;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for &k in self.map.get(&(cx + dx, cy + dy)).into_iter().flatten() {
                    if (blobs[k].centre - p).norm() <= tol {
                        if found.is_some() {
                            return None;
                        }
                        found = Some(k);
                    }
                }
            }
        }
        found
    }
}

/// The plane homography (X, Y) ↦ (col, row) through four correspondences.
fn homography(plane: &[Vector2<f64>; 4], image: &[Vector2<f64>; 4]) -> Option<SMatrix<f64, 3, 3>> {
    let mut a = SMatrix::<f64, 8, 8>::zeros();
    let mut b = SVector::<f64, 8>::zeros();
    for k in 0..4 {
        let (x, y) = (plane[k].x, plane[k].y);
        let (u, v) = (image[k].x, image[k].y);
        let r = 2 * k;
        a.row_mut(r)
            .copy_from_slice(&[x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y]);
        a.row_mut(r + 1)
            .copy_from_slice(&[0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y]);
        b[r] = u;
        b[r + 1] = v;
    }
    let h = a.lu().solve(&b)?;
    Some(SMatrix::<f64, 3, 3>::new(
        h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0,
    ))
}

fn apply(h: &SMatrix<f64, 3, 3>, p: Vector2<f64>) -> Vector2<f64> {
    let q = h * Vector3::new(p.x, p.y, 1.0);
    Vector2::new(q.x / q.z, q.y / q.z)
}

/// Steps 3 for one set of correspondences (layout index, blob index): resect, project every
/// control point, match, twice. Returns the labels, pose and residual RMS.
fn refine(
    layout: &Layout,
    blobs: &[Blob],
    buckets: &Buckets,
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    start: &[(usize, Vector2<f64>)],
    tol: f64,
) -> Option<LayoutMatch> {
    let mut pairs = start.to_vec();
    let mut last: Option<LayoutMatch> = None;
    for _ in 0..6 {
        let points: Vec<_> = pairs
            .iter()
            .map(|&(p, c)| (c, layout.points[p].1))
            .collect();
        let res = robust_resect(grid, inner, points, last.as_ref().map(|m| m.exterior))?;
        let exterior = res.exterior;
        // The tolerance shrinks to what the resection's residuals allow (neighbouring dots).
        let tol = tol.min((8.0 * res.rms_px).max(1.5));
        let camera = Camera {
            grid: *grid,
            inner: *inner,
            exterior,
        };
        let mut labels = vec![None; blobs.len()];
        let mut claimed = vec![0usize; blobs.len()];
        let mut expected = 0;
        let mut found = Vec::new();
        for (p, (_, xyz)) in layout.points.iter().enumerate() {
            let Ok((c, r)) = camera.world_to_pixel(xyz) else {
                continue;
            };
            if !grid.contains(c, r) {
                continue;
            }
            expected += 1;
            if let Some(b) = buckets.unique_within(blobs, Vector2::new(c, r), tol) {
                claimed[b] += 1;
                found.push((p, b, (blobs[b].centre - Vector2::new(c, r)).norm_squared()));
            }
        }
        // A blob claimed by two control points labels neither.
        found.retain(|&(_, b, _)| claimed[b] == 1);
        if found.len() < 4 {
            return None;
        }
        let rms_px = (found.iter().map(|f| f.2).sum::<f64>() / found.len() as f64).sqrt();
        for &(p, b, _) in &found {
            labels[b] = Some(p);
        }
        pairs = found
            .iter()
            .map(|&(p, b, _)| (p, blobs[b].centre))
            .collect();
        let settled = last.as_ref().is_some_and(|m| m.labels == labels);
        last = Some(LayoutMatch {
            labels,
            exterior,
            rms_px,
            expected,
            matched: pairs.len(),
        });
        if settled {
            break;
        }
    }
    last
}

/// Space resection (from `start` if given, else closed form) that drops wrong correspondences
/// (a dot taken for a target): points whose residual exceeds 3× the median (at least 1 px) are
/// removed and the pose resected again (at least 4 px from a closed-form start).
fn robust_resect(
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    mut points: Vec<(Vector2<f64>, Vector3<f64>)>,
    start: Option<ExteriorOrientation<f64>>,
) -> Option<deltaz_calib::resection::ResectionResult> {
    loop {
        let res = match start {
            Some(pose) => deltaz_calib::resection::resect_from(grid, inner, &points, pose),
            None => deltaz_calib::resection::resect(grid, inner, &points),
        }
        .ok()?;
        let camera = Camera {
            grid: *grid,
            inner: *inner,
            exterior: res.exterior,
        };
        let residual = |(p, x): &(Vector2<f64>, Vector3<f64>)| {
            camera
                .world_to_pixel(x)
                .map_or(f64::INFINITY, |(c, r)| (Vector2::new(c, r) - p).norm())
        };
        let mut sorted: Vec<f64> = points.iter().map(residual).collect();
        sorted.sort_by(f64::total_cmp);
        // The first, closed-form pose may rest on merged blobs' centres, off by pixels.
        let floor = if start.is_none() { 4.0 } else { 1.0 };
        let limit = (3.0 * sorted[sorted.len() / 2]).max(floor);
        let before = points.len();
        points.retain(|p| residual(p) <= limit);
        if points.len() == before {
            return Some(res);
        }
        if points.len() < 4 {
            return None;
        }
    }
}

/// All k-subsets of 0..n in lexicographic order.
fn subsets(n: usize, k: usize) -> Vec<Vec<usize>> {
    let mut out = Vec::new();
    let mut current = Vec::with_capacity(k);
    fn rec(start: usize, n: usize, k: usize, cur: &mut Vec<usize>, out: &mut Vec<Vec<usize>>) {
        if cur.len() == k {
            out.push(cur.clone());
            return;
        }
        for i in start..n {
            cur.push(i);
            rec(i + 1, n, k, cur, out);
            cur.pop();
        }
    }
    rec(0, n, k, &mut current, &mut out);
    out
}

/// All orderings of `items`.
fn permutations(items: &[usize]) -> Vec<Vec<usize>> {
    if items.len() <= 1 {
        return vec![items.to_vec()];
    }
    let mut out = Vec::new();
    for (i, &first) in items.iter().enumerate() {
        let mut rest = items.to_vec();
        rest.remove(i);
        for mut tail in permutations(&rest) {
            tail.insert(0, first);
            out.push(tail);
        }
    }
    out
}

/// An assignment's score (distinct targets, plane points explained) and its start
/// correspondences (layout index, image position).
type Scored = ((usize, usize), Vec<(usize, Vector2<f64>)>);

/// Steps 1-4 of the module docs: label the blobs of one image with the layout's control points.
/// `blobs` are the measured targets (the ones that get labels); `rejected` are blobs that failed
/// the shape or fit tests, used only as candidates for distinct targets (a projected dot on a
/// distinct target merges with it; its centre is then off by a pixel or two, enough for the
/// start). `inner` may be approximate (the sensor's start values); `tol` is the matching
/// tolerance (px).
pub fn match_layout(
    layout: &Layout,
    blobs: &[Blob],
    rejected: &[Blob],
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    tol: f64,
) -> Result<LayoutMatch, LayoutError> {
    // Step 1: the candidates, largest first (two spare for a missing distinct target).
    let all: Vec<&Blob> = blobs.iter().chain(rejected).collect();
    let mut order: Vec<usize> = (0..all.len()).collect();
    order.sort_by(|&a, &b| all[b].area.total_cmp(&all[a].area));
    order.truncate(layout.distinct.len() + 2);
    if order.len() < 4 {
        return Err(LayoutError::TooFewCandidates(order.len()));
    }
    let buckets = Buckets::new(blobs, tol.max(1.0));
    let level: Vec<usize> = (0..layout.points.len())
        .filter(|&p| (layout.points[p].1.z - layout.level).abs() <= 1.0)
        .collect();
    let plane = |p: usize| layout.points[p].1.xy();
    // Step 2: score every assignment by the distinct targets it explains (the ones beyond the
    // four land on candidates too), then by the plane's points it explains.
    let mut scored: Vec<Scored> = Vec::new();
    let distinct_sets = subsets(layout.distinct.len(), 4);
    let on_candidate = |p: Vector2<f64>| {
        order
            .iter()
            .copied()
            .find(|&k| (all[k].centre - p).norm() <= 2.0 * tol)
    };
    for blob_set in subsets(order.len(), 4) {
        let image = [0, 1, 2, 3].map(|k| all[order[blob_set[k]]].centre);
        for chosen in &distinct_sets {
            for perm in permutations(chosen) {
                let targets = [0, 1, 2, 3].map(|k| layout.distinct[perm[k]]);
                let Some(h) = homography(&targets.map(plane), &image) else {
                    continue;
                };
                // A degenerate homography (from nearly collinear candidates) crowds the layout
                // together: the control points must stay 2 tolerances apart.
                let projected: Vec<Vector2<f64>> =
                    level.iter().map(|&p| apply(&h, plane(p))).collect();
                let crowded = projected.iter().enumerate().any(|(i, a)| {
                    !(a.x.is_finite() && a.y.is_finite())
                        || projected[i + 1..]
                            .iter()
                            .any(|b| (a - b).norm() < 2.0 * tol)
                });
                if crowded {
                    continue;
                }
                let mut hit: Vec<usize> = layout
                    .distinct
                    .iter()
                    .filter_map(|&d| on_candidate(apply(&h, plane(d))))
                    .collect();
                hit.sort_unstable();
                hit.dedup();
                let distinct_hits = hit.len();
                let mut start: Vec<(usize, Vector2<f64>)> = level
                    .iter()
                    .zip(&projected)
                    .filter_map(|(&p, &x)| {
                        buckets
                            .unique_within(blobs, x, tol)
                            .map(|b| (p, blobs[b].centre))
                    })
                    .collect();
                let level_hits = start.len();
                // The candidates join the start where the plane's points are too few, or where
                // they are measured targets (a merged blob's centre is off by pixels).
                for (k, (t, c)) in targets.iter().zip(image).enumerate() {
                    let measured = order[blob_set[k]] < blobs.len();
                    if (measured || level_hits < 4) && start.iter().all(|(p, _)| p != t) {
                        start.push((*t, c));
                    }
                }
                start.sort_by_key(|a| a.0);
                scored.push(((distinct_hits, level_hits), start));
            }
        }
    }
    scored.sort_by_key(|a| std::cmp::Reverse(a.0));
    scored.dedup_by(|a, b| a.1 == b.1);
    // Step 3 for every correspondence set that explains the most distinct targets (on a plate
    // the projected dots make the plane's point count a weak guide).
    let most_distinct = scored.first().map_or(0, |s| s.0 .0);
    let mut results: Vec<LayoutMatch> = scored
        .iter()
        .take_while(|(score, _)| score.0 == most_distinct)
        .take(MAX_REFINED)
        .filter_map(|(_, pairs)| refine(layout, blobs, &buckets, grid, inner, pairs, tol))
        .collect();
    // Step 4: among the labellings that fit about as well as the best-fitting one (of at least
    // six points), the one with the most matches; a different one as good is ambiguous.
    let enough = results.iter().any(|r| r.matched >= MIN_FIT_POINTS);
    let best_rms = results
        .iter()
        .filter(|r| !enough || r.matched >= MIN_FIT_POINTS)
        .map(|r| r.rms_px)
        .fold(f64::INFINITY, f64::min);
    results.retain(|r| r.rms_px <= 3.0 * best_rms + 0.3);
    results.sort_by(|a, b| {
        b.matched
            .cmp(&a.matched)
            .then(a.rms_px.total_cmp(&b.rms_px))
    });
    let best = results.first().ok_or(LayoutError::NoMatch)?;
    // A labelling that fits worse than a quarter of the tolerance is a wrong one (a mirrored
    // layout, dots taken for targets): an error, never a silent guess.
    if best.rms_px > tol / 4.0 {
        return Err(LayoutError::NoMatch);
    }
    if let Some(rival) = results
        .iter()
        .find(|r| r.labels != best.labels && r.matched == best.matched)
    {
        return Err(LayoutError::Ambiguous {
            matched: best.matched,
            rms: best.rms_px,
            runner_up_rms: rival.rms_px,
        });
    }
    Ok(best.clone())
}
