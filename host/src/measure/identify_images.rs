//! From image folders to labelled observations with no hand work: control targets by the known
//! layout ([`super::layout`]) and, on plate images, the projected dots by the pattern's grid walk
//! from its marker dot ([`super::grid`]).
//!
//! On a plate image the control targets and the projected dots are told apart by the layout
//! match: every blob within the tolerance of a projected control point (matched or not) is a
//! target; the others are dots. With the projector's dots on it, most control targets of the
//! paper plate merge with a dot (dot pitch about 35 px, targets 10-16 px across) and fail the
//! shape tests; so a plate is best also taken with the projector off (`p1_control.png` beside
//! `p1.png`, same pose): the control targets are then measured there. Without it the control
//! comes from the dot image itself. The marker is the largest of the dots, and it must be at least
//! [`MARKER_AREA_RATIO`] times the median dot's area (the simulator draws it 1.7 times larger in
//! diameter, 2.9 times in area).

use super::grid::walk_grid;
use super::layout::{match_layout, Blob, Layout};
use super::{measure_file, MeasureParams, Measurement};
use crate::io::observations::{Observation, PointKind};
use crate::pattern::PatternSpec;
use anyhow::{bail, Context, Result};
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::Camera;
use nalgebra::Vector2;
use std::path::{Path, PathBuf};

use crate::target_field::CONTROL_SUFFIX;

/// How much larger (in area) than the median dot the marker must be.
pub const MARKER_AREA_RATIO: f64 = 1.8;

/// The image files (PNG, TIFF, JPEG by extension) of a folder whose names start with `prefix`,
/// sorted by name, without the projector-off images ([`CONTROL_SUFFIX`]); an error if there
/// are none.
pub fn image_files(dir: &Path, prefix: &str) -> Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("{}: cannot read the folder", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            let ext = p
                .extension()
                .and_then(|e| e.to_str())
                .map(str::to_ascii_lowercase);
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
            matches!(
                ext.as_deref(),
                Some("png" | "tif" | "tiff" | "jpg" | "jpeg")
            ) && name.starts_with(prefix)
                && !p
                    .file_stem()
                    .and_then(|s| s.to_str())
                    .is_some_and(|s| s.ends_with(CONTROL_SUFFIX))
        })
        .collect();
    files.sort();
    if files.is_empty() {
        bail!(
            "{}: no PNG, TIFF or JPEG images{}",
            dir.display(),
            if prefix.is_empty() {
                String::new()
            } else {
                format!(" named {prefix}*")
            }
        );
    }
    Ok(files)
}

/// The projected pattern as the grid walk needs it.
#[derive(Debug, Clone, PartialEq)]
pub struct DotGrid {
    /// The pattern (grid size and node → ray id).
    pub pattern: PatternSpec,
    /// The marker's node (row, column).
    pub marker: (u16, u16),
    /// Approximate image direction (col, row) in which the column index grows.
    pub col_dir: Vector2<f64>,
    /// Approximate image direction in which the row index grows.
    pub row_dir: Vector2<f64>,
}

/// What was found in one image.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageReport {
    /// Image label (file stem).
    pub image: String,
    /// Accepted blobs.
    pub blobs: usize,
    /// Control points the final pose projects into the image.
    pub expected: usize,
    /// Control points identified.
    pub identified: usize,
    /// Residual RMS (px) of the identified targets under the given inner orientation.
    pub rms_px: f64,
    /// Dots labelled by the grid walk.
    pub dots: usize,
    /// Dot blobs the walk could not label.
    pub dots_unlabelled: usize,
}

impl std::fmt::Display for ImageReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: {} blobs, {} of {} control targets identified ({:.2} px RMS)",
            self.image, self.blobs, self.identified, self.expected, self.rms_px
        )?;
        if self.dots + self.dots_unlabelled > 0 {
            write!(
                f,
                ", {} dots labelled, {} not",
                self.dots, self.dots_unlabelled
            )?;
        }
        Ok(())
    }
}

/// Labelled observations of a set of images, and a report per image.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct IdentifiedImages {
    /// Control targets (kind `control`, the control label) and, with a dot grid, dots (kind
    /// `dot`, point = ray id).
    pub observations: Vec<Observation>,
    /// One report per image.
    pub reports: Vec<ImageReport>,
}

/// Measure and identify every image: control targets by `layout` (with the inner orientation
/// `inner`, approximate for a camera calibration), and with `dots` the projected dots. An image
/// that cannot be read, has no targets or cannot be matched is an error naming it.
pub fn identify_images(
    paths: &[PathBuf],
    params: &MeasureParams,
    layout: &Layout,
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    tolerance_px: f64,
    dots: Option<&DotGrid>,
) -> Result<IdentifiedImages> {
    let mut out = IdentifiedImages::default();
    for path in paths {
        let label = path
            .file_stem()
            .and_then(|s| s.to_str())
            .with_context(|| format!("{}: no usable file name", path.display()))?
            .to_owned();
        if out.reports.iter().any(|r| r.image == label) {
            bail!("{}: a second image labelled {label}", path.display());
        }
        let measured = measure_file(path, params)?;
        // A projector-off image of the same plate, if there is one, carries the control.
        let control = match control_image(path) {
            Some(c) if dots.is_some() => Some(measure_file(&c, params)?),
            _ => None,
        };
        let report = identify_measurement(
            &label,
            control.as_ref().unwrap_or(&measured),
            &measured,
            layout,
            grid,
            inner,
            tolerance_px,
            dots,
            &mut out.observations,
        )
        .with_context(|| {
            if dots.is_some() && control.is_none() {
                format!(
                    "{} (no projector-off image {label}{CONTROL_SUFFIX} beside it: its dots may cover the control targets)",
                    path.display()
                )
            } else {
                format!("{}", path.display())
            }
        })?;
        out.reports.push(report);
    }
    Ok(out)
}

/// The projector-off sibling of an image (`p1.png` → `p1_control.png`), if it exists.
fn control_image(path: &Path) -> Option<PathBuf> {
    let stem = path.file_stem()?.to_str()?;
    let ext = path.extension()?.to_str()?;
    let sibling = path.with_file_name(format!("{stem}{CONTROL_SUFFIX}.{ext}"));
    sibling.is_file().then_some(sibling)
}

/// One measured image: its observations appended to `observations`. The control targets are
/// taken from `measured` (the projector-off image where there is one), the dots from
/// `dot_image`.
#[allow(clippy::too_many_arguments)]
pub fn identify_measurement(
    label: &str,
    measured: &Measurement,
    dot_image: &Measurement,
    layout: &Layout,
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    tolerance_px: f64,
    dots: Option<&DotGrid>,
    observations: &mut Vec<Observation>,
) -> Result<ImageReport> {
    let blobs = target_blobs(measured);
    let rejected: Vec<Blob> = measured
        .rejected
        .iter()
        .map(|(b, _)| Blob {
            centre: Vector2::new(b.gravity.0, b.gravity.1),
            area: b.area as f64,
        })
        .collect();
    let matched = match_layout(layout, &blobs, &rejected, grid, inner, tolerance_px)
        .map_err(|e| anyhow::anyhow!("control layout: {e}"))?;
    for (b, p) in blobs.iter().zip(&matched.labels) {
        if let Some(p) = p {
            observations.push(Observation::target(
                label,
                &layout.points[*p].0,
                b.centre.x,
                b.centre.y,
            ));
        }
    }
    let mut report = ImageReport {
        image: label.to_owned(),
        blobs: blobs.len(),
        expected: matched.expected,
        identified: matched.matched,
        rms_px: matched.rms_px,
        dots: 0,
        dots_unlabelled: 0,
    };
    let Some(dot_grid) = dots else {
        return Ok(report);
    };
    // Everything near a projected control point is a target, the rest are dots.
    let camera = Camera {
        grid: *grid,
        inner: *inner,
        exterior: matched.exterior,
    };
    let projected: Vec<Vector2<f64>> = layout
        .points
        .iter()
        .filter_map(|(_, xyz)| camera.world_to_pixel(xyz).ok())
        .map(|(c, r)| Vector2::new(c, r))
        .collect();
    let dot_image_blobs = target_blobs(dot_image);
    let dot_blobs: Vec<&Blob> = dot_image_blobs
        .iter()
        .filter(|b| {
            projected
                .iter()
                .all(|p| (p - b.centre).norm() > tolerance_px)
        })
        .collect();
    let centres: Vec<Vector2<f64>> = dot_blobs.iter().map(|b| b.centre).collect();
    let marker = (0..dot_blobs.len())
        .max_by(|&a, &b| dot_blobs[a].area.total_cmp(&dot_blobs[b].area))
        .context("no projected dots")?;
    // The marker must stand out (a marker merged with a target would leave an ordinary dot as
    // the largest, and the walk would label every dot wrongly).
    let mut areas: Vec<f64> = dot_blobs.iter().map(|b| b.area).collect();
    areas.sort_by(f64::total_cmp);
    let median = areas[areas.len() / 2];
    if dot_blobs[marker].area < MARKER_AREA_RATIO * median {
        bail!(
            "the marker dot is not found: the largest dot ({} px) is not {MARKER_AREA_RATIO} times the median dot ({median} px)",
            dot_blobs[marker].area
        );
    }
    let pattern = &dot_grid.pattern;
    let nodes = walk_grid(
        &centres,
        marker,
        (i32::from(dot_grid.marker.0), i32::from(dot_grid.marker.1)),
        dot_grid.col_dir,
        dot_grid.row_dir,
        (i32::from(pattern.rows), i32::from(pattern.cols)),
    );
    for (c, node) in centres.iter().zip(&nodes) {
        let Some((r, col)) = node else {
            report.dots_unlabelled += 1;
            continue;
        };
        let id = pattern.id(*r as u16, *col as u16);
        let mut o = Observation::target(label, &id.to_string(), c.x, c.y);
        o.kind = PointKind::Dot;
        observations.push(o);
        report.dots += 1;
    }
    Ok(report)
}

/// What `deltaz calibrate camera|projector --images DIR` needs to turn a folder into
/// observations.
#[derive(Debug, Clone)]
pub struct FolderArgs {
    /// The folder.
    pub dir: PathBuf,
    /// Only the images whose file names start with this.
    pub prefix: String,
    /// The control file: the layout.
    pub control: PathBuf,
    /// Distinct targets (labels); `None` for [`super::layout::distinct_targets`]'s rule.
    pub distinct: Option<Vec<String>>,
    /// Matching tolerance (px).
    pub tolerance_px: f64,
}

/// The accepted targets of a measured image as layout blobs (fitted centre, pixel area).
fn target_blobs(measured: &Measurement) -> Vec<Blob> {
    measured
        .targets
        .iter()
        .map(|t| Blob {
            centre: Vector2::new(t.col, t.row),
            area: t.blob.area as f64,
        })
        .collect()
}

/// The observations file written next to `out` for inspection: `camera.json` →
/// `camera.obs.csv`.
pub fn observations_path(out: &Path) -> PathBuf {
    out.with_extension("obs.csv")
}

/// Measure and identify a folder's images (each of the sensor's size in `grid`), say a line per
/// image on stderr, and write the observations (atomically) next to `out`; returns that file's
/// path.
pub fn folder_observations(
    args: &FolderArgs,
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    dots: Option<&DotGrid>,
    out: &Path,
    output: crate::cli::Output,
) -> Result<PathBuf> {
    let control = crate::io::control::read_control(&args.control)?;
    let points: Vec<_> = control.iter().map(|c| (c.point.clone(), c.xyz)).collect();
    let layout = match &args.distinct {
        Some(labels) => Layout::new(points, labels),
        None => Layout::with_default_distinct(points),
    }
    .map_err(|e| anyhow::anyhow!("{}: {e}", args.control.display()))?;
    let paths = image_files(&args.dir, &args.prefix)?;
    // An image of another size (resized, cropped) is refused as such, before its targets are
    // matched against a layout projected for the sensor.
    let params = MeasureParams {
        sensor: Some((grid.width, grid.height)),
        ..MeasureParams::default()
    };
    let found = identify_images(
        &paths,
        &params,
        &layout,
        grid,
        inner,
        args.tolerance_px,
        dots,
    )?;
    for r in &found.reports {
        output.status(r);
    }
    let path = observations_path(out);
    crate::io::observations::write_observations(&path, &found.observations)?;
    output.status(format!(
        "{} observations in {} images -> {}",
        found.observations.len(),
        paths.len(),
        path.display()
    ));
    Ok(path)
}
