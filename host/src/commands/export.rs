//! `deltaz export opencv`.

use super::args::OutputArgs;
use crate::io::opencv::export_opencv;
use crate::report::console::Output;
use anyhow::Result;
use std::path::PathBuf;

/// What to export.
#[derive(clap::Subcommand)]
pub enum What {
    /// OpenCV's camera file (YAML for cv2.FileStorage): image_width, image_height,
    /// camera_matrix (px), distortion_coefficients (k1, k2, p1, p2, k3, refitted to OpenCV's
    /// model; the largest refit error over the sensor is reported in px) and
    /// extrinsic_parameters, one row rvec (rad) | tvec (mm) per image in OpenCV's camera axes.
    Opencv {
        /// A camera calibration (camera.json): its stations become the extrinsics.
        #[arg(long, required_unless_present = "system", conflicts_with = "system")]
        camera: Option<PathBuf>,
        /// A system calibration (system.json): the camera's pose in the system's frame.
        #[arg(long)]
        system: Option<PathBuf>,
        /// Output YAML file (e.g. camera.yml).
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        output: OutputArgs,
    },
}

/// Runs `deltaz export`.
pub fn exec(what: What) -> Result<()> {
    let What::Opencv {
        camera,
        system,
        out,
        output,
    } = what;
    let (input, is_system) = match (camera, system) {
        (Some(camera), _) => (camera, false),
        (None, Some(system)) => (system, true),
        (None, None) => anyhow::bail!("give --camera FILE or --system FILE"),
    };
    let (cv, warning) = export_opencv(&input, is_system, &out)?;
    if let Some(warning) = warning {
        eprintln!("warning: {warning}");
    }
    Output::from(output).result(
        &format!(
            "OpenCV camera: f {:.2} px, principal point ({:.2}, {:.2}) px, {} images, \
             distortion refit error at most {:.4} px -> {}\n",
            cv.focal_px[0],
            cv.principal_px[0],
            cv.principal_px[1],
            cv.extrinsics.len(),
            cv.refit_max_px,
            out.display()
        ),
        &serde_json::json!({
            "focal_px": cv.focal_px,
            "principal_px": cv.principal_px,
            "distortion": cv.distortion,
            "refit_max_px": cv.refit_max_px,
            "images": cv.extrinsics.len(),
            "out": out,
        }),
    )
}
