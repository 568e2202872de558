//! `deltaz station`: the operator's station, a local web page from camera to back report.
//!
//! | module | what |
//! |---|---|
//! | [`source`] | frames from a folder replayed at a frame rate, or a V4L2 camera |
//! | [`live`] | the live chain: frames measured, identified and intersected by the device, published per frame |
//! | [`surface_view`] | the back analysis of the latest frames, drawn for the Surface panel |
//! | [`sessions`] | captured sessions under the data folder: written whole, named safely, listed, compared |
//! | [`calibration_check`] | the calibration's facts and the plane check with its verdict |
//! | [`state`] | what the threads and the server share |
//! | [`server`] | the HTTP server: the page, its events and the JSON API |
//! | [`bench`](mod@bench) | the end-to-end frame rate and latency (frame read → event at the page) |
//!
//! Threads: a reader (source, measurement), the device's (identify, intersect, publish), the
//! surface's (analysis) and the server's runtime (two workers). Each failure of a source, the
//! device or a frame is shown on the page and the station keeps running.

pub mod bench;
pub mod calibration_check;
pub mod live;
pub mod server;
pub mod sessions;
pub mod source;
pub mod state;
pub mod surface_view;

use crate::io::system_file::SystemFile;
use crate::link::centroid_step_px;
use crate::workflows::back::Calibration;
use crate::workflows::device::{check_capacity, LinkArgs};
use anyhow::{Context, Result};
use deltaz_shared::identify::DepthRange;
use live::{DeviceSetup, Latest};
use source::SourceArgs;
use state::Shared;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// What `deltaz station` is given.
#[derive(Debug, Clone)]
pub struct StationArgs {
    /// system.json (of `calibrate system`: the points' covariance).
    pub system: PathBuf,
    /// Where the frames come from.
    pub source: SourceArgs,
    /// The device.
    pub link: LinkArgs,
    /// The subject's depth range (mm from the camera along its axis).
    pub depth: DepthRange<f64>,
    /// Identification tolerance (px).
    pub tolerance: f64,
    /// The address to listen on.
    pub listen: SocketAddr,
    /// The data folder (sessions).
    pub data: PathBuf,
    /// Frames of a capture.
    pub burst: usize,
}

/// A running station.
pub struct Running {
    /// The address it listens on.
    pub addr: SocketAddr,
    stop: Arc<AtomicBool>,
    shutdown: Option<tokio::sync::oneshot::Sender<()>>,
    threads: Vec<std::thread::JoinHandle<()>>,
    server: Option<std::thread::JoinHandle<Result<()>>>,
}

impl Running {
    /// Serve until the server fails (or the process is ended).
    pub fn wait(mut self) -> Result<()> {
        let served = match self.server.take() {
            Some(server) => server
                .join()
                .unwrap_or_else(|_| Err(anyhow::anyhow!("the server stopped"))),
            None => Ok(()),
        };
        self.stop_threads();
        served
    }

    /// Stop the threads and stop accepting connections (an event stream still open ends
    /// with the process).
    pub fn stop(mut self) {
        if let Some(shutdown) = self.shutdown.take() {
            let _ = shutdown.send(());
        }
        self.stop_threads();
    }

    fn stop_threads(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for thread in self.threads.drain(..) {
            let _ = thread.join();
        }
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        if let Some(shutdown) = self.shutdown.take() {
            let _ = shutdown.send(());
        }
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// Starts the station: the calibration loaded (with its covariance), the source opened, the
/// data folder created, the address bound; then the threads and the server. Any of these that
/// fails is an error here, before anything runs.
pub fn start(args: StationArgs) -> Result<Running> {
    let (file, rig) = SystemFile::load(&args.system)?;
    check_capacity(&args.system, &rig)?;
    let fingerprint = file.fingerprint_u64()?;
    let calibration = Arc::new(Calibration::load(&args.system)?);
    let grid = rig.grid();
    let sensor = (grid.width, grid.height);
    let step = Some(centroid_step_px(grid.width, grid.height));
    let source = source::open(&args.source, sensor)?;
    std::fs::create_dir_all(&args.data)
        .with_context(|| format!("{}: cannot create the data folder", args.data.display()))?;
    let listener = std::net::TcpListener::bind(args.listen)
        .with_context(|| format!("--listen {}: cannot listen", args.listen))?;
    listener.set_nonblocking(true)?;
    let addr = listener.local_addr()?;
    let hosts = addr
        .ip()
        .is_loopback()
        .then(|| vec![addr.to_string(), format!("localhost:{}", addr.port())]);
    let shared = Arc::new(Shared::new(
        args.burst.max(surface_view::LIVE_FRAMES).max(3),
    ));
    let stop = Arc::new(AtomicBool::new(false));
    let measured = Arc::new(Latest::default());
    let poke = Arc::new(Latest::default());
    let setup = DeviceSetup {
        system: args.system.clone(),
        rig: Arc::new(rig),
        fingerprint,
        link: args.link.clone(),
        depth: args.depth,
        tolerance: args.tolerance,
    };
    let mut threads = Vec::new();
    {
        let (shared, measured, stop) = (shared.clone(), measured.clone(), stop.clone());
        threads.push(std::thread::spawn(move || {
            live::read_frames(source, sensor, &shared, &measured, &stop);
        }));
    }
    {
        let (shared, measured, poke, stop) =
            (shared.clone(), measured.clone(), poke.clone(), stop.clone());
        threads.push(std::thread::spawn(move || {
            live::identify_frames(&setup, &shared, &measured, &poke, &stop);
        }));
    }
    {
        let (shared, calibration, stop) = (shared.clone(), calibration.clone(), stop.clone());
        threads.push(std::thread::spawn(move || {
            surface_view::analyse_frames(&calibration, step, &shared, &poke, &stop);
        }));
    }
    let app = Arc::new(server::App {
        shared,
        calibration,
        system: args.system.clone(),
        data: args.data.clone(),
        centroid_step_px: step,
        burst: args.burst.max(1),
        hosts,
    });
    let (shutdown, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = std::thread::spawn(move || -> Result<()> {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()?;
        runtime.block_on(async move {
            let listener = tokio::net::TcpListener::from_std(listener)?;
            axum::serve(listener, server::router(app))
                .with_graceful_shutdown(async {
                    let _ = stopped.await;
                })
                .await?;
            Ok(())
        })
    });
    Ok(Running {
        addr,
        stop,
        shutdown: Some(shutdown),
        threads,
        server: Some(server),
    })
}
