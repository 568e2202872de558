//! `deltaz device ports|info|upload|stream`.

use super::args::{positive_f32, MethodArg};
use crate::report::console::Output;
use crate::workflows::device::{self as session, LinkArgs};
use crate::workflows::stream::{self, StreamArgs, StreamSource};
use anyhow::Result;
use deltaz_shared::protocol::calibration::IdentifyParams;
use std::path::PathBuf;

/// Arguments of `deltaz device`: how to reach it, then what to do.
#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    device: DeviceOpts,
    /// `info`, `upload` and `stream`: print one JSON object on stdout (status on stderr).
    #[arg(long, global = true)]
    json: bool,
    /// No status lines or progress on stderr (errors are still printed).
    #[arg(long, global = true)]
    quiet: bool,
    #[command(subcommand)]
    what: What,
}

/// The device's port, or QEMU, or (neither) the firmware's logic in-process.
#[derive(Debug, Clone, clap::Args)]
pub struct DeviceOpts {
    /// Serial port of the device (see `deltaz device ports`).
    #[arg(long, global = true)]
    port: Option<String>,
    /// Baud rate of --port.
    #[arg(long, global = true, default_value_t = 2_000_000)]
    baud: u32,
    /// Run the firmware in QEMU (mps2-an386) and talk to it over a pty; `--qemu=ELF` names the
    /// firmware (default: thumbv7em-none-eabihf/release/mps2_an386 in the build directory that
    /// holds this program).
    #[arg(long, global = true, num_args = 0..=1, require_equals = true)]
    qemu: Option<Option<PathBuf>>,
    /// Response timeout (ms).
    #[arg(long, global = true, default_value_t = 3000)]
    timeout_ms: u64,
}

impl DeviceOpts {
    /// The link these options name, reporting as `output` says.
    pub fn link(&self, output: Output) -> LinkArgs {
        LinkArgs {
            port: self.port.clone(),
            baud: self.baud,
            qemu: self
                .qemu
                .as_ref()
                .map(|elf| elf.clone().unwrap_or_else(default_firmware_elf)),
            timeout: std::time::Duration::from_millis(self.timeout_ms),
            output,
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

#[derive(clap::Subcommand)]
enum What {
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
        method: MethodArg,
        #[command(flatten)]
        identification: IdentifyArgs,
    },
    /// Stream centroids (an observations CSV, one frame per image, or simulated frames) through
    /// the device into PLY and/or CSV (both written, or neither when the stream fails), with a
    /// progress bar; says what became of every dot sent: a point, not identified, or no point,
    /// each by reason.
    Stream {
        /// The system the device must hold (uploaded first to an in-process or QEMU device):
        /// the host places the device's points with it, in its frame.
        #[arg(long)]
        system: Option<PathBuf>,
        /// Observations CSV `image,point,col,row[,kind]` (dot rows; point = ray id).
        #[arg(long, conflicts_with = "simulate")]
        obs: Option<PathBuf>,
        /// Simulate this many frames (1 to 100,000) of the system's dots on three plates 100 mm
        /// apart in front of the camera: Z = 0, 100, 200 mm of a plate frame; across the
        /// camera's axis from where the pattern's middle ray passes it, in the camera system.
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=100_000))]
        simulate: Option<u32>,
        /// Output PLY (binary; mm, the system's frame, the calibration's fingerprint, each
        /// point's frame).
        #[arg(long, requires = "system")]
        out: Option<PathBuf>,
        /// Output CSV `image,point,X,Y,Z,miss` (mm, the system's frame).
        #[arg(long, requires = "system")]
        csv: Option<PathBuf>,
        /// Intersection on the device when uploading.
        #[arg(long, default_value = "closest")]
        method: MethodArg,
        /// Send the dots without their ray ids: the device identifies them (its calibration
        /// needs a depth range: --near/--far here when uploading, or at `device upload`).
        #[arg(long)]
        identify: bool,
        #[command(flatten)]
        identification: IdentifyArgs,
    },
}

/// How the device identifies unlabelled dots (part of the uploaded calibration).
#[derive(clap::Args)]
struct IdentifyArgs {
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

impl IdentifyArgs {
    fn params(&self) -> Result<Option<IdentifyParams>> {
        let (Some(near), Some(far)) = (self.near, self.far) else {
            return Ok(None);
        };
        anyhow::ensure!(
            near < far,
            "--near {near} mm must be less than --far {far} mm"
        );
        Ok(Some(IdentifyParams {
            near,
            far,
            tolerance: self.identify_tolerance,
            cell: self.identify_cell,
        }))
    }
}

/// Runs `deltaz device`.
pub fn exec(args: Args) -> Result<()> {
    let output = Output {
        json: args.json,
        quiet: args.quiet,
    };
    let link = args.device.link(output);
    match args.what {
        What::Ports => session::ports(),
        What::Info => session::info(&link),
        What::Upload {
            system,
            method,
            identification,
        } => session::upload(&link, &system, method.into(), identification.params()?),
        What::Stream {
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
                (Some(path), _) => StreamSource::Csv(path),
                (None, Some(frames)) => StreamSource::Simulated {
                    frames: frames as usize,
                },
                (None, None) => anyhow::bail!("give --obs FILE or --simulate FRAMES"),
            };
            stream::stream(&StreamArgs {
                link,
                system,
                source,
                out,
                csv,
                method: method.into(),
                identify,
                identification: identification.params()?,
            })
        }
    }
}
