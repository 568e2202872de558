//! `deltaz station`.

use super::args::positive;
use super::device::DeviceOpts;
use crate::report::console::Output;
use crate::station::source::SourceArgs;
use crate::station::{start, StationArgs};
use anyhow::Result;
use deltaz_shared::identify::DepthRange;
use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;

/// Arguments of `deltaz station`.
#[derive(clap::Args)]
pub struct Args {
    /// The calibrated system (system.json of `calibrate system` or `calibrate projector`, with
    /// its covariance: every measure's σ).
    #[arg(long)]
    system: PathBuf,
    /// A V4L2 video device (a UVC webcam, e.g. /dev/video0), read as grey at the
    /// calibration's sensor size.
    #[arg(long, conflicts_with = "replay", required_unless_present = "replay")]
    camera: Option<PathBuf>,
    /// A folder of frames (PNG, TIFF, JPEG) played in name order, in a loop.
    #[arg(long)]
    replay: Option<PathBuf>,
    /// The replay's frame rate (frames per second).
    #[arg(long, default_value_t = 15.0, value_parser = positive, requires = "replay")]
    fps: f64,
    /// Nearest surface distance from the camera along its axis (mm).
    #[arg(long)]
    near: f64,
    /// Farthest surface distance from the camera along its axis (mm).
    #[arg(long)]
    far: f64,
    /// Largest distance of a dot from its ray's epipolar segment (px).
    #[arg(long, default_value_t = 1.0, value_parser = positive)]
    tolerance: f64,
    /// The address to serve the page on (only this computer by default; another address lets
    /// other computers on the network in).
    #[arg(long, default_value = "127.0.0.1:8470")]
    listen: SocketAddr,
    /// The folder of the captured sessions (DATA/<subject>/<time>/).
    #[arg(long, default_value = "station-data")]
    data: PathBuf,
    /// Frames of a capture (the latest ones when Capture is pressed).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=50))]
    burst: u32,
    #[command(flatten)]
    device: DeviceOpts,
}

impl Args {
    /// The station these arguments describe.
    pub fn station(&self) -> StationArgs {
        let source = match (&self.camera, &self.replay) {
            (Some(device), _) => SourceArgs::Camera {
                device: device.clone(),
            },
            (None, dir) => SourceArgs::Replay {
                dir: dir.clone().unwrap_or_default(),
                fps: self.fps,
            },
        };
        StationArgs {
            system: self.system.clone(),
            source,
            link: self.device.link(Output::default()),
            depth: DepthRange {
                near: self.near,
                far: self.far,
            },
            tolerance: self.tolerance,
            listen: self.listen,
            data: self.data.clone(),
            burst: self.burst as usize,
        }
    }
}

/// Runs `deltaz station`: prints the page's address, then serves until ended (Ctrl-C).
pub fn exec(args: Args) -> Result<()> {
    let station = start(args.station())?;
    if !station.addr.ip().is_loopback() {
        eprintln!(
            "warning: listening on {}: other computers on the network can open the station",
            station.addr
        );
    }
    println!("station at http://{}/", station.addr);
    std::io::stdout().flush()?;
    station.wait()
}
