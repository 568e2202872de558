//! `deltaz demo`.

use crate::report::console::Output;
use crate::workflows::demo;
use anyhow::Result;
use std::path::PathBuf;

/// Arguments of `deltaz demo`.
#[derive(clap::Args)]
pub struct Args {
    /// Output directory.
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// Random seed of the simulation.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Run from simulated image observations (0.5 px noise) instead of rendered images.
    #[arg(long)]
    observations: bool,
}

/// Runs `deltaz demo`.
pub fn exec(args: Args) -> Result<()> {
    let progress = Output::default().progress(format!(
        "running the demo (simulation, calibrations, reconstructions) -> {}",
        args.out.display()
    ));
    let summary = if args.observations {
        let report = demo::observations::run(&args.out, args.seed)?;
        demo::observations::summary(&report)
    } else {
        let report = demo::images::run(&args.out, args.seed)?;
        demo::images::summary(&report)?
    };
    progress.finish_and_clear();
    println!("{summary}");
    println!("-> {}", args.out.display());
    Ok(())
}
