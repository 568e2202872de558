//! `deltaz bench-reconstruct`.

use super::args::OutputArgs;
use crate::report::console::Output;
use crate::workflows::bench_reconstruct::reconstruct_scaling;
use anyhow::Result;

/// Arguments of `deltaz bench-reconstruct`.
#[derive(clap::Args)]
pub struct Args {
    /// Dots, 1,000 to 100,000,000.
    #[arg(long, default_value_t = 1_000_000,
          value_parser = clap::value_parser!(u64).range(1_000..=100_000_000))]
    dots: u64,
    /// The numbers of images the same dots are split over (comma-separated; each must divide
    /// the dots, the fewest get the numpy script too).
    #[arg(long, value_delimiter = ',', default_values_t = [2_000u64, 20_000],
          value_parser = clap::value_parser!(u64).range(1..=100_000_000))]
    images: Vec<u64>,
    #[command(flatten)]
    output: OutputArgs,
}

/// Runs `deltaz bench-reconstruct`.
pub fn exec(args: Args) -> Result<()> {
    let output = Output::from(args.output);
    let images: Vec<usize> = args.images.iter().map(|&n| n as usize).collect();
    let (text, runs) = reconstruct_scaling(args.dots as usize, &images, output)?;
    output.result(&text, &serde_json::json!({ "runs": runs }))
}
