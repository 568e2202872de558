//! `deltaz compare`.

use super::args::OutputArgs;
use crate::io::read_points;
use crate::report::console::Output;
use anyhow::Result;
use deltaz_calib::compare::{assess, check_not_collinear, match_points};
use std::path::PathBuf;

/// Arguments of `deltaz compare`.
#[derive(clap::Args)]
pub struct Args {
    /// Reconstructed points (mm).
    #[arg(long)]
    reconstructed: PathBuf,
    /// Reference points (mm).
    #[arg(long)]
    reference: PathBuf,
    #[command(flatten)]
    output: OutputArgs,
}

/// Runs `deltaz compare`.
pub fn exec(args: Args) -> Result<()> {
    let (reconstructed, reference) = (&args.reconstructed, &args.reference);
    let matched =
        match_points(&read_points(reconstructed)?, &read_points(reference)?).map_err(|e| {
            anyhow::anyhow!(
                "{} against {}: {e:#}",
                reconstructed.display(),
                reference.display()
            )
        })?;
    for (path, points) in [
        (reconstructed, &matched.reconstructed),
        (reference, &matched.reference),
    ] {
        check_not_collinear(points).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    }
    let a = assess(&matched.reconstructed, &matched.reference)?;
    Output::from(args.output).result(&a.to_text(&matched.labels), &a.to_json(&matched.labels))
}
