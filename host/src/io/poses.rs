//! `deltaz resect`'s output ("deltaz.poses/1"): one station per resected image, with σ, σ0 and
//! RMS.

use crate::io::camera_file::{PoseParams, Station};
use deltaz_calib::resection::ResectionResult;

/// A resection as a station record of `camera.json`.
pub fn station(result: &ResectionResult, image: &str) -> Station {
    Station {
        image: image.to_owned(),
        pose: result.exterior.into(),
        sigma: Some(PoseParams::from_array(result.sigma)),
        sigma0: Some(result.sigma0),
        rms_px: Some(result.rms_px),
        observations: Some(result.points),
    }
}

/// The format tag of a resection's output file.
pub const POSES_FORMAT: &str = "deltaz.poses/1";

/// `deltaz resect`'s output: one station per image, with σ, σ0 and RMS.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PosesFile {
    /// Always [`POSES_FORMAT`].
    pub format: String,
    /// The resected images.
    pub stations: Vec<Station>,
}

impl PosesFile {
    /// The file for resection results.
    pub fn new(results: &[(String, ResectionResult)]) -> Self {
        Self {
            format: POSES_FORMAT.to_owned(),
            stations: results.iter().map(|(i, r)| station(r, i)).collect(),
        }
    }

    /// A human-readable table of the poses with their σ.
    pub fn table(&self) -> String {
        let mut t = String::from(
            "image      kappa(rad)         phi(rad)           omega(rad)         X0(mm)              Y0(mm)              Z0(mm)              rms(px)\n",
        );
        for s in &self.stations {
            t.push_str(&format!("{:<8}", s.image));
            let sigma = s.sigma.unwrap_or_default().to_array();
            for (k, (v, sd)) in s.pose.to_array().iter().zip(sigma).enumerate() {
                if k < 3 {
                    t.push_str(&format!(" {v:>9.5} ±{sd:<7.5}"));
                } else {
                    t.push_str(&format!(" {v:>9.3} ±{sd:<8.3}"));
                }
            }
            t.push_str(&format!(" {:.3}\n", s.rms_px.unwrap_or(f64::NAN)));
        }
        t
    }
}
