//! Image measurement: blob detection ([`detect`]) and sub-pixel centres ([`fit`]), put together
//! by [`measure`]. (Synthetic images to measure come from [`render`].)
//!
//! # Centre methods
//! - [`CentreMethod::Gravity`]: the paper's intensity-weighted centroid over the pixels above the
//!   threshold (section 6.2.1). Biased by the threshold cut and by background gradients.
//! - [`CentreMethod::Template`] (default): a least-squares fit of a blurred ellipse on a tilted
//!   background ([`fit::fit_template`]); several times more precise (see the crate's tests for the
//!   figures).
//!
//! # Perspective bias
//! Both methods find the centre of the imaged *ellipse*, which is not the image of the circle's
//! centre. The shift grows with the square of the target radius over the distance and with the
//! tilt of the target plane; [`perspective_bias`] computes it exactly (no distortion) where the
//! target's pose and size are known, so it can be subtracted. At the paper's geometry (f = 47 mm,
//! 45 µm pixels, 1.6-1.9 m, up to 600 mm off axis, planes tilted up to 45°) it stays below
//! 0.02 pixel for 20 mm targets and, scaling with ρ², below 0.005 pixel for 10 mm targets
//! (test `perspective_bias_at_paper_geometry`): below the centroid noise, so the calibration
//! commands leave it uncorrected. Projected dots are footprints of the projector's light cone
//! and carry a shift of the same kind; it is not corrected either.
#![deny(missing_docs)]

pub mod bench;
pub mod board;
pub mod components;
pub mod crlb;
pub mod detect;
pub mod fit;
pub mod grid;
pub mod layout;
pub mod population;
pub mod render;
pub mod target_field;

use anyhow::{bail, Context, Result};
use components::{components, components_in, Components, RunLabels};
use deltaz_shared::identify::Identifier;
use detect::{check_shape, noise_sigma, BackgroundField, Blob, DetectParams, GrayView, Rejection};
use nalgebra::{Matrix3, Vector2, Vector3};
use rayon::prelude::*;
use std::path::Path;

/// How the sub-pixel centre is found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CentreMethod {
    /// The paper's intensity-weighted centroid.
    Gravity,
    /// Least-squares blurred-ellipse template (the default: the more precise).
    #[default]
    Template,
}

/// Measurement settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasureParams {
    /// Detection and shape tests.
    pub detect: DetectParams,
    /// Centre method.
    pub method: CentreMethod,
    /// Pixels of background around a blob in the template window.
    pub margin: usize,
    /// Largest accepted template residual RMS, in units of the image noise σ.
    pub max_rms_sigma: f64,
    /// ... plus this fraction of the target's amplitude (the template's mismatch and
    /// compression artefacts grow with the contrast).
    pub max_rms_fraction: f64,
    /// Largest distance between the template and gravity centres (pixels): a blob that is not
    /// one symmetric ellipse (a dot merged into a target, a partly covered target) moves its
    /// gravity centre away from the fitted ellipse's centre.
    pub max_centre_shift: f64,
    /// A circle-grid board to find in every image: its circles are named by grid position
    /// (`rIcJ`, see [`board`]) and the other targets left out.
    pub board: Option<board::Board>,
    /// The camera's sensor (width, height in pixels), when measuring for a calibrated
    /// system: an image of another size is an error.
    pub sensor: Option<(u32, u32)>,
}

impl Default for MeasureParams {
    fn default() -> Self {
        Self {
            detect: DetectParams::default(),
            method: CentreMethod::Template,
            margin: 3,
            max_rms_sigma: 3.0,
            max_rms_fraction: 0.015,
            max_centre_shift: 0.25,
            board: None,
            sensor: None,
        }
    }
}

/// One measured target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Target {
    /// Centre column (pixels) by the chosen method.
    pub col: f64,
    /// Centre row (pixels) by the chosen method.
    pub row: f64,
    /// The component it came from (area, box, gravity centre, moments).
    pub blob: Blob,
    /// The template fit, if that method was used.
    pub fit: Option<fit::EllipseFit>,
}

/// All targets of one image and what was rejected.
#[derive(Debug, Clone, PartialEq)]
pub struct Measurement {
    /// Accepted targets, in row-major order of their boxes.
    pub targets: Vec<Target>,
    /// Rejected components and why.
    pub rejected: Vec<(Blob, Rejection)>,
    /// The image noise σ (DN) the threshold used.
    pub noise_sigma: f64,
}

/// Detect and measure all targets of an image.
///
/// The steps, each following from the image rather than from fixed pixel sizes:
/// 1. the noise σ and the threshold (k σ, at least `min_contrast`);
/// 2. components on a tiled background; when the targets are large against the tiles (a tile
///    mostly covered by a target has a biased median), again on tiles of
///    [`TILE_PER_DIAMETER`] typical target diameters ([`scale_aware_tile`]);
/// 3. shape tests, then the template fit on the window around each blob, leaving out the
///    pixels of *other* components (and 2 pixels around them) but nothing else: a large blob
///    around the targets (a dark room, a frame) does not empty their windows;
/// 4. the gates (`gate_fits`): residual and template-vs-gravity limits from the noise, the
///    target's amplitude and size, and the spread of the image's own fits;
/// 5. the population ([`population::gate_faint`]): a target far fainter than the targets around
///    it (a speck of a textured background) is left out.
pub fn measure<P: Copy + Into<f64> + Sync>(
    img: &GrayView<P>,
    params: &MeasureParams,
) -> Measurement {
    let d = &params.detect;
    // Quantisation alone gives σ ≥ 1/√12 DN.
    let sigma = noise_sigma(img).max(0.29 * img.dn);
    let threshold = (d.k_sigma * sigma).max(d.min_contrast * img.dn);
    let mut background = BackgroundField::estimate(img, d.polarity, d.tile);
    let mut found = components(img, d.polarity, &background, threshold);
    if let Some(tile) = scale_aware_tile(&found.blobs, d, img.width, img.height) {
        background = BackgroundField::estimate(img, d.polarity, tile);
        found = components(img, d.polarity, &background, threshold);
    }
    let Components { mut blobs, labels } = found;
    let split = split_merged(img, d, &background, threshold, &labels, &mut blobs);
    // One blob's verdict: shape tests, then the centre (ungated).
    let centre = |scratch: &mut fit::Scratch,
                  i: usize|
     -> std::result::Result<Candidate, (Blob, Rejection)> {
        let blob = &blobs[i];
        if let Some(why) = check_shape(blob, d, img.width, img.height) {
            return Err((*blob, why));
        }
        let (gc, gr) = blob.gravity;
        if params.method == CentreMethod::Gravity {
            return Ok(Candidate {
                target: Target {
                    col: gc,
                    row: gr,
                    blob: *blob,
                    fit: None,
                },
                check: None,
            });
        }
        let window = grown_box(blob.bbox, params.margin + CHECK_MARGIN, img);
        let exclude = match split[i] {
            None => labels.foreign_runs(i, window, FOREIGN_GROW),
            // A part split off at a higher threshold: the components at that threshold.
            Some(higher) => {
                let local = components_in(
                    img,
                    d.polarity,
                    &background,
                    higher,
                    grown_box(window, FOREIGN_GROW, img),
                );
                let own = local
                    .blobs
                    .iter()
                    .position(|b| b.area == blob.area && b.bbox == blob.bbox);
                let own = own.unwrap_or(usize::MAX);
                local.labels.foreign_runs(own, window, FOREIGN_GROW)
            }
        };
        let f = fit::fit_template(
            img,
            d.polarity,
            blob,
            background.at(gc, gr),
            params.margin,
            &exclude,
            scratch,
        )
        .ok_or((*blob, Rejection::Fit))?;
        let target = Target {
            col: f.col,
            row: f.row,
            blob: *blob,
            fit: Some(f),
        };
        let check = symmetric_gravity(img, d.polarity, &f, blob, params.margin, &exclude);
        Ok(Candidate { target, check })
    };
    // The blobs are independent: spread them over the cores, keep their order.
    let verdicts: Vec<_> = (0..blobs.len())
        .into_par_iter()
        .map_init(fit::Scratch::default, centre)
        .collect();
    let mut targets = Vec::new();
    let mut rejected = Vec::new();
    for verdict in verdicts {
        match verdict {
            Ok(t) => targets.push(t),
            Err(r) => rejected.push(r),
        }
    }
    let (targets, gated) = gate_fits(targets, sigma.max(img.dn), params);
    rejected.extend(gated);
    let (targets, faint) = population::gate_faint(targets);
    rejected.extend(faint);
    Measurement {
        targets,
        rejected,
        noise_sigma: sigma / img.dn,
    }
}

/// Split the components that fail the shape tests at a higher threshold, half their peak
/// contrast: a target touching a fainter blob (a stain, a faint spot, a neighbour's halo) comes
/// apart from it. When exactly one part passes the shape tests it replaces the component (the
/// others stay as they were, to be rejected). Returns the threshold of each split blob.
fn split_merged<P: Copy + Into<f64>>(
    img: &GrayView<P>,
    d: &DetectParams,
    background: &BackgroundField,
    threshold: f64,
    labels: &RunLabels,
    blobs: &mut [Blob],
) -> Vec<Option<f64>> {
    let mut thresholds = vec![None; blobs.len()];
    for k in 0..blobs.len() {
        let blob = blobs[k];
        if check_shape(&blob, d, img.width, img.height) != Some(Rejection::Shape) {
            continue;
        }
        let higher = (0.5 * blob.peak).max(threshold);
        // Parts of this component only, not of others reaching into its box.
        let parts: Vec<Blob> = components_in(img, d.polarity, background, higher, blob.bbox)
            .blobs
            .into_iter()
            .filter(|p| {
                let (c, r) = (p.gravity.0.round() as usize, p.gravity.1.round() as usize);
                labels.at(c, r) == Some(k) && check_shape(p, d, img.width, img.height).is_none()
            })
            .collect();
        // One part only: a target and a fainter blob. Two targets merged stay rejected (their
        // parts, cut at a higher threshold, would look smaller than the other targets).
        if let [part] = parts[..] {
            blobs[k] = part;
            thresholds[k] = Some(higher);
        }
    }
    thresholds
}

/// Background tiles per typical target diameter when the targets are large.
pub const TILE_PER_DIAMETER: f64 = 4.0;

/// A larger background tile when the targets are large against `params.tile`: the 90th
/// percentile of the equivalent diameters of the blobs that pass the shape tests, times
/// [`TILE_PER_DIAMETER`]; `None` when that is not more than twice `params.tile` (a target
/// covers less than a fifth of such a tile: its median is the background) or with too few blobs.
pub fn scale_aware_tile(
    blobs: &[Blob],
    params: &DetectParams,
    width: usize,
    height: usize,
) -> Option<usize> {
    let mut diameters: Vec<f64> = blobs
        .iter()
        .filter(|b| check_shape(b, params, width, height).is_none())
        .map(|b| 2.0 * (b.area as f64 / std::f64::consts::PI).sqrt())
        .collect();
    if diameters.len() < 3 {
        return None;
    }
    let k = ((diameters.len() * 9) / 10).min(diameters.len() - 1);
    let d90 = *diameters.select_nth_unstable_by(k, f64::total_cmp).1;
    let tile = (TILE_PER_DIAMETER * d90).ceil() as usize;
    (tile > 2 * params.tile).then_some(tile.min(width.max(height)))
}

/// Pixels by which other components are grown to leave out their blur.
const FOREIGN_GROW: usize = 2;

/// A box `[c0, r0, c1, r1]` grown by `by` pixels on every side, within the image.
fn grown_box<P>(bbox: [usize; 4], by: usize, img: &GrayView<P>) -> [usize; 4] {
    [
        bbox[0].saturating_sub(by),
        bbox[1].saturating_sub(by),
        (bbox[2] + by).min(img.width - 1),
        (bbox[3] + by).min(img.height - 1),
    ]
}

/// Extra pixels around the fit window for the gravity check's background ring.
const CHECK_MARGIN: usize = 3;

/// A fitted target before the gates, with its gravity check.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    target: Target,
    /// The gravity centre about the fitted ellipse ([`symmetric_gravity`]) and its σ (px).
    check: Option<((f64, f64), f64)>,
}

/// The intensity-weighted centroid of a fitted target that is free of the threshold cut and of
/// the tiled background: weights I − b over the pixels within the fitted ellipse grown by
/// 2 edge widths + 1 px, with b a plane fitted to the pixels outside it (in the blob's box grown
/// by `margin` + [`CHECK_MARGIN`], foreign pixels left out). For one symmetric ellipse it
/// agrees with the template's centre within its noise; a dot merged into the target, a partly
/// covered target or a fit gone astray move them apart. Returns the centre and its noise σ
/// (σ of I − b times √Σ w² d² / Σ w, the plane's own noise neglected); `None` when there are
/// too few background pixels.
fn symmetric_gravity<P: Copy + Into<f64>>(
    img: &GrayView<P>,
    polarity: detect::Polarity,
    f: &fit::EllipseFit,
    blob: &Blob,
    margin: usize,
    exclude: &[[usize; 4]],
) -> Option<((f64, f64), f64)> {
    let window = grown_box(blob.bbox, margin + CHECK_MARGIN, img);
    let grow = 2.0 * f.edge + 1.0;
    let (ia, ib) = (1.0 / (f.semi_major + grow), 1.0 / (f.semi_minor + grow));
    let (ca, sn) = (f.angle.cos(), f.angle.sin());
    // Positions relative to the fitted centre.
    let (mut inside, mut outside) = (PixelSums::default(), PixelSums::default());
    fit::for_each_span(window, exclude, |r, first, last| {
        let y = r as f64 - f.row;
        for c in first..=last {
            let x = c as f64 - f.col;
            let (u, v) = ((ca * x + sn * y) * ia, (-sn * x + ca * y) * ib);
            let sums = if u * u + v * v <= 1.0 {
                &mut inside
            } else {
                &mut outside
            };
            sums.add(x, y, img.signed(c, r, polarity));
        }
    });
    let o = &outside;
    if o.n < 12.0 {
        return None;
    }
    // The background plane b₀ + b₁ x + b₂ y fitted to the outside pixels.
    let normal = nalgebra::Matrix3::new(o.n, o.x, o.y, o.x, o.xx, o.xy, o.y, o.xy, o.yy);
    let rhs = Vector3::new(o.v, o.xv, o.yv);
    let b = normal.cholesky()?.solve(&rhs);
    // The residual variance of the plane fit: the noise of one pixel.
    let var = ((o.vv - b.dot(&rhs)) / (o.n - 3.0)).max(0.0);
    // Σ w, Σ w x, Σ w y of the weights w = v − plane inside, from the sums.
    let i = &inside;
    let sw = i.v - (b[0] * i.n + b[1] * i.x + b[2] * i.y);
    let swx = i.xv - (b[0] * i.x + b[1] * i.xx + b[2] * i.xy);
    let swy = i.yv - (b[0] * i.y + b[1] * i.xy + b[2] * i.yy);
    if sw <= 0.0 {
        return None;
    }
    let (gx, gy) = (swx / sw, swy / sw);
    // Σ |p − g|² over the inside pixels.
    let spread = i.xx + i.yy - 2.0 * (gx * i.x + gy * i.y) + i.n * (gx * gx + gy * gy);
    Some(((f.col + gx, f.row + gy), (var * spread / 2.0).sqrt() / sw))
}

/// Sums of 1, x, y, v and their products over pixels (x, y) of value v.
#[derive(Debug, Clone, Copy, Default)]
struct PixelSums {
    n: f64,
    x: f64,
    y: f64,
    v: f64,
    xx: f64,
    xy: f64,
    yy: f64,
    xv: f64,
    yv: f64,
    vv: f64,
}

impl PixelSums {
    fn add(&mut self, x: f64, y: f64, v: f64) {
        self.n += 1.0;
        self.x += x;
        self.y += y;
        self.v += v;
        self.xx += x * x;
        self.xy += x * y;
        self.yy += y * y;
        self.xv += x * v;
        self.yv += y * v;
        self.vv += v * v;
    }
}

/// The fit gates, from the noise, each target's amplitude and size, and the spread of the
/// image's own fits (so that JPEG halos and sharpening, which leave every fit a few DN of
/// misfit, do not reject them all):
/// - residual: RMS ≤ `max_rms_sigma` σ + `max_rms_fraction` A, or, if larger, ≤ A times the
///   median of RMS / A over the image's fits plus 5 robust σ of it (its MAD · 1.4826);
/// - template vs gravity: the distance between the template centre and the symmetric gravity
///   centre ([`symmetric_gravity`]) ≤ `max_centre_shift` + 5 σ of that gravity centre + 10 %
///   of the semi-major axis (the pixel sampling and the background plane's misfit bias the
///   gravity centre in proportion to the target's size; a fit gone astray, a merged dot or a
///   covered part move it by a good fraction of the radius).
///
/// Returns the accepted targets and the rejected ones (with the gate that failed).
fn gate_fits(
    candidates: Vec<Candidate>,
    sigma: f64,
    params: &MeasureParams,
) -> (Vec<Target>, Vec<(Blob, Rejection)>) {
    let mut relative: Vec<f64> = candidates
        .iter()
        .filter_map(|c| c.target.fit.map(|f| f.rms / f.amplitude))
        .collect();
    let spread_limit = if relative.len() >= 5 {
        let mid = median(&mut relative);
        let mut dev: Vec<f64> = relative.iter().map(|r| (r - mid).abs()).collect();
        mid + 5.0 * 1.4826 * median(&mut dev)
    } else {
        0.0
    };
    let mut accepted = Vec::with_capacity(candidates.len());
    let mut rejected = Vec::new();
    for Candidate { target: t, check } in candidates {
        let Some(f) = t.fit else {
            accepted.push(t);
            continue;
        };
        let allowed = (params.max_rms_sigma * sigma + params.max_rms_fraction * f.amplitude)
            .max(spread_limit * f.amplitude);
        // Without a background ring (crowded targets) the blob's own gravity centre stands in.
        let ((gc, gr), gs) = check.unwrap_or((t.blob.gravity, 0.0));
        let shifted = (f.col - gc).hypot(f.row - gr)
            > params.max_centre_shift + 5.0 * gs + 0.1 * f.semi_major;
        if f.rms > allowed {
            rejected.push((t.blob, Rejection::Residual));
        } else if shifted {
            rejected.push((t.blob, Rejection::Shift));
        } else {
            accepted.push(t);
        }
    }
    (accepted, rejected)
}

/// The median of a buffer (the upper one of an even count; reordered in place); 0 for an empty one.
pub(crate) fn median(buf: &mut [f64]) -> f64 {
    if buf.is_empty() {
        return 0.0;
    }
    let mid = buf.len() / 2;
    *buf.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// A decoded image: 8- and 16-bit grayscale are kept as decoded; colour is converted to 16-bit
/// luma (one copy).
pub enum LoadedImage {
    /// 8-bit samples.
    Eight(image::ImageBuffer<image::Luma<u8>, Vec<u8>>),
    /// 16-bit samples.
    Sixteen(image::ImageBuffer<image::Luma<u16>, Vec<u16>>),
}

impl LoadedImage {
    /// (width, height) in pixels.
    pub fn dimensions(&self) -> (u32, u32) {
        match self {
            LoadedImage::Eight(b) => b.dimensions(),
            LoadedImage::Sixteen(b) => b.dimensions(),
        }
    }

    /// Its targets measured ([`measure`]), one DN the 8-bit scale's.
    pub fn measure(&self, params: &MeasureParams) -> Measurement {
        match self {
            LoadedImage::Eight(b) => measure(&view(b, 1.0), params),
            LoadedImage::Sixteen(b) => measure(&view(b, 257.0), params),
        }
    }
}

/// Read a PNG, TIFF or JPEG image (format from its content), with clear errors for missing,
/// empty, corrupt and truncated files.
pub fn load_image(path: &Path) -> Result<LoadedImage> {
    let bytes = std::fs::metadata(path)
        .with_context(|| format!("{}: cannot read", path.display()))?
        .len();
    if bytes == 0 {
        bail!("{}: the file is empty", path.display());
    }
    let mut head = [0u8; 32];
    let n = std::io::Read::read(
        &mut std::fs::File::open(path)
            .with_context(|| format!("{}: cannot open", path.display()))?,
        &mut head,
    )
    .with_context(|| format!("{}: cannot read", path.display()))?;
    let format = image::guess_format(&head[..n])
        .ok()
        .filter(|f| {
            matches!(
                f,
                image::ImageFormat::Png | image::ImageFormat::Tiff | image::ImageFormat::Jpeg
            )
        })
        .with_context(|| format!("{}: not a PNG, TIFF or JPEG image", path.display()))?;
    let mut reader = image::ImageReader::open(path)
        .with_context(|| format!("{}: cannot open", path.display()))?;
    reader.set_format(format);
    let decoded = reader.decode().map_err(|e| match e {
        image::ImageError::Unsupported(e) => anyhow::anyhow!(
            "{}: the image's sample format is not supported ({e}): use 8- or 16-bit integer samples",
            path.display()
        ),
        e => anyhow::anyhow!("{}: corrupt or truncated image: {e}", path.display()),
    })?;
    if decoded.width() == 0 || decoded.height() == 0 {
        bail!("{}: the image has no pixels", path.display());
    }
    Ok(match decoded {
        image::DynamicImage::ImageLuma8(b) => LoadedImage::Eight(b),
        image::DynamicImage::ImageLuma16(b) => LoadedImage::Sixteen(b),
        other => LoadedImage::Sixteen(other.into_luma16()),
    })
}

impl Measurement {
    /// The rejected components counted per reason: "12 small, 3 shape, 1 residual" (reasons
    /// without rejections left out; "none" when nothing was rejected).
    pub fn rejection_counts(&self) -> String {
        let counts: Vec<String> = Rejection::ALL
            .iter()
            .filter_map(|&why| {
                let n = self.rejected.iter().filter(|(_, r)| *r == why).count();
                (n > 0).then(|| format!("{n} {}", why.name()))
            })
            .collect();
        if counts.is_empty() {
            "none".to_owned()
        } else {
            counts.join(", ")
        }
    }
}

/// Read and measure one image file. An image without any accepted target is an error that
/// gives the rejections per reason and, when the other polarity finds targets, says so.
pub fn measure_file(path: &Path, params: &MeasureParams) -> Result<Measurement> {
    measure_loaded_file(path, &load_image(path)?, params)
}

/// [`measure_file`] on an image already read.
pub fn measure_loaded_file(
    path: &Path,
    image: &LoadedImage,
    params: &MeasureParams,
) -> Result<Measurement> {
    let size = image.dimensions();
    if let Some(sensor) = params.sensor.filter(|&s| s != size) {
        bail!(
            "{}: the image size differs from the expected one: {} × {} pixels, the camera's \
             sensor {} × {} (a resized or cropped image?)",
            path.display(),
            size.0,
            size.1,
            sensor.0,
            sensor.1
        );
    }
    let measured = image.measure(params);
    if measured.targets.is_empty() {
        let mut other = *params;
        other.detect.polarity = match params.detect.polarity {
            detect::Polarity::Bright => detect::Polarity::Dark,
            detect::Polarity::Dark => detect::Polarity::Bright,
        };
        let found = image.measure(&other).targets.len();
        let hint = match (found, other.detect.polarity) {
            (0, _) => String::new(),
            (n, detect::Polarity::Dark) => format!("; {n} dark targets found with --dark"),
            (n, detect::Polarity::Bright) => format!("; {n} bright targets found with --bright"),
        };
        bail!(
            "{}: no targets found ({} components rejected: {}){hint}",
            path.display(),
            measured.rejected.len(),
            measured.rejection_counts()
        );
    }
    Ok(measured)
}

/// The host's identifier: up to 4096 rays, 16384 grid cells, 65535 cell entries (a 12 MP image
/// in 32-pixel cells). It is about 0.6 MB and [`Identifier::new`] builds it on the stack: build
/// it on the main thread or on one with a large stack, then box it.
pub type HostIdentifier = Identifier<f64, 4096, 16384, 65535>;

/// Build a [`HostIdentifier`] on a thread with a stack large enough for it, boxed.
pub fn host_identifier(
    rig: &deltaz_calib::reconstruct::SystemRig,
    depth: deltaz_shared::identify::DepthRange<f64>,
    tolerance: f64,
    cell: f64,
) -> Result<Box<HostIdentifier>> {
    std::thread::scope(|s| {
        std::thread::Builder::new()
            .stack_size(16 << 20)
            .spawn_scoped(s, || {
                HostIdentifier::new(rig, depth, tolerance, cell)
                    .map(Box::new)
                    .map_err(|e| anyhow::anyhow!("identification: {e}"))
            })
            .context("cannot start a thread")?
            .join()
            .map_err(|_| anyhow::anyhow!("identification: the building thread panicked"))?
    })
}

fn view<P: image::Primitive>(
    b: &image::ImageBuffer<image::Luma<P>, Vec<P>>,
    dn: f64,
) -> GrayView<'_, P> {
    GrayView {
        width: b.width() as usize,
        height: b.height() as usize,
        pixels: b.as_raw(),
        dn,
    }
}

/// The perspective bias of a circular target (no lens distortion): the centre of the imaged
/// ellipse minus the image of the circle's centre, in refined photo coordinates (mm).
///
/// The circle (centre `centre`, unit normal `normal`, radius `radius`, all in the camera system,
/// x right, y up, looking along −z) maps to the image by the plane homography H = [f e₁ f e₂ f c]
/// up to the sign of eq. (1); its image conic is C' = H⁻ᵀ diag(1, 1, −ρ²) H⁻¹ and the ellipse
/// centre is −A⁻¹ b of C' = [[A, b], [bᵀ, c]].
pub fn perspective_bias(
    f: f64,
    centre: Vector3<f64>,
    normal: Vector3<f64>,
    radius: f64,
) -> Option<Vector2<f64>> {
    let n = normal.normalize();
    let helper = if n.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = n.cross(&helper).normalize();
    let e2 = n.cross(&e1);
    // Image of a plane point s e1 + t e2 + c: (x, y) = −f (X, Y) / Z (eq. 1).
    let proj = Matrix3::new(-f, 0.0, 0.0, 0.0, -f, 0.0, 0.0, 0.0, 1.0);
    let h = proj * Matrix3::from_columns(&[e1, e2, centre]);
    let hinv = h.try_inverse()?;
    let conic =
        hinv.transpose() * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -radius * radius)) * hinv;
    let a = conic.fixed_view::<2, 2>(0, 0).into_owned();
    let b = conic.fixed_view::<2, 1>(0, 2).into_owned();
    let ellipse_centre = -(a.try_inverse()? * b);
    let image_of_centre = Vector2::new(-f * centre.x / centre.z, -f * centre.y / centre.z);
    Some(ellipse_centre - image_of_centre)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ellipse centre from densely sampled projected boundary points: the midpoints of the
    /// x and y extents (an ellipse is symmetric about its centre).
    fn sampled_bias(
        f: f64,
        centre: Vector3<f64>,
        normal: Vector3<f64>,
        radius: f64,
    ) -> Vector2<f64> {
        let n = normal.normalize();
        let e1 = n.cross(&Vector3::x()).normalize();
        let e2 = n.cross(&e1);
        let (mut lo, mut hi) = (
            Vector2::repeat(f64::INFINITY),
            Vector2::repeat(f64::NEG_INFINITY),
        );
        for k in 0..200_000 {
            let t = k as f64 * std::f64::consts::TAU / 200_000.0;
            let p = centre + radius * (t.cos() * e1 + t.sin() * e2);
            let img = Vector2::new(-f * p.x / p.z, -f * p.y / p.z);
            lo = lo.inf(&img);
            hi = hi.sup(&img);
        }
        (lo + hi) / 2.0 - Vector2::new(-f * centre.x / centre.z, -f * centre.y / centre.z)
    }

    /// The conic formula agrees with sampling, and bounds the bias at the paper's geometry:
    /// f = 46.981 mm, 45 µm pixels, Z = 1640..1840 mm, targets 20 mm across, tilted up to 45°,
    /// up to 600 mm off axis: below 0.02 pixel (and at least 0.01: the effect is real).
    #[test]
    fn perspective_bias_at_paper_geometry() {
        let f = 46.981;
        let mut worst: f64 = 0.0;
        for (x, z, tilt) in [
            (300.0, -1640.0, 0.5),
            (600.0, -1640.0, 0.785),
            (-450.0, -1840.0, 0.785),
            (0.0, -1640.0, 0.785),
        ] {
            let centre = Vector3::new(x, 0.4 * x, z);
            let normal = Vector3::new(f64::sin(tilt), 0.0, f64::cos(tilt));
            let bias = perspective_bias(f, centre, normal, 10.0).unwrap();
            let sampled = sampled_bias(f, centre, normal, 10.0);
            assert!((bias - sampled).norm() < 1e-9, "{bias} vs {sampled}");
            worst = worst.max(bias.norm() / 0.045);
        }
        println!("worst perspective bias {worst:.5} px");
        assert!(worst < 0.02 && worst > 0.01, "{worst}");
    }
}
