//! Images → observations: image files measured into observations ([`measure_images`]: targets,
//! board circles or identified dots) and, with no hand work, image folders into labelled
//! observations: control targets by the known layout ([`deltaz_measure::layout`]) and, on plate
//! images, the projected dots by the pattern's grid walk from its marker dot
//! ([`deltaz_measure::grid`]).
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

use crate::io::atomic::write_atomic;
use crate::io::control::read_control;
use crate::io::observations::{write_observations, Observation, PointKind};
use crate::report::console::Output;
use crate::simulate::pattern::PatternSpec;
use anyhow::{bail, Context, Result};
use deltaz_measure::board::Board;
use deltaz_measure::grid::walk_grid;
use deltaz_measure::layout::{match_layout, Blob, Layout};
use deltaz_measure::target_field::CONTROL_SUFFIX;
use deltaz_measure::{
    load_image, measure_file, measure_loaded_file, HostIdentifier, MeasureParams, Measurement,
};
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::Camera;
use deltaz_shared::identify::Assignment;
use nalgebra::Vector2;
use std::path::{Path, PathBuf};

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
    /// Distinct targets (labels); `None` for [`deltaz_measure::target_field::distinct_targets`]'s
    /// rule.
    pub distinct: Option<Vec<String>>,
    /// Matching tolerance (px).
    pub tolerance_px: f64,
    /// The targets' polarity.
    pub polarity: deltaz_measure::detect::Polarity,
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
    output: Output,
) -> Result<PathBuf> {
    let control = read_control(&args.control)?;
    let points: Vec<_> = control.iter().map(|c| (c.point.clone(), c.xyz)).collect();
    let layout = match &args.distinct {
        Some(labels) => Layout::new(points, labels),
        None => Layout::with_default_distinct(points),
    }
    .map_err(|e| anyhow::anyhow!("{}: {e}", args.control.display()))?;
    let paths = image_files(&args.dir, &args.prefix)?;
    // An image of another size (resized, cropped) is refused as such, before its targets are
    // matched against a layout projected for the sensor.
    let mut params = MeasureParams {
        sensor: Some((grid.width, grid.height)),
        ..MeasureParams::default()
    };
    params.detect.polarity = args.polarity;
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
    write_observations(&path, &found.observations)?;
    output.status(format!(
        "{} observations in {} images -> {}",
        found.observations.len(),
        paths.len(),
        path.display()
    ));
    Ok(path)
}
/// Observations of measured images, and a line for every dot that identification left out.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MeasuredImages {
    /// Without identification: every target as `m1`, `m2`, ... (kind `control`); with it: the
    /// identified dots (kind `dot`, point = ray id).
    pub observations: Vec<Observation>,
    /// "image mK (col, row): why" for each ambiguous, conflicting or unassigned dot.
    pub unidentified: Vec<String>,
    /// One line per measured image: what was found in it (with identification: how many dots
    /// were identified, and why the others were not).
    pub summaries: Vec<String>,
    /// One error per image without targets or board (the others are measured all the same).
    pub failed: Vec<String>,
}

/// Measure image files into observations: image label = file stem, point label = `m` + the
/// target's number in the image (1-based, in row-major order of the targets' boxes), or with an
/// identifier the dot's ray id. An image without targets (or, with a board, without the board)
/// is reported in `failed` and the others are measured; an image that cannot be read and two
/// images with one label are errors.
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
        let image = load_image(path)?;
        let measured = match measure_loaded_file(path, &image, params) {
            Ok(m) => m,
            Err(e) => {
                out.failed.push(format!("{e:#}"));
                continue;
            }
        };
        let targets = measured.targets.len();
        if let Some(board) = params.board {
            match board_observations(path, &label, &board, &measured) {
                Ok(found) => {
                    out.summaries.push(format!(
                        "{label}: {targets} targets, {} circles of the board",
                        found.len()
                    ));
                    out.observations.extend(found);
                }
                Err(e) => out.failed.push(format!("{e:#}")),
            }
            continue;
        }
        let Some(identifier) = identifier else {
            for (k, t) in measured.targets.iter().enumerate() {
                let name = format!("m{}", k + 1);
                out.observations
                    .push(Observation::target(&label, &name, t.col, t.row));
            }
            out.summaries.push(format!("{label}: {targets} targets"));
            continue;
        };
        let dots: Vec<(f64, f64)> = measured.targets.iter().map(|t| (t.col, t.row)).collect();
        let mut assigned = vec![Assignment::Unassigned; dots.len()];
        identifier.identify_frame(&dots, &mut assigned);
        out.summaries
            .push(format!("{label}: {}", identification_summary(&assigned)));
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

/// What identification made of an image's dots, every dot counted once: "440 dots: 352
/// identified, 88 not (50 ambiguous, 3 conflicts, 35 with no epipolar segment within
/// tolerance)".
pub fn identification_summary<T>(assigned: &[Assignment<T>]) -> String {
    let count = |f: fn(&Assignment<T>) -> bool| assigned.iter().filter(|a| f(a)).count();
    let identified = count(|a| matches!(a, Assignment::Ray { .. }));
    let ambiguous = count(|a| matches!(a, Assignment::Ambiguous { .. }));
    let conflicts = count(|a| matches!(a, Assignment::Conflict { .. }));
    let unassigned = count(|a| matches!(a, Assignment::Unassigned));
    format!(
        "{} dots: {identified} identified, {} not ({ambiguous} ambiguous, {conflicts} conflicts, \
         {unassigned} with no epipolar segment within tolerance)",
        assigned.len(),
        ambiguous + conflicts + unassigned
    )
}

/// The circles of a board among an image's targets, as observations named `rIcJ`.
fn board_observations(
    path: &Path,
    label: &str,
    board: &Board,
    measured: &Measurement,
) -> Result<Vec<Observation>> {
    let centres: Vec<Vector2<f64>> = measured
        .targets
        .iter()
        .map(|t| Vector2::new(t.col, t.row))
        .collect();
    let radii: Vec<f64> = measured
        .targets
        .iter()
        .map(|t| (t.blob.area as f64).sqrt())
        .collect();
    let (width, height) = image::image_dimensions(path)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    let found = board
        .find(&centres, &radii, width as usize, height as usize)
        .with_context(|| path.display().to_string())?;
    Ok(found
        .iter()
        .map(|p| {
            let t = &measured.targets[p.target];
            Observation::target(label, &Board::name(p.row, p.col), t.col, t.row)
        })
        .collect())
}

/// The observations file `--images` writes next to `--out` before calibrating: unless the
/// calibration succeeds ([`ObservationsGuard::keep`]), it is put back as it was (removed, or its
/// former content), so that a failed run leaves no file created or changed.
pub struct ObservationsGuard {
    path: PathBuf,
    before: Option<Vec<u8>>,
}

impl ObservationsGuard {
    /// Remembers the observations file next to `out` as it is now.
    pub fn new(out: &Path) -> Self {
        let path = observations_path(out);
        let before = std::fs::read(&path).ok();
        Self { path, before }
    }

    /// The calibration succeeded: the file stays.
    pub fn keep(mut self) {
        self.before = std::fs::read(&self.path).ok();
    }
}

impl Drop for ObservationsGuard {
    fn drop(&mut self) {
        let now = std::fs::read(&self.path).ok();
        if now != self.before {
            let _ = match &self.before {
                Some(bytes) => write_atomic(&self.path, bytes).map_err(|_| ()),
                None => std::fs::remove_file(&self.path).map_err(|_| ()),
            };
        }
    }
}
