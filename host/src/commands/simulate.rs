//! `deltaz simulate`.

use crate::report::console::Output;
use crate::simulate::{self, images::ImageSpec};
use crate::workflows::system::simulated_system;
use anyhow::Result;
use deltaz_measure::render::BitDepth;
use std::path::PathBuf;

/// Arguments of `deltaz simulate`.
#[derive(clap::Args)]
pub struct Args {
    /// `paper`, `desk`, `back` (built in) or a scenario TOML file.
    #[arg(long)]
    scenario: String,
    /// Output directory.
    #[arg(long)]
    out: PathBuf,
    /// Random seed (default: the scenario's).
    #[arg(long)]
    seed: Option<u64>,
    /// Also render the images (PNG) into OUT/images, true centres in images/centres.csv.
    #[arg(long)]
    images: bool,
    /// 16-bit PNG instead of 8-bit (with --images).
    #[arg(long)]
    sixteen_bit: bool,
}

/// Runs `deltaz simulate`.
pub fn exec(args: Args) -> Result<()> {
    let scenario = simulate::load_scenario(&args.scenario)?;
    let seed = args.seed.unwrap_or(scenario.seed);
    let spec = args.images.then(|| ImageSpec {
        depth: if args.sixteen_bit {
            BitDepth::Sixteen
        } else {
            BitDepth::Eight
        },
        ..Default::default()
    });
    let progress = spec
        .map(|_| Output::default().progress(format!("rendering the images of {}", scenario.name)));
    // A scenario with a back comes with its calibration, as `calibrate system` gives it.
    let system = match &scenario.back {
        Some(_) => Some(simulated_system(&simulate::simulate(&scenario, seed))?),
        None => None,
    };
    let extra: Vec<(&str, &[u8])> = system
        .iter()
        .map(|json| ("system.json", json.as_bytes()))
        .collect();
    let written = simulate::write_scenario(&args.out, &scenario, seed, spec.as_ref(), &extra)?;
    if let Some(progress) = progress {
        progress.finish_and_clear();
    }
    if let Some(counts) = written.rendered {
        let images = args.out.join("images");
        println!("{} images -> {}", counts.images, images.display());
        println!(
            "{} test object frames -> {}",
            counts.objects,
            images.join("objects").display()
        );
        if counts.back > 0 {
            println!(
                "{} back frames -> {}",
                counts.back,
                images.join("back").display()
            );
        }
    }
    let sim = &written.simulation;
    println!(
        "{}: {} field observations in {} images, {} plate observations in {} images -> {}",
        scenario.name,
        sim.camera_obs.len(),
        sim.truth.stations.len(),
        sim.plate_obs.len(),
        sim.truth.plate.images.len(),
        args.out.display()
    );
    Ok(())
}
