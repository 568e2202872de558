//! OpenCV's camera file (`deltaz export opencv`): a calibration as the YAML that
//! `cv2.FileStorage` reads, with the names of OpenCV's calibration sample: `image_width`, `image_height`,
//! `camera_matrix`, `distortion_coefficients` (k1, k2, p1, p2, k3) and `extrinsic_parameters`
//! (one row `rvec | tvec` per image).
//!
//! Three conventions differ and are converted here:
//! - Axes: deltaz's camera looks along −z with y up (eq. 1); OpenCV's looks along +z with y down.
//!   x_cv = D x_cam with D = diag(1, −1, −1), so R_cv = D R and t_cv = −D R X0 (eq. 2, 3).
//! - Distortion: deltaz corrects observed coordinates (observed → refined, Brown-Conrady in mm);
//!   OpenCV distorts ideal ones (ideal → observed, in focal-length units). The OpenCV
//!   coefficients are refitted by linear least squares over a grid covering the sensor; the
//!   largest remaining difference over that grid is reported in pixels.
//! - RMS: deltaz's `rms_px` is per coordinate; OpenCV's reprojection error is per point
//!   (√2 times larger for the same residuals). Both are written, named.

use super::camera_file::read_camera;
use super::system_file::SystemFile;
use anyhow::{Context, Result};
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::ExteriorOrientation;
use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, UnitQuaternion, Vector2, Vector3};
use std::path::Path;

/// Samples per image side of the distortion refit.
const REFIT_SAMPLES: u32 = 41;

/// A camera in OpenCV's conventions.
#[derive(Debug, Clone, PartialEq)]
pub struct OpenCvCamera {
    /// Image width (px).
    pub width: u32,
    /// Image height (px).
    pub height: u32,
    /// fx, fy (px).
    pub focal_px: [f64; 2],
    /// cx, cy (px, OpenCV's pixel coordinates: (0, 0) the centre of the top-left pixel).
    pub principal_px: [f64; 2],
    /// k1, k2, p1, p2, k3 of OpenCV's model.
    pub distortion: [f64; 5],
    /// The largest difference between OpenCV's model with these coefficients and deltaz's
    /// over the sensor (px).
    pub refit_max_px: f64,
    /// Image label and `rvec | tvec` (rad, mm) per image.
    pub extrinsics: Vec<(String, [f64; 6])>,
    /// deltaz's residual RMS per coordinate (px), if the file has one.
    pub rms_px: Option<f64>,
}

impl OpenCvCamera {
    /// The intrinsics of a deltaz camera, its distortion refitted to OpenCV's model.
    pub fn new(grid: &PixelGrid<f64>, inner: &InnerOrientation<f64>) -> Self {
        Self::refitted(grid, inner, [true; 5])
    }

    /// As [`new`](Self::new) with only the `free` ones of OpenCV's k1, k2, p1, p2, k3 refitted
    /// (the others zero): the OpenCV camera to compare with a `calibrateCamera` that estimated
    /// those.
    pub fn refitted(grid: &PixelGrid<f64>, inner: &InnerOrientation<f64>, free: [bool; 5]) -> Self {
        let s = grid.pixel_size;
        let focal = inner.f / s;
        let principal = [
            grid.origin_col + inner.cx / s,
            grid.origin_row - inner.cy / s,
        ];
        let samples = sensor_samples(grid, inner);
        let distortion = refit_distortion(&samples, focal, principal, free);
        let mut camera = Self {
            width: grid.width,
            height: grid.height,
            focal_px: [focal, focal],
            principal_px: principal,
            distortion,
            refit_max_px: 0.0,
            extrinsics: Vec::new(),
            rms_px: None,
        };
        camera.refit_max_px = samples
            .iter()
            .map(|(ideal, pixel)| (camera.project_normalised(*ideal) - pixel).norm())
            .fold(0.0, f64::max);
        camera
    }

    /// OpenCV's `projectPoints` for a point already in normalised camera coordinates
    /// (X/Z, Y/Z of OpenCV's camera frame): distortion, then the camera matrix.
    pub fn project_normalised(&self, ideal: Vector2<f64>) -> Vector2<f64> {
        let [k1, k2, p1, p2, k3] = self.distortion;
        let (x, y) = (ideal.x, ideal.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        Vector2::new(
            self.focal_px[0] * xd + self.principal_px[0],
            self.focal_px[1] * yd + self.principal_px[1],
        )
    }

    /// The OpenCV camera file (YAML 1.0 as written by `cv2.FileStorage`).
    pub fn to_yaml(&self, source: &str) -> String {
        let [fx, fy] = self.focal_px;
        let [cx, cy] = self.principal_px;
        let mut text = format!(
            "%YAML:1.0\n---\n\
             # deltaz export opencv of {source}: pixels (0, 0) = centre of the top-left pixel,\n\
             # OpenCV camera axes (x right, y down, z forward), mm, rad.\n\
             # distortion_coefficients = k1, k2, p1, p2, k3, refitted from deltaz's model; the\n\
             # largest difference over the sensor is distortion_refit_max_px (px).\n\
             image_width: {}\nimage_height: {}\n",
            self.width, self.height
        );
        text += &matrix(
            "camera_matrix",
            3,
            3,
            &[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        );
        text += &matrix("distortion_coefficients", 5, 1, &self.distortion);
        text += &format!("distortion_refit_max_px: {:e}\n", self.refit_max_px);
        if let Some(rms) = self.rms_px {
            text += "# deltaz's RMS is per coordinate, OpenCV's per point (sqrt 2 larger).\n";
            text += &format!("rms_per_coordinate_px: {rms:e}\n");
            text += &format!("avg_reprojection_error: {:e}\n", rms * 2f64.sqrt());
        }
        if !self.extrinsics.is_empty() {
            text += &format!("nr_of_frames: {}\n", self.extrinsics.len());
            let names: Vec<String> = self
                .extrinsics
                .iter()
                .map(|(name, _)| format!("{name:?}"))
                .collect();
            text += &format!("image_names: [ {} ]\n", names.join(", "));
            text += "# extrinsic_parameters: one row rvec (Rodrigues, rad) | tvec (mm) per image\n";
            let data: Vec<f64> = self.extrinsics.iter().flat_map(|(_, r)| *r).collect();
            text += &matrix("extrinsic_parameters", self.extrinsics.len(), 6, &data);
        }
        text
    }
}

/// OpenCV's `rvec | tvec` of a deltaz pose: x_cv = D R (X − X0), D = diag(1, −1, −1).
pub fn opencv_pose(exterior: &ExteriorOrientation<f64>) -> [f64; 6] {
    let flip = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
    let r = flip * exterior.r_cam_world();
    let t = -(r * exterior.centre);
    // Through the quaternion: well defined at a half turn, where the axis-angle form of the
    // matrix is not.
    let rvec =
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)).scaled_axis();
    [rvec.x, rvec.y, rvec.z, t.x, t.y, t.z]
}

/// Pairs (OpenCV normalised ideal coordinates, observed pixel) over a grid covering the sensor:
/// deltaz's refinement of each observed pixel gives its ideal image point.
fn sensor_samples(
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
) -> Vec<(Vector2<f64>, Vector2<f64>)> {
    let along =
        |i: u32, size: u32| f64::from(i) * f64::from(size - 1) / f64::from(REFIT_SAMPLES - 1);
    (0..REFIT_SAMPLES)
        .flat_map(|i| (0..REFIT_SAMPLES).map(move |j| (i, j)))
        .map(|(i, j)| {
            let (col, row) = (along(i, grid.width), along(j, grid.height));
            let refined = inner.refine(grid.pixel_to_photo(col, row));
            let ideal = Vector2::new(refined.x / inner.f, -refined.y / inner.f);
            (ideal, Vector2::new(col, row))
        })
        .collect()
}

/// OpenCV's k1, k2, p1, p2, k3 (the `free` ones; the others zero) that best map the ideal points
/// onto the observed pixels (linear least squares: the model is linear in them once fx, fy, cx,
/// cy are fixed).
fn refit_distortion(
    samples: &[(Vector2<f64>, Vector2<f64>)],
    focal: f64,
    principal: [f64; 2],
    free: [bool; 5],
) -> [f64; 5] {
    let columns: Vec<usize> = (0..5).filter(|&c| free[c]).collect();
    let mut a = DMatrix::zeros(2 * samples.len(), columns.len());
    let mut b = DVector::zeros(2 * samples.len());
    for (k, (ideal, pixel)) in samples.iter().enumerate() {
        let (x, y) = (ideal.x, ideal.y);
        let r2 = x * x + y * y;
        let (r4, r6) = (r2 * r2, r2 * r2 * r2);
        let target = [
            (pixel.x - principal[0]) / focal - x,
            (pixel.y - principal[1]) / focal - y,
        ];
        let rows = [
            [x * r2, x * r4, 2.0 * x * y, r2 + 2.0 * x * x, x * r6],
            [y * r2, y * r4, r2 + 2.0 * y * y, 2.0 * x * y, y * r6],
        ];
        for (axis, row) in rows.iter().enumerate() {
            for (c, &coefficient) in columns.iter().enumerate() {
                a[(2 * k + axis, c)] = row[coefficient];
            }
            b[2 * k + axis] = target[axis];
        }
    }
    // Columns scaled to unit norm so that the r⁶ column is not lost to conditioning.
    let scale: Vec<f64> = (0..columns.len())
        .map(|c| a.column(c).norm().max(1e-300))
        .collect();
    for (c, s) in scale.iter().enumerate() {
        a.column_mut(c).scale_mut(1.0 / s);
    }
    let solution = a
        .svd(true, true)
        .solve(&b, 1e-12)
        .unwrap_or_else(|_| DVector::zeros(columns.len()));
    let mut distortion = [0.0; 5];
    for (c, &coefficient) in columns.iter().enumerate() {
        distortion[coefficient] = solution[c] / scale[c];
    }
    distortion
}

/// An `!!opencv-matrix` of doubles.
fn matrix(name: &str, rows: usize, cols: usize, data: &[f64]) -> String {
    let values: Vec<String> = data.iter().map(|v| format!("{v:e}")).collect();
    format!(
        "{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {} ]\n",
        values.join(", ")
    )
}

/// The OpenCV camera of a `camera.json` (intrinsics, one extrinsic row per station in the file's
/// order, the residual RMS), and a warning when the file is no calibration (a camera_init.json:
/// no adjustment gave it a σ0).
pub fn from_camera_file(path: &Path) -> Result<(OpenCvCamera, Option<String>)> {
    let file = read_camera(path)?;
    let warning = file.sigma0.is_none().then(|| {
        format!(
            "{}: not calibrated (no adjustment, no σ0: a camera_init.json?): its focal length \
             and principal point are starting values, its distortion zero",
            path.display()
        )
    });
    let mut camera = OpenCvCamera::new(&file.grid(), &file.inner());
    camera.extrinsics = file
        .stations
        .iter()
        .map(|s| (s.image.clone(), opencv_pose(&s.pose.into())))
        .collect();
    camera.rms_px = file.rms_px;
    Ok((camera, warning))
}

/// The OpenCV camera of a `system.json`: its camera and its pose in the rig frame (`rig`).
pub fn from_system_file(path: &Path) -> Result<OpenCvCamera> {
    let (file, _) = SystemFile::load(path)?;
    let c = &file.content.camera;
    let mut camera = OpenCvCamera::new(&c.grid, &c.inner);
    camera.extrinsics = vec![("rig".to_owned(), opencv_pose(&c.pose.into()))];
    Ok(camera)
}

/// `deltaz export opencv`: writes the YAML atomically; the camera for the report, and a
/// warning about the input (see [`from_camera_file`]).
pub fn export_opencv(
    input: &Path,
    system: bool,
    out: &Path,
) -> Result<(OpenCvCamera, Option<String>)> {
    let (camera, warning) = if system {
        (from_system_file(input)?, None)
    } else {
        from_camera_file(input)?
    };
    let name = input.file_name().unwrap_or_default().to_string_lossy();
    crate::io::atomic::write_atomic(out, camera.to_yaml(&name).as_bytes())
        .with_context(|| "export opencv")?;
    Ok((camera, warning))
}

#[cfg(test)]
mod tests {
    use super::*;
    use deltaz_shared::paper::{DC40_GRID, TABLE1_INNER};

    /// Without distortion the refit is exact; the paper's k1 leaves a small refit error, far
    /// below what ignoring the distortion would cost.
    #[test]
    fn refit_error_is_small_and_measured() {
        let ideal = OpenCvCamera::new(&DC40_GRID, &InnerOrientation::ideal(46.0));
        assert!(ideal.refit_max_px < 1e-9, "{}", ideal.refit_max_px);
        assert!(ideal.distortion.iter().all(|k| k.abs() < 1e-12));
        let paper = OpenCvCamera::new(&DC40_GRID, &TABLE1_INNER);
        let mut undistorted = paper.clone();
        undistorted.distortion = [0.0; 5];
        let ignored = sensor_samples(&DC40_GRID, &TABLE1_INNER)
            .iter()
            .map(|(i, p)| (undistorted.project_normalised(*i) - p).norm())
            .fold(0.0, f64::max);
        assert!(paper.refit_max_px < 0.05, "{}", paper.refit_max_px);
        assert!(ignored > 100.0 * paper.refit_max_px, "{ignored}");
        // k1 of the opposite sign (OpenCV distorts where deltaz corrects), ≈ −k1·f².
        let k1_scaled = -TABLE1_INNER.k1 * TABLE1_INNER.f.powi(2);
        assert!((paper.distortion[0] / k1_scaled - 1.0).abs() < 0.1);
    }

    /// Refitting only some coefficients leaves the others zero; a radially distorted camera is
    /// refitted by k1 and k2 alone within 0.05 px, by k1 alone less well.
    #[test]
    fn refit_of_chosen_coefficients() {
        let radial = InnerOrientation {
            p1: 0.0,
            p2: 0.0,
            k3: 0.0,
            ..TABLE1_INNER
        };
        let k1k2 = OpenCvCamera::refitted(&DC40_GRID, &radial, [true, true, false, false, false]);
        assert_eq!(k1k2.distortion[2..], [0.0; 3]);
        assert!(k1k2.refit_max_px < 0.05, "{}", k1k2.refit_max_px);
        let k1 = OpenCvCamera::refitted(&DC40_GRID, &radial, [true, false, false, false, false]);
        assert!(k1.refit_max_px > k1k2.refit_max_px, "{}", k1.refit_max_px);
    }

    /// A point straight ahead of an upright camera lands on the principal point, and the axis
    /// flip turns deltaz's −z viewing direction into OpenCV's +z.
    #[test]
    fn pose_flips_axes() {
        let eo = ExteriorOrientation {
            kappa: 0.0,
            phi: 0.0,
            omega: 0.0,
            centre: Vector3::new(10.0, 20.0, 1000.0),
        };
        let p = opencv_pose(&eo);
        // Rotation by π about x.
        assert!((p[0].abs() - std::f64::consts::PI).abs() < 1e-12 && p[1].abs() < 1e-12);
        assert_eq!([p[3], p[4], p[5]], [-10.0, 20.0, 1000.0]);
    }
}
