//! `deltaz`: the command-line front end.
use clap::{Parser, Subcommand};
use deltaz_host::calibration_plots::residual_plots;
use deltaz_host::{bundle, cli, demo, device_cli, io, measure, render, scan, simulate};
use std::path::PathBuf;
use std::process::ExitCode;

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
    /// errors with no fit, flatness. Point files are CSV `point,X,Y,Z` (mm), matched by `point`.
    /// The similarity maps the reconstructed points into the reference frame; residuals, errors
    /// and flatness are in mm, in the reference frame.
    Compare {
        /// Reconstructed points (mm).
        #[arg(long)]
        reconstructed: PathBuf,
        /// Reference points (mm).
        #[arg(long)]
        reference: PathBuf,
        #[command(flatten)]
        output: cli::Output,
    },
    /// Reconstruct identified dots (CSV `image,point,col,row[,kind]` in pixels, `point` = ray id;
    /// with a `kind` column only the `dot` rows) into a PLY point cloud: X, Y, Z in mm in the rig
    /// frame (the frame of the 1st plate image of the projector calibration).
    Reconstruct {
        #[command(flatten)]
        args: cli::ReconstructArgs,
        #[command(flatten)]
        output: cli::Output,
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
        #[command(flatten)]
        output: cli::Output,
    },
    /// The whole system on the simulated paper rig: images rendered, camera and projector
    /// calibrated from them, uploaded to the device, test objects (sphere, plane, torso) scanned
    /// through it; writes OUT/images, cloud.ply, report.md, report.json, system.json and SVG
    /// plots.
    Demo {
        /// Output directory.
        #[arg(long, default_value = "out")]
        out: PathBuf,
        /// Random seed of the simulation.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Run from simulated image observations (0.5 px noise) instead of rendered images.
        #[arg(long)]
        observations: bool,
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
        /// Find a circle-grid board, `circles:COLSxROWS[:SPACING_MM]` or
        /// `acircles:COLSxROWS[:SPACING_MM]` (OpenCV's pattern size): its circles are written
        /// as points `rIcJ` (row I, column J), the other targets left out. The order is
        /// OpenCV's: the board seen from its front (from the column direction to the row
        /// direction clockwise in the image), then of the board's rotations onto itself the one
        /// with column 0 at the left (and row 0 at the top when upright).
        #[arg(long, conflicts_with = "system")]
        board: Option<measure::board::Board>,
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
        #[arg(long, default_value_t = 1.0, value_parser = cli::positive, allow_negative_numbers = true)]
        tolerance: f64,
        /// With --system: also one line per dot that is not identified, and why.
        #[arg(long, requires = "system")]
        verbose: bool,
    },
    /// Timings of image measurement: 768 x 512 with 440 dots, 12 MP with 4,000 dots.
    BenchMeasure {
        /// Repetitions (the best is reported), 1 to 100.
        #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u16).range(1..=100))]
        repeats: u16,
    },
    /// Scan camera frames: measure each frame on the host, identify and reconstruct it through
    /// the device (--port, --qemu, in-process by default) or on the host (--host), pipelined
    /// across the cores; one PLY per frame in OUT (or one with --one-file), optionally a CSV of
    /// all points.
    Scan {
        /// Folder of frames (PNG, TIFF, JPEG), scanned in name order.
        frames: PathBuf,
        /// The calibrated system (system.json).
        #[arg(long)]
        system: PathBuf,
        /// Nearest surface distance from the camera along its axis (mm).
        #[arg(long)]
        near: f64,
        /// Farthest surface distance from the camera along its axis (mm).
        #[arg(long)]
        far: f64,
        /// Largest distance of a dot from its ray's epipolar segment (px).
        #[arg(long, default_value_t = 1.0)]
        tolerance: f64,
        /// Output folder: OUT/<frame>.ply.
        #[arg(long)]
        out: PathBuf,
        /// One PLY OUT/scan.ply of all frames, each point with its `frame` index.
        #[arg(long)]
        one_file: bool,
        /// Also a CSV `frame,image,point,X,Y,Z,miss,saturated` of all frames (saturated = 1:
        /// the device's miss distance is at its wire limit, a lower bound).
        #[arg(long)]
        csv: Option<PathBuf>,
        /// Intersection: eqs (8)-(9) (`paper`) or the closest approach (`closest`).
        #[arg(long, default_value = "closest")]
        method: cli::MethodArg,
        /// Identify and intersect on the host (f64) instead of the device.
        #[arg(long, conflicts_with_all = ["port", "qemu", "upload"])]
        host: bool,
        /// Upload the system to the device on --port when it holds another calibration.
        #[arg(long)]
        upload: bool,
        #[command(flatten)]
        device: DeviceOpts,
        #[command(flatten)]
        output: cli::Output,
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
    /// Write a calibration in another program's format.
    Export {
        #[command(subcommand)]
        what: ExportWhat,
    },
    /// Timings: camera calibration and the whole-system adjustment of the paper scenario and of
    /// a large network (with five plates of 440 dots).
    Bench {
        /// Images of the large network, 2 to 5,000.
        #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(u32).range(2..=5_000))]
        images: u32,
        /// Targets of the large network, 4 to 100,000.
        #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(4..=100_000))]
        targets: u32,
        #[command(flatten)]
        output: cli::Output,
    },
}

#[derive(Subcommand)]
enum ExportWhat {
    /// OpenCV's camera file (YAML for cv2.FileStorage): image_width, image_height,
    /// camera_matrix (px), distortion_coefficients (k1, k2, p1, p2, k3, refitted to OpenCV's
    /// model; the largest refit error over the sensor is reported in px) and
    /// extrinsic_parameters, one row rvec (rad) | tvec (mm) per image in OpenCV's camera axes.
    Opencv {
        /// A camera calibration (camera.json): its stations become the extrinsics.
        #[arg(long, required_unless_present = "system", conflicts_with = "system")]
        camera: Option<PathBuf>,
        /// A system calibration (system.json): the camera's pose in the rig frame.
        #[arg(long)]
        system: Option<PathBuf>,
        /// Output YAML file (e.g. camera.yml).
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        output: cli::Output,
    },
}

/// How to reach the device, and how to report.
#[derive(clap::Args)]
struct LinkOpts {
    #[command(flatten)]
    device: DeviceOpts,
    /// `info`, `upload` and `stream`: print one JSON object on stdout (status on stderr).
    #[arg(long, global = true)]
    json: bool,
    /// No status lines or progress on stderr (errors are still printed).
    #[arg(long, global = true)]
    quiet: bool,
}

/// The device's port, or QEMU, or (neither) the firmware's logic in-process.
#[derive(clap::Args)]
struct DeviceOpts {
    /// Serial port of the device (see `deltaz device ports`).
    #[arg(long, global = true)]
    port: Option<String>,
    /// Baud rate of --port.
    #[arg(long, global = true, default_value_t = 2_000_000)]
    baud: u32,
    /// Run the firmware in QEMU (mps2-an386) and talk to it over a pty; `--qemu=ELF` names the
    /// firmware (default: thumbv7em-none-eabihf/release/mps2_an386 in the build directory that
    /// holds this program).
    #[arg(long, global = true, num_args = 0..=1, require_equals = true, default_missing_value = "")]
    qemu: Option<PathBuf>,
    /// Response timeout (ms).
    #[arg(long, global = true, default_value_t = 3000)]
    timeout_ms: u64,
}

impl LinkOpts {
    fn args(&self) -> device_cli::LinkArgs {
        device_cli::LinkArgs {
            output: cli::Output {
                json: self.json,
                quiet: self.quiet,
            },
            ..self.device.args()
        }
    }
}

impl DeviceOpts {
    fn args(&self) -> device_cli::LinkArgs {
        device_cli::LinkArgs {
            port: self.port.clone(),
            baud: self.baud,
            qemu: self.qemu.as_ref().map(|elf| {
                if elf.as_os_str().is_empty() {
                    default_firmware_elf()
                } else {
                    elf.clone()
                }
            }),
            timeout: std::time::Duration::from_millis(self.timeout_ms),
            output: cli::Output::default(),
        }
    }
}

/// The QEMU firmware next to this program: `target/release/deltaz` ->
/// `target/thumbv7em-none-eabihf/release/mps2_an386`, whatever the working directory.
fn default_firmware_elf() -> PathBuf {
    let relative = PathBuf::from("thumbv7em-none-eabihf/release/mps2_an386");
    std::env::current_exe()
        .ok()
        .and_then(|exe| Some(exe.parent()?.parent()?.join(&relative)))
        .unwrap_or_else(|| PathBuf::from("target").join(relative))
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
    /// the device into PLY and/or CSV (both written, or neither when the stream fails), with a
    /// progress bar; says what became of every dot sent: a point, not identified, or no point,
    /// each by reason.
    Stream {
        /// The system the device must hold (uploaded first to an in-process or QEMU device).
        #[arg(long)]
        system: Option<PathBuf>,
        /// Observations CSV `image,point,col,row[,kind]` (dot rows; point = ray id).
        #[arg(long, conflicts_with = "simulate")]
        obs: Option<PathBuf>,
        /// Simulate this many frames (1 to 100,000) of the system's dots on plates Z = 0, 100,
        /// 200 mm.
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=100_000))]
        simulate: Option<u32>,
        /// Output PLY (binary; mm, rig frame, the calibration's fingerprint, each point's frame).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Output CSV `image,point,X,Y,Z,miss,saturated` (mm; saturated = 1: the device's miss
        /// distance is at its wire limit, a lower bound).
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
    #[arg(long, requires = "far", value_parser = positive_f32, allow_negative_numbers = true)]
    near: Option<f32>,
    /// Farthest surface distance from the camera along its axis (mm, beyond --near).
    #[arg(long, requires = "near", value_parser = positive_f32, allow_negative_numbers = true)]
    far: Option<f32>,
    /// Largest distance of a dot from its ray's epipolar segment (px).
    #[arg(long, default_value_t = 1.0, value_parser = positive_f32, allow_negative_numbers = true)]
    identify_tolerance: f32,
    /// Side of the device's lookup grid cells (px).
    #[arg(long, default_value_t = 16.0, value_parser = positive_f32, allow_negative_numbers = true)]
    identify_cell: f32,
}

impl DeviceIdentifyArgs {
    fn params(
        &self,
    ) -> anyhow::Result<Option<deltaz_shared::protocol::calibration::IdentifyParams>> {
        let (Some(near), Some(far)) = (self.near, self.far) else {
            return Ok(None);
        };
        anyhow::ensure!(
            near < far,
            "--near {near} mm must be less than --far {far} mm"
        );
        Ok(Some(deltaz_shared::protocol::calibration::IdentifyParams {
            near,
            far,
            tolerance: self.identify_tolerance,
            cell: self.identify_cell,
        }))
    }
}

/// [`cli::positive`] for the device's single-precision parameters.
fn positive_f32(text: &str) -> Result<f32, String> {
    cli::positive(text).map(|v| v as f32)
}

/// A `--flag A,B` value: two comma-separated numbers.
fn pair<T: std::str::FromStr>(text: &str) -> Result<[T; 2], String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let parse = |s: &str| s.parse::<T>().map_err(|_| format!("{s:?} is not a number"));
    match parts[..] {
        [a, b] => Ok([parse(a)?, parse(b)?]),
        _ => Err(format!("{text:?} is not two comma-separated numbers A,B")),
    }
}

/// Observations measured from a folder of images instead of an observations CSV.
#[derive(clap::Args)]
struct ImageFolder {
    /// Measure the targets in this folder's images (PNG, TIFF, JPEG) instead of --obs:
    /// control targets identified by the layout of --control from its distinct (larger)
    /// targets; the observations are written next to --out (*.obs.csv).
    #[arg(long, conflicts_with = "obs")]
    images: Option<PathBuf>,
    /// With --images: only the files whose names start with this.
    #[arg(long, default_value = "", requires = "images")]
    only: String,
    /// With --images: the distinct (larger) control targets, comma-separated labels
    /// (default: the ones `simulate --images` renders larger).
    #[arg(long, value_delimiter = ',', requires = "images")]
    distinct: Option<Vec<String>>,
    /// With --images: tolerance (px) of the layout match.
    #[arg(long, default_value_t = 8.0, value_parser = cli::positive, allow_negative_numbers = true)]
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
    /// Projector calibration with the camera as a prior (the joint / non-central models: the
    /// whole-system adjustment without the field images), or by the paper's ΔZ method (steps
    /// 4-7): writes system.json ("deltaz.system/1").
    Projector {
        #[command(flatten)]
        args: cli::ProjectorArgs,
        /// Plate observations CSV `image,point,col,row,kind`: `control` rows resect each image,
        /// `dot` rows (point = ray id) calibrate the projector (`paper`: the 1st image's frame).
        #[arg(long, required_unless_present = "images")]
        obs: Option<PathBuf>,
        #[command(flatten)]
        folder: ImageFolder,
        /// With --images: the projected pattern, `paper` or a scenario TOML file (its rig's
        /// pattern: grid size and node ids); the dots are labelled by the grid walk.
        #[arg(long, default_value = "paper")]
        pattern: String,
        /// With --images: the marker dot's grid node ROW,COL.
        #[arg(long, value_parser = pair::<u16>, default_value = "10,11")]
        marker: [u16; 2],
        /// With --images: image direction COL,ROW in which the pattern's column index grows.
        #[arg(long, value_parser = pair::<f64>, default_value = "1,0", allow_hyphen_values = true)]
        col_dir: [f64; 2],
        /// With --images: image direction COL,ROW in which the pattern's row index grows.
        #[arg(long, value_parser = pair::<f64>, default_value = "0,-1", allow_hyphen_values = true)]
        row_dir: [f64; 2],
        #[command(flatten)]
        output: cli::Output,
    },
    /// Camera and projector in one: the camera by bundle adjustment, then plates, control,
    /// projector and camera (as a prior) in one whole-system adjustment with variance components;
    /// system.json in the camera system with the covariance a point's σ needs.
    System {
        #[command(flatten)]
        args: cli::SystemArgs,
        #[command(flatten)]
        output: cli::Output,
    },
    /// Camera calibration by self-calibrating bundle adjustment (f, cx, cy, k1 by default).
    Camera {
        /// The starting sensor: camera_init.json (pixel mapping, approximate f); not with
        /// --board.
        #[arg(long, required_unless_present = "board")]
        init: Option<PathBuf>,
        /// Calibrate from views of a flat circle-grid board in --images instead,
        /// `circles:COLSxROWS[:SPACING_MM]` or `acircles:COLSxROWS[:SPACING_MM]` (dark circles;
        /// see `--bright`): the start from the views' homographies, the board as weighted
        /// control; the labelled circles and the board are written next to --out
        /// (*.obs.csv, *.control.csv).
        #[arg(long, requires = "images", conflicts_with_all = ["init", "obs", "control"])]
        board: Option<measure::board::Board>,
        /// With --board: the pixel size (mm); without it photo coordinates are in units of 100
        /// pixels (f and σ in pixels are printed all the same).
        #[arg(long, default_value_t = 0.01, requires = "board")]
        pixel_size: f64,
        /// With --board: σ of the board's circle positions (its flatness and spacing errors,
        /// in the spacing's unit).
        #[arg(long, default_value_t = 0.02, requires = "board")]
        board_sigma: f64,
        /// With --board: the circles are brighter than the board.
        #[arg(long, requires = "board")]
        bright: bool,
        /// Keep every observation (no data snooping).
        #[arg(long)]
        no_snooping: bool,
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
        /// A priori σ of image coordinates (px, > 0), weighting control against images.
        #[arg(long, default_value_t = 0.5, value_parser = cli::positive, allow_negative_numbers = true)]
        image_sigma_px: f64,
        #[command(flatten)]
        plots: cli::PlotsArg,
        #[command(flatten)]
        output: cli::Output,
    },
}

/// The observations file `--images` writes next to `--out` before calibrating: unless the
/// calibration succeeds, it is put back as it was (removed, or its former content), so that a
/// failed run leaves no file created or changed.
struct ObservationsGuard {
    path: PathBuf,
    before: Option<Vec<u8>>,
}

impl ObservationsGuard {
    fn new(out: &std::path::Path) -> Self {
        let path = measure::identify_images::observations_path(out);
        let before = std::fs::read(&path).ok();
        Self { path, before }
    }

    /// The calibration succeeded: the file stays.
    fn keep(mut self) {
        self.before = std::fs::read(&self.path).ok();
    }
}

impl Drop for ObservationsGuard {
    fn drop(&mut self) {
        let now = std::fs::read(&self.path).ok();
        if now != self.before {
            let _ = match &self.before {
                Some(bytes) => io::atomic::write_atomic(&self.path, bytes).map_err(|_| ()),
                None => std::fs::remove_file(&self.path).map_err(|_| ()),
            };
        }
    }
}

/// The default action for SIGPIPE, as Unix tools have: `deltaz ... | head` then ends quietly
/// when the reader closes the pipe, where Rust's runtime (which ignores SIGPIPE) would panic in
/// `println!` with "failed printing to stdout".
#[cfg(unix)]
fn default_sigpipe() {
    // SAFETY: called first in `main`, before any other thread exists, and SIG_DFL installs no
    // handler code: it only gives the signal back its default disposition.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// Runs the command; any error prints as one `error: ...` chain (never a backtrace, whatever
/// RUST_BACKTRACE says) and exits with 1, like a bad command line.
fn main() -> ExitCode {
    #[cfg(unix)]
    default_sigpipe();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            let _ = e.print();
            return if e.use_stderr() {
                ExitCode::FAILURE
            } else {
                ExitCode::SUCCESS
            };
        }
    };
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// The end of `calibrate camera`: the residuals' summary (with the σ0 warning) and where the
/// files went on stderr, the calibrated camera on stdout (text or JSON).
fn camera_result(
    file: &io::camera_file::CameraFile,
    residuals: &[deltaz_host::residuals::Residual],
    options: &bundle::CalibrationOptions,
    out: &std::path::Path,
    output: cli::Output,
) -> anyhow::Result<()> {
    output.status(format!(
        "{}camera calibration -> {}, residuals -> {}",
        deltaz_host::residuals::summary(
            residuals,
            file.sigma0.unwrap_or(f64::NAN) / file.pixel_size,
            options.image_sigma_px
        ),
        out.display(),
        deltaz_host::residuals::residuals_path(out).display()
    ));
    let mut json = serde_json::to_value(file)?;
    json["out"] = serde_json::json!(out);
    output.result(&cli::camera_summary(file, &options.free.inner), &json)
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
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
            let spec = simulate::images::ImageSpec {
                depth: if sixteen_bit {
                    render::BitDepth::Sixteen
                } else {
                    render::BitDepth::Eight
                },
                ..Default::default()
            };
            let rendered = io::atomic::write_dir_all_or_nothing(&out, |dir| {
                simulate::write_simulation(dir, &sim)?;
                if !images {
                    return Ok(None);
                }
                let progress = cli::Output::default()
                    .progress(format!("rendering the images of {}", scenario.name));
                let images = simulate::images::write_images(&scenario, seed, &spec, dir)?;
                let objects = simulate::objects::write_objects(&scenario, seed, dir)?;
                progress.finish_and_clear();
                Ok(Some((images, objects)))
            })?;
            if let Some((images, objects)) = rendered {
                println!("{images} images -> {}", out.join("images").display());
                println!(
                    "{objects} test object frames -> {}",
                    out.join("images/objects").display()
                );
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
        Command::Demo {
            out,
            seed,
            observations,
        } => {
            let progress = cli::Output::default().progress(format!(
                "running the demo (simulation, calibrations, reconstructions) -> {}",
                out.display()
            ));
            if observations {
                let report = demo::observations::run(&out, seed)?;
                progress.finish_and_clear();
                println!("{}", demo::observations::summary(&report));
            } else {
                let report = demo::images::run(&out, seed)?;
                progress.finish_and_clear();
                println!("{}", demo::images::summary(&report)?);
            }
            println!("-> {}", out.display());
        }
        Command::Compare {
            reconstructed,
            reference,
            output,
        } => cli::compare(&reconstructed, &reference, output)?,
        Command::Reconstruct { args, output } => cli::reconstruct(&args, output)?,
        Command::Resect {
            camera,
            obs,
            control,
            out,
            output,
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
            if let Some(out) = &out {
                io::atomic::write_json_atomic(out, &poses)?;
                output.status(format!(
                    "{} poses -> {}",
                    poses.stations.len(),
                    out.display()
                ));
            }
            output.result(&poses.table(), &serde_json::to_value(&poses)?)?;
        }
        Command::BenchMeasure { repeats } => {
            type Step<'a> = Box<dyn Fn() -> anyhow::Result<String> + 'a>;
            let steps: [(&str, Step); 3] = [
                (
                    "image measurement",
                    Box::new(|| Ok(measure::bench::run(repeats.into()))),
                ),
                (
                    "dot identification",
                    Box::new(|| Ok(scan::identification())),
                ),
                ("the scan pipeline", Box::new(scan::bench)),
            ];
            for (what, step) in steps {
                let progress = cli::Output::default().progress(format!("benchmarking {what}"));
                let text = step()?;
                progress.finish_and_clear();
                print!("{text}");
            }
        }
        Command::Scan {
            frames,
            system,
            near,
            far,
            tolerance,
            out,
            one_file,
            csv,
            method,
            host,
            upload,
            device,
            output,
        } => {
            let on = if host {
                scan::ScanOn::Host
            } else {
                scan::ScanOn::Device {
                    link: device.args(),
                    upload,
                }
            };
            let stats = scan::scan_command(&scan::ScanArgs {
                system,
                frames: scan::frame_files(&frames)?,
                depth: deltaz_shared::identify::DepthRange { near, far },
                tolerance,
                out: out.clone(),
                one_file,
                csv,
                method: method.into(),
                on,
                quiet: output.quiet,
            })?;
            if stats.saturated > 0 {
                eprintln!(
                    "warning: {} points have the device's saturated miss distance (≥ {:.3} mm, a lower bound): flagged in the CSV's `saturated` column",
                    stats.saturated,
                    scan::miss_saturated_mm()
                );
            }
            let text = format!(
                "{} frames, {} points in {:.2} s ({:.1} frames/s, latency {:.1} ms), {} dots off the sensor rejected, {} saturated miss distances -> {}\n",
                stats.frames,
                stats.points,
                stats.elapsed.as_secs_f64(),
                stats.frames_per_second(),
                stats.mean_latency.as_secs_f64() * 1e3,
                stats.off_sensor,
                stats.saturated,
                out.display()
            );
            let json = serde_json::json!({
                "frames": stats.frames,
                "points": stats.points,
                "seconds": stats.elapsed.as_secs_f64(),
                "frames_per_s": stats.frames_per_second(),
                "mean_latency_ms": stats.mean_latency.as_secs_f64() * 1e3,
                "off_sensor": stats.off_sensor,
                "saturated_miss": stats.saturated,
                "out": out,
            });
            output.result(&text, &json)?;
        }
        Command::Measure {
            images,
            out,
            dark,
            gravity,
            board,
            system,
            near,
            far,
            tolerance,
            verbose,
        } => {
            let mut params = measure::MeasureParams::default();
            if dark {
                params.detect.polarity = measure::detect::Polarity::Dark;
            }
            if gravity {
                params.method = measure::CentreMethod::Gravity;
            }
            params.board = board;
            let identifier = match (system, near, far) {
                (Some(path), Some(near), Some(far)) => {
                    let (_, rig) = deltaz_host::system::SystemFile::load(&path)?;
                    params.sensor = Some((rig.grid().width, rig.grid().height));
                    let cell = if rig.grid().width > 2000 { 32.0 } else { 16.0 };
                    let depth = deltaz_shared::identify::DepthRange { near, far };
                    let built = measure::HostIdentifier::new(&rig, depth, tolerance, cell)
                        .map_err(|e| anyhow::anyhow!("{}: identification: {e}", path.display()))?;
                    Some(Box::new(built))
                }
                _ => None,
            };
            let measured = measure::measure_images(&images, &params, identifier.as_deref())?;
            if measured.failed.len() == images.len() {
                anyhow::bail!("{}", measured.failed.join("\n"));
            }
            io::observations::write_observations(&out, &measured.observations)?;
            for line in &measured.summaries {
                println!("{line}");
            }
            if verbose {
                for line in &measured.unidentified {
                    println!("not identified: {line}");
                }
            }
            println!(
                "{} observations in {} images{} -> {}",
                measured.observations.len(),
                images.len() - measured.failed.len(),
                if identifier.is_some() {
                    format!(
                        " ({} dots not identified{})",
                        measured.unidentified.len(),
                        if verbose {
                            ""
                        } else {
                            "; --verbose lists them"
                        }
                    )
                } else {
                    String::new()
                },
                out.display()
            );
            for line in &measured.failed {
                eprintln!("{line}");
            }
            if !measured.failed.is_empty() {
                anyhow::bail!(
                    "{} of {} images not measured (see above)",
                    measured.failed.len(),
                    images.len()
                );
            }
        }
        Command::Calibrate {
            what:
                CalibrateWhat::Projector {
                    args,
                    obs,
                    folder,
                    pattern,
                    marker,
                    col_dir,
                    row_dir,
                    output,
                },
        } => {
            let leftover = ObservationsGuard::new(&args.out);
            let obs = match (obs, folder.with_control(&args.control)) {
                (Some(obs), _) => obs,
                (None, Some(folder)) => {
                    let cam = io::camera_file::read_camera(&args.camera)?;
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
                        &args.out,
                        output,
                    )?
                }
                (None, None) => anyhow::bail!("give --obs FILE or --images DIR"),
            };
            cli::calibrate_projector(&args, &obs, output)?;
            leftover.keep();
        }
        Command::Calibrate {
            what:
                CalibrateWhat::Camera {
                    init,
                    board,
                    pixel_size,
                    board_sigma,
                    bright,
                    no_snooping,
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
                    plots,
                    output,
                },
        } => {
            let mut options = bundle::CalibrationOptions {
                free_network,
                image_sigma_px,
                snooping: !no_snooping,
                ..Default::default()
            };
            for (k, on) in [(4, k2), (5, k3), (6, p1), (7, p2)] {
                options.free.inner[k] |= on;
            }
            let residuals_path = deltaz_host::residuals::residuals_path(&out);
            if let (Some(board), Some(dir)) = (board, folder.images.as_deref()) {
                let mut params = measure::MeasureParams::default();
                if !bright {
                    params.detect.polarity = measure::detect::Polarity::Dark;
                }
                let progress =
                    output.progress(format!("calibrating the camera from {}", dir.display()));
                let cal = deltaz_host::board_calibration::calibrate_board(
                    dir,
                    &board,
                    &params,
                    pixel_size,
                    board_sigma,
                    &options,
                )?;
                progress.finish_and_clear();
                for line in &cal.failed {
                    output.status(format!("left out: {line}"));
                }
                let [width, height] = cal.file.image_size;
                let (obs_path, control_path) = (
                    out.with_extension("obs.csv"),
                    out.with_extension("control.csv"),
                );
                let obs_csv = io::observations::observations_csv(&cal.observations);
                let control_csv = io::control::control_csv(&cal.control);
                let json = serde_json::to_string_pretty(&cal.file)? + "\n";
                let residuals_csv = deltaz_host::residuals::residuals_csv(&cal.residuals);
                plots.write_with(
                    &[
                        (&obs_path, obs_csv.as_bytes()),
                        (&control_path, control_csv.as_bytes()),
                        (&out, json.as_bytes()),
                        (&residuals_path, residuals_csv.as_bytes()),
                    ],
                    || residual_plots(&cal.residuals, width, height),
                    output,
                )?;
                output.status(format!(
                    "start from the homographies: f = {:.1} px; adjusted: f = {:.2} ± {:.2} px",
                    cal.start_f_px,
                    cal.file.inner.f / pixel_size,
                    cal.file.sigma.f / pixel_size
                ));
                return camera_result(&cal.file, &cal.residuals, &options, &out, output);
            }
            let init = init.expect("clap requires --init without --board");
            let folder = control.as_deref().and_then(|c| folder.with_control(c));
            let leftover = ObservationsGuard::new(&out);
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
                        output,
                    )?
                }
                _ => anyhow::bail!("give --obs FILE, or --images DIR with --control FILE"),
            };
            let progress =
                output.progress(format!("calibrating the camera from {}", obs.display()));
            let (file, residuals, plots_made) =
                deltaz_host::camera_calibration::calibrate_files_with_residuals(
                    &init,
                    &obs,
                    control.as_deref(),
                    &out,
                    &options,
                    plots.plots.as_deref(),
                )?;
            progress.finish_and_clear();
            plots.report(&plots_made, output);
            camera_result(&file, &residuals, &options, &out, output)?;
            leftover.keep();
        }
        Command::Calibrate {
            what: CalibrateWhat::System { args, output },
        } => cli::calibrate_system(&args, output)?,
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
                identification.params()?,
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
                    (None, Some(frames)) => device_cli::StreamSource::Simulated {
                        frames: frames as usize,
                    },
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
                    identification: identification.params()?,
                })?
            }
        },
        Command::Export {
            what:
                ExportWhat::Opencv {
                    camera,
                    system,
                    out,
                    output,
                },
        } => {
            let (input, is_system) = match (camera, system) {
                (Some(camera), _) => (camera, false),
                (None, Some(system)) => (system, true),
                (None, None) => anyhow::bail!("give --camera FILE or --system FILE"),
            };
            let cv = deltaz_host::export::export_opencv(&input, is_system, &out)?;
            output.result(
                &format!(
                    "OpenCV camera: f {:.2} px, principal point ({:.2}, {:.2}) px, {} images, \
                     distortion refit error at most {:.4} px -> {}\n",
                    cv.focal_px[0],
                    cv.principal_px[0],
                    cv.principal_px[1],
                    cv.extrinsics.len(),
                    cv.refit_max_px,
                    out.display()
                ),
                &serde_json::json!({
                    "focal_px": cv.focal_px,
                    "principal_px": cv.principal_px,
                    "distortion": cv.distortion,
                    "refit_max_px": cv.refit_max_px,
                    "images": cv.extrinsics.len(),
                    "out": out,
                }),
            )?;
        }
        Command::Bench {
            images,
            targets,
            output,
        } => {
            let mut text = String::new();
            let mut runs = Vec::new();
            for scenario in [
                simulate::Scenario::paper(),
                simulate::Scenario::large(images, targets),
            ] {
                let progress = output.progress(format!("calibrating {}", scenario.name));
                let sim = simulate::simulate(&scenario, 1);
                let start = std::time::Instant::now();
                let cal = deltaz_host::accuracy::bundle_camera(
                    &sim,
                    &bundle::CalibrationOptions::default(),
                )?;
                let seconds = start.elapsed().as_secs_f64();
                progress.finish_and_clear();
                let file = deltaz_host::camera_calibration::camera_file(&cal, &sim.camera_obs);
                text += &format!(
                    "{}: {} images, {} targets, {} observations: {:.3} s, {} LM iterations, σ0 {:.4} mm, {} correlations > 0.9\n",
                    scenario.name,
                    cal.problem.images.len(),
                    cal.problem.xyz.len(),
                    sim.camera_obs.len(),
                    seconds,
                    cal.iterations,
                    cal.solution.sigma0,
                    file.correlations.len()
                );
                runs.push(serde_json::json!({
                    "scenario": scenario.name,
                    "images": cal.problem.images.len(),
                    "targets": cal.problem.xyz.len(),
                    "observations": sim.camera_obs.len(),
                    "seconds": seconds,
                    "iterations": cal.iterations,
                    "sigma0_mm": cal.solution.sigma0,
                    "correlations": file.correlations.len(),
                }));
            }
            let progress = output.progress("adjusting the whole systems".into());
            let (system_text, system_runs) = deltaz_host::system_bench::run(images, targets)?;
            progress.finish_and_clear();
            text += &system_text;
            runs.extend(system_runs);
            output.result(&text, &serde_json::json!({ "runs": runs }))?;
        }
    }
    Ok(())
}
