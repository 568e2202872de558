//! The bodies of `deltaz device ports|info|upload|stream` (argument parsing stays in `main.rs`).

use crate::cli::dot_observations;
use crate::io::atomic::write_atomic;
use crate::io::observations::read_observations;
use crate::link::{Device, DeviceError, InProcess, Qemu, Serial, Transport, WorldPoint};
use crate::ply::{write_ply, Encoding};
use crate::reconstruct::ReconstructedPoint;
use crate::system::{SystemFile, SystemRig};
use anyhow::{bail, Context, Result};
use deltaz_shared::collinearity::project_camera_point;
use deltaz_shared::protocol::calibration::IdentifyParams;
use deltaz_shared::protocol::{PointStatus, MAX_BATCH};
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
}

/// Whatever transport the arguments name.
pub type AnyDevice = Device<Box<dyn Transport>>;

/// Connect as `args` say.
pub fn connect(args: &LinkArgs) -> Result<AnyDevice> {
    let transport: Box<dyn Transport> = match (&args.port, &args.qemu) {
        (Some(_), Some(_)) => bail!("--port and --qemu exclude each other"),
        (Some(port), None) => Box::new(Serial::open(port, args.baud)?),
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

/// `deltaz device info`.
pub fn info(args: &LinkArgs) -> Result<()> {
    let mut device = connect(args)?;
    let i = device.info()?;
    let [a, b, c] = i.firmware;
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
    Ok(())
}

/// Load `system.json`: the rig and its fingerprint.
pub fn load_system(path: &Path) -> Result<(SystemRig, u64)> {
    let (file, rig) = SystemFile::load(path)?;
    let fingerprint = file.fingerprint_u64()?;
    Ok((rig, fingerprint))
}

/// Upload `system` to `device` (with the parameters to identify unlabelled dots, if given) and
/// say so.
fn upload_to(
    device: &mut AnyDevice,
    system: &Path,
    method: Method,
    identification: Option<IdentifyParams>,
) -> Result<u64> {
    let (rig, fingerprint) = load_system(system)?;
    let s = device
        .upload_identifying(&rig, fingerprint, method, identification)
        .with_context(|| format!("uploading {}", system.display()))?;
    eprintln!(
        "uploaded {} ({} rays): fingerprint {:016x} read back, generation {}",
        system.display(),
        s.rays,
        s.fingerprint,
        s.generation
    );
    Ok(fingerprint)
}

/// `deltaz device upload system.json`.
pub fn upload(
    args: &LinkArgs,
    system: &Path,
    method: Method,
    identification: Option<IdentifyParams>,
) -> Result<()> {
    let mut device = connect(args)?;
    upload_to(&mut device, system, method, identification)?;
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

/// `deltaz device stream`: frames in, points out, with a live points/s figure.
pub fn stream(args: &StreamArgs) -> Result<()> {
    let mut device = connect(&args.link)?;
    if let Some(system) = &args.system {
        let (_, fingerprint) = load_system(system)?;
        match device.expect_calibration(fingerprint) {
            Ok(_) => {}
            Err(DeviceError::Fingerprint { .. }) if args.link.port.is_none() => {
                upload_to(&mut device, system, args.method, args.identification)?;
            }
            Err(e) => return Err(e).context(
                "the device does not hold this system's calibration: run `deltaz device upload`",
            ),
        }
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
    let start = Instant::now();
    let mut shown = Instant::now();
    let (mut points, mut failed, mut csv) =
        (Vec::new(), 0usize, String::from("image,point,X,Y,Z,miss\n"));
    let mut unidentified = 0usize;
    for (image, frame) in &frames {
        let results = if args.identify {
            if frame.len() > MAX_BATCH {
                bail!(
                    "{image}: {} dots, the device identifies at most {MAX_BATCH} per frame",
                    frame.len()
                );
            }
            let dots: Vec<(f64, f64)> = frame.iter().map(|&(_, col, row)| (col, row)).collect();
            device.identify(&dots)?
        } else {
            let results = device.compute(frame)?;
            frame.iter().map(|&(id, _, _)| id).zip(results).collect()
        };
        for (id, r) in results {
            match r {
                Ok(WorldPoint { point, miss }) => {
                    csv += &format!("{image},{id},{},{},{},{miss}\n", point.x, point.y, point.z);
                    points.push(ReconstructedPoint {
                        id,
                        point,
                        miss,
                        sigma: None,
                    });
                }
                Err(PointStatus::Unassigned | PointStatus::Ambiguous | PointStatus::Conflict) => {
                    unidentified += 1
                }
                Err(_) => failed += 1,
            }
        }
        if shown.elapsed() > Duration::from_millis(500) {
            shown = Instant::now();
            let n = points.len() + failed + unidentified;
            eprint!(
                "\r{n} points, {:.0} points/s",
                n as f64 / start.elapsed().as_secs_f64()
            );
        }
    }
    let n = points.len() + failed + unidentified;
    let (sent, received) = device.byte_counts();
    if args.identify {
        eprintln!("\r{unidentified} dots not identified (unassigned, ambiguous or conflicts)");
    }
    eprintln!(
        "\r{n} points in {} frames, {:.0} points/s, {:.2} bytes per point on the link, {failed} without a point",
        frames.len(),
        n as f64 / start.elapsed().as_secs_f64(),
        (sent + received) as f64 / n.max(1) as f64
    );
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
            let cam = rig.r_cam_world() * line.at(t);
            let refined = project_camera_point(rig.inner().f, &cam).ok()?;
            let (col, row) = rig
                .grid()
                .photo_to_pixel(rig.inner().unrefine(refined).ok()?);
            rig.grid().contains(col, row).then_some((ray.id, col, row))
        })
        .collect()
}
