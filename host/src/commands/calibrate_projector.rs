//! `deltaz calibrate projector`.

use super::args::{pair, positive, ImageFolder, OutputArgs, PlotsArg};
use crate::io::camera_file::read_camera;
use crate::io::system_file::SystemFile;
use crate::report::calibration_plots::write_with_plots;
use crate::report::console::Output;
use crate::simulate::load_scenario;
use crate::workflows::observations::{folder_observations, DotGrid, ObservationsGuard};
use crate::workflows::projector::calibrate_projector;
use anyhow::Result;
use deltaz_calib::projector_calibration::Model;
use nalgebra::Vector2;
use std::path::PathBuf;

/// Arguments of `deltaz calibrate projector`.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// camera.json (inner orientation and pixel mapping).
    #[arg(long)]
    camera: PathBuf,
    /// The plate's control CSV (point,X,Y,Z,sigma; plate surface at Z = 0).
    #[arg(long)]
    control: PathBuf,
    /// Output system.json.
    #[arg(long)]
    out: PathBuf,
    /// `joint` (the whole-system adjustment with the camera as a prior: the σ of camera,
    /// poses, projector and dots; the camera system), `noncentral` (the same, every ray a free
    /// line) or `paper` (eqs 11-14, its σ from the dots alone, camera and poses taken as exact;
    /// the plate frame of the 1st plate image).
    #[arg(long, default_value = "joint")]
    model: Model,
    /// Image noise (px, > 0): `paper` weights the plane points and gives the rays' covariances
    /// with it; `joint` and `noncentral` start from it and estimate it.
    #[arg(long, default_value_t = 0.5, value_parser = positive, allow_negative_numbers = true)]
    image_sigma_px: f64,
    #[command(flatten)]
    plots: PlotsArg,
    /// Images that cannot be resected and rays seen on one plate are errors.
    #[arg(long)]
    strict: bool,
    /// Plate observations CSV `image,point,col,row,kind`: `control` rows resect each image,
    /// `dot` rows (point = ray id) calibrate the projector (`paper`: the 1st image's frame).
    #[arg(long, required_unless_present = "images")]
    obs: Option<PathBuf>,
    #[command(flatten)]
    folder: ImageFolder,
    /// With --images: the projected pattern, `paper` or a scenario TOML file (its rig's
    /// pattern: grid size and node ids); the dots are labelled by the grid walk.
    #[arg(long, default_value = "paper")]
    pattern: String,
    /// With --images: the marker dot's grid node ROW,COL.
    #[arg(long, value_parser = pair::<u16>, default_value = "10,11")]
    marker: [u16; 2],
    /// With --images: image direction COL,ROW in which the pattern's column index grows.
    #[arg(long, value_parser = pair::<f64>, default_value = "1,0", allow_hyphen_values = true)]
    col_dir: [f64; 2],
    /// With --images: image direction COL,ROW in which the pattern's row index grows.
    #[arg(long, value_parser = pair::<f64>, default_value = "0,-1", allow_hyphen_values = true)]
    row_dir: [f64; 2],
    #[command(flatten)]
    output: OutputArgs,
}

/// Runs `deltaz calibrate projector`: resection per image (step 4), then the projector with the
/// camera as a prior (or the paper's steps 5-7), system.json written atomically only when
/// everything succeeded. Images too poorly
/// controlled to resect and rays seen on one plate are left out (or, central models, determined
/// through the centre) and listed on stderr and in the file; `--strict` makes them errors.
pub fn exec(args: Args) -> Result<()> {
    let output = Output::from(args.output);
    let leftover = ObservationsGuard::new(&args.out);
    let obs = match (args.obs, args.folder.with_control(&args.control)) {
        (Some(obs), _) => obs,
        (None, Some(folder)) => {
            let cam = read_camera(&args.camera)?;
            let dots = DotGrid {
                pattern: load_scenario(&args.pattern)?.rig.pattern,
                marker: (args.marker[0], args.marker[1]),
                col_dir: Vector2::from(args.col_dir),
                row_dir: Vector2::from(args.row_dir),
            };
            folder_observations(
                &folder,
                &cam.grid(),
                &cam.inner(),
                Some(&dots),
                &args.out,
                output,
            )?
        }
        (None, None) => anyhow::bail!("give --obs FILE or --images DIR"),
    };
    let progress = output.progress(format!("calibrating the projector from {}", obs.display()));
    let system = calibrate_projector(
        &args.camera,
        &args.control,
        &obs,
        args.model,
        args.image_sigma_px,
    )?;
    progress.finish_and_clear();
    for note in &system.notes {
        eprintln!("warning: {note}");
    }
    let warnings = &system.content.warnings;
    if args.strict {
        warnings.strict(&obs)?;
    }
    for line in warnings.lines() {
        eprintln!("warning: {line}");
    }
    let rig = system.content.rig()?;
    let file = SystemFile::new(system.content.clone())?;
    let json = file.to_json()?;
    let files = [(args.out.as_path(), json.as_bytes())];
    write_with_plots(
        &files,
        args.plots.plots.as_deref(),
        || system.plots(&rig),
        output,
    )?;
    let projector = &file.content.projector;
    let worst = (projector.rays.iter()).max_by(|a, b| a.miss_rms.total_cmp(&b.miss_rms));
    let (c, cs, model) = (&projector.centre, &projector.centre_sigma, args.model);
    output.result(
        &format!(
            "{model:?} model: projector centre ({:.2}, {:.2}, {:.2}) ± ({:.2}, {:.2}, {:.2}) mm \
             in {}, {} rays{}; fingerprint {} -> {}\n",
            c[0],
            c[1],
            c[2],
            cs[0],
            cs[1],
            cs[2],
            file.content.frame,
            projector.rays.len(),
            worst.map_or(String::new(), |w| format!(
                ", worst ray {} misses its plane points by {:.3} mm RMS",
                w.id, w.miss_rms
            )),
            file.fingerprint,
            args.out.display()
        ),
        &serde_json::json!({
            "model": format!("{model:?}").to_lowercase(),
            "frame": file.content.frame.to_string(),
            "centre_mm": c,
            "centre_sigma_mm": cs,
            "rays": projector.rays.len(),
            "worst_ray": worst.map(|w| serde_json::json!({"id": w.id, "miss_rms_mm": w.miss_rms})),
            "fingerprint": file.fingerprint,
            "out": args.out,
        }),
    )?;
    leftover.keep();
    Ok(())
}
