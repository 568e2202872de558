//! `deltaz bench`.

use super::args::OutputArgs;
use crate::report::console::Output;
use crate::workflows::bench;
use anyhow::Result;

/// Arguments of `deltaz bench`.
#[derive(clap::Args)]
pub struct Args {
    /// Images of the large network, 2 to 5,000.
    #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(u32).range(2..=5_000))]
    images: u32,
    /// Targets of the large network, 4 to 100,000.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(4..=100_000))]
    targets: u32,
    #[command(flatten)]
    output: OutputArgs,
}

/// Runs `deltaz bench`.
pub fn exec(args: Args) -> Result<()> {
    let output = Output::from(args.output);
    let (text, runs) = bench::calibration(args.images, args.targets, output)?;
    output.result(&text, &serde_json::json!({ "runs": runs }))
}
