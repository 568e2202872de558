//! Connected components above the threshold, found row by row: bands of rows labelled on all
//! cores, joined where their runs touch; the label image kept as runs ([`RunLabels`]), each
//! component's area, box, moments and gravity centre summed as its runs are found.

use crate::detect::{BackgroundField, Blob, GrayView, Polarity, RowInterpolation};
use rayon::prelude::*;

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
/// of `BAND_ROWS` rows on all cores, joined where their runs touch across the bands' edges.
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

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
        let mut rng = StdRng::seed_from_u64(12345);
        let px: Vec<u8> = (0..w * h)
            .map(|_| if rng.random_bool(0.3) { 9 } else { 0 })
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
}
