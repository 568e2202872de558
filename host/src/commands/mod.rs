//! The `deltaz` command line: one module per subcommand, each with its clap arguments (their help
//! text beside them) and an `exec` that maps files and options to library calls; [`Command`] lists
//! them (`main.rs` parses and dispatches).

mod analyse;
mod args;
mod bench;
mod bench_measure;
mod bench_reconstruct;
mod calibrate;
mod calibrate_camera;
mod calibrate_projector;
mod calibrate_system;
mod compare;
mod demo;
mod device;
mod export;
mod measure;
mod reconstruct;
mod resect;
mod scan;
mod simulate;
mod station;

use anyhow::Result;

/// The subcommands of `deltaz`.
#[derive(clap::Subcommand)]
pub enum Command {
    /// Simulate a scenario: camera_init.json, camera_obs.csv, camera_control.csv, plate_obs.csv,
    /// plate_control.csv and truth.json in the output directory.
    Simulate(simulate::Args),
    /// Accuracy assessment (Tables 6-7): 7-parameter similarity, residuals, n−1 std, absolute
    /// errors with no fit, flatness. Point files are CSV `point,X,Y,Z` (mm), matched by `point`.
    /// The similarity maps the reconstructed points into the reference frame; residuals, errors
    /// and flatness are in mm, in the reference frame.
    Compare(compare::Args),
    /// Reconstruct identified dots (CSV `image,point,col,row[,kind]` in pixels, `point` = ray id;
    /// with a `kind` column only the `dot` rows) into a PLY point cloud: X, Y, Z in mm in the
    /// system's frame (or the one --frame asks for).
    Reconstruct(reconstruct::Args),
    /// Space resection: the exterior orientation of every image from known control.
    Resect(resect::Args),
    /// The whole system on the simulated paper rig: images rendered, camera and projector
    /// calibrated from them, uploaded to the device, test objects (sphere, plane, torso) scanned
    /// through it; writes OUT/images, cloud.ply, report.md, report.json, system.json and SVG
    /// plots.
    Demo(demo::Args),
    /// Measure targets and dots in images (PNG, TIFF, JPEG): sub-pixel centres into an
    /// observations CSV (image = file stem, point = m1, m2, ... in row-major order).
    Measure(measure::Args),
    /// Timings of image measurement: 768 x 512 with 440 dots, 12 MP with 4,000 dots.
    BenchMeasure(bench_measure::Args),
    /// Timings of `reconstruct`: the same dots (10^6) over 2,000 and over 20,000 images, beside
    /// a numpy script (loadtxt and eqs 6-9) on the same file.
    BenchReconstruct(bench_reconstruct::Args),
    /// Scan camera frames: measure each frame on the host, identify and reconstruct it through
    /// the device (--port, --qemu, in-process by default) or on the host (--host), pipelined
    /// across the cores; one PLY per frame in OUT (or one with --one-file), optionally a CSV of
    /// all points.
    Scan(scan::Args),
    /// Calibration steps.
    Calibrate {
        #[command(subcommand)]
        /// Camera, projector or both.
        what: calibrate::What,
    },
    /// The device: list ports, show its info, upload a calibration, stream centroids through it.
    /// Without --port or --qemu the firmware's logic runs in-process.
    Device(device::Args),
    /// Write a calibration in another program's format.
    Export {
        #[command(subcommand)]
        /// The format.
        what: export::What,
    },
    /// The back analysis: the measures a scoliosis screening reads, from scans of a back, and
    /// their follow-up.
    Analyse {
        #[command(subcommand)]
        /// A back, or two analyses compared.
        what: analyse::What,
    },
    /// Timings: camera calibration and the whole-system adjustment of the paper scenario and of
    /// a large network (with five plates of 440 dots); with --station DIR the station's frame
    /// rate and latency.
    Bench(bench::Args),
    /// The operator's station: a page in the browser (on this computer) with the live frame and
    /// its dots, the back's surface as frames arrive, capture of sessions per subject and their
    /// follow-up, and the calibration's check. Prints the page's address.
    Station(station::Args),
}

impl Command {
    /// Runs the subcommand.
    pub fn exec(self) -> Result<()> {
        match self {
            Command::Simulate(args) => simulate::exec(args),
            Command::Compare(args) => compare::exec(args),
            Command::Reconstruct(args) => reconstruct::exec(args),
            Command::Resect(args) => resect::exec(args),
            Command::Demo(args) => demo::exec(args),
            Command::Measure(args) => measure::exec(args),
            Command::BenchMeasure(args) => bench_measure::exec(args),
            Command::BenchReconstruct(args) => bench_reconstruct::exec(args),
            Command::Scan(args) => scan::exec(args),
            Command::Calibrate { what } => calibrate::exec(what),
            Command::Device(args) => device::exec(args),
            Command::Export { what } => export::exec(what),
            Command::Analyse { what } => analyse::exec(what),
            Command::Bench(args) => bench::exec(args),
            Command::Station(args) => station::exec(args),
        }
    }
}
