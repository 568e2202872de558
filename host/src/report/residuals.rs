//! The image residuals of a camera calibration, per observation (CSV next to camera.json) and
//! per image, with a warning when σ0 is far above the a-priori image σ that names the worst
//! images and points.
//!
//! A residual is observed − computed, in pixels (col, row), the computed position being the
//! adjusted point projected through the adjusted camera (eqs 1-2). RMS figures are per
//! coordinate, as deltaz reports them (OpenCV's per point is √2 larger).

use crate::io::observations::Observation;
use deltaz_calib::bundle::Calibration;
use deltaz_shared::collinearity::project_camera_point;
use std::borrow::Cow;
use std::fmt::Write as _;

/// σ0 above this many times the a-priori image σ draws a warning.
pub const WARN_FACTOR: f64 = 3.0;

/// The residuals file written next to a calibration: `camera.json` → `camera.residuals.csv`.
pub fn residuals_path(out: &std::path::Path) -> std::path::PathBuf {
    out.with_extension("residuals.csv")
}

/// One observation's residual.
#[derive(Debug, Clone, PartialEq)]
pub struct Residual {
    /// Image label.
    pub image: String,
    /// Point label.
    pub point: String,
    /// Observed column, row (px).
    pub observed: [f64; 2],
    /// Observed − computed (px).
    pub v: [f64; 2],
    /// Rejected as a gross error (not in the adjustment).
    pub rejected: bool,
}

impl Residual {
    /// Length of the residual vector (px).
    pub fn norm(&self) -> f64 {
        self.v[0].hypot(self.v[1])
    }
}

/// Every target observation's residual after the calibration, as the adjustment sees it: the
/// refined observation minus the projected adjusted point (eq. 1), in photo coordinates turned
/// into pixels (col, row). To first order this is the residual in the raw image; under strong
/// distortion the two differ, and this one is the one σ0 and the RMS are computed from.
pub fn residuals(calibration: &Calibration, observations: &[Observation]) -> Vec<Residual> {
    let p = &calibration.problem;
    let s = p.grid.pixel_size;
    p.observations
        .iter()
        .filter_map(|o| {
            let cam = p.poses[o.image].world_to_camera(&p.xyz[o.point]);
            let computed = project_camera_point(p.inner.f, &cam).ok()?;
            let v = p.inner.refine(o.photo) - computed;
            let source = &observations[o.source];
            Some(Residual {
                image: p.images[o.image].clone(),
                point: p.points[o.point].clone(),
                observed: [source.col, source.row],
                v: [v.x / s, -v.y / s],
                rejected: !o.active,
            })
        })
        .collect()
}

/// CSV `image,point,col,row,v_col,v_row,v_px,rejected` (px).
pub fn residuals_csv(residuals: &[Residual]) -> String {
    crate::io::csv_text(
        &[
            "image", "point", "col", "row", "v_col", "v_row", "v_px", "rejected",
        ],
        residuals.iter().map(|r| {
            vec![
                Cow::from(r.image.as_str()),
                Cow::from(r.point.as_str()),
                Cow::from(format!("{:.4}", r.observed[0])),
                Cow::from(format!("{:.4}", r.observed[1])),
                Cow::from(format!("{:.4}", r.v[0])),
                Cow::from(format!("{:.4}", r.v[1])),
                Cow::from(format!("{:.4}", r.norm())),
                Cow::from(if r.rejected { "1" } else { "0" }),
            ]
        }),
    )
}

/// RMS per coordinate (px) of the adjusted (not rejected) residuals of each image, in order of
/// first appearance.
pub fn per_image_rms(residuals: &[Residual]) -> Vec<(String, f64)> {
    let mut sums: Vec<(String, f64, usize)> = Vec::new();
    for r in residuals.iter().filter(|r| !r.rejected) {
        let at = match sums.iter().position(|(i, _, _)| *i == r.image) {
            Some(at) => at,
            None => {
                sums.push((r.image.clone(), 0.0, 0));
                sums.len() - 1
            }
        };
        sums[at].1 += r.v[0] * r.v[0] + r.v[1] * r.v[1];
        sums[at].2 += 2;
    }
    sums.into_iter()
        .map(|(image, sum, n)| (image, (sum / n as f64).sqrt()))
        .collect()
}

/// The residuals for people: RMS per image, and, when σ0 exceeds `WARN_FACTOR` times the
/// a-priori σ (`sigma0_px` and `apriori_px` both in px), a warning naming the three worst
/// images and points.
pub fn summary(residuals: &[Residual], sigma0_px: f64, apriori_px: f64) -> String {
    let mut images = per_image_rms(residuals);
    let mut text = String::from("residual RMS per image (px per coordinate):");
    for (image, rms) in &images {
        let _ = write!(text, " {image} {rms:.3}");
    }
    text.push('\n');
    let factor = sigma0_px / apriori_px;
    if factor > WARN_FACTOR {
        images.sort_by(|a, b| b.1.total_cmp(&a.1));
        let mut worst: Vec<&Residual> = residuals.iter().filter(|r| !r.rejected).collect();
        worst.sort_by(|a, b| b.norm().total_cmp(&a.norm()));
        let _ = writeln!(
            text,
            "warning: σ0 is {sigma0_px:.2} px, {factor:.1} times the a-priori image σ of \
             {apriori_px} px: the control, the observations or the camera model do not fit. \
             Worst images: {}. Worst points: {}.",
            images
                .iter()
                .take(3)
                .map(|(i, rms)| format!("{i} ({rms:.2} px)"))
                .collect::<Vec<_>>()
                .join(", "),
            worst
                .iter()
                .take(3)
                .map(|r| format!("{} in {} ({:.2} px)", r.point, r.image, r.norm()))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    fn residual(image: &str, point: &str, v: [f64; 2]) -> Residual {
        Residual {
            image: image.into(),
            point: point.into(),
            observed: [10.0, 20.0],
            v,
            rejected: false,
        }
    }

    #[test]
    fn per_image_and_warning() {
        let r = vec![
            residual("s1", "T1", [0.3, 0.4]),
            residual("s2", "T1", [3.0, 4.0]),
            residual("s2", "T2", [0.0, 0.0]),
        ];
        let images = per_image_rms(&r);
        assert_eq!(images[0].0, "s1");
        assert!((images[0].1 - (0.25f64 / 2.0).sqrt()).abs() < 1e-12);
        assert!((images[1].1 - (25.0f64 / 4.0).sqrt()).abs() < 1e-12);
        let calm = summary(&r, 0.5, 0.5);
        assert!(!calm.contains("warning"), "{calm}");
        let loud = summary(&r, 2.0, 0.5);
        assert!(
            loud.contains("4.0 times")
                && loud.contains("Worst images: s2 (2.50 px), s1")
                && loud.contains("Worst points: T1 in s2 (5.00 px)"),
            "{loud}"
        );
        let csv = residuals_csv(&r);
        assert!(
            csv.contains("s2,T1,10.0000,20.0000,3.0000,4.0000,5.0000,0\n"),
            "{csv}"
        );
    }
}
