//! `deltaz resect`.

use super::args::OutputArgs;
use crate::io::atomic::write_json_atomic;
use crate::io::camera_file::read_camera;
use crate::io::control::read_control;
use crate::io::observations::read_observations;
use crate::io::poses::PosesFile;
use crate::report::console::Output;
use crate::workflows::plates::{check_on_sensor, resect_images};
use anyhow::Result;
use std::path::PathBuf;

/// Arguments of `deltaz resect`.
#[derive(clap::Args)]
pub struct Args {
    /// camera.json (or camera_init.json) with the inner orientation.
    #[arg(long)]
    camera: PathBuf,
    /// Observations CSV (image,point,col,row[,kind]); dots are skipped.
    #[arg(long)]
    obs: PathBuf,
    /// Control CSV (point,X,Y,Z,sigma).
    #[arg(long)]
    control: PathBuf,
    /// Also write the poses as JSON ("deltaz.poses/1").
    #[arg(long)]
    out: Option<PathBuf>,
    #[command(flatten)]
    output: OutputArgs,
}

/// Runs `deltaz resect`.
pub fn exec(args: Args) -> Result<()> {
    let output = Output::from(args.output);
    let cam = read_camera(&args.camera)?;
    let observations = read_observations(&args.obs)?;
    let control = read_control(&args.control)?;
    check_on_sensor(&args.obs, &cam.grid(), &observations)?;
    let results = resect_images(
        &args.obs,
        &cam.grid(),
        &cam.inner(),
        &observations,
        &control,
    )?;
    let poses = PosesFile::new(&results);
    if let Some(out) = &args.out {
        write_json_atomic(out, &poses)?;
        output.status(format!(
            "{} poses -> {}",
            poses.stations.len(),
            out.display()
        ));
    }
    output.result(&poses.table(), &serde_json::to_value(&poses)?)
}
