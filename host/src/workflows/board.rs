//! Camera calibration from views of a flat circle-grid board (`deltaz calibrate camera --board
//! SPEC --images DIR`), with no init file:
//! 1. the board's circles measured and labelled in every image ([`deltaz_measure::board`]);
//! 2. the start from the plane homographies: with the principal point at the image centre,
//!    square pixels and no skew, the image of the absolute conic is ω = diag(1/f², 1/f², 1) and
//!    every view's homography H = [h₁ h₂ h₃] gives Zhang's two constraints h₁ᵀ ω h₂ = 0 and
//!    h₁ᵀ ω h₁ = h₂ᵀ ω h₂, linear in 1/f² ([`focal_from_homographies`]); no distortion;
//! 3. the self-calibrating bundle adjustment ([`deltaz_calib::bundle`]) from there, the poses by
//!    resection, the board's circles as control points of σ `board_sigma`: its flatness and
//!    spacing errors are adjusted within that σ instead of being taken as exact.

use super::camera::{bundle_field, camera_file, camera_prior, Targets};
use super::observations::measure_images;
use crate::io::camera_file::CameraFile;
use crate::io::control::{control_csv, ControlPoint};
use crate::io::observations::{observations_csv, Observation};
use crate::report::calibration_plots::{residual_plots, write_with_plots};
use crate::report::console::Output;
use crate::report::residuals::{residuals, residuals_csv, residuals_path, Residual};
use anyhow::{bail, Context, Result};
use deltaz_calib::bundle::CalibrationOptions;
use deltaz_calib::system_adjustment::CameraPrior;
use deltaz_measure::board::{homography, Board};
use deltaz_measure::MeasureParams;
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use nalgebra::{Matrix3, Vector2};
use std::path::{Path, PathBuf};

/// The result of a board calibration.
#[derive(Debug, Clone)]
pub struct BoardCalibration {
    /// The calibrated camera.
    pub file: CameraFile,
    /// The free inner parameters and their covariance (mm, as in `file`).
    pub inner_covariance: CameraPrior,
    /// The labelled circles of every view.
    pub observations: Vec<Observation>,
    /// The board's circles as control.
    pub control: Vec<ControlPoint>,
    /// Every observation's image residual.
    pub residuals: Vec<Residual>,
    /// The starting focal length from the homographies (pixels).
    pub start_f_px: f64,
    /// The images left out (no board found), with why.
    pub failed: Vec<String>,
}

/// The focal length (pixels) from plane homographies board → image, image coordinates relative
/// to the principal point: least squares over Zhang's two constraints per view (see the
/// module's doc). `None` when the views do not determine it (fronto-parallel or too few).
pub fn focal_from_homographies(hs: &[Matrix3<f64>]) -> Option<f64> {
    // Each constraint reads a w + b = 0 with w = 1/f².
    let (mut aa, mut ab) = (0.0, 0.0);
    for h in hs {
        let h = h / h.column(0).norm().max(h.column(1).norm());
        let (h1, h2) = (h.column(0), h.column(1));
        for (a, b) in [
            (h1[0] * h2[0] + h1[1] * h2[1], h1[2] * h2[2]),
            (
                h1[0] * h1[0] + h1[1] * h1[1] - h2[0] * h2[0] - h2[1] * h2[1],
                h1[2] * h1[2] - h2[2] * h2[2],
            ),
        ] {
            aa += a * a;
            ab += a * b;
        }
    }
    let w = -ab / aa;
    (aa > 0.0 && w > 0.0 && w.is_finite()).then(|| 1.0 / w.sqrt())
}

/// The image files (PNG, TIFF, JPEG by extension) of a folder, sorted by name.
fn image_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("{}: cannot read the folder", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                matches!(
                    e.to_ascii_lowercase().as_str(),
                    "png" | "tif" | "tiff" | "jpg" | "jpeg"
                )
            })
        })
        .collect();
    files.sort();
    if files.is_empty() {
        bail!("{}: no PNG, TIFF or JPEG images", dir.display());
    }
    Ok(files)
}

/// Calibrate a camera from the board views in `dir` (see the module's doc). `params` gives the
/// detection settings (its board is replaced by `board`); pixel coordinates become photo
/// coordinates with `pixel_size` (mm) about the image centre.
pub fn calibrate_board(
    dir: &Path,
    board: &Board,
    params: &MeasureParams,
    pixel_size: f64,
    board_sigma: f64,
    options: &CalibrationOptions,
) -> Result<BoardCalibration> {
    let files = image_files(dir)?;
    let (width, height) = image::image_dimensions(&files[0])
        .with_context(|| format!("{}: cannot read", files[0].display()))?;
    for f in &files[1..] {
        let size =
            image::image_dimensions(f).with_context(|| format!("{}: cannot read", f.display()))?;
        if size != (width, height) {
            bail!(
                "{}: {}x{} pixels, but {} has {width}x{height}: one camera, one image size",
                f.display(),
                size.0,
                size.1,
                files[0].display()
            );
        }
    }
    let measured = measure_images(
        &files,
        &MeasureParams {
            board: Some(*board),
            ..*params
        },
        None,
    )?;
    let observations = measured.observations;
    let grid = PixelGrid {
        pixel_size,
        width,
        height,
        origin_col: (f64::from(width) - 1.0) / 2.0,
        origin_row: (f64::from(height) - 1.0) / 2.0,
    };
    let control: Vec<ControlPoint> = board
        .circles()
        .map(|(r, c)| ControlPoint {
            point: Board::name(r, c),
            xyz: board.position(r, c),
            sigma: board_sigma,
        })
        .collect();
    let position: std::collections::HashMap<&str, Vector2<f64>> = control
        .iter()
        .map(|c| (c.point.as_str(), c.xyz.xy()))
        .collect();
    let mut views: Vec<&str> = observations.iter().map(|o| o.image.as_str()).collect();
    views.dedup();
    let homographies: Vec<Matrix3<f64>> = views
        .iter()
        .filter_map(|v| {
            let pairs: Vec<(Vector2<f64>, Vector2<f64>)> = observations
                .iter()
                .filter(|o| o.image == *v)
                .map(|o| {
                    (
                        position[o.point.as_str()],
                        Vector2::new(o.col - grid.origin_col, o.row - grid.origin_row),
                    )
                })
                .collect();
            homography(&pairs)
        })
        .collect();
    if homographies.len() < 3 {
        bail!(
            "{}: the board was found in {} image(s); calibration needs at least 3 views{}",
            dir.display(),
            homographies.len(),
            if measured.failed.is_empty() {
                String::new()
            } else {
                format!(" ({})", measured.failed.join("; "))
            }
        );
    }
    let start_f_px = focal_from_homographies(&homographies).with_context(|| {
        format!(
            "{}: the views do not determine the focal length (all nearly fronto-parallel?)",
            dir.display()
        )
    })?;
    let inner = InnerOrientation::ideal(start_f_px * pixel_size);
    let views = Targets {
        path: dir,
        observations: &observations,
        control: &control,
    };
    let calibration = bundle_field(&grid, &inner, views, options)?;
    Ok(BoardCalibration {
        file: camera_file(&calibration, &observations),
        inner_covariance: camera_prior(&calibration),
        residuals: residuals(&calibration, &observations),
        observations,
        control,
        start_f_px,
        failed: measured.failed,
    })
}

impl BoardCalibration {
    /// Writes the camera file `out` with, next to it, the labelled circles (`*.obs.csv`), the
    /// board as control (`*.control.csv`) and every residual (`*.residuals.csv`), and with
    /// `plots` the residual plots there: all or nothing.
    pub fn write(&self, out: &Path, plots: Option<&Path>, output: Output) -> Result<()> {
        let [width, height] = self.file.image_size;
        let (obs_path, control_path) = (
            out.with_extension("obs.csv"),
            out.with_extension("control.csv"),
        );
        let obs_csv = observations_csv(&self.observations);
        let control_csv = control_csv(&self.control);
        let json = serde_json::to_string_pretty(&self.file)? + "\n";
        let residuals_csv = residuals_csv(&self.residuals);
        let residuals_path = residuals_path(out);
        let files = [
            (obs_path.as_path(), obs_csv.as_bytes()),
            (control_path.as_path(), control_csv.as_bytes()),
            (out, json.as_bytes()),
            (residuals_path.as_path(), residuals_csv.as_bytes()),
        ];
        let make = || residual_plots(&self.residuals, width, height);
        write_with_plots(&files, plots, make, output)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    /// The focal length from exact homographies of tilted views of a plane.
    #[test]
    fn focal_from_views() {
        let f = 812.0;
        let k = Matrix3::new(f, 0.0, 0.0, 0.0, f, 0.0, 0.0, 0.0, 1.0);
        let hs: Vec<Matrix3<f64>> = [(0.3, 0.1, 0.2), (-0.2, 0.35, -0.1), (0.1, -0.3, 0.4)]
            .iter()
            .map(|&(a, b, c)| {
                let r = Rotation3::from_euler_angles(a, b, c);
                let t = Vector3::new(20.0, -10.0, 400.0);
                k * Matrix3::from_columns(&[
                    r.matrix().column(0).into(),
                    r.matrix().column(1).into(),
                    t,
                ])
            })
            .collect();
        let got = focal_from_homographies(&hs).unwrap();
        assert!((got - f).abs() < 1e-6 * f, "{got}");
    }
}
