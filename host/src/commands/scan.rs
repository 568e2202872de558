//! `deltaz scan`.

use super::args::{MethodArg, OutputArgs};
use super::device::DeviceOpts;
use crate::report::console::Output;
use crate::workflows::scan::{frame_files, scan_command, ScanArgs, ScanOn};
use anyhow::Result;
use deltaz_shared::identify::DepthRange;
use std::path::PathBuf;

/// Arguments of `deltaz scan`.
#[derive(clap::Args)]
pub struct Args {
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
    /// Also a CSV `frame,image,point,X,Y,Z,miss` of all frames.
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Intersection: eqs (8)-(9) (`paper`) or the closest approach (`closest`).
    #[arg(long, default_value = "closest")]
    method: MethodArg,
    /// Identify and intersect on the host (f64) instead of the device.
    #[arg(long, conflicts_with_all = ["port", "qemu", "upload"])]
    host: bool,
    /// Upload the system to the device on --port when it holds another calibration.
    #[arg(long)]
    upload: bool,
    #[command(flatten)]
    device: DeviceOpts,
    #[command(flatten)]
    output: OutputArgs,
}

/// Runs `deltaz scan`.
pub fn exec(args: Args) -> Result<()> {
    let output = Output::from(args.output);
    let on = if args.host {
        ScanOn::Host
    } else {
        ScanOn::Device {
            link: args.device.link(output),
            upload: args.upload,
        }
    };
    let (stats, frame) = scan_command(&ScanArgs {
        system: args.system,
        frames: frame_files(&args.frames)?,
        depth: DepthRange {
            near: args.near,
            far: args.far,
        },
        tolerance: args.tolerance,
        out: args.out.clone(),
        one_file: args.one_file,
        csv: args.csv,
        method: args.method.into(),
        on,
        quiet: output.quiet,
    })?;
    let text = format!(
        "{} frames, {} points in {:.2} s ({:.1} frames/s, latency {:.1} ms), {} dots off the sensor rejected, in {} -> {}\n",
        stats.frames,
        stats.points,
        stats.elapsed.as_secs_f64(),
        stats.frames_per_second(),
        stats.mean_latency.as_secs_f64() * 1e3,
        stats.off_sensor,
        frame,
        args.out.display()
    );
    let json = serde_json::json!({
        "frames": stats.frames,
        "points": stats.points,
        "seconds": stats.elapsed.as_secs_f64(),
        "frames_per_s": stats.frames_per_second(),
        "mean_latency_ms": stats.mean_latency.as_secs_f64() * 1e3,
        "off_sensor": stats.off_sensor,
        "frame": frame,
        "out": args.out,
    });
    output.result(&text, &json)
}
