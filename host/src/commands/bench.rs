//! `deltaz bench`.

use super::args::{positive, OutputArgs};
use crate::report::console::Output;
use crate::station::source::SourceArgs;
use crate::station::{bench as station_bench, server::page_weight, StationArgs};
use crate::workflows::bench;
use crate::workflows::device::LinkArgs;
use anyhow::Result;
use deltaz_shared::identify::DepthRange;
use std::path::PathBuf;

/// Arguments of `deltaz bench`.
#[derive(clap::Args)]
pub struct Args {
    /// Images of the large network, 2 to 5,000.
    #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(u32).range(2..=5_000))]
    images: u32,
    /// Targets of the large network, 4 to 100,000.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(4..=100_000))]
    targets: u32,
    /// Time the station instead: frames per second and latency from a frame's read to its
    /// event at the page, replaying this folder through the in-process device (as fast as it
    /// goes, then at 15 frames/s); needs --system, --near and --far.
    #[arg(long, requires_all = ["system", "near", "far"])]
    station: Option<PathBuf>,
    /// The station's system.json.
    #[arg(long)]
    system: Option<PathBuf>,
    /// The station's nearest surface distance (mm).
    #[arg(long)]
    near: Option<f64>,
    /// The station's farthest surface distance (mm).
    #[arg(long)]
    far: Option<f64>,
    /// Seconds of each station run.
    #[arg(long, default_value_t = 10.0, value_parser = positive)]
    seconds: f64,
    #[command(flatten)]
    output: OutputArgs,
}

/// Runs `deltaz bench`.
pub fn exec(args: Args) -> Result<()> {
    let output = Output::from(args.output);
    if let (Some(dir), Some(system), Some(near), Some(far)) =
        (&args.station, &args.system, args.near, args.far)
    {
        let data = std::env::temp_dir().join(format!("deltaz-bench-{}", std::process::id()));
        let station = StationArgs {
            system: system.clone(),
            source: SourceArgs::Replay {
                dir: dir.clone(),
                fps: 15.0,
            },
            link: LinkArgs {
                port: None,
                baud: 0,
                qemu: None,
                timeout: crate::link::DEFAULT_TIMEOUT,
                output: Output::default(),
            },
            depth: DepthRange { near, far },
            tolerance: 1.0,
            listen: ([127, 0, 0, 1], 0).into(),
            data: data.clone(),
            burst: 5,
        };
        let runs = [1000.0, 15.0].map(|fps| station_bench::run(&station, fps, args.seconds));
        let _ = std::fs::remove_dir_all(&data);
        let runs = runs.into_iter().collect::<Result<Vec<_>>>()?;
        let mut text = format!(
            "station on {} (in-process device); the page: {} bytes (HTML, CSS, script)\n",
            dir.display(),
            page_weight()
        );
        for r in &runs {
            let [mean, median, p95, max] = r.latency_ms;
            text += &format!(
                "  replay at {:.0} frames/s: {:.1} frames/s at the page, {:.0} points per frame; \
                 latency frame read → page {mean:.1} ms mean, {median:.1} median, {p95:.1} 95 %, \
                 {max:.1} largest; live event {:.0} bytes; surface {:.1} updates/s, {:.0} ms \
                 after its newest frame's read\n",
                r.fps_asked, r.fps, r.points, r.live_event_bytes, r.surface[0], r.surface[1]
            );
        }
        let json = serde_json::json!({ "page_bytes": page_weight(), "runs": runs });
        return output.result(&text, &json);
    }
    let (text, runs) = bench::calibration(args.images, args.targets, output)?;
    output.result(&text, &serde_json::json!({ "runs": runs }))
}
