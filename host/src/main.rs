//! `deltaz`: the command-line front end.
use clap::{Parser, Subcommand};
use deltaz_host::{io, measure, resection, simulate};
use std::path::PathBuf;

/// deltaz: structured-light measurement (camera + dot projector).
#[derive(Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate a scenario: camera_init.json, camera_obs.csv, camera_control.csv, plate_obs.csv,
    /// plate_control.csv and truth.json in the output directory.
    Simulate {
        /// `paper` (built in) or a scenario TOML file.
        #[arg(long)]
        scenario: String,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Random seed (default: the scenario's).
        #[arg(long)]
        seed: Option<u64>,
    },
    /// Space resection: the exterior orientation of every image from known control.
    Resect {
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
    },
    /// Measure targets and dots in images (PNG, TIFF, JPEG): sub-pixel centres into an
    /// observations CSV (image = file stem, point = m1, m2, ... in row-major order).
    Measure {
        /// Image files.
        #[arg(required = true)]
        images: Vec<PathBuf>,
        /// Observations CSV to write.
        #[arg(long)]
        out: PathBuf,
        /// Targets are darker than the background.
        #[arg(long)]
        dark: bool,
        /// Use the paper's gravity centre instead of the (more precise) template fit.
        #[arg(long)]
        gravity: bool,
    },
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Command::Simulate {
            scenario,
            out,
            seed,
        } => {
            let scenario = simulate::load_scenario(&scenario)?;
            let sim = simulate::simulate(&scenario, seed.unwrap_or(scenario.seed));
            simulate::write_simulation(&out, &sim)?;
            println!(
                "{}: {} field observations in {} images, {} plate observations in {} images -> {}",
                scenario.name,
                sim.camera_obs.len(),
                sim.truth.stations.len(),
                sim.plate_obs.len(),
                sim.truth.plate.images.len(),
                out.display()
            );
        }
        Command::Resect {
            camera,
            obs,
            control,
            out,
        } => {
            let cam = io::camera_file::read_camera(&camera)?;
            let observations = io::observations::read_observations(&obs)?;
            let control = io::control::read_control(&control)?;
            let results =
                resection::resect_images(&obs, &cam.grid(), &cam.inner(), &observations, &control)?;
            let poses = resection::PosesFile::new(&results);
            print!("{}", poses.table());
            if let Some(out) = out {
                io::atomic::write_json_atomic(&out, &poses)?;
            }
        }
        Command::Measure {
            images,
            out,
            dark,
            gravity,
        } => {
            let mut params = measure::MeasureParams::default();
            if dark {
                params.detect.polarity = measure::detect::Polarity::Dark;
            }
            if gravity {
                params.method = measure::CentreMethod::Gravity;
            }
            let observations = measure::measure_images(&images, &params)?;
            io::observations::write_observations(&out, &observations)?;
            println!(
                "{} targets in {} images -> {}",
                observations.len(),
                images.len(),
                out.display()
            );
        }
    }
    Ok(())
}
