//! `deltaz reconstruct`.

use super::args::{positive, FrameArg, MethodArg, OutputArgs};
use crate::report::console::Output;
use crate::workflows::reconstruct::{reconstruct_stream, ReconstructArgs};
use anyhow::Result;
use std::path::PathBuf;

/// Arguments of `deltaz reconstruct`.
#[derive(clap::Args)]
pub struct Args {
    /// The calibrated system (system.json).
    #[arg(long)]
    system: PathBuf,
    /// Dot observations.
    #[arg(long)]
    obs: PathBuf,
    /// Output PLY file.
    #[arg(long)]
    out: PathBuf,
    /// Also write a CSV `image,point,X,Y,Z,miss[,sigma_X,sigma_Y,sigma_Z]` here (mm).
    #[arg(long)]
    csv: Option<PathBuf>,
    /// ASCII PLY instead of binary.
    #[arg(long)]
    ascii: bool,
    /// Image noise (px, > 0): adds the propagated σ of every point (mm).
    #[arg(long, value_parser = positive, allow_negative_numbers = true)]
    sigma_px: Option<f64>,
    /// Intersection: eqs (8)-(9) (`paper`) or the closest approach (`closest`).
    #[arg(long, default_value = "closest")]
    method: MethodArg,
    /// The points' frame: `camera` (the instrument's own) or `plate` (the control frame of the
    /// datum plate image of `calibrate system`, the transform's σ included). Default: the
    /// system's own frame (the camera system for `calibrate system`, the 1st plate image's
    /// frame for `calibrate projector`); a frame the system cannot give is an error.
    #[arg(long)]
    frame: Option<FrameArg>,
    #[command(flatten)]
    output: OutputArgs,
}

/// Runs `deltaz reconstruct`: streamed, nothing written on failure.
pub fn exec(args: Args) -> Result<()> {
    let output = Output::from(args.output);
    let progress = output.progress(format!("reconstructing {}", args.obs.display()));
    let s = reconstruct_stream(&ReconstructArgs {
        system: args.system,
        obs: args.obs.clone(),
        out: args.out.clone(),
        csv: args.csv.clone(),
        ascii: args.ascii,
        sigma_px: args.sigma_px,
        method: args.method.into(),
        frame: args.frame.map(Into::into),
    })?;
    progress.finish_and_clear();
    output.result(
        &format!(
            "{} points from {} images, miss distance RMS {:.3} mm, in {} (mm) -> {}\n",
            s.points,
            s.images,
            s.miss_rms,
            s.frame,
            args.out.display()
        ),
        &serde_json::json!({
            "points": s.points,
            "images": s.images,
            "miss_rms_mm": s.miss_rms,
            "frame": s.frame,
            "fingerprint": s.fingerprint,
            "out": args.out,
            "csv": args.csv,
        }),
    )
}
