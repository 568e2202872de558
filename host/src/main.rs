//! `deltaz`: the command-line front end.
use clap::{Parser, Subcommand};
use deltaz_host::{bundle, io, resection, simulate};
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
    /// Calibration steps.
    Calibrate {
        #[command(subcommand)]
        what: CalibrateWhat,
    },
    /// Timings: camera calibration of the paper scenario and of a large network.
    Bench {
        /// Images of the large network.
        #[arg(long, default_value_t = 200)]
        images: u32,
        /// Targets of the large network.
        #[arg(long, default_value_t = 1000)]
        targets: u32,
    },
}

#[derive(Subcommand)]
enum CalibrateWhat {
    /// Camera calibration by self-calibrating bundle adjustment (f, cx, cy, k1 by default).
    Camera {
        /// The starting sensor: camera_init.json (pixel mapping, approximate f).
        #[arg(long)]
        init: PathBuf,
        /// Target observations CSV.
        #[arg(long)]
        obs: PathBuf,
        /// Control CSV (point,X,Y,Z,sigma); without it the network is free (arbitrary datum).
        #[arg(long)]
        control: Option<PathBuf>,
        /// Output camera.json.
        #[arg(long)]
        out: PathBuf,
        /// Also estimate k2.
        #[arg(long)]
        k2: bool,
        /// Also estimate k3.
        #[arg(long)]
        k3: bool,
        /// Also estimate p1.
        #[arg(long)]
        p1: bool,
        /// Also estimate p2.
        #[arg(long)]
        p2: bool,
        /// Free network: control only gives approximate values; minimal constraints.
        #[arg(long)]
        free_network: bool,
        /// A priori σ of image coordinates (px), weighting control against images.
        #[arg(long, default_value_t = 0.5)]
        image_sigma_px: f64,
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
        Command::Calibrate {
            what:
                CalibrateWhat::Camera {
                    init,
                    obs,
                    control,
                    out,
                    k2,
                    k3,
                    p1,
                    p2,
                    free_network,
                    image_sigma_px,
                },
        } => {
            let mut options = bundle::CalibrationOptions {
                free_network,
                image_sigma_px,
                ..Default::default()
            };
            for (k, on) in [(4, k2), (5, k3), (6, p1), (7, p2)] {
                options.free.inner[k] |= on;
            }
            let file = bundle::calibrate_files(&init, &obs, control.as_deref(), &out, &options)?;
            print!("{}", bundle::summary(&file, &options.free));
        }
        Command::Bench { images, targets } => {
            for scenario in [
                simulate::Scenario::paper(),
                simulate::Scenario::large(images, targets),
            ] {
                let sim = simulate::simulate(&scenario, 1);
                let options = bundle::CalibrationOptions::default();
                let start = std::time::Instant::now();
                let problem = bundle::build_problem(
                    std::path::Path::new("simulated"),
                    &sim.camera_init.grid(),
                    &sim.camera_init.inner(),
                    &sim.camera_obs,
                    &sim.camera_control,
                    &options,
                )?;
                let cal = bundle::calibrate(problem, &options)?;
                let file = cal.camera_file(&sim.camera_obs);
                println!(
                    "{}: {} images, {} targets, {} observations: {:.3} s, {} LM iterations, σ0 {:.4} mm, {} correlations > 0.9",
                    scenario.name,
                    cal.problem.images.len(),
                    cal.problem.xyz.len(),
                    sim.camera_obs.len(),
                    start.elapsed().as_secs_f64(),
                    cal.iterations,
                    cal.solution.sigma0,
                    file.correlations.len()
                );
            }
        }
    }
    Ok(())
}
