//! The camera calibration file `camera.json` ("deltaz.camera/1") and its initial form
//! `camera_init.json` (the pixel mapping and an approximate f; every other field optional).
//!
//! ```json
//! { "format": "deltaz.camera/1",
//!   "inner": {"f": 46.981, "cx": -0.133, "cy": 0.208, "k1": 6.3e-5, "k2": 0, "k3": 0, "p1": 0, "p2": 0},
//!   "sigma": {"f": 0.066, ...},            // same keys, 0 = held fixed
//!   "sigma0": 0.025,                       // a posteriori σ0 (mm)
//!   "pixel_size": 0.045, "image_size": [768, 512], "origin": [378, 252],
//!   "stations": [{"image": "s1", "kappa": .., "phi": .., "omega": .., "X0": .., "Y0": .., "Z0": ..,
//!                 "sigma": {...}, "rms_px": .., "observations": ..}],
//!   "correlations": [{"a": "f", "b": "s1.Z0", "r": 0.93}],
//!   "covariance": {"parameters": ["f", "cx", "cy", "k1"], "matrix": [[4.4e-3, ..], ..]},
//!   "rms_px": 0.5, "rejected": [{"image": "s3", "point": "T07", "col": .., "row": .., "residual_px": ..}] }
//! ```
//!
//! `covariance` (optional, absent from files written before it) is the covariance of the
//! estimated inner parameters with every correlation, the a-posteriori σ0² included: what
//! `calibrate projector` takes as the camera's prior, so that the camera's uncertainty reaches
//! the projector and the points as in `calibrate system`.

use super::atomic::write_json_atomic;
use super::{FileError, Result};
use deltaz_calib::system_adjustment::CameraPrior;
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::ExteriorOrientation;
use nalgebra::{DMatrix, Vector3};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The format tag of `camera.json`.
pub const CAMERA_FORMAT: &str = "deltaz.camera/1";

/// The inner orientation parameters (mm), or their σ.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct InnerParams {
    /// Focal length (mm).
    pub f: f64,
    /// Principal point x (mm).
    pub cx: f64,
    /// Principal point y (mm).
    pub cy: f64,
    /// Radial distortion k1 (mm⁻²).
    pub k1: f64,
    /// Radial distortion k2 (mm⁻⁴).
    pub k2: f64,
    /// Radial distortion k3 (mm⁻⁶).
    pub k3: f64,
    /// Decentring p1 (mm⁻¹).
    pub p1: f64,
    /// Decentring p2 (mm⁻¹).
    pub p2: f64,
}

impl InnerParams {
    /// The values in the order f, cx, cy, k1, k2, k3, p1, p2 (see [`INNER_NAMES`]).
    pub fn to_array(&self) -> [f64; 8] {
        [
            self.f, self.cx, self.cy, self.k1, self.k2, self.k3, self.p1, self.p2,
        ]
    }

    /// From values in the order of [`INNER_NAMES`].
    pub fn from_array(a: [f64; 8]) -> Self {
        let [f, cx, cy, k1, k2, k3, p1, p2] = a;
        Self {
            f,
            cx,
            cy,
            k1,
            k2,
            k3,
            p1,
            p2,
        }
    }
}

/// The largest image side accepted (px): larger is a typing error, and would allocate gigabytes.
pub const MAX_IMAGE_SIDE: u32 = 65_536;

/// The largest focal length accepted, in pixels (a 2 m lens on 2 µm pixels is 1e6 px).
pub const MAX_FOCAL_PX: f64 = 1e7;

pub use deltaz_calib::residual::INNER_NAMES;
use deltaz_calib::residual::{inner_from_array, inner_to_array};

impl From<InnerParams> for InnerOrientation<f64> {
    fn from(p: InnerParams) -> Self {
        inner_from_array(p.to_array())
    }
}

impl From<InnerOrientation<f64>> for InnerParams {
    fn from(p: InnerOrientation<f64>) -> Self {
        Self::from_array(inner_to_array(&p))
    }
}

/// An exterior orientation (eq. 3) in files: κ, φ, ω (rad), X0, Y0, Z0 (mm), or their σ.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[allow(non_snake_case)]
pub struct PoseParams {
    /// κ (rad).
    pub kappa: f64,
    /// φ (rad).
    pub phi: f64,
    /// ω (rad).
    pub omega: f64,
    /// X0 (mm).
    pub X0: f64,
    /// Y0 (mm).
    pub Y0: f64,
    /// Z0 (mm).
    pub Z0: f64,
}

/// The pose parameters' names, in the order of [`PoseParams::to_array`].
pub const POSE_NAMES: [&str; 6] = ["kappa", "phi", "omega", "X0", "Y0", "Z0"];

impl PoseParams {
    /// κ, φ, ω, X0, Y0, Z0.
    pub fn to_array(&self) -> [f64; 6] {
        [self.kappa, self.phi, self.omega, self.X0, self.Y0, self.Z0]
    }

    /// From κ, φ, ω, X0, Y0, Z0.
    pub fn from_array(a: [f64; 6]) -> Self {
        Self {
            kappa: a[0],
            phi: a[1],
            omega: a[2],
            X0: a[3],
            Y0: a[4],
            Z0: a[5],
        }
    }
}

impl From<PoseParams> for ExteriorOrientation<f64> {
    fn from(p: PoseParams) -> Self {
        ExteriorOrientation {
            kappa: p.kappa,
            phi: p.phi,
            omega: p.omega,
            centre: Vector3::new(p.X0, p.Y0, p.Z0),
        }
    }
}

impl From<ExteriorOrientation<f64>> for PoseParams {
    fn from(e: ExteriorOrientation<f64>) -> Self {
        Self {
            kappa: e.kappa,
            phi: e.phi,
            omega: e.omega,
            X0: e.centre.x,
            Y0: e.centre.y,
            Z0: e.centre.z,
        }
    }
}

/// One image's exterior orientation with its σ and residual figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Station {
    /// The image label.
    pub image: String,
    /// The pose.
    #[serde(flatten)]
    pub pose: PoseParams,
    /// σ of each pose parameter.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma: Option<PoseParams>,
    /// A posteriori σ0 of this image's resection (mm), when resected alone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma0: Option<f64>,
    /// Residual RMS of this image (px).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rms_px: Option<f64>,
    /// Number of observations used.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub observations: Option<usize>,
}

/// A pair of parameters whose estimates are highly correlated.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Correlation {
    /// First parameter (e.g. "f" or "s3.Z0").
    pub a: String,
    /// Second parameter.
    pub b: String,
    /// The correlation coefficient.
    pub r: f64,
}

/// An observation rejected as a gross error.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Rejected {
    /// Image label.
    pub image: String,
    /// Point label.
    pub point: String,
    /// Observed column.
    pub col: f64,
    /// Observed row.
    pub row: f64,
    /// Its residual when rejected (px).
    pub residual_px: f64,
}

/// The covariance of the estimated inner parameters, with every correlation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InnerCovariance {
    /// The estimated parameters by name (of [`INNER_NAMES`]), in the matrix's order.
    pub parameters: Vec<String>,
    /// The covariance, row by row (the products of the parameters' units: mm², mm · mm⁻², …).
    pub matrix: Vec<Vec<f64>>,
}

impl InnerCovariance {
    /// The covariance of a camera calibration's prior (its free parameters in their order).
    pub fn new(prior: &CameraPrior) -> Self {
        Self {
            parameters: (0..INNER_NAMES.len())
                .filter(|k| prior.free[*k])
                .map(|k| INNER_NAMES[k].to_owned())
                .collect(),
            matrix: prior
                .covariance
                .row_iter()
                .map(|r| r.iter().copied().collect())
                .collect(),
        }
    }

    /// The prior: the free parameters and the covariance in the order of [`INNER_NAMES`];
    /// every check of [`CameraFile`]'s reading but positive definiteness made here.
    fn prior(&self) -> std::result::Result<CameraPrior, String> {
        let n = self.parameters.len();
        let mut index = Vec::with_capacity(n);
        for name in &self.parameters {
            let k = INNER_NAMES
                .iter()
                .position(|x| x == name)
                .ok_or_else(|| format!("`covariance.parameters`: unknown parameter {name:?}"))?;
            if index.contains(&k) {
                return Err(format!("`covariance.parameters`: {name:?} appears twice"));
            }
            index.push(k);
        }
        if self.matrix.len() != n || self.matrix.iter().any(|r| r.len() != n) {
            return Err(format!(
                "`covariance.matrix` must be {n} × {n}, one row and column per parameter"
            ));
        }
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by_key(|&a| index[a]);
        let covariance = DMatrix::from_fn(n, n, |a, b| self.matrix[order[a]][order[b]]);
        if !covariance.iter().all(|v| v.is_finite())
            || (&covariance - covariance.transpose()).amax() > 1e-9 * covariance.amax()
        {
            return Err("`covariance.matrix` is not a finite symmetric matrix".into());
        }
        let mut free = [false; 8];
        for &k in &index {
            free[k] = true;
        }
        Ok(CameraPrior { free, covariance })
    }
}

/// `camera.json` / `camera_init.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraFile {
    /// Always [`CAMERA_FORMAT`].
    pub format: String,
    /// Inner orientation (mm).
    pub inner: InnerParams,
    /// σ of the inner orientation (0 = held fixed).
    #[serde(default)]
    pub sigma: InnerParams,
    /// A posteriori σ0 (mm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma0: Option<f64>,
    /// Pixel size (mm).
    pub pixel_size: f64,
    /// Image size [width, height] (pixels).
    pub image_size: [u32; 2],
    /// Pixel [col, row] of the photo-coordinate origin.
    pub origin: [f64; 2],
    /// Exterior orientations.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub stations: Vec<Station>,
    /// Correlations above 0.9 in magnitude.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub correlations: Vec<Correlation>,
    /// Residual RMS over all images (px).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rms_px: Option<f64>,
    /// Observations rejected as gross errors.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub rejected: Vec<Rejected>,
    /// Iterations of the adjustment.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub iterations: Option<usize>,
    /// The covariance of the estimated inner parameters.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub covariance: Option<InnerCovariance>,
}

impl CameraFile {
    /// The initial form: the pixel mapping and an approximate inner orientation.
    pub fn init(grid: &PixelGrid<f64>, inner: InnerOrientation<f64>) -> Self {
        Self {
            format: CAMERA_FORMAT.to_owned(),
            inner: inner.into(),
            sigma: InnerParams::default(),
            sigma0: None,
            pixel_size: grid.pixel_size,
            image_size: [grid.width, grid.height],
            origin: [grid.origin_col, grid.origin_row],
            stations: Vec::new(),
            correlations: Vec::new(),
            rms_px: None,
            rejected: Vec::new(),
            iterations: None,
            covariance: None,
        }
    }

    /// The camera as the prior of a later adjustment (`calibrate projector`): its estimated
    /// inner parameters with their `covariance`, or, in a file written without one, with their
    /// σ alone (no correlations: see [`Self::covariance`]). None when no parameter has a σ (a
    /// camera taken as exact, as `camera_init.json`).
    pub fn prior(&self) -> Option<CameraPrior> {
        if let Some(c) = &self.covariance {
            return c.prior().ok();
        }
        let sigma = self.sigma.to_array();
        let free: [bool; 8] = sigma.map(|s| s > 0.0);
        let estimated: Vec<f64> = sigma.into_iter().filter(|s| *s > 0.0).collect();
        (!estimated.is_empty()).then(|| CameraPrior {
            free,
            covariance: DMatrix::from_diagonal(&nalgebra::DVector::from_iterator(
                estimated.len(),
                estimated.iter().map(|s| s * s),
            )),
        })
    }

    /// The pixel mapping.
    pub fn grid(&self) -> PixelGrid<f64> {
        PixelGrid {
            pixel_size: self.pixel_size,
            width: self.image_size[0],
            height: self.image_size[1],
            origin_col: self.origin[0],
            origin_row: self.origin[1],
        }
    }

    /// The inner orientation.
    pub fn inner(&self) -> InnerOrientation<f64> {
        self.inner.into()
    }

    /// The checks of [`read_camera`] after the format (numbers finite, sizes positive and
    /// within limits, the covariance consistent with σ).
    fn validate(&self, path: &Path) -> Result<()> {
        let numbers = self
            .inner
            .to_array()
            .into_iter()
            .chain(self.sigma.to_array())
            .chain([self.pixel_size, self.origin[0], self.origin[1]])
            .chain(self.stations.iter().flat_map(|s| s.pose.to_array()));
        if numbers.into_iter().any(|v| !v.is_finite()) {
            return Err(FileError::whole(path, "a parameter is NaN or infinite"));
        }
        if self.inner.f <= 0.0 {
            return Err(FileError::whole(path, "`inner.f` must be positive"));
        }
        if self.pixel_size <= 0.0 || self.image_size.contains(&0) {
            return Err(FileError::whole(
                path,
                "`pixel_size` and `image_size` must be positive",
            ));
        }
        let [width, height] = self.image_size;
        if width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
            return Err(FileError::whole(
                path,
                format!(
                    "`image_size` {width} x {height} px exceeds the limit of {MAX_IMAGE_SIDE} px a side"
                ),
            ));
        }
        if let Some(c) = &self.covariance {
            let prior = c.prior().map_err(|e| FileError::whole(path, e))?;
            let sigma = self.sigma.to_array();
            let mut at = 0;
            for (k, name) in INNER_NAMES.iter().enumerate() {
                let variance = if prior.free[k] {
                    at += 1;
                    prior.covariance[(at - 1, at - 1)]
                } else {
                    0.0
                };
                if (variance.max(0.0).sqrt() - sigma[k]).abs() > 1e-6 * sigma[k].max(1e-300) {
                    return Err(FileError::whole(
                        path,
                        format!(
                            "`covariance` gives {name} a σ of {:e}, `sigma.{name}` is {:e}",
                            variance.max(0.0).sqrt(),
                            sigma[k]
                        ),
                    ));
                }
            }
            if prior.covariance.clone().cholesky().is_none() {
                return Err(FileError::whole(
                    path,
                    "`covariance.matrix` is not positive definite",
                ));
            }
        }
        let focal_px = self.inner.f / self.pixel_size;
        if focal_px > MAX_FOCAL_PX {
            return Err(FileError::whole(
                path,
                format!(
                    "`inner.f` {:e} mm is {focal_px:.3e} px: not a focal length (at most {MAX_FOCAL_PX:.0e} px)",
                    self.inner.f
                ),
            ));
        }
        Ok(())
    }
}

/// Reads and validates `camera.json` or `camera_init.json`.
pub fn read_camera(path: &Path) -> Result<CameraFile> {
    let text = std::fs::read_to_string(path).map_err(|e| FileError::whole(path, e.to_string()))?;
    // A file of another kind is named as such before its fields are looked for.
    if let Some(tag) = super::format_tag(&text).filter(|t| t != CAMERA_FORMAT) {
        let kind = match tag.split('/').next() {
            Some("deltaz.system") => ": a system calibration (system.json), not a camera file",
            Some("deltaz.poses") => ": resected poses (resect --out), not a camera file",
            Some("deltaz.back") => ": a back analysis (analysis.json), not a camera file",
            _ => "",
        };
        return Err(FileError::whole(
            path,
            format!(
                "format {tag:?}{kind}; expected {CAMERA_FORMAT:?} (camera.json of `calibrate \
                 camera`, or camera_init.json of `simulate`)"
            ),
        ));
    }
    let file: CameraFile =
        serde_json::from_str(&text).map_err(|e| FileError::at(path, e.line(), e.to_string()))?;
    file.validate(path)?;
    Ok(file)
}

/// Writes `camera.json` atomically.
pub fn write_camera(path: &Path, file: &CameraFile) -> Result<()> {
    write_json_atomic(path, file)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn init_form_round_trip_and_conversions() {
        let grid = PixelGrid {
            pixel_size: 0.045,
            width: 768,
            height: 512,
            origin_col: 378.0,
            origin_row: 252.0,
        };
        let mut file = CameraFile::init(&grid, InnerOrientation::ideal(46.0));
        file.stations.push(Station {
            image: "s1".into(),
            pose: PoseParams::from_array([0.1, 0.2, 0.3, 1.0, 2.0, 3.0]),
            sigma: None,
            sigma0: None,
            rms_px: Some(0.5),
            observations: Some(48),
        });
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("camera.json");
        write_camera(&path, &file).unwrap();
        let back = read_camera(&path).unwrap();
        assert_eq!(back, file);
        assert_eq!(back.grid(), grid);
        assert_eq!(back.inner().f, 46.0);
        let eo: ExteriorOrientation<f64> = back.stations[0].pose.into();
        assert_eq!(eo.centre, Vector3::new(1.0, 2.0, 3.0));
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains("\"X0\": 1.0") && text.contains("\"kappa\": 0.1"));
    }

    /// The covariance round-trips and becomes the prior in the order f, cx, cy, k1, whatever
    /// the file's order; a file without it gives the σ alone; bad matrices name the problem.
    #[test]
    fn covariance_is_the_prior() {
        let grid = PixelGrid {
            pixel_size: 0.045,
            width: 768,
            height: 512,
            origin_col: 378.0,
            origin_row: 252.0,
        };
        let mut file = CameraFile::init(&grid, InnerOrientation::ideal(46.0));
        assert_eq!(file.prior(), None);
        file.sigma.f = 0.2;
        file.sigma.k1 = 1e-6;
        let diagonal = file.prior().unwrap();
        assert_eq!(
            diagonal.free,
            [true, false, false, true, false, false, false, false]
        );
        assert_eq!(diagonal.covariance[(1, 1)], 1e-12);
        file.covariance = Some(InnerCovariance {
            parameters: vec!["k1".into(), "f".into()],
            matrix: vec![vec![1e-12, -1.5e-7], vec![-1.5e-7, 0.04]],
        });
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("camera.json");
        write_camera(&path, &file).unwrap();
        let back = read_camera(&path).unwrap();
        assert_eq!(back, file);
        let prior = back.prior().unwrap();
        assert_eq!(prior.free, diagonal.free);
        assert_eq!(prior.covariance[(0, 0)], 0.04);
        assert_eq!(prior.covariance[(0, 1)], -1.5e-7);
        let bad = |edit: &dyn Fn(&mut InnerCovariance), expect: &str| {
            let mut f = file.clone();
            edit(f.covariance.as_mut().unwrap());
            write_camera(&path, &f).unwrap();
            let e = read_camera(&path).unwrap_err().to_string();
            assert!(e.contains("camera.json") && e.contains(expect), "{e}");
        };
        bad(
            &|c| c.parameters[0] = "k9".into(),
            "unknown parameter \"k9\"",
        );
        bad(&|c| c.parameters[0] = "f".into(), "\"f\" appears twice");
        bad(&|c| c.matrix.pop().map(drop).unwrap_or(()), "must be 2 × 2");
        bad(&|c| c.matrix[0][1] = 0.0, "not a finite symmetric matrix");
        bad(
            &|c| c.matrix[1][1] = 0.09,
            "gives f a σ of 3e-1, `sigma.f` is 2e-1",
        );
        bad(
            &|c| {
                c.matrix[0][1] = -3e-7;
                c.matrix[1][0] = -3e-7;
            },
            "not positive definite",
        );
    }

    #[test]
    fn minimal_init_file_and_errors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("camera_init.json");
        let ok = r#"{"format":"deltaz.camera/1","inner":{"f":46},"pixel_size":0.045,
                     "image_size":[768,512],"origin":[378,252]}"#;
        std::fs::write(&path, ok).unwrap();
        assert_eq!(read_camera(&path).unwrap().inner().k1, 0.0);
        let bad = [
            (
                ok.replace("deltaz.camera/1", "x/2"),
                "format \"x/2\"; expected",
            ),
            (
                ok.replace("\"f\":46", "\"f\":-1"),
                "`inner.f` must be positive",
            ),
            (
                ok.replace(",\"pixel_size\":0.045", ""),
                "missing field `pixel_size`",
            ),
            (
                ok.replace("[768,512]", "[4294967295,512]"),
                "`image_size` 4294967295 x 512 px exceeds the limit",
            ),
            (ok.replace("\"f\":46", "\"f\":1e300"), "`inner.f` 1e300 mm"),
        ];
        for (text, expect) in bad {
            std::fs::write(&path, text).unwrap();
            let e = read_camera(&path).unwrap_err().to_string();
            assert!(e.contains("camera_init.json") && e.contains(expect), "{e}");
        }
    }
}
