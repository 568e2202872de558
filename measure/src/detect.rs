//! Blob detection: a tiled background model, an adaptive threshold, the components above it
//! ([`crate::components()`]) and shape tests.
//!
//! Each component yields its area, bounding box, second moments and the intensity-weighted
//! centroid (the paper's "gravity centre", section 6.2.1) with weights w = I − background over the
//! pixels above the threshold.

use crate::median;
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
pub(crate) struct RowInterpolation<'a> {
    field: &'a BackgroundField,
    /// The first column.
    pub(crate) first: usize,
    /// (left tile, right tile, columns) of each span, from the first column on.
    spans: Vec<(usize, usize, usize)>,
    /// Each column's weight of its span's right tile.
    pub(crate) weights: Vec<f64>,
    tiles: Vec<f64>,
}

impl<'a> RowInterpolation<'a> {
    /// For the columns `columns` (`row` then fills one value per column, from the first).
    pub(crate) fn new(
        field: &'a BackgroundField,
        columns: std::ops::RangeInclusive<usize>,
    ) -> Self {
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
    pub(crate) fn row(&mut self, row: usize, out: &mut [f64]) {
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
    /// Far fainter than the targets around it: a speck of the background, not one of them
    /// ([`crate::population`]).
    Faint,
}

impl Rejection {
    /// Every reason, in the order of the tests.
    pub const ALL: [Rejection; 8] = [
        Rejection::TooSmall,
        Rejection::TooLarge,
        Rejection::Border,
        Rejection::Shape,
        Rejection::Fit,
        Rejection::Residual,
        Rejection::Shift,
        Rejection::Faint,
    ];

    /// A short name for counts ("small", "large", "border", "shape", "fit", "residual",
    /// "shift", "faint").
    pub fn name(self) -> &'static str {
        match self {
            Rejection::TooSmall => "small",
            Rejection::TooLarge => "large",
            Rejection::Border => "border",
            Rejection::Shape => "shape",
            Rejection::Fit => "fit",
            Rejection::Residual => "residual",
            Rejection::Shift => "shift",
            Rejection::Faint => "faint",
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
            Rejection::Faint => "far fainter than the targets around it",
        })
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
