//! Blob detection: a tiled background model, an adaptive threshold, connected components by runs
//! (one row at a time, bands of rows on all cores; the label image kept as runs, [`RunLabels`])
//! and shape tests.
//!
//! Each component yields its area, bounding box, second moments and the intensity-weighted
//! centroid (the paper's "gravity centre", section 6.2.1) with weights w = I − background over the
//! pixels above the threshold.

use rayon::prelude::*;
use std::f64::consts::PI;

/// A borrowed grayscale image, row-major (8-bit, 16-bit or float samples): no copy is made.
#[derive(Debug, Clone, Copy)]
pub struct GrayView<'a, P> {
    /// Width (pixels).
    pub width: usize,
    /// Height (pixels).
    pub height: usize,
    /// Row-major samples, `width * height` of them.
    pub pixels: &'a [P],
    /// One DN of the 8-bit scale in sample units (1 for 8-bit, 257 for 16-bit samples): the
    /// unit of contrasts and reported noise.
    pub dn: f64,
}

/// Whether targets are brighter or darker than their surroundings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Polarity {
    /// Bright targets on a darker background (projected dots, retro-reflective targets).
    #[default]
    Bright,
    /// Dark targets on a brighter background.
    Dark,
}

impl<P: Copy + Into<f64>> GrayView<'_, P> {
    /// The sample at (col, row) with the polarity's sign: targets are always positive.
    #[inline]
    pub fn signed(&self, col: usize, row: usize, polarity: Polarity) -> f64 {
        let v: f64 = self.pixels[row * self.width + col].into();
        match polarity {
            Polarity::Bright => v,
            Polarity::Dark => -v,
        }
    }
}

/// Detection settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectParams {
    /// Bright or dark targets.
    pub polarity: Polarity,
    /// Side of the background tiles (pixels); a few target diameters.
    pub tile: usize,
    /// Threshold above the local background, in units of the image noise σ.
    pub k_sigma: f64,
    /// ... but at least this contrast (DN of the 8-bit scale): compressed images (JPEG) can
    /// show almost no noise and blocking artefacts instead.
    pub min_contrast: f64,
    /// Smallest accepted component (pixels).
    pub min_area: usize,
    /// Largest accepted component (pixels).
    pub max_area: usize,
    /// Accepted range of area / (area of the moments' ellipse): 1 for a filled ellipse, about
    /// 0.89 for two touching discs.
    pub fill: (f64, f64),
    /// Largest accepted axis ratio of the moments' ellipse.
    pub max_aspect: f64,
}

impl Default for DetectParams {
    fn default() -> Self {
        Self {
            polarity: Polarity::Bright,
            tile: 32,
            k_sigma: 5.0,
            min_contrast: 8.0,
            min_area: 12,
            max_area: 5000,
            fill: (0.93, 1.08),
            max_aspect: 3.0,
        }
    }
}

/// The smooth background: the median of each tile, interpolated bilinearly between tile centres.
#[derive(Debug, Clone, PartialEq)]
pub struct BackgroundField {
    tile: usize,
    nx: usize,
    ny: usize,
    medians: Vec<f64>,
}

impl BackgroundField {
    /// Estimate from an image (signed by polarity).
    pub fn estimate<P: Copy + Into<f64> + Sync>(
        img: &GrayView<P>,
        polarity: Polarity,
        tile: usize,
    ) -> Self {
        let tile = tile.max(4);
        let nx = img.width.div_ceil(tile);
        let ny = img.height.div_ceil(tile);
        // Every other row and column of a large tile is enough for its median (256 of 32²).
        let stride = if tile >= 16 { 2 } else { 1 };
        // Rows of tiles in parallel, each with its own buffer.
        let rows: Vec<Vec<f64>> = (0..ny)
            .into_par_iter()
            .map_init(Vec::new, |buf, ty| {
                (0..nx)
                    .map(|tx| {
                        buf.clear();
                        for r in (ty * tile..((ty + 1) * tile).min(img.height)).step_by(stride) {
                            for c in (tx * tile..((tx + 1) * tile).min(img.width)).step_by(stride) {
                                buf.push(img.signed(c, r, polarity));
                            }
                        }
                        median(buf)
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
        Self {
            tile,
            nx,
            ny,
            medians: rows.concat(),
        }
    }

    /// The background at a pixel (signed by polarity).
    pub fn at(&self, col: f64, row: f64) -> f64 {
        let t = self.tile as f64;
        let fx = ((col + 0.5) / t - 0.5).clamp(0.0, (self.nx - 1) as f64);
        let fy = ((row + 0.5) / t - 0.5).clamp(0.0, (self.ny - 1) as f64);
        let (x0, y0) = (fx.floor() as usize, fy.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.nx - 1), (y0 + 1).min(self.ny - 1));
        let (ax, ay) = (fx - x0 as f64, fy - y0 as f64);
        let m = |x: usize, y: usize| self.medians[y * self.nx + x];
        (1.0 - ay) * ((1.0 - ax) * m(x0, y0) + ax * m(x1, y0))
            + ay * ((1.0 - ax) * m(x0, y1) + ax * m(x1, y1))
    }
}

/// [`BackgroundField::at`] along one row, all columns at once: the columns in spans between
/// the same two tile centres, and each column's weight between them, computed once per image.
#[derive(Clone)]
struct RowInterpolation<'a> {
    field: &'a BackgroundField,
    /// The first column.
    first: usize,
    /// (left tile, right tile, columns) of each span, from the first column on.
    spans: Vec<(usize, usize, usize)>,
    /// Each column's weight of its span's right tile.
    weights: Vec<f64>,
    tiles: Vec<f64>,
}

impl<'a> RowInterpolation<'a> {
    /// For the columns `columns` (`row` then fills one value per column, from the first).
    fn new(field: &'a BackgroundField, columns: std::ops::RangeInclusive<usize>) -> Self {
        let t = field.tile as f64;
        let first = *columns.start();
        let mut spans: Vec<(usize, usize, usize)> = Vec::new();
        let mut weights = Vec::with_capacity(columns.clone().count());
        for c in columns {
            let fx = ((c as f64 + 0.5) / t - 0.5).clamp(0.0, (field.nx - 1) as f64);
            let x0 = fx.floor() as usize;
            let x1 = (x0 + 1).min(field.nx - 1);
            weights.push(fx - x0 as f64);
            match spans.last_mut() {
                Some((l, r, n)) if (*l, *r) == (x0, x1) => *n += 1,
                _ => spans.push((x0, x1, 1)),
            }
        }
        Self {
            field,
            first,
            spans,
            weights,
            tiles: vec![0.0; field.nx],
        }
    }

    /// The background of every column of `row` into `out`.
    fn row(&mut self, row: usize, out: &mut [f64]) {
        let f = self.field;
        let fy = ((row as f64 + 0.5) / f.tile as f64 - 0.5).clamp(0.0, (f.ny - 1) as f64);
        let y0 = fy.floor() as usize;
        let y1 = (y0 + 1).min(f.ny - 1);
        let ay = fy - y0 as f64;
        for (x, tile) in self.tiles.iter_mut().enumerate() {
            *tile = (1.0 - ay) * f.medians[y0 * f.nx + x] + ay * f.medians[y1 * f.nx + x];
        }
        let (mut out, mut weights) = (out, &self.weights[..]);
        for &(x0, x1, n) in &self.spans {
            let (a, b) = (self.tiles[x0], self.tiles[x1]);
            let (o, rest) = out.split_at_mut(n);
            let (w, more) = weights.split_at(n);
            for (o, &ax) in o.iter_mut().zip(w) {
                *o = (1.0 - ax) * a + ax * b;
            }
            (out, weights) = (rest, more);
        }
    }
}

/// The median of a buffer (reordered in place); 0 for an empty one.
fn median(buf: &mut [f64]) -> f64 {
    if buf.is_empty() {
        return 0.0;
    }
    let mid = buf.len() / 2;
    *buf.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// The image noise σ from the median absolute difference of horizontal neighbours
/// (σ = 1.4826 · median|Δ| / √2), robust to targets and a smooth background. At most about 2¹⁶
/// pairs are sampled (the median's relative error is then about 0.5 %).
pub fn noise_sigma<P: Copy + Into<f64>>(img: &GrayView<P>) -> f64 {
    let pairs = img.width.saturating_sub(1) * img.height;
    let step = (pairs >> 16).max(1);
    let mut diffs: Vec<f64> = (0..pairs)
        .step_by(step)
        .map(|k| {
            let (r, c) = (k / (img.width - 1), k % (img.width - 1));
            (img.signed(c + 1, r, Polarity::Bright) - img.signed(c, r, Polarity::Bright)).abs()
        })
        .collect();
    1.4826 * median(&mut diffs) / 2f64.sqrt()
}

/// One connected component above the threshold.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Blob {
    /// Pixels in the component.
    pub area: usize,
    /// Bounding box: first column, first row, last column, last row (inclusive).
    pub bbox: [usize; 4],
    /// The gravity centre: Σ w (col, row) / Σ w, w = I − background.
    pub gravity: (f64, f64),
    /// Second central moments of the pixel positions: (cc, cr, rr).
    pub cov: (f64, f64, f64),
    /// The largest I − background (DN, signed by polarity).
    pub peak: f64,
}

impl Blob {
    /// The axis ratio of the moments' ellipse (≥ 1).
    pub fn aspect(&self) -> f64 {
        let (a, b, c) = self.cov;
        let mean = (a + c) / 2.0;
        let dev = (((a - c) / 2.0).powi(2) + b * b).sqrt();
        ((mean + dev) / (mean - dev).max(1e-12)).sqrt()
    }

    /// Area over the area of the ellipse with the same second moments, 4π√det: 1 for a filled
    /// ellipse.
    pub fn fill(&self) -> f64 {
        let (a, b, c) = self.cov;
        self.area as f64 / (4.0 * PI * (a * c - b * b).max(1e-12).sqrt())
    }
}

/// Why a component is not a target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rejection {
    /// Fewer pixels than `min_area` (noise, specks).
    TooSmall,
    /// More pixels than `max_area` (clutter, reflections).
    TooLarge,
    /// It touches the image border (its centre would be biased).
    Border,
    /// Not an ellipse: fill or axis ratio out of range (merged blobs, lines, clutter).
    Shape,
    /// The sub-pixel fit did not converge to an ellipse inside the blob's box.
    Fit,
    /// The fit's residuals are far above the noise and the image's other fits.
    Residual,
    /// The template and gravity centres disagree: not one symmetric ellipse (a dot merged
    /// into a target, a partly covered target).
    Shift,
}

impl Rejection {
    /// Every reason, in the order of the tests.
    pub const ALL: [Rejection; 7] = [
        Rejection::TooSmall,
        Rejection::TooLarge,
        Rejection::Border,
        Rejection::Shape,
        Rejection::Fit,
        Rejection::Residual,
        Rejection::Shift,
    ];

    /// A short name for counts ("small", "large", "border", "shape", "fit", "residual",
    /// "shift").
    pub fn name(self) -> &'static str {
        match self {
            Rejection::TooSmall => "small",
            Rejection::TooLarge => "large",
            Rejection::Border => "border",
            Rejection::Shape => "shape",
            Rejection::Fit => "fit",
            Rejection::Residual => "residual",
            Rejection::Shift => "shift",
        }
    }
}

impl std::fmt::Display for Rejection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Rejection::TooSmall => "smaller than the minimum area",
            Rejection::TooLarge => "larger than the maximum area",
            Rejection::Border => "touches the image border",
            Rejection::Shape => "not elliptical (merged blobs or clutter)",
            Rejection::Fit => "the sub-pixel fit failed",
            Rejection::Residual => "the fit leaves residuals far above the noise",
            Rejection::Shift => "the template and gravity centres disagree",
        })
    }
}

/// Running sums of one component.
#[derive(Debug, Clone, Copy)]
struct Sums {
    n: usize,
    sc: f64,
    sr: f64,
    scc: f64,
    scr: f64,
    srr: f64,
    sw: f64,
    swc: f64,
    swr: f64,
    bbox: [usize; 4],
    peak: f64,
}

impl Sums {
    fn new(col: usize, row: usize) -> Self {
        Self {
            n: 0,
            sc: 0.0,
            sr: 0.0,
            scc: 0.0,
            scr: 0.0,
            srr: 0.0,
            sw: 0.0,
            swc: 0.0,
            swr: 0.0,
            bbox: [col, row, col, row],
            peak: f64::NEG_INFINITY,
        }
    }

    /// A run of pixels of one row from column `first` on, with their weights.
    fn add_run(&mut self, first: usize, row: usize, weights: &[f64]) {
        let (n, r) = (weights.len(), row as f64);
        let (a, b) = (first as f64, (first + n - 1) as f64);
        // Σ c and Σ c² over first..first + n, exact in f64.
        let (sum_c, sum_cc) = (
            (a + b) * n as f64 / 2.0,
            (b * (b + 1.0) * (2.0 * b + 1.0) - (a - 1.0) * a * (2.0 * a - 1.0)) / 6.0,
        );
        self.n += n;
        self.sc += sum_c;
        self.sr += r * n as f64;
        self.scc += sum_cc;
        self.scr += r * sum_c;
        self.srr += r * r * n as f64;
        let (mut sw, mut swc, mut peak) = (0.0, 0.0, self.peak);
        for (c, &w) in (first..).zip(weights) {
            sw += w;
            swc += w * c as f64;
            peak = w.max(peak);
        }
        self.sw += sw;
        self.swc += swc;
        self.swr += r * sw;
        self.bbox = [
            self.bbox[0].min(first),
            self.bbox[1].min(row),
            self.bbox[2].max(first + n - 1),
            self.bbox[3].max(row),
        ];
        self.peak = peak;
    }

    fn merge(&mut self, o: &Sums) {
        self.n += o.n;
        self.sc += o.sc;
        self.sr += o.sr;
        self.scc += o.scc;
        self.scr += o.scr;
        self.srr += o.srr;
        self.sw += o.sw;
        self.swc += o.swc;
        self.swr += o.swr;
        self.bbox = [
            self.bbox[0].min(o.bbox[0]),
            self.bbox[1].min(o.bbox[1]),
            self.bbox[2].max(o.bbox[2]),
            self.bbox[3].max(o.bbox[3]),
        ];
        self.peak = self.peak.max(o.peak);
    }

    fn blob(&self) -> Blob {
        let n = self.n as f64;
        let (mc, mr) = (self.sc / n, self.sr / n);
        Blob {
            area: self.n,
            bbox: self.bbox,
            gravity: (self.swc / self.sw, self.swr / self.sw),
            cov: (
                self.scc / n - mc * mc,
                self.scr / n - mc * mr,
                self.srr / n - mr * mr,
            ),
            peak: self.peak,
        }
    }
}

fn find(parent: &mut [usize], mut i: usize) -> usize {
    while parent[i] != i {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    i
}

/// One row run of a component: columns `start..end` of its row, and the component's index.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Run {
    start: usize,
    end: usize,
    blob: usize,
}

/// The components' label image, run-length encoded: each row's runs above the threshold in
/// column order, each with the index of its component in [`Components::blobs`].
#[derive(Debug, Clone, PartialEq)]
pub struct RunLabels {
    first_row: usize,
    /// Where each row's runs start in `runs`, and one entry past the last row.
    row_start: Vec<usize>,
    runs: Vec<Run>,
}

impl RunLabels {
    /// The runs of a row (none outside the labelled rows).
    fn row(&self, row: usize) -> &[Run] {
        match row.checked_sub(self.first_row) {
            Some(k) if k + 1 < self.row_start.len() => {
                &self.runs[self.row_start[k]..self.row_start[k + 1]]
            }
            _ => &[],
        }
    }

    /// The component at a pixel, if it is above the threshold.
    pub fn at(&self, col: usize, row: usize) -> Option<usize> {
        let runs = self.row(row);
        let k = runs.partition_point(|run| run.end <= col);
        runs.get(k)
            .filter(|run| run.start <= col)
            .map(|run| run.blob)
    }

    /// The pixels of components other than `own` grown by `grow` pixels (a square: their blur),
    /// within `window` (`[c0, r0, c1, r1]`, inclusive), as row runs `[c0, r, c1, r]`.
    pub fn foreign_runs(&self, own: usize, window: [usize; 4], grow: usize) -> Vec<[usize; 4]> {
        let [c0, r0, c1, r1] = window;
        let mut out = Vec::new();
        let mut spans: Vec<(usize, usize)> = Vec::new();
        for r in r0..=r1 {
            spans.clear();
            for rr in r.saturating_sub(grow)..=r + grow {
                let runs = self.row(rr);
                let first = runs.partition_point(|run| run.end + grow <= c0);
                for run in runs[first..]
                    .iter()
                    .take_while(|run| run.start <= c1 + grow)
                {
                    if run.blob != own {
                        spans.push((
                            run.start.saturating_sub(grow).max(c0),
                            (run.end - 1 + grow).min(c1),
                        ));
                    }
                }
            }
            spans.sort_unstable();
            let mut spans = spans.iter();
            let Some(&(mut a, mut b)) = spans.next() else {
                continue;
            };
            for &(s, e) in spans {
                if s > b + 1 {
                    out.push([a, r, b, r]);
                    a = s;
                }
                b = b.max(e);
            }
            out.push([a, r, b, r]);
        }
        out
    }
}

/// The components of an image (or window) and their label image.
#[derive(Debug, Clone, PartialEq)]
pub struct Components {
    /// One blob per component, in the order their first pixels occur row by row.
    pub blobs: Vec<Blob>,
    /// Which component each pixel above the threshold belongs to.
    pub labels: RunLabels,
}

/// Rows of the image labelled together in [`components`] (bands in parallel).
const BAND_ROWS: usize = 32;

/// The components of the pixels above background + k σ (8-connected), found row by row: bands
/// of [`BAND_ROWS`] rows on all cores, joined where their runs touch across the bands' edges.
pub fn components<P: Copy + Into<f64> + Sync>(
    img: &GrayView<P>,
    polarity: Polarity,
    background: &BackgroundField,
    threshold: f64,
) -> Components {
    let bands = img.height.div_ceil(BAND_ROWS);
    let columns = RowInterpolation::new(background, 0..=img.width - 1);
    let labelled: Vec<Labelling> = (0..bands)
        .into_par_iter()
        .map(|k| {
            let (r0, r1) = (k * BAND_ROWS, ((k + 1) * BAND_ROWS).min(img.height) - 1);
            Labelling::of(img, polarity, columns.clone(), threshold, r0..=r1)
        })
        .collect();
    let mut bands = labelled.into_iter();
    let mut all = bands.next().expect("an image has rows");
    for band in bands {
        all.append(band);
    }
    all.finish()
}

/// [`components`] within a window `[c0, r0, c1, r1]` (inclusive).
pub fn components_in<P: Copy + Into<f64>>(
    img: &GrayView<P>,
    polarity: Polarity,
    background: &BackgroundField,
    threshold: f64,
    window: [usize; 4],
) -> Components {
    let [c0, r0, c1, r1] = window;
    let columns = RowInterpolation::new(background, c0..=c1);
    Labelling::of(img, polarity, columns, threshold, r0..=r1).finish()
}

/// Row runs with provisional labels joined by union-find (a label's root is the smallest label
/// of its component), and each label's sums.
struct Labelling {
    parent: Vec<usize>,
    sums: Vec<Sums>,
    /// Runs, `blob` being the provisional label.
    runs: Vec<Run>,
    first_row: usize,
    row_start: Vec<usize>,
}

impl Labelling {
    /// The runs of the rows `rows` within the columns of `background`, row by row.
    fn of<P: Copy + Into<f64>>(
        img: &GrayView<P>,
        polarity: Polarity,
        mut background: RowInterpolation<'_>,
        threshold: f64,
        rows: std::ops::RangeInclusive<usize>,
    ) -> Self {
        let (r0, r1) = (*rows.start(), *rows.end());
        let (c0, c1) = (
            background.first,
            background.first + background.weights.len() - 1,
        );
        let sign = match polarity {
            Polarity::Bright => 1.0,
            Polarity::Dark => -1.0,
        };
        let mut labelling = Labelling {
            parent: Vec::new(),
            sums: Vec::new(),
            runs: Vec::new(),
            first_row: r0,
            row_start: Vec::with_capacity(r1 + 2 - r0),
        };
        let mut height = vec![0.0; c1 + 1 - c0];
        for r in rows {
            labelling.row_start.push(labelling.runs.len());
            // The height above the background of every pixel of the row.
            background.row(r, &mut height);
            let pixels = &img.pixels[r * img.width + c0..=r * img.width + c1];
            for (h, &p) in height.iter_mut().zip(pixels) {
                *h = sign * p.into() - *h;
            }
            let mut above = height.iter().map(|&h| h > threshold);
            let mut c = 0;
            while let Some(skip) = above.position(|a| a) {
                let start = c + skip;
                let end = start + 1 + above.by_ref().take_while(|&a| a).count();
                c = end + 1;
                labelling.add_run(c0 + start, r, &height[start..end]);
            }
        }
        labelling.row_start.push(labelling.runs.len());
        labelling
    }

    /// The runs of the `k`-th row (from the first).
    fn row(&self, k: usize) -> std::ops::Range<usize> {
        self.row_start[k]..self.row_start[k + 1]
    }

    /// A run of the current (last) row: joined to the runs of the row above that it touches
    /// (8-connected), or a new label.
    fn add_run(&mut self, first: usize, row: usize, heights: &[f64]) {
        let last = first + heights.len();
        let rows = self.row_start.len() - 1;
        let above = if rows > 0 { self.row(rows - 1) } else { 0..0 };
        // The runs above are in column order: skip those ending left of this one.
        let skip = self.runs[above.clone()].partition_point(|run| run.end < first);
        let mut label = None;
        for k in above.start + skip..above.end {
            let run = self.runs[k];
            if run.start > last {
                break;
            }
            label = Some(self.join(run.blob, label));
        }
        let label = label.unwrap_or_else(|| {
            self.parent.push(self.parent.len());
            self.sums.push(Sums::new(first, row));
            self.parent.len() - 1
        });
        self.sums[label].add_run(first, row, heights);
        self.runs.push(Run {
            start: first,
            end: last,
            blob: label,
        });
    }

    /// Join label `a` to the component of root `b` (if any): the smaller root stays.
    fn join(&mut self, a: usize, b: Option<usize>) -> usize {
        let root = find(&mut self.parent, a);
        match b {
            Some(b) if b != root => {
                let (keep, gone) = (b.min(root), b.max(root));
                self.parent[gone] = keep;
                keep
            }
            _ => root,
        }
    }

    /// The labelling of the rows just below appended, components touching across the edge
    /// joined.
    fn append(&mut self, below: Labelling) {
        let offset = self.parent.len();
        let rows = self.row_start.len() - 1;
        debug_assert_eq!(below.first_row, self.first_row + rows);
        let edge = self.row(rows - 1);
        let run_offset = self.runs.len();
        self.parent.extend(below.parent.iter().map(|&p| p + offset));
        self.sums.extend(below.sums);
        self.row_start.pop();
        self.row_start
            .extend(below.row_start.iter().map(|&k| k + run_offset));
        self.runs.extend(below.runs.iter().map(|run| Run {
            blob: run.blob + offset,
            ..*run
        }));
        for k in self.row(rows) {
            let run = self.runs[k];
            for j in edge.clone() {
                let up = self.runs[j];
                if up.end >= run.start && up.start <= run.end {
                    let root = find(&mut self.parent, run.blob);
                    self.join(up.blob, Some(root));
                }
            }
        }
    }

    /// The components (in the order of their first runs) and the resolved label image.
    fn finish(mut self) -> Components {
        let parent = &mut self.parent;
        for i in 0..parent.len() {
            let root = find(parent, i);
            if root != i {
                let moved = self.sums[i];
                self.sums[root].merge(&moved);
            }
        }
        let mut index = vec![0; parent.len()];
        let mut blobs = Vec::new();
        for i in 0..parent.len() {
            if parent[i] == i {
                index[i] = blobs.len();
                blobs.push(self.sums[i].blob());
            }
        }
        for run in &mut self.runs {
            run.blob = index[find(parent, run.blob)];
        }
        Components {
            blobs,
            labels: RunLabels {
                first_row: self.first_row,
                row_start: self.row_start,
                runs: self.runs,
            },
        }
    }
}

/// The shape tests of a component, in order: area, border, ellipse fill and axis ratio.
pub fn check_shape(
    blob: &Blob,
    params: &DetectParams,
    width: usize,
    height: usize,
) -> Option<Rejection> {
    if blob.area < params.min_area {
        return Some(Rejection::TooSmall);
    }
    if blob.area > params.max_area {
        return Some(Rejection::TooLarge);
    }
    let [c0, r0, c1, r1] = blob.bbox;
    if c0 == 0 || r0 == 0 || c1 + 1 >= width || r1 + 1 >= height {
        return Some(Rejection::Border);
    }
    let fill = blob.fill();
    if fill < params.fill.0 || fill > params.fill.1 || blob.aspect() > params.max_aspect {
        return Some(Rejection::Shape);
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two squares and an L joined diagonally: three components, the L's diagonal neighbour
    /// merged by 8-connectivity, gravity centres exact.
    #[test]
    fn components_by_runs() {
        #[rustfmt::skip]
        let px: [u8; 8 * 6] = [
            0, 0, 0, 0, 0, 0, 0, 0,
            0, 9, 9, 0, 0, 0, 5, 0,
            0, 9, 9, 0, 0, 5, 0, 0,
            0, 0, 0, 0, 5, 0, 0, 0,
            0, 7, 0, 0, 5, 5, 0, 0,
            0, 0, 0, 0, 0, 0, 0, 0,
        ];
        let img = GrayView {
            width: 8,
            height: 6,
            pixels: &px,
            dn: 1.0,
        };
        let bg = BackgroundField::estimate(&img, Polarity::Bright, 8);
        assert_eq!(bg.at(3.0, 3.0), 0.0);
        let found = components(&img, Polarity::Bright, &bg, 1.0);
        let mut blobs = found.blobs.clone();
        blobs.sort_by_key(|b| b.area);
        assert_eq!(blobs.len(), 3);
        assert_eq!((blobs[0].area, blobs[0].gravity), (1, (1.0, 4.0)));
        assert_eq!((blobs[1].area, blobs[1].gravity), (4, (1.5, 1.5)));
        assert_eq!(blobs[2].area, 5);
        assert_eq!(blobs[2].bbox, [4, 1, 6, 4]);
        assert!((blobs[2].gravity.0 - 24.0 / 5.0).abs() < 1e-12);
        let dark: Vec<u8> = px.iter().map(|v| 20 - v).collect();
        let img = GrayView {
            width: 8,
            height: 6,
            pixels: &dark[..],
            dn: 1.0,
        };
        let bg = BackgroundField::estimate(&img, Polarity::Dark, 8);
        assert_eq!(components(&img, Polarity::Dark, &bg, 1.0).blobs.len(), 3);
    }

    /// The run-length labels against a flood fill of a random speckle image (three bands of
    /// rows joined): the same components, areas and, around each component, the same foreign
    /// pixels grown by 2; the spans outside them cover the rest of the window once.
    #[test]
    fn run_labels_match_flood_fill() {
        let (w, h) = (41, 2 * BAND_ROWS + 11);
        let mut state = 12345u32;
        let px: Vec<u8> = (0..w * h)
            .map(|_| {
                state = state.wrapping_mul(1_103_515_245).wrapping_add(12345);
                if (state >> 16) % 100 < 30 {
                    9
                } else {
                    0
                }
            })
            .collect();
        let img = GrayView {
            width: w,
            height: h,
            pixels: &px[..],
            dn: 1.0,
        };
        let bg = BackgroundField::estimate(&img, Polarity::Bright, 64);
        let found = components(&img, Polarity::Bright, &bg, 1.0);
        // Flood fill, 8-connected.
        let mut flood = vec![usize::MAX; w * h];
        let mut count = 0;
        for start in 0..w * h {
            if px[start] == 0 || flood[start] != usize::MAX {
                continue;
            }
            let mut stack = vec![start];
            flood[start] = count;
            while let Some(k) = stack.pop() {
                let (r, c) = ((k / w) as i64, (k % w) as i64);
                for (dr, dc) in (-1..=1).flat_map(|dr| (-1..=1).map(move |dc| (dr, dc))) {
                    let (rr, cc) = (r + dr, c + dc);
                    if rr >= 0 && cc >= 0 && rr < h as i64 && cc < w as i64 {
                        let j = rr as usize * w + cc as usize;
                        if px[j] != 0 && flood[j] == usize::MAX {
                            flood[j] = count;
                            stack.push(j);
                        }
                    }
                }
            }
            count += 1;
        }
        assert!(count > 50, "{count} components");
        assert_eq!(found.blobs.len(), count);
        let label = |c: usize, r: usize| found.labels.at(c, r);
        // The same partition: flood label ↔ run label one to one, areas agree.
        let mut to_run = vec![None; count];
        for r in 0..h {
            for c in 0..w {
                let f = flood[r * w + c];
                if f == usize::MAX {
                    assert_eq!(label(c, r), None);
                    continue;
                }
                let k = label(c, r).expect("labelled");
                assert_eq!(*to_run[f].get_or_insert(k), k);
            }
        }
        for (f, k) in to_run.iter().enumerate() {
            let area = flood.iter().filter(|&&l| l == f).count();
            assert_eq!(found.blobs[k.unwrap()].area, area);
        }
        let windows = [[3, 2, 30, 25], [5, BAND_ROWS - 9, 38, 2 * BAND_ROWS + 3]];
        for (own, window) in [0, count / 2, count - 1]
            .into_iter()
            .zip(windows.iter().cycle())
        {
            let window = *window;
            let runs = found.labels.foreign_runs(own, window, 2);
            let own_flood = to_run.iter().position(|&k| k == Some(own)).unwrap();
            let mut seen = vec![0; w * h];
            crate::fit::for_each_span(window, &runs, |r, first, last| {
                for c in first..=last {
                    seen[r * w + c] += 1;
                }
            });
            for r in window[1]..=window[3] {
                for c in window[0]..=window[2] {
                    let near_foreign = (r.saturating_sub(2)..=(r + 2).min(h - 1)).any(|rr| {
                        (c.saturating_sub(2)..=(c + 2).min(w - 1)).any(|cc| {
                            let f = flood[rr * w + cc];
                            f != usize::MAX && f != own_flood
                        })
                    });
                    let in_runs = runs.iter().any(|b| b[1] == r && (b[0]..=b[2]).contains(&c));
                    assert_eq!(in_runs, near_foreign, "pixel ({c}, {r}), own {own}");
                    assert_eq!(seen[r * w + c], usize::from(!near_foreign));
                }
            }
            assert_eq!(seen.iter().sum::<usize>(), {
                let [c0, r0, c1, r1] = window;
                (c1 - c0 + 1) * (r1 - r0 + 1) - runs.iter().map(|b| b[2] - b[0] + 1).sum::<usize>()
            });
        }
    }

    #[test]
    fn noise_estimate() {
        use crate::render::{Background, Scene};
        let scene = Scene {
            width: 300,
            height: 200,
            spots: vec![],
            background: Background {
                level: 80.0,
                slope_col: 0.2,
                slope_row: -0.1,
                ripple: 10.0,
                ripple_period: 150.0,
            },
            falloff: 0.0,
            blur_sigma: 0.0,
            noise_sigma: 3.0,
            seed: 3,
        };
        let img = scene.render();
        let view = GrayView {
            width: 300,
            height: 200,
            pixels: &img.pixels[..],
            dn: 1.0,
        };
        let s = noise_sigma(&view);
        assert!((s - 3.0).abs() < 0.1, "{s}");
    }
}
