//! `deltaz measure`.

use super::args::{positive, PolarityArgs};
use crate::io::observations::write_observations;
use crate::io::system_file::SystemFile;
use crate::workflows::observations::measure_images;
use anyhow::Result;
use deltaz_measure::board::Board;
use deltaz_measure::{CentreMethod, HostIdentifier, MeasureParams};
use deltaz_shared::identify::DepthRange;
use std::path::PathBuf;

/// Arguments of `deltaz measure`.
#[derive(clap::Args)]
pub struct Args {
    /// Image files.
    #[arg(required = true)]
    images: Vec<PathBuf>,
    /// Observations CSV to write.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    polarity: PolarityArgs,
    /// Use the paper's gravity centre instead of the (more precise) template fit.
    #[arg(long)]
    gravity: bool,
    /// Find a circle-grid board, `circles:COLSxROWS[:SPACING_MM]` or
    /// `acircles:COLSxROWS[:SPACING_MM]` (OpenCV's pattern size): its circles are written
    /// as points `rIcJ` (row I, column J), the other targets left out. The order is
    /// OpenCV's: the board seen from its front (from the column direction to the row
    /// direction clockwise in the image), then of the board's rotations onto itself the one
    /// with column 0 at the left (and row 0 at the top when upright).
    #[arg(long, conflicts_with = "system")]
    board: Option<Board>,
    /// Identify the projected dots with this calibrated system.json: identified dots are
    /// written as `dot` rows (point = ray id), every other dot is reported.
    #[arg(long, requires_all = ["near", "far"])]
    system: Option<PathBuf>,
    /// Nearest surface distance from the camera along its axis (mm).
    #[arg(long)]
    near: Option<f64>,
    /// Farthest surface distance from the camera along its axis (mm).
    #[arg(long)]
    far: Option<f64>,
    /// Largest distance of a dot from its ray's epipolar segment (px).
    #[arg(long, default_value_t = 1.0, value_parser = positive, allow_negative_numbers = true)]
    tolerance: f64,
    /// With --system: also one line per dot that is not identified, and why.
    #[arg(long, requires = "system")]
    verbose: bool,
}

/// Runs `deltaz measure`.
pub fn exec(args: Args) -> Result<()> {
    let mut params = MeasureParams::default();
    params.detect.polarity = args.polarity.polarity(args.board.is_some());
    if args.gravity {
        params.method = CentreMethod::Gravity;
    }
    params.board = args.board;
    let identifier = match (&args.system, args.near, args.far) {
        (Some(path), Some(near), Some(far)) => {
            let (_, rig) = SystemFile::load(path)?;
            params.sensor = Some((rig.grid().width, rig.grid().height));
            let cell = if rig.grid().width > 2000 { 32.0 } else { 16.0 };
            let depth = DepthRange { near, far };
            let built = HostIdentifier::new(&rig, depth, args.tolerance, cell)
                .map_err(|e| anyhow::anyhow!("{}: identification: {e}", path.display()))?;
            Some(Box::new(built))
        }
        _ => None,
    };
    let images = &args.images;
    let measured = measure_images(images, &params, identifier.as_deref())?;
    if measured.failed.len() == images.len() {
        anyhow::bail!("{}", measured.failed.join("\n"));
    }
    write_observations(&args.out, &measured.observations)?;
    for line in &measured.summaries {
        println!("{line}");
    }
    if args.verbose {
        for line in &measured.unidentified {
            println!("not identified: {line}");
        }
    }
    let identified = if identifier.is_none() {
        String::new()
    } else {
        format!(
            " ({} dots not identified{})",
            measured.unidentified.len(),
            if args.verbose {
                ""
            } else {
                "; --verbose lists them"
            }
        )
    };
    println!(
        "{} observations in {} images{identified} -> {}",
        measured.observations.len(),
        images.len() - measured.failed.len(),
        args.out.display()
    );
    for line in &measured.failed {
        eprintln!("{line}");
    }
    if !measured.failed.is_empty() {
        anyhow::bail!(
            "{} of {} images not measured (see above)",
            measured.failed.len(),
            images.len()
        );
    }
    Ok(())
}
