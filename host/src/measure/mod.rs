//! Image measurement: synthetic target images ([`render`]), blob detection ([`detect`]) and
//! sub-pixel centres ([`fit`]), put together by [`measure`].
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

pub mod bench;
pub mod detect;
pub mod fit;
pub mod grid;
pub mod identify_images;
pub mod layout;
pub mod render;

use crate::io::observations::{Observation, PointKind};
use anyhow::{bail, Context, Result};
use deltaz_shared::identify::{Assignment, Identifier};
use detect::{
    check_shape, components, noise_sigma, BackgroundField, Blob, DetectParams, GrayView, Rejection,
};
use nalgebra::{Matrix3, Vector2, Vector3};
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
    /// The calibration's sensor (width, height in pixels), when measuring for a calibrated
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
pub fn measure<P: Copy + Into<f64> + Sync>(
    img: &GrayView<P>,
    params: &MeasureParams,
) -> Measurement {
    let d = &params.detect;
    let background = BackgroundField::estimate(img, d.polarity, d.tile);
    // Quantisation alone gives σ ≥ 1/√12 DN.
    let sigma = noise_sigma(img).max(0.29 * img.dn);
    let threshold = (d.k_sigma * sigma).max(d.min_contrast * img.dn);
    let blobs = components(img, d.polarity, &background, threshold);
    let grown: Vec<[usize; 4]> = blobs
        .iter()
        .map(|b| {
            let g = 2;
            [
                b.bbox[0].saturating_sub(g),
                b.bbox[1].saturating_sub(g),
                b.bbox[2] + g,
                b.bbox[3] + g,
            ]
        })
        .collect();
    // The grown boxes by their first row, to find a window's neighbours by binary search.
    let mut by_top: Vec<usize> = (0..grown.len()).collect();
    by_top.sort_unstable_by_key(|&j| grown[j][1]);
    let tops: Vec<usize> = by_top.iter().map(|&j| grown[j][1]).collect();
    let tallest = grown.iter().map(|g| g[3] - g[1]).max().unwrap_or(0);
    // One blob's verdict: shape tests, then the centre.
    let centre =
        |scratch: &mut Scratch, i: usize| -> std::result::Result<Target, (Blob, Rejection)> {
            let blob = &blobs[i];
            if let Some(why) = check_shape(blob, d, img.width, img.height) {
                return Err((*blob, why));
            }
            let (gc, gr) = blob.gravity;
            if params.method == CentreMethod::Gravity {
                return Ok(Target {
                    col: gc,
                    row: gr,
                    blob: *blob,
                    fit: None,
                });
            }
            let m = params.margin;
            let window = [
                blob.bbox[0].saturating_sub(m),
                blob.bbox[1].saturating_sub(m),
                blob.bbox[2] + m,
                blob.bbox[3] + m,
            ];
            let first = tops.partition_point(|&t| t + tallest < window[1]);
            let last = tops.partition_point(|&t| t <= window[3]);
            scratch.exclude.clear();
            scratch.exclude.extend(
                by_top[first..last]
                    .iter()
                    .filter(|&&j| {
                        let g = &grown[j];
                        j != i
                            && g[0] <= window[2]
                            && g[2] >= window[0]
                            && g[1] <= window[3]
                            && g[3] >= window[1]
                    })
                    .map(|&j| grown[j]),
            );
            let background = background.at(gc, gr);
            let Scratch { exclude, fit } = scratch;
            fit::fit_template(img, d.polarity, blob, background, m, exclude, fit)
                .filter(|f| {
                    let allowed = params.max_rms_sigma * sigma.max(img.dn)
                        + params.max_rms_fraction * f.amplitude;
                    let moved = (f.col - gc).hypot(f.row - gr);
                    f.rms <= allowed && moved <= params.max_centre_shift
                })
                .map(|f| Target {
                    col: f.col,
                    row: f.row,
                    blob: *blob,
                    fit: Some(f),
                })
                .ok_or((*blob, Rejection::Fit))
        };
    // The blobs are independent: spread them over the cores, keep their order.
    let verdicts = crate::parallel::parallel_map(blobs.len(), centre);
    let mut targets = Vec::new();
    let mut rejected = Vec::new();
    for verdict in verdicts {
        match verdict {
            Ok(t) => targets.push(t),
            Err(r) => rejected.push(r),
        }
    }
    Measurement {
        targets,
        rejected,
        noise_sigma: sigma / img.dn,
    }
}

/// A measuring thread's reused buffers: the neighbours' boxes and the fit's window.
#[derive(Default)]
struct Scratch {
    exclude: Vec<[usize; 4]>,
    fit: fit::Scratch,
}

/// A decoded image: 8- and 16-bit grayscale are kept as decoded; colour is converted to 16-bit
/// luma (one copy).
pub enum LoadedImage {
    /// 8-bit samples.
    Eight(image::ImageBuffer<image::Luma<u8>, Vec<u8>>),
    /// 16-bit samples.
    Sixteen(image::ImageBuffer<image::Luma<u16>, Vec<u16>>),
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
    let decoded = reader
        .decode()
        .map_err(|e| anyhow::anyhow!("{}: corrupt or truncated image: {e}", path.display()))?;
    if decoded.width() == 0 || decoded.height() == 0 {
        bail!("{}: the image has no pixels", path.display());
    }
    Ok(match decoded {
        image::DynamicImage::ImageLuma8(b) => LoadedImage::Eight(b),
        image::DynamicImage::ImageLuma16(b) => LoadedImage::Sixteen(b),
        other => LoadedImage::Sixteen(other.into_luma16()),
    })
}

/// Read and measure one image file; an image without any accepted target, or of another size
/// than [`MeasureParams::sensor`], is an error.
pub fn measure_file(path: &Path, params: &MeasureParams) -> Result<Measurement> {
    let image = load_image(path)?;
    let size = match &image {
        LoadedImage::Eight(b) => b.dimensions(),
        LoadedImage::Sixteen(b) => b.dimensions(),
    };
    if let Some(sensor) = params.sensor.filter(|&s| s != size) {
        bail!(
            "{}: the image is {} × {} pixels, the calibration's sensor {} × {}",
            path.display(),
            size.0,
            size.1,
            sensor.0,
            sensor.1
        );
    }
    let measured = match image {
        LoadedImage::Eight(b) => measure(&view(&b, 1.0), params),
        LoadedImage::Sixteen(b) => measure(&view(&b, 257.0), params),
    };
    if measured.targets.is_empty() {
        bail!(
            "{}: no targets found ({} components rejected)",
            path.display(),
            measured.rejected.len()
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
    rig: &crate::system::SystemRig,
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

/// Observations of measured images, and a line for every dot that identification left out.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MeasuredImages {
    /// Without identification: every target as `m1`, `m2`, ... (kind `control`); with it: the
    /// identified dots (kind `dot`, point = ray id).
    pub observations: Vec<Observation>,
    /// "image mK (col, row): why" for each ambiguous, conflicting or unassigned dot.
    pub unidentified: Vec<String>,
}

/// Measure image files into observations: image label = file stem, point label = `m` + the
/// target's number in the image (1-based, in row-major order of the targets' boxes), or with an
/// identifier the dot's ray id. Stops at the first image that cannot be read or has no targets.
pub fn measure_images(
    paths: &[std::path::PathBuf],
    params: &MeasureParams,
    identifier: Option<&HostIdentifier>,
) -> Result<MeasuredImages> {
    let mut out = MeasuredImages::default();
    let mut labels = std::collections::HashSet::new();
    for path in paths {
        let label = path
            .file_stem()
            .and_then(|s| s.to_str())
            .with_context(|| format!("{}: no usable file name", path.display()))?
            .to_owned();
        if !labels.insert(label.clone()) {
            bail!("{}: a second image labelled {label}", path.display());
        }
        let measured = measure_file(path, params)?;
        let Some(identifier) = identifier else {
            for (k, t) in measured.targets.iter().enumerate() {
                let name = format!("m{}", k + 1);
                out.observations
                    .push(Observation::target(&label, &name, t.col, t.row));
            }
            continue;
        };
        let dots: Vec<(f64, f64)> = measured.targets.iter().map(|t| (t.col, t.row)).collect();
        let mut assigned = vec![Assignment::Unassigned; dots.len()];
        identifier.identify_frame(&dots, &mut assigned);
        for (k, (&(col, row), a)) in dots.iter().zip(&assigned).enumerate() {
            let why = match a {
                Assignment::Ray { id, .. } => {
                    let mut o = Observation::target(&label, &id.to_string(), col, row);
                    o.kind = PointKind::Dot;
                    out.observations.push(o);
                    continue;
                }
                Assignment::Ambiguous { first, second } => {
                    format!("ambiguous between rays {first} and {second}")
                }
                Assignment::Conflict { id } => format!("ray {id} claimed by another dot too"),
                Assignment::Unassigned => "no ray's epipolar segment within tolerance".to_owned(),
            };
            out.unidentified
                .push(format!("{label} m{} ({col:.2}, {row:.2}): {why}", k + 1));
        }
    }
    Ok(out)
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
