//! `deltaz bench-measure`.

use crate::report::console::Output;
use crate::workflows::bench;
use anyhow::Result;

/// Arguments of `deltaz bench-measure`.
#[derive(clap::Args)]
pub struct Args {
    /// Repetitions (the best is reported), 1 to 100.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u16).range(1..=100))]
    repeats: u16,
}

/// Runs `deltaz bench-measure`: image measurement, dot identification, the scan pipeline.
pub fn exec(args: Args) -> Result<()> {
    type Step<'a> = Box<dyn Fn() -> Result<String> + 'a>;
    let steps: [(&str, Step); 3] = [
        (
            "image measurement",
            Box::new(|| Ok(deltaz_measure::bench::run(args.repeats.into()))),
        ),
        (
            "dot identification",
            Box::new(|| Ok(bench::identification())),
        ),
        ("the scan pipeline", Box::new(bench::scans)),
    ];
    for (what, step) in steps {
        let progress = Output::default().progress(format!("benchmarking {what}"));
        let text = step()?;
        progress.finish_and_clear();
        print!("{text}");
    }
    Ok(())
}
