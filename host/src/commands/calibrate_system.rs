//! `deltaz calibrate system`.

use super::args::{OutputArgs, PlotsArg};
use crate::io::camera_file::read_camera;
use crate::io::control::read_control;
use crate::io::observations::read_observations;
use crate::io::system_file::SystemFile;
use crate::report::calibration_plots::{
    control_residuals, system_plots, write_with_plots, PlateView,
};
use crate::report::console::Output;
use crate::workflows::camera::Targets;
use crate::workflows::plates::check_on_sensor;
use crate::workflows::system::calibrate_system;
use anyhow::Result;
use deltaz_calib::bundle::CalibrationOptions;
use std::path::PathBuf;

/// Arguments of `deltaz calibrate system`.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// The starting sensor: camera_init.json (pixel mapping, approximate f).
    #[arg(long)]
    init: PathBuf,
    /// Target-field observations CSV.
    #[arg(long)]
    camera_obs: PathBuf,
    /// Target-field control CSV (without it the field network is free).
    #[arg(long)]
    camera_control: Option<PathBuf>,
    /// The plate's control CSV (point,X,Y,Z,sigma; plate surface at Z = 0).
    #[arg(long)]
    control: PathBuf,
    /// Plate observations CSV (`control` rows resect, `dot` rows calibrate the projector).
    #[arg(long)]
    obs: PathBuf,
    /// Output system.json.
    #[arg(long)]
    out: PathBuf,
    /// Every ray a free line (rays seen on one plate are then left out).
    #[arg(long)]
    noncentral: bool,
    /// Images that cannot be resected and rays seen on one plate are errors.
    #[arg(long)]
    strict: bool,
    #[command(flatten)]
    plots: PlotsArg,
    #[command(flatten)]
    output: OutputArgs,
}

/// Runs `deltaz calibrate system`: the camera by bundle adjustment and the plate images by
/// resection (the starts), then the camera's inner orientation, the field and plate images, both
/// controls and the projector in one whole-system adjustment with a variance component per group
/// (field targets, plate targets, dots); system.json in the camera system with the covariance a
/// point's σ needs. Images that cannot be resected and rays seen on one plate are listed (in the
/// file too); `--strict` makes them errors. Nothing is written if anything fails.
pub fn exec(args: Args) -> Result<()> {
    let output = Output::from(args.output);
    let start = read_camera(&args.init)?;
    let grid = start.grid();
    let field = read_observations(&args.camera_obs)?;
    let field_control = match &args.camera_control {
        Some(path) => read_control(path)?,
        None => Vec::new(),
    };
    let control = read_control(&args.control)?;
    let observations = read_observations(&args.obs)?;
    check_on_sensor(&args.camera_obs, &grid, &field)?;
    check_on_sensor(&args.obs, &grid, &observations)?;
    let progress = output.progress(format!(
        "calibrating the system from {} and {}",
        args.camera_obs.display(),
        args.obs.display()
    ));
    let system = calibrate_system(
        grid,
        &start.inner(),
        Targets {
            path: &args.camera_obs,
            observations: &field,
            control: &field_control,
        },
        Targets {
            path: &args.obs,
            observations: &observations,
            control: &control,
        },
        &CalibrationOptions::default(),
        args.noncentral,
    )?;
    progress.finish_and_clear();
    let warnings = &system.content.warnings;
    if args.strict {
        warnings.strict(&args.obs)?;
    }
    for line in warnings.lines() {
        eprintln!("warning: {line}");
    }
    let rig = system.content.rig()?;
    let file = SystemFile::new(system.content.clone())?;
    let json = file.to_json()?;
    let make = || {
        // The plate targets' residuals in the whole-system adjustment (its inner orientation
        // and plate poses), not the field's in the bundle adjustment that only started it.
        let adjustment = &system.adjustment;
        let poses: Vec<_> = (system.plates.iter().zip(&adjustment.poses))
            .map(|(p, exterior)| (p.image.clone(), *exterior))
            .collect();
        let residuals = control_residuals(
            &grid,
            &adjustment.model.inner,
            &poses,
            &observations,
            &control,
        );
        let rays: Vec<_> = adjustment
            .model
            .rays
            .iter()
            .map(|r| (r.id, (r.planes > 1).then_some((r.miss_rms, r.miss_max))))
            .collect();
        let views: Vec<_> = system
            .plates
            .iter()
            .zip(&adjustment.poses)
            .map(|(p, exterior)| PlateView {
                image: &p.image,
                exterior: *exterior,
                dots: &p.dots,
            })
            .collect();
        system_plots(&residuals, &grid, &rays, &rig, &views)
    };
    let files = [(args.out.as_path(), json.as_bytes())];
    write_with_plots(&files, args.plots.plots.as_deref(), make, output)?;
    let (adjustment, m) = (&system.adjustment, &system.adjustment.model);
    let sigma = m.centre_sigma();
    output.result(
        &format!(
            "system: projector centre ({:.2}, {:.2}, {:.2}) ± ({:.2}, {:.2}, {:.2}) mm in the \
             camera system, {} rays; σ0 field targets {}, plate targets {:.3} px, dots {:.3} px; \
             fingerprint {} -> {}\n",
            m.centre.x,
            m.centre.y,
            m.centre.z,
            sigma.x,
            sigma.y,
            sigma.z,
            m.rays.len(),
            adjustment
                .sigma_field_px
                .map_or_else(|| "–".to_owned(), |s| format!("{s:.3} px")),
            adjustment.sigma_targets_px,
            m.sigma_dots_px,
            file.fingerprint,
            args.out.display()
        ),
        &serde_json::json!({
            "frame": file.content.frame.to_string(),
            "centre_mm": m.centre.as_slice(),
            "centre_sigma_mm": sigma.as_slice(),
            "rays": m.rays.len(),
            "sigma_field_px": adjustment.sigma_field_px,
            "sigma_targets_px": adjustment.sigma_targets_px,
            "sigma_dots_px": m.sigma_dots_px,
            "fingerprint": file.fingerprint,
            "out": args.out,
        }),
    )
}
