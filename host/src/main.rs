//! `deltaz`: the command-line front end.
use clap::{Parser, Subcommand};
use deltaz_host::{bundle, cli, demo, device_cli, io, measure, simulate};
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
        /// Also render the images (PNG) into OUT/images, true centres in images/centres.csv.
        #[arg(long)]
        images: bool,
        /// 16-bit PNG instead of 8-bit (with --images).
        #[arg(long)]
        sixteen_bit: bool,
    },
    /// Accuracy assessment (Tables 6-7): 7-parameter similarity, residuals, n−1 std, absolute
    /// errors with no fit, flatness. Point files are CSV `point,X,Y,Z`, matched by `point`.
    Compare {
        /// Reconstructed points.
        #[arg(long)]
        reconstructed: PathBuf,
        /// Reference points.
        #[arg(long)]
        reference: PathBuf,
        /// Print JSON instead of tables.
        #[arg(long)]
        json: bool,
    },
    /// Reconstruct identified dots (CSV `image,point,col,row[,kind]`, `point` = ray id; with a
    /// `kind` column only the `dot` rows) into a PLY point cloud.
    Reconstruct {
        /// The calibrated system (system.json).
        #[arg(long)]
        system: PathBuf,
        /// Dot observations.
        #[arg(long)]
        obs: PathBuf,
        /// Output PLY file.
        #[arg(long)]
        out: PathBuf,
        /// Also write a CSV `image,point,X,Y,Z,miss[,sigma_X,sigma_Y,sigma_Z]` here.
        #[arg(long)]
        csv: Option<PathBuf>,
        /// ASCII PLY instead of binary.
        #[arg(long)]
        ascii: bool,
        /// Image noise (px): adds the propagated σ of every point.
        #[arg(long)]
        sigma_px: Option<f64>,
        /// Intersection: eqs (8)-(9) (`paper`) or the closest approach (`closest`).
        #[arg(long, default_value = "closest")]
        method: cli::MethodArg,
        /// The points' frame: `camera` (the instrument's own) or `plate` (the control frame of
        /// the datum plate image of `calibrate system`, the transform's σ included).
        #[arg(long, default_value = "camera")]
        frame: cli::FrameArg,
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
    /// The whole system on the simulated paper rig: camera and projector calibration, upload to
    /// the device, one frame of a torso-like surface; writes cloud.ply, report.md, report.json,
    /// system.json and SVG plots.
    Demo {
        /// Output directory.
        #[arg(long, default_value = "out")]
        out: PathBuf,
        /// Random seed of the simulation.
        #[arg(long, default_value_t = 1)]
        seed: u64,
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
        /// Identify the projected dots with this calibrated system.json: identified dots are
        /// written as `dot` rows (point = ray id), every other dot is reported.
        #[arg(long, requires_all = ["near", "far"])]
        system: Option<PathBuf>,
        /// Nearest surface distance from the camera along its axis (mm).
        #[arg(long)]
        near: Option<f64>,
        /// Farthest surface distance from the camera along its axis (mm).
        #[arg(long)]
        far: Option<f64>,
        /// Largest distance of a dot from its ray's epipolar segment (px).
        #[arg(long, default_value_t = 1.0)]
        tolerance: f64,
    },
    /// Timings of image measurement: 768 x 512 with 440 dots, 12 MP with 4,000 dots.
    BenchMeasure {
        /// Repetitions (the best is reported).
        #[arg(long, default_value_t = 3)]
        repeats: usize,
    },
    /// Calibration steps.
    Calibrate {
        #[command(subcommand)]
        what: CalibrateWhat,
    },
    /// The device: list ports, show its info, upload a calibration, stream centroids through it.
    /// Without --port or --qemu the firmware's logic runs in-process.
    Device {
        #[command(flatten)]
        link: LinkOpts,
        #[command(subcommand)]
        what: DeviceWhat,
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

/// How to reach the device.
#[derive(clap::Args)]
struct LinkOpts {
    /// Serial port of the device (see `deltaz device ports`).
    #[arg(long, global = true)]
    port: Option<String>,
    /// Baud rate of --port.
    #[arg(long, global = true, default_value_t = 2_000_000)]
    baud: u32,
    /// Run the firmware in QEMU (mps2-an386) and talk to it over a pty; optionally the ELF.
    #[arg(long, global = true, num_args = 0..=1,
          default_missing_value = "target/thumbv7em-none-eabihf/release/mps2_an386")]
    qemu: Option<PathBuf>,
    /// Response timeout (ms).
    #[arg(long, global = true, default_value_t = 3000)]
    timeout_ms: u64,
}

impl LinkOpts {
    fn args(&self) -> device_cli::LinkArgs {
        device_cli::LinkArgs {
            port: self.port.clone(),
            baud: self.baud,
            qemu: self.qemu.clone(),
            timeout: std::time::Duration::from_millis(self.timeout_ms),
        }
    }
}

#[derive(Subcommand)]
enum DeviceWhat {
    /// List the serial ports.
    Ports,
    /// Firmware and protocol version, capacities, the calibration's fingerprint.
    Info,
    /// Upload system.json in chunks, verified by reading the fingerprint back.
    Upload {
        /// The calibrated system.
        system: PathBuf,
        /// Intersection on the device.
        #[arg(long, default_value = "closest")]
        method: cli::MethodArg,
        #[command(flatten)]
        identification: DeviceIdentifyArgs,
    },
    /// Stream centroids (an observations CSV, one frame per image, or simulated frames) through
    /// the device into PLY and/or CSV, with a live points/s figure.
    Stream {
        /// The system the device must hold (uploaded first to an in-process or QEMU device).
        #[arg(long)]
        system: Option<PathBuf>,
        /// Observations CSV `image,point,col,row[,kind]` (dot rows; point = ray id).
        #[arg(long, conflicts_with = "simulate")]
        obs: Option<PathBuf>,
        /// Simulate this many frames of the system's dots on plates Z = 0, 100, 200 mm.
        #[arg(long)]
        simulate: Option<usize>,
        /// Output PLY (binary).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Output CSV `image,point,X,Y,Z,miss`.
        #[arg(long)]
        csv: Option<PathBuf>,
        /// Intersection on the device when uploading.
        #[arg(long, default_value = "closest")]
        method: cli::MethodArg,
        /// Send the dots without their ray ids: the device identifies them (its calibration
        /// needs a depth range: --near/--far here when uploading, or at `device upload`).
        #[arg(long)]
        identify: bool,
        #[command(flatten)]
        identification: DeviceIdentifyArgs,
    },
}

/// How the device identifies unlabelled dots (part of the uploaded calibration).
#[derive(clap::Args)]
struct DeviceIdentifyArgs {
    /// Nearest surface distance from the camera along its axis (mm), for identifying dots.
    #[arg(long, requires = "far")]
    near: Option<f32>,
    /// Farthest surface distance from the camera along its axis (mm), for identifying dots.
    #[arg(long, requires = "near")]
    far: Option<f32>,
    /// Largest distance of a dot from its ray's epipolar segment (px).
    #[arg(long, default_value_t = 1.0)]
    identify_tolerance: f32,
    /// Side of the device's lookup grid cells (px).
    #[arg(long, default_value_t = 16.0)]
    identify_cell: f32,
}

impl DeviceIdentifyArgs {
    fn params(&self) -> Option<deltaz_shared::protocol::calibration::IdentifyParams> {
        Some(deltaz_shared::protocol::calibration::IdentifyParams {
            near: self.near?,
            far: self.far?,
            tolerance: self.identify_tolerance,
            cell: self.identify_cell,
        })
    }
}

/// Observations measured from a folder of images instead of an observations CSV.
#[derive(clap::Args)]
struct ImageFolder {
    /// Measure the targets in this folder's images (PNG, TIFF, JPEG) instead of --obs:
    /// control targets identified by the layout of --control from its distinct targets
    /// (see `measure::layout`); the observations are written next to --out (*.obs.csv).
    #[arg(long, conflicts_with = "obs")]
    images: Option<PathBuf>,
    /// With --images: only the files whose names start with this.
    #[arg(long, default_value = "", requires = "images")]
    only: String,
    /// With --images: the distinct (larger) control targets, comma-separated labels
    /// (default: the rule of `measure::layout::distinct_targets`, which `simulate` renders).
    #[arg(long, value_delimiter = ',', requires = "images")]
    distinct: Option<Vec<String>>,
    /// With --images: tolerance (px) of the layout match.
    #[arg(long, default_value_t = 8.0)]
    tolerance: f64,
}

impl ImageFolder {
    /// The folder's measuring arguments with this control layout, or `None` without --images.
    fn with_control(
        self,
        control: &std::path::Path,
    ) -> Option<measure::identify_images::FolderArgs> {
        Some(measure::identify_images::FolderArgs {
            dir: self.images?,
            prefix: self.only,
            control: control.to_path_buf(),
            distinct: self.distinct,
            tolerance_px: self.tolerance,
        })
    }
}

#[derive(Subcommand)]
enum CalibrateWhat {
    /// Projector calibration by the ΔZ method (steps 4-7), or the joint / non-central models:
    /// writes system.json ("deltaz.system/1").
    Projector {
        /// camera.json (inner orientation and pixel mapping).
        #[arg(long)]
        camera: PathBuf,
        /// The plate's control CSV (point,X,Y,Z,sigma; plate surface at Z = 0).
        #[arg(long)]
        control: PathBuf,
        /// Plate observations CSV `image,point,col,row,kind`: `control` rows resect each image,
        /// `dot` rows (point = ray id) calibrate the projector. The 1st image defines the frame.
        #[arg(long, required_unless_present = "images")]
        obs: Option<PathBuf>,
        #[command(flatten)]
        folder: ImageFolder,
        /// With --images: the projected pattern, `paper` or a scenario TOML file (its rig's
        /// pattern: grid size and node ids); the dots are labelled by the grid walk.
        #[arg(long, default_value = "paper")]
        pattern: String,
        /// With --images: the marker dot's grid node ROW,COL.
        #[arg(long, value_delimiter = ',', num_args = 2, default_values_t = [10u16, 11])]
        marker: Vec<u16>,
        /// With --images: image direction (col,row) in which the pattern's column index grows.
        #[arg(long, value_delimiter = ',', num_args = 2, default_values_t = [1.0, 0.0], allow_negative_numbers = true)]
        col_dir: Vec<f64>,
        /// With --images: image direction (col,row) in which the pattern's row index grows.
        #[arg(long, value_delimiter = ',', num_args = 2, default_values_t = [0.0, -1.0], allow_negative_numbers = true)]
        row_dir: Vec<f64>,
        /// Output system.json.
        #[arg(long)]
        out: PathBuf,
        /// `paper` (eqs 11-14), `joint` (weighted, with σ) or `noncentral` (free lines).
        #[arg(long, default_value = "paper")]
        model: deltaz_host::projector_calibration::Model,
        /// Image noise (px) weighting the plane points and giving the rays' covariances.
        #[arg(long, default_value_t = 0.5)]
        image_sigma_px: f64,
        /// Images that cannot be resected and rays seen on one plate are errors.
        #[arg(long)]
        strict: bool,
    },
    /// Camera and projector in one: the camera by bundle adjustment, then plates, control,
    /// projector and camera (as a prior) in one whole-system adjustment with variance components;
    /// system.json in the camera system with the covariance a point's σ needs.
    System {
        /// The starting sensor: camera_init.json (pixel mapping, approximate f).
        #[arg(long)]
        init: PathBuf,
        /// Target-field observations CSV.
        #[arg(long)]
        camera_obs: PathBuf,
        /// Target-field control CSV (without it the field network is free).
        #[arg(long)]
        camera_control: Option<PathBuf>,
        /// The plate's control CSV (point,X,Y,Z,sigma; plate surface at Z = 0).
        #[arg(long)]
        control: PathBuf,
        /// Plate observations CSV (`control` rows resect, `dot` rows calibrate the projector).
        #[arg(long)]
        obs: PathBuf,
        /// Output system.json.
        #[arg(long)]
        out: PathBuf,
        /// Every ray a free line (rays seen on one plate are then left out).
        #[arg(long)]
        noncentral: bool,
        /// Images that cannot be resected and rays seen on one plate are errors.
        #[arg(long)]
        strict: bool,
    },
    /// Camera calibration by self-calibrating bundle adjustment (f, cx, cy, k1 by default).
    Camera {
        /// The starting sensor: camera_init.json (pixel mapping, approximate f).
        #[arg(long)]
        init: PathBuf,
        /// Target observations CSV.
        #[arg(long, required_unless_present = "images")]
        obs: Option<PathBuf>,
        #[command(flatten)]
        folder: ImageFolder,
        /// Control CSV (point,X,Y,Z,sigma); without it the network is free (arbitrary datum).
        /// Required with --images (the layout).
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
            images,
            sixteen_bit,
        } => {
            let scenario = simulate::load_scenario(&scenario)?;
            let seed = seed.unwrap_or(scenario.seed);
            let sim = simulate::simulate(&scenario, seed);
            simulate::write_simulation(&out, &sim)?;
            if images {
                let spec = simulate::images::ImageSpec {
                    depth: if sixteen_bit {
                        measure::render::BitDepth::Sixteen
                    } else {
                        measure::render::BitDepth::Eight
                    },
                    ..Default::default()
                };
                let n = simulate::images::write_images(&scenario, seed, &spec, &out)?;
                println!("{n} images -> {}", out.join("images").display());
            }
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
        Command::Demo { out, seed } => {
            let report = demo::run(&out, seed)?;
            println!(
                "torso error std {} mm (floor {} mm), flat plate vs truth {} mm -> {}",
                report["error_std_mm"],
                report["torso"]["floor_mm"],
                report["flat_plate"]["vs_truth_mm"],
                out.display()
            );
        }
        Command::Compare {
            reconstructed,
            reference,
            json,
        } => cli::compare(&reconstructed, &reference, json)?,
        Command::Reconstruct {
            system,
            obs,
            out,
            csv,
            ascii,
            sigma_px,
            method,
            frame,
        } => cli::reconstruct(&cli::ReconstructArgs {
            system,
            obs,
            out,
            csv,
            ascii,
            sigma_px,
            method,
            frame,
        })?,
        Command::Resect {
            camera,
            obs,
            control,
            out,
        } => {
            let cam = io::camera_file::read_camera(&camera)?;
            let observations = io::observations::read_observations(&obs)?;
            let control = io::control::read_control(&control)?;
            let results = deltaz_host::plates::resect_images(
                &obs,
                &cam.grid(),
                &cam.inner(),
                &observations,
                &control,
            )?;
            let poses = deltaz_host::plates::PosesFile::new(&results);
            print!("{}", poses.table());
            if let Some(out) = out {
                io::atomic::write_json_atomic(&out, &poses)?;
            }
        }
        Command::BenchMeasure { repeats } => print!("{}", measure::bench::run(repeats)),
        Command::Measure {
            images,
            out,
            dark,
            gravity,
            system,
            near,
            far,
            tolerance,
        } => {
            let mut params = measure::MeasureParams::default();
            if dark {
                params.detect.polarity = measure::detect::Polarity::Dark;
            }
            if gravity {
                params.method = measure::CentreMethod::Gravity;
            }
            let identifier = match (system, near, far) {
                (Some(path), Some(near), Some(far)) => {
                    let (_, rig) = deltaz_host::system::SystemFile::load(&path)?;
                    let cell = if rig.grid().width > 2000 { 32.0 } else { 16.0 };
                    let depth = deltaz_shared::identify::DepthRange { near, far };
                    let built = measure::HostIdentifier::new(&rig, depth, tolerance, cell)
                        .map_err(|e| anyhow::anyhow!("{}: identification: {e}", path.display()))?;
                    Some(Box::new(built))
                }
                _ => None,
            };
            let measured = measure::measure_images(&images, &params, identifier.as_deref())?;
            io::observations::write_observations(&out, &measured.observations)?;
            for line in &measured.unidentified {
                println!("{line}");
            }
            println!(
                "{} observations in {} images ({} dots not identified) -> {}",
                measured.observations.len(),
                images.len(),
                measured.unidentified.len(),
                out.display()
            );
        }
        Command::Calibrate {
            what:
                CalibrateWhat::Projector {
                    camera,
                    control,
                    obs,
                    folder,
                    pattern,
                    marker,
                    col_dir,
                    row_dir,
                    out,
                    model,
                    image_sigma_px,
                    strict,
                },
        } => {
            let obs = match (obs, folder.with_control(&control)) {
                (Some(obs), _) => obs,
                (None, Some(folder)) => {
                    let cam = io::camera_file::read_camera(&camera)?;
                    let dots = measure::identify_images::DotGrid {
                        pattern: simulate::load_scenario(&pattern)?.rig.pattern,
                        marker: (marker[0], marker[1]),
                        col_dir: nalgebra::Vector2::new(col_dir[0], col_dir[1]),
                        row_dir: nalgebra::Vector2::new(row_dir[0], row_dir[1]),
                    };
                    measure::identify_images::folder_observations(
                        &folder,
                        &cam.grid(),
                        &cam.inner(),
                        Some(&dots),
                        &out,
                    )?
                }
                (None, None) => anyhow::bail!("give --obs FILE or --images DIR"),
            };
            cli::calibrate_projector(&camera, &control, &obs, &out, model, image_sigma_px, strict)?
        }
        Command::Calibrate {
            what:
                CalibrateWhat::Camera {
                    init,
                    obs,
                    folder,
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
            let folder = control.as_deref().and_then(|c| folder.with_control(c));
            let obs = match (obs, folder) {
                (Some(obs), _) => obs,
                (None, Some(folder)) => {
                    let start = io::camera_file::read_camera(&init)?;
                    measure::identify_images::folder_observations(
                        &folder,
                        &start.grid(),
                        &start.inner(),
                        None,
                        &out,
                    )?
                }
                _ => anyhow::bail!("give --obs FILE, or --images DIR with --control FILE"),
            };
            let file = deltaz_host::camera_calibration::calibrate_files(
                &init,
                &obs,
                control.as_deref(),
                &out,
                &options,
            )?;
            print!(
                "{}",
                deltaz_host::camera_calibration::summary(&file, &options.free)
            );
        }
        Command::Calibrate {
            what:
                CalibrateWhat::System {
                    init,
                    camera_obs,
                    camera_control,
                    control,
                    obs,
                    out,
                    noncentral,
                    strict,
                },
        } => cli::calibrate_system(&cli::SystemArgs {
            init,
            camera_obs,
            camera_control,
            control,
            obs,
            out,
            noncentral,
            strict,
        })?,
        Command::Device { link, what } => match what {
            DeviceWhat::Ports => device_cli::ports()?,
            DeviceWhat::Info => device_cli::info(&link.args())?,
            DeviceWhat::Upload {
                system,
                method,
                identification,
            } => device_cli::upload(
                &link.args(),
                &system,
                method.into(),
                identification.params(),
            )?,
            DeviceWhat::Stream {
                system,
                obs,
                simulate,
                out,
                csv,
                method,
                identify,
                identification,
            } => {
                let source = match (obs, simulate) {
                    (Some(path), _) => device_cli::StreamSource::Csv(path),
                    (None, Some(frames)) => device_cli::StreamSource::Simulated { frames },
                    (None, None) => anyhow::bail!("give --obs FILE or --simulate FRAMES"),
                };
                device_cli::stream(&device_cli::StreamArgs {
                    link: link.args(),
                    system,
                    source,
                    out,
                    csv,
                    method: method.into(),
                    identify,
                    identification: identification.params(),
                })?
            }
        },
        Command::Bench { images, targets } => {
            for scenario in [
                simulate::Scenario::paper(),
                simulate::Scenario::large(images, targets),
            ] {
                let sim = simulate::simulate(&scenario, 1);
                let options = bundle::CalibrationOptions::default();
                let start = std::time::Instant::now();
                let problem = deltaz_host::camera_calibration::build_problem(
                    std::path::Path::new("simulated"),
                    &sim.camera_init.grid(),
                    &sim.camera_init.inner(),
                    &sim.camera_obs,
                    &sim.camera_control,
                    &options,
                )?;
                let cal = bundle::calibrate(problem, &options)?;
                let file = deltaz_host::camera_calibration::camera_file(&cal, &sim.camera_obs);
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
