//! `deltaz`: the command-line front end.
use clap::Parser;

/// deltaz: structured-light measurement (camera + dot projector).
#[derive(Parser)]
#[command(version, about)]
struct Cli {}

fn main() -> anyhow::Result<()> {
    Cli::parse();
    Ok(())
}
