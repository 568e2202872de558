//! `deltaz scan`: a sequence of camera frames → measured dots → identified dots → 3D points, in
//! process, pipelined: one thread reads and measures frame n + 1 (the measurement itself spread
//! over the cores) while the caller's thread identifies and reconstructs frame n and hands its
//! points to the output.

use super::device::{check_capacity, connect, ensure_calibration, LinkArgs};
use crate::io::atomic::{Pending, Staged};
use crate::io::ply::{encode_with, CloudInfo, Encoding};
use crate::io::points_comment;
use crate::io::system_file::{SystemFile, SystemRig};
use anyhow::{bail, Context, Result};
use deltaz_calib::projector_calibration::DotObservation;
use deltaz_calib::reconstruct::{reconstruct, ReconstructedPoint};
use deltaz_measure::{host_identifier, load_image, HostIdentifier, LoadedImage, MeasureParams};
use deltaz_shared::identify::Assignment;
use deltaz_shared::rig::Method;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The image files of a folder (PNG, TIFF, JPEG), in name order.
pub fn frame_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("{}: cannot read the folder", dir.display()))?
        .filter_map(|e| Some(e.ok()?.path()))
        .filter(|p| {
            p.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                ["png", "tif", "tiff", "jpg", "jpeg"].contains(&e.to_lowercase().as_str())
            })
        })
        .collect();
    files.sort();
    if files.is_empty() {
        bail!("{}: no PNG, TIFF or JPEG images", dir.display());
    }
    Ok(files)
}

/// One scanned frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FramePoints {
    /// Frame number (0-based, in scan order).
    pub frame: usize,
    /// The frame's label (file stem).
    pub label: String,
    /// Measured dots.
    pub dots: usize,
    /// The frame's identified dots and their points.
    pub found: Identified,
}

/// What identification and intersection made of a frame's dots.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Identified {
    /// The identified dots (ray id and pixel).
    pub identified: Vec<DotObservation>,
    /// Their points, in the same order.
    pub points: Vec<ReconstructedPoint>,
    /// Dots rejected for lying off the calibration's sensor.
    pub off_sensor: usize,
    /// Dots identified with a ray but without a point (degenerate or out of range).
    pub failed: usize,
}

/// Frames per second and latency (from the start of reading a frame to its points).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanStats {
    /// Frames scanned.
    pub frames: usize,
    /// Points reconstructed.
    pub points: usize,
    /// Dots rejected off the sensor.
    pub off_sensor: usize,
    /// Wall time of the whole scan.
    pub elapsed: Duration,
    /// Mean latency per frame.
    pub mean_latency: Duration,
}

impl ScanStats {
    /// Frames per second.
    pub fn frames_per_second(&self) -> f64 {
        self.frames as f64 / self.elapsed.as_secs_f64()
    }
}

/// Identification and intersection on the host (f64): dots off the sensor are rejected, the
/// rest identified with `identifier` and intersected with `method`.
pub fn on_host<'a>(
    rig: &'a SystemRig,
    identifier: &'a HostIdentifier,
    method: Method,
) -> impl FnMut(&[(f64, f64)]) -> Result<Identified> + 'a {
    let mut assigned = Vec::new();
    move |dots| {
        let on = on_sensor(rig, dots);
        assigned.clear();
        assigned.resize(on.len(), Assignment::Unassigned);
        identifier.identify_frame(&on, &mut assigned);
        let identified: Vec<DotObservation> = on
            .iter()
            .zip(&assigned)
            .filter_map(|(&(col, row), a)| match a {
                Assignment::Ray { id, .. } => Some(DotObservation { id: *id, col, row }),
                _ => None,
            })
            .collect();
        let points = reconstruct(rig, &identified, method, None, None)?;
        Ok(Identified {
            failed: identified.len() - points.len(),
            identified,
            points,
            off_sensor: dots.len() - on.len(),
        })
    }
}

/// The dots on the calibration's sensor (within half a pixel of its edge pixels' centres).
fn on_sensor(rig: &SystemRig, dots: &[(f64, f64)]) -> Vec<(f64, f64)> {
    dots.iter()
        .copied()
        .filter(|&(c, r)| rig.grid().contains(c, r))
        .collect()
}

/// Identification and intersection by the device (Identify requests, f32 on the device): it
/// must hold `rig`'s calibration with identification parameters. Dots off `rig`'s sensor are
/// rejected before they are sent (the device would reject them too). A frame of more than
/// `MAX_BATCH` dots goes in several requests, its conflicts found across all of them.
pub fn on_device<'a, T: crate::link::Transport>(
    rig: &'a SystemRig,
    device: &'a mut crate::link::Device<T>,
) -> impl FnMut(&[(f64, f64)]) -> Result<Identified> + 'a {
    use deltaz_shared::protocol::PointStatus;
    move |dots| {
        let on = on_sensor(rig, dots);
        let mut out = Identified {
            off_sensor: dots.len() - on.len(),
            ..Identified::default()
        };
        for (&(col, row), (id, r)) in on.iter().zip(device.identify(&on)?) {
            match r {
                Ok(w) => {
                    out.identified.push(DotObservation { id, col, row });
                    out.points.push(ReconstructedPoint {
                        id,
                        point: w.point,
                        miss: w.miss,
                        sigma: None,
                    });
                }
                Err(PointStatus::OffSensor) => out.off_sensor += 1,
                Err(PointStatus::Unassigned | PointStatus::Ambiguous | PointStatus::Conflict) => {}
                Err(_) => out.failed += 1,
            }
        }
        Ok(out)
    }
}

/// Scan `count` frames: `load(i)` gives frame i's label and image. The image must have the
/// calibration's size; `identify` makes points of its dots ([`on_host`], [`on_device`]);
/// `sink` receives each frame's points in order (and may stop the scan with an error).
pub fn scan(
    rig: &SystemRig,
    params: &MeasureParams,
    count: usize,
    load: impl Fn(usize) -> Result<(String, LoadedImage)> + Send,
    mut identify: impl FnMut(&[(f64, f64)]) -> Result<Identified>,
    mut sink: impl FnMut(&FramePoints) -> Result<()>,
) -> Result<ScanStats> {
    let sensor = (rig.grid().width, rig.grid().height);
    let start = Instant::now();
    let (send, receive) = std::sync::mpsc::sync_channel(2);
    let mut stats = ScanStats {
        frames: 0,
        points: 0,
        off_sensor: 0,
        elapsed: Duration::ZERO,
        mean_latency: Duration::ZERO,
    };
    let mut latency = Duration::ZERO;
    std::thread::scope(|scope| -> Result<()> {
        scope.spawn(move || {
            for i in 0..count {
                let began = Instant::now();
                let measured = load(i).and_then(|(label, image)| {
                    let dots = measure_dots(sensor, params, &label, &image)?;
                    Ok((label, dots))
                });
                let failed = measured.is_err();
                if send.send((i, began, measured)).is_err() || failed {
                    return;
                }
            }
        });
        for (frame, began, measured) in receive {
            let (label, dots) = measured?;
            let found = identify(&dots).with_context(|| format!("frame {label}"))?;
            let out = FramePoints {
                frame,
                label,
                dots: dots.len(),
                found,
            };
            sink(&out)?;
            stats.frames += 1;
            stats.points += out.found.points.len();
            stats.off_sensor += out.found.off_sensor;
            latency += began.elapsed();
        }
        Ok(())
    })?;
    stats.elapsed = start.elapsed();
    stats.mean_latency = latency / stats.frames.max(1) as u32;
    Ok(stats)
}

/// The dots `(col, row)` measured in frame `label`, whose image must have the calibration's
/// `sensor` size (width, height).
pub fn measure_dots(
    sensor: (u32, u32),
    params: &MeasureParams,
    label: &str,
    image: &LoadedImage,
) -> Result<Vec<(f64, f64)>> {
    let (size, m) = (image.dimensions(), image.measure(params));
    if size != sensor {
        bail!(
            "frame {label}: the image is {} × {} pixels, the calibration's sensor {} × {}",
            size.0,
            size.1,
            sensor.0,
            sensor.1
        );
    }
    Ok(m.targets.iter().map(|t| (t.col, t.row)).collect())
}

/// Scan image files: frame label = file stem.
pub fn scan_files(
    rig: &SystemRig,
    params: &MeasureParams,
    files: &[PathBuf],
    identify: impl FnMut(&[(f64, f64)]) -> Result<Identified>,
    sink: impl FnMut(&FramePoints) -> Result<()>,
) -> Result<ScanStats> {
    let load = |i: usize| -> Result<(String, LoadedImage)> {
        let path = &files[i];
        let label = path
            .file_stem()
            .and_then(|s| s.to_str())
            .with_context(|| format!("{}: no usable file name", path.display()))?
            .to_owned();
        Ok((label, load_image(path)?))
    };
    scan(rig, params, files.len(), load, identify, sink)
}

/// The device's identification parameters for a depth range, tolerance and lookup cell (px).
pub fn identify_params(
    depth: deltaz_shared::identify::DepthRange<f64>,
    tolerance: f64,
    cell: f64,
) -> deltaz_shared::protocol::calibration::IdentifyParams {
    deltaz_shared::protocol::calibration::IdentifyParams {
        near: depth.near as f32,
        far: depth.far as f32,
        tolerance: tolerance as f32,
        cell: cell as f32,
    }
}

/// Where `deltaz scan` identifies and intersects.
#[derive(Debug, Clone)]
pub enum ScanOn {
    /// On the host, in f64.
    Host,
    /// Through the device (`--port`, `--qemu` or in-process); `upload`: upload the system when
    /// the device holds another calibration.
    Device {
        /// The link.
        link: LinkArgs,
        /// Upload the system to a device on `--port` that holds another calibration.
        upload: bool,
    },
}

/// Arguments of `deltaz scan`.
#[derive(Debug, Clone)]
pub struct ScanArgs {
    /// system.json.
    pub system: PathBuf,
    /// The frames, in scan order.
    pub frames: Vec<PathBuf>,
    /// Depth range of the surface (mm from the camera along its axis).
    pub depth: deltaz_shared::identify::DepthRange<f64>,
    /// Identification tolerance (px).
    pub tolerance: f64,
    /// Output folder: one PLY per frame, or `scan.ply` with a `frame` property.
    pub out: PathBuf,
    /// One PLY `OUT/scan.ply` of all frames with the `frame` property.
    pub one_file: bool,
    /// CSV `frame,image,point,X,Y,Z,miss` of all frames.
    pub csv: Option<PathBuf>,
    /// Intersection method.
    pub method: Method,
    /// Host or device.
    pub on: ScanOn,
    /// No progress bar.
    pub quiet: bool,
}

/// `deltaz scan`: one PLY per frame (`OUT/<label>.ply`) or one with a `frame` property
/// (`OUT/scan.ply`), and the CSV, a progress bar with frames/s on stderr. Every file is staged
/// and renamed into place when every frame succeeded: a failed scan leaves no file behind (nor
/// the folder OUT when it created it). Returns the statistics and the points' frame (the
/// system's), in words.
pub fn scan_command(args: &ScanArgs) -> Result<(ScanStats, String)> {
    let (file, rig) = SystemFile::load(&args.system)?;
    let fingerprint = file.fingerprint_u64()?;
    if matches!(args.on, ScanOn::Device { .. }) {
        check_capacity(&args.system, &rig)?;
    }
    let frame = file.content.frame.to_string();
    let created = !args.out.exists();
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("{}: cannot create", args.out.display()))?;
    let result = scan_into(args, &rig, (fingerprint, &frame));
    if result.is_err() && created {
        let _ = std::fs::remove_dir_all(&args.out);
    }
    Ok((result?, frame))
}

/// [`scan_command`] into its existing output folder.
fn scan_into(
    args: &ScanArgs,
    rig: &SystemRig,
    (fingerprint, frame): (u64, &str),
) -> Result<ScanStats> {
    use std::io::Write;
    let cell = if rig.grid().width > 2000 { 32.0 } else { 16.0 };
    let mut csv = match &args.csv {
        Some(path) => {
            let (pending, mut writer) = Pending::new(path, "csv")?;
            write!(writer, "{}", points_comment(frame, fingerprint))?;
            writeln!(writer, "frame,image,point,X,Y,Z,miss")?;
            Some((pending, writer))
        }
        None => None,
    };
    let bar = if args.quiet {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(args.frames.len() as u64)
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} frames, {per_sec} {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let grid = rig.grid();
    let info = CloudInfo {
        frame: frame.to_owned(),
        fingerprint: Some(format!("{fingerprint:016x}")),
        frames: None,
        centroid_step_px: matches!(args.on, ScanOn::Device { .. })
            .then(|| crate::link::centroid_step_px(grid.width, grid.height)),
    };
    let (mut all, mut all_frames) = (Vec::new(), Vec::new());
    let mut staged = Staged::default();
    let sink = |f: &FramePoints| -> Result<()> {
        let points = &f.found.points;
        if args.one_file {
            all.extend_from_slice(points);
            all_frames.extend(std::iter::repeat_n(f.frame as u32, points.len()));
        } else {
            let bytes = encode_with(points, Encoding::BinaryLittleEndian, &info);
            staged.add(&args.out.join(format!("{}.ply", f.label)), &bytes)?;
        }
        if let Some((pending, writer)) = &mut csv {
            for p in points {
                let x = p.point;
                writeln!(
                    writer,
                    "{},{},{},{},{},{},{}",
                    f.frame, f.label, p.id, x.x, x.y, x.z, p.miss
                )
                .with_context(|| format!("{}: cannot write", pending.target.display()))?;
            }
        }
        bar.inc(1);
        bar.set_message(format!("{} of {} dots identified", points.len(), f.dots));
        Ok(())
    };
    let params = MeasureParams::default();
    let stats = match &args.on {
        ScanOn::Host => {
            let identifier = host_identifier(rig, args.depth, args.tolerance, cell)
                .with_context(|| args.system.display().to_string())?;
            let identify = on_host(rig, &identifier, args.method);
            scan_files(rig, &params, &args.frames, identify, sink)?
        }
        ScanOn::Device { link, upload } => {
            let mut device = connect(link)?;
            let identification = identify_params(args.depth, args.tolerance, cell);
            ensure_calibration(
                &mut device,
                link,
                (&args.system, rig, fingerprint),
                args.method,
                Some(identification),
                *upload,
            )?;
            scan_files(
                rig,
                &params,
                &args.frames,
                on_device(rig, &mut device),
                sink,
            )?
        }
    };
    bar.finish_and_clear();
    if args.one_file {
        let info = CloudInfo {
            frames: Some(all_frames),
            ..info
        };
        let bytes = encode_with(&all, Encoding::BinaryLittleEndian, &info);
        staged.add(&args.out.join("scan.ply"), &bytes)?;
    }
    if let Some((pending, writer)) = csv {
        pending.commit(writer)?;
    }
    staged.commit()?;
    Ok(stats)
}
