//! The bodies of `deltaz device ports|info|upload|stream` (argument parsing stays in `main.rs`).

use crate::cli::dot_observations;
use crate::io::atomic::write_atomic;
use crate::io::observations::read_observations;
use crate::link::{
    Device, DeviceError, InProcess, PointOutcome, Qemu, Serial, Transport, WorldPoint,
};
use crate::ply::{write_ply, Encoding};
use crate::reconstruct::ReconstructedPoint;
use crate::system::{SystemFile, SystemRig};
use anyhow::{bail, Context, Result};
use deltaz_shared::protocol::calibration::IdentifyParams;
use deltaz_shared::protocol::{PointStatus, MAX_BATCH, MAX_RAYS};
use deltaz_shared::rig::Method;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Which device to talk to.
#[derive(Debug, Clone)]
pub struct LinkArgs {
    /// A serial port; without it (and without `qemu`) the firmware's logic runs in-process.
    pub port: Option<String>,
    /// Baud rate of `port`.
    pub baud: u32,
    /// Start the firmware in QEMU (mps2-an386) from this ELF and talk to it over a pty.
    pub qemu: Option<PathBuf>,
    /// Response timeout.
    pub timeout: Duration,
    /// Print one JSON object on stdout instead of text.
    pub json: bool,
}

/// Whatever transport the arguments name.
pub type AnyDevice = Device<Box<dyn Transport>>;

/// Connect as `args` say.
pub fn connect(args: &LinkArgs) -> Result<AnyDevice> {
    let transport: Box<dyn Transport> = match (&args.port, &args.qemu) {
        (Some(_), Some(_)) => bail!("--port and --qemu exclude each other"),
        (Some(port), None) => {
            // A board queues what it receives while it answers in a 1 KiB ring (the firmware's
            // `rx_ring`), less than a second 440-dot request: one request in flight (QEMU's
            // UART holds the line instead, so pipelining works there).
            let serial = Serial::open(port, args.baud)?;
            return Ok(Device::new(Box::new(serial) as Box<dyn Transport>)
                .with_timeout(args.timeout)
                .with_window(1));
        }
        (None, Some(elf)) => {
            if !elf.exists() {
                bail!(
                    "no firmware at {} (cargo build -p deltaz-firmware --target \
                     thumbv7em-none-eabihf --release)",
                    elf.display()
                );
            }
            Box::new(Qemu::spawn(elf)?)
        }
        (None, None) => Box::new(InProcess::new()),
    };
    Ok(Device::new(transport).with_timeout(args.timeout))
}

/// `deltaz device ports`.
pub fn ports() -> Result<()> {
    let ports = crate::link::list_ports()?;
    if ports.is_empty() {
        println!("no serial ports");
    }
    for (path, what) in ports {
        println!("{path}\t{what}");
    }
    Ok(())
}

/// `deltaz device info` (`--json`: one JSON object on stdout).
pub fn info(args: &LinkArgs) -> Result<()> {
    let mut device = connect(args)?;
    let i = device.info()?;
    let [a, b, c] = i.firmware;
    if args.json {
        let calibration = i.calibration.map(|s| {
            serde_json::json!({
                "fingerprint": format!("{:016x}", s.fingerprint),
                "generation": s.generation,
                "rays": s.rays,
                "centroid_bits": s.centroid_bits,
                "camera_centre_mm": s.camera_centre,
            })
        });
        let json = serde_json::json!({
            "firmware": format!("{a}.{b}.{c}"),
            "protocol": i.protocol,
            "ray_capacity": i.ray_capacity,
            "max_batch": i.max_batch,
            "max_frame": i.max_frame,
            "max_calibration": i.max_calibration,
            "calibration": calibration,
            "boot_error": i.boot_error.map(|e| e.to_string()),
        });
        println!("{json}");
        return Ok(());
    }
    println!("firmware {a}.{b}.{c}, protocol {}", i.protocol);
    println!(
        "capacity: {} rays, {} centroids per frame, frames up to {} bytes, calibration up to {} bytes",
        i.ray_capacity, i.max_batch, i.max_frame, i.max_calibration
    );
    match i.calibration {
        Some(s) => println!(
            "calibration {:016x} (generation {}): {} rays, centroids in 1/{} pixel, camera centre {:.3?} mm",
            s.fingerprint,
            s.generation,
            s.rays,
            1u32 << s.centroid_bits,
            s.camera_centre
        ),
        None => println!("no calibration"),
    }
    if let Some(e) = i.boot_error {
        println!("the stored calibration failed to load at boot: {e}");
    }
    Ok(())
}

/// Load `system.json`: the rig and its fingerprint; refused when it has more rays than a
/// device holds ([`MAX_RAYS`]).
pub fn load_system(path: &Path) -> Result<(SystemRig, u64)> {
    let (file, rig) = SystemFile::load(path)?;
    let rays = file.content.projector.rays.len();
    if rays > MAX_RAYS {
        bail!(
            "{}: {rays} projector rays, more than the device's capacity of {MAX_RAYS}",
            path.display()
        );
    }
    let fingerprint = file.fingerprint_u64()?;
    Ok((rig, fingerprint))
}

/// Upload `system` to `device` (with the parameters to identify unlabelled dots, if given) and
/// say so.
fn upload_to(
    device: &mut AnyDevice,
    system: &Path,
    (rig, fingerprint): &(SystemRig, u64),
    method: Method,
    identification: Option<IdentifyParams>,
) -> Result<u64> {
    let s = device
        .upload_identifying(rig, *fingerprint, method, identification)
        .with_context(|| format!("uploading {}", system.display()))?;
    eprintln!(
        "uploaded {} ({} rays): fingerprint {:016x} read back, generation {}",
        system.display(),
        s.rays,
        s.fingerprint,
        s.generation
    );
    Ok(*fingerprint)
}

/// Check that `device` holds `system`'s calibration (its fingerprint); upload it (with
/// `identification`) when it does not and the device is in-process or in QEMU (fresh each
/// time) or `upload` says so, else fail saying how.
pub fn ensure_calibration(
    device: &mut AnyDevice,
    link: &LinkArgs,
    system: &Path,
    method: Method,
    identification: Option<IdentifyParams>,
    upload: bool,
) -> Result<()> {
    let loaded = load_system(system)?;
    match device.expect_calibration(loaded.1) {
        Ok(_) => Ok(()),
        Err(DeviceError::Fingerprint { .. }) if upload || link.port.is_none() => {
            upload_to(device, system, &loaded, method, identification).map(|_| ())
        }
        Err(e @ DeviceError::Fingerprint { .. }) => Err(e).context(format!(
            "the device does not hold the calibration of {}: run `deltaz device upload` \
             (or `deltaz scan --upload`)",
            system.display()
        )),
        Err(e) => Err(e).context("asking the device for its calibration"),
    }
}

/// `deltaz device upload system.json`.
pub fn upload(
    args: &LinkArgs,
    system: &Path,
    method: Method,
    identification: Option<IdentifyParams>,
) -> Result<()> {
    let loaded = load_system(system)?;
    let mut device = connect(args)?;
    upload_to(&mut device, system, &loaded, method, identification)?;
    if args.port.is_none() {
        eprintln!(
            "note: the in-process and QEMU devices live only as long as this command; \
             `deltaz device stream --system` uploads to them itself"
        );
    }
    Ok(())
}

/// Where `deltaz device stream` takes its centroids from.
#[derive(Debug, Clone)]
pub enum StreamSource {
    /// An observations CSV (`image,point,col,row[,kind]`; dot rows, point = ray id); one frame
    /// per image.
    Csv(PathBuf),
    /// `frames` simulated frames: the system's dots on plates Z = 0, 100, 200, ... (rig frame).
    Simulated {
        /// Number of frames.
        frames: usize,
    },
}

/// Arguments of `deltaz device stream`.
#[derive(Debug, Clone)]
pub struct StreamArgs {
    /// The link.
    pub link: LinkArgs,
    /// The calibration the device must hold (uploaded first to an in-process or QEMU device).
    pub system: Option<PathBuf>,
    /// The centroids.
    pub source: StreamSource,
    /// PLY output.
    pub out: Option<PathBuf>,
    /// CSV output `image,point,X,Y,Z,miss`.
    pub csv: Option<PathBuf>,
    /// Intersection method for an upload.
    pub method: Method,
    /// Send the dots without ids: the device identifies them.
    pub identify: bool,
    /// The depth range and tolerance the device identifies with (part of an upload).
    pub identification: Option<IdentifyParams>,
}

/// One camera frame: its image label and centroids `(ray id, col, row)`.
type Frame = (String, Vec<(u16, f64, f64)>);

/// Frames streamed (pipelined) between two looks at the progress line.
const STREAM_GROUP: usize = 16;

/// The results `(ray id, point or status)` of a group of frames, each frame in order.
fn stream_group(
    device: &mut AnyDevice,
    group: &[Frame],
    identify: bool,
) -> Result<Vec<Vec<(u16, PointOutcome)>>, DeviceError> {
    if identify {
        let dots: Vec<Vec<(f64, f64)>> = group
            .iter()
            .map(|(_, f)| f.iter().map(|&(_, col, row)| (col, row)).collect())
            .collect();
        return device.identify_frames(&dots);
    }
    // A frame of more than MAX_BATCH centroids goes as several requests.
    let batches: Vec<&[(u16, f64, f64)]> = group
        .iter()
        .flat_map(|(_, f)| f.chunks(MAX_BATCH))
        .collect();
    let mut results = device.compute_frames(&batches)?.into_iter();
    Ok(group
        .iter()
        .map(|(_, f)| {
            let points: Vec<PointOutcome> = (0..f.len().div_ceil(MAX_BATCH))
                .flat_map(|_| results.next().unwrap_or_default())
                .collect();
            f.iter().map(|&(id, _, _)| id).zip(points).collect()
        })
        .collect())
}

/// `deltaz device stream`: frames in, points out, with a live points/s figure.
pub fn stream(args: &StreamArgs) -> Result<()> {
    // The system is checked (its rays against the device's capacity) before connecting.
    if let Some(system) = &args.system {
        load_system(system)?;
    }
    let mut device = connect(&args.link)?;
    if let Some(system) = &args.system {
        ensure_calibration(
            &mut device,
            &args.link,
            system,
            args.method,
            args.identification,
            false,
        )?;
    }
    let frames = match &args.source {
        StreamSource::Csv(path) => {
            let obs = read_observations(path)?;
            let dots = dot_observations(path, &obs)?;
            let mut frames: Vec<Frame> = Vec::new();
            for (image, d) in dots {
                match frames.last_mut() {
                    Some((name, frame)) if *name == image => frame.push((d.id, d.col, d.row)),
                    _ => frames.push((image, vec![(d.id, d.col, d.row)])),
                }
            }
            frames
        }
        StreamSource::Simulated { frames } => {
            let Some(system) = &args.system else {
                bail!("a simulated stream needs --system");
            };
            let (rig, _) = load_system(system)?;
            (0..*frames)
                .map(|k| {
                    let z = 100.0 * (k % 3) as f64;
                    (format!("sim{k}"), plate_dots(&rig, z))
                })
                .collect()
        }
    };
    if args.identify {
        if let Some((image, frame)) = frames.iter().find(|(_, f)| f.len() > MAX_BATCH) {
            bail!(
                "{image}: {} dots, the device identifies at most {MAX_BATCH} per frame",
                frame.len()
            );
        }
    }
    let start = Instant::now();
    let mut shown = Instant::now();
    let mut progress = false;
    let (mut points, mut failed, mut csv) =
        (Vec::new(), 0usize, String::from("image,point,X,Y,Z,miss\n"));
    let mut unidentified = 0usize;
    // Groups of frames, each pipelined (several requests in flight), between progress lines.
    for group in frames.chunks(STREAM_GROUP) {
        let results = stream_group(&mut device, group, args.identify).inspect_err(|_| {
            if progress {
                // The error goes on its own line, not after the progress counter.
                eprintln!();
            }
        })?;
        for ((image, _), results) in group.iter().zip(results) {
            for (id, r) in results {
                match r {
                    Ok(WorldPoint { point, miss }) => {
                        csv +=
                            &format!("{image},{id},{},{},{},{miss}\n", point.x, point.y, point.z);
                        points.push(ReconstructedPoint {
                            id,
                            point,
                            miss,
                            sigma: None,
                        });
                    }
                    Err(
                        PointStatus::Unassigned | PointStatus::Ambiguous | PointStatus::Conflict,
                    ) => unidentified += 1,
                    Err(_) => failed += 1,
                }
            }
        }
        if shown.elapsed() > Duration::from_millis(500) && !args.link.json {
            shown = Instant::now();
            progress = true;
            let n = points.len() + failed + unidentified;
            eprint!(
                "\r{n} points, {:.0} points/s",
                n as f64 / start.elapsed().as_secs_f64()
            );
        }
    }
    let seconds = start.elapsed().as_secs_f64();
    let n = points.len() + failed + unidentified;
    let (sent, received) = device.byte_counts();
    let line = device.line_counts();
    let bytes_per_point = (sent + received) as f64 / n.max(1) as f64;
    if args.link.json {
        let stats = device.stats().context("reading the device's statistics")?;
        let json = serde_json::json!({
            "frames": frames.len(),
            "points": points.len(),
            "without_point": failed,
            "unidentified": unidentified,
            "seconds": seconds,
            "points_per_s": n as f64 / seconds,
            "bytes_sent": sent,
            "bytes_received": received,
            "bytes_per_point": bytes_per_point,
            "line": {
                "resent": line.resent,
                "damaged": line.damaged,
                "unreadable": line.unreadable,
                "stale": line.stale,
            },
            "stats": {
                "requests": stats.requests,
                "bad_frames": stats.bad_frames,
                "points": stats.points,
                "last_compute_ticks": stats.last_compute_ticks,
                "last_compute_points": stats.last_compute_points,
                "stack_peak_bytes": stats.stack_peak,
            },
        });
        println!("{json}");
    } else {
        if progress {
            eprintln!();
        }
        if args.identify {
            eprintln!("{unidentified} dots not identified (unassigned, ambiguous or conflicts)");
        }
        eprintln!(
            "{n} points in {} frames, {:.0} points/s, {bytes_per_point:.2} bytes per point on the link, {failed} without a point",
            frames.len(),
            n as f64 / seconds,
        );
        if line.resent > 0 {
            eprintln!(
                "the link resent {} requests ({} damaged frames, {} unreadable, {} stale answers)",
                line.resent, line.damaged, line.unreadable, line.stale
            );
        }
    }
    if let Some(out) = &args.out {
        write_ply(out, &points, Encoding::BinaryLittleEndian)?;
    }
    if let Some(path) = &args.csv {
        write_atomic(path, csv.as_bytes())?;
    }
    Ok(())
}

/// The centroids of the rig's dots on the plate Z = `z` (rig frame) that the camera sees.
pub fn plate_dots(rig: &SystemRig, z: f64) -> Vec<(u16, f64, f64)> {
    let x0 = rig.camera_centre();
    let projector = rig.projector_centred();
    projector
        .rays()
        .iter()
        .filter_map(|ray| {
            let line = projector.ray(ray.id).ok()?;
            let t = (z - x0.z - line.point.z) / line.direction.z;
            let (col, row) = rig.pixel_of_centred(&line.at(t)).ok()?;
            rig.grid().contains(col, row).then_some((ray.id, col, row))
        })
        .collect()
}
