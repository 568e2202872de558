//! `deltaz calibrate camera`.

use super::args::{pixel_size, positive, ImageFolder, OutputArgs, PlotsArg};
use crate::io::camera_file::{read_camera, CameraFile, INNER_NAMES};
use crate::report::calibration_plots::report_plots;
use crate::report::console::Output;
use crate::report::residuals::{residuals_path, summary, Residual};
use crate::workflows::board::calibrate_board;
use crate::workflows::camera::calibrate_files_with_residuals;
use crate::workflows::observations::{folder_observations, ObservationsGuard};
use anyhow::Result;
use deltaz_calib::bundle::CalibrationOptions;
use deltaz_measure::board::Board;
use deltaz_measure::MeasureParams;
use std::path::{Path, PathBuf};

/// Arguments of `deltaz calibrate camera`.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// The starting sensor: camera_init.json (pixel mapping, approximate f); not with
    /// --board.
    #[arg(long, required_unless_present = "board")]
    init: Option<PathBuf>,
    /// Calibrate from views of a flat circle-grid board in --images instead,
    /// `circles:COLSxROWS[:SPACING_MM]` or `acircles:COLSxROWS[:SPACING_MM]` (dark circles
    /// unless `--bright`): the start from the views' homographies, the board as weighted
    /// control; the labelled circles and the board are written next to --out
    /// (*.obs.csv, *.control.csv).
    #[arg(long, requires = "images", conflicts_with_all = ["init", "obs", "control"])]
    board: Option<Board>,
    /// With --board: the pixel size (mm); without it photo coordinates are in units of 100
    /// pixels (f and σ in pixels are printed all the same).
    #[arg(long, default_value_t = 0.01, requires = "board", value_parser = pixel_size,
          allow_negative_numbers = true)]
    pixel_size: f64,
    /// With --board: σ of the board's circle positions (its flatness and spacing errors,
    /// in the spacing's unit).
    #[arg(long, default_value_t = 0.02, requires = "board")]
    board_sigma: f64,
    /// Keep every observation (no data snooping).
    #[arg(long)]
    no_snooping: bool,
    /// Target observations CSV.
    #[arg(long, required_unless_present = "images")]
    obs: Option<PathBuf>,
    #[command(flatten)]
    folder: ImageFolder,
    /// Control CSV (point,X,Y,Z,sigma); without it the network is free (arbitrary datum).
    /// Required with --images (the layout).
    #[arg(long)]
    control: Option<PathBuf>,
    /// Output camera.json.
    #[arg(long)]
    out: PathBuf,
    /// Also estimate k2.
    #[arg(long)]
    k2: bool,
    /// Also estimate k3.
    #[arg(long)]
    k3: bool,
    /// Also estimate p1.
    #[arg(long)]
    p1: bool,
    /// Also estimate p2.
    #[arg(long)]
    p2: bool,
    /// Free network: control only gives approximate values; minimal constraints.
    #[arg(long)]
    free_network: bool,
    /// A priori σ of image coordinates (px, > 0), weighting control against images.
    #[arg(long, default_value_t = 0.5, value_parser = positive, allow_negative_numbers = true)]
    image_sigma_px: f64,
    #[command(flatten)]
    plots: PlotsArg,
    #[command(flatten)]
    output: OutputArgs,
}

/// Runs `deltaz calibrate camera`: from a board's views, or from target observations (a file or
/// a folder of images) with an init file.
pub fn exec(args: Args) -> Result<()> {
    let output = Output::from(args.output);
    let mut options = CalibrationOptions {
        free_network: args.free_network,
        image_sigma_px: args.image_sigma_px,
        snooping: !args.no_snooping,
        ..Default::default()
    };
    for (k, on) in [(4, args.k2), (5, args.k3), (6, args.p1), (7, args.p2)] {
        options.free.inner[k] |= on;
    }
    let plots = args.plots.plots.as_deref();
    let out = &args.out;
    if let (Some(board), Some(dir)) = (args.board, args.folder.images.as_deref()) {
        let mut params = MeasureParams::default();
        params.detect.polarity = args.folder.polarity.polarity(true);
        let progress = output.progress(format!("calibrating the camera from {}", dir.display()));
        let cal = calibrate_board(
            dir,
            &board,
            &params,
            args.pixel_size,
            args.board_sigma,
            &options,
        )?;
        progress.finish_and_clear();
        for line in &cal.failed {
            output.status(format!("left out: {line}"));
        }
        cal.write(out, plots, output)?;
        output.status(format!(
            "start from the homographies: f = {:.1} px; adjusted: f = {:.2} ± {:.2} px",
            cal.start_f_px,
            cal.file.inner.f / args.pixel_size,
            cal.file.sigma.f / args.pixel_size
        ));
        return camera_result(&cal.file, &cal.residuals, &options, out, output);
    }
    let Some(init) = &args.init else {
        anyhow::bail!("give --init FILE (or --board with --images)");
    };
    let control = args.control.as_deref();
    let folder = control.and_then(|c| args.folder.clone().with_control(c));
    let leftover = ObservationsGuard::new(out);
    let obs = match (&args.obs, folder) {
        (Some(obs), _) => obs.clone(),
        (None, Some(folder)) => {
            let start = read_camera(init)?;
            folder_observations(&folder, &start.grid(), &start.inner(), None, out, output)?
        }
        _ => anyhow::bail!("give --obs FILE, or --images DIR with --control FILE"),
    };
    let progress = output.progress(format!("calibrating the camera from {}", obs.display()));
    let (file, residuals, plots_made) =
        calibrate_files_with_residuals(init, &obs, control, out, &options, plots)?;
    progress.finish_and_clear();
    report_plots(plots, &plots_made, output);
    camera_result(&file, &residuals, &options, out, output)?;
    leftover.keep();
    Ok(())
}

/// The end of `calibrate camera`: the residuals' summary (with the σ0 warning) and where the
/// files went on stderr, the calibrated camera on stdout (text or JSON).
fn camera_result(
    file: &CameraFile,
    residuals: &[Residual],
    options: &CalibrationOptions,
    out: &Path,
    output: Output,
) -> Result<()> {
    output.status(format!(
        "{}camera calibration -> {}, residuals -> {}",
        summary(
            residuals,
            file.sigma0.unwrap_or(f64::NAN) / file.pixel_size,
            options.image_sigma_px
        ),
        out.display(),
        residuals_path(out).display()
    ));
    let mut json = serde_json::to_value(file)?;
    json["out"] = serde_json::json!(out);
    output.result(&camera_summary(file, &options.free.inner), &json)
}

/// The calibrated camera for people: the estimated parameters with σ and units, then σ0, RMS
/// (per coordinate) and the rejected observations.
fn camera_summary(file: &CameraFile, free: &[bool; 8]) -> String {
    const UNITS: [&str; 8] = ["mm", "mm", "mm", "mm⁻²", "mm⁻⁴", "mm⁻⁶", "mm⁻¹", "mm⁻¹"];
    let (values, sigma) = (file.inner.to_array(), file.sigma.to_array());
    let mut text = String::new();
    for k in (0..8).filter(|k| free[*k]) {
        let (name, unit) = (INNER_NAMES[k], UNITS[k]);
        text += &if k < 3 {
            format!("{name:>3} = {:9.4} ± {:.4} {unit}\n", values[k], sigma[k])
        } else {
            format!(
                "{name:>3} = {:10.3e} ± {:.2e} {unit}\n",
                values[k], sigma[k]
            )
        };
    }
    text += &format!(
        "σ0 = {:.4} mm in the image, RMS {:.3} px per coordinate ({:.3} px per point), \
         {} iterations, {} rejected, {} correlations > 0.9\n",
        file.sigma0.unwrap_or(f64::NAN),
        file.rms_px.unwrap_or(f64::NAN),
        file.rms_px.unwrap_or(f64::NAN) * 2f64.sqrt(),
        file.iterations.unwrap_or(0),
        file.rejected.len(),
        file.correlations.len()
    );
    for r in &file.rejected {
        text += &format!(
            "rejected: image {} point {} ({:.1} px)\n",
            r.image, r.point, r.residual_px
        );
    }
    text
}
