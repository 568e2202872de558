//! `deltaz scan`: a sequence of camera frames → measured dots → identified dots → 3D points, in
//! process, pipelined: one thread reads and measures frame n + 1 (the measurement itself spread
//! over the cores) while the caller's thread identifies and reconstructs frame n and hands its
//! points to the output.

use crate::measure::{
    host_identifier, load_image, measure, HostIdentifier, LoadedImage, MeasureParams,
};
use crate::projector_calibration::DotObservation;
use crate::reconstruct::{reconstruct, ReconstructedPoint};
use crate::system::SystemRig;
use anyhow::{bail, Context, Result};
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
    /// The identified dots (ray id and pixel).
    pub identified: Vec<DotObservation>,
    /// Their points, in the same order.
    pub points: Vec<ReconstructedPoint>,
}

/// Frames per second and latency (from the start of reading a frame to its points).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanStats {
    /// Frames scanned.
    pub frames: usize,
    /// Points reconstructed.
    pub points: usize,
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

/// Scan `count` frames: `load(i)` gives frame i's label and image. The image must have the
/// calibration's size; `sink` receives each frame's points in order (and may stop the scan with
/// an error).
pub fn scan(
    rig: &SystemRig,
    identifier: &HostIdentifier,
    params: &MeasureParams,
    method: Method,
    count: usize,
    load: impl Fn(usize) -> Result<(String, LoadedImage)> + Send,
    mut sink: impl FnMut(&FramePoints) -> Result<()>,
) -> Result<ScanStats> {
    let sensor = (rig.grid().width, rig.grid().height);
    let start = Instant::now();
    let (send, receive) = std::sync::mpsc::sync_channel(2);
    let mut stats = ScanStats {
        frames: 0,
        points: 0,
        elapsed: Duration::ZERO,
        mean_latency: Duration::ZERO,
    };
    let mut latency = Duration::ZERO;
    std::thread::scope(|scope| -> Result<()> {
        scope.spawn(move || {
            for i in 0..count {
                let began = Instant::now();
                let measured = load(i).and_then(|(label, image)| {
                    let (size, m) = match &image {
                        LoadedImage::Eight(b) => (b.dimensions(), measure(&view(b, 1.0), params)),
                        LoadedImage::Sixteen(b) => {
                            (b.dimensions(), measure(&view(b, 257.0), params))
                        }
                    };
                    if size != sensor {
                        bail!(
                            "frame {label}: the image is {} × {} pixels, the calibration's sensor {} × {}",
                            size.0, size.1, sensor.0, sensor.1
                        );
                    }
                    let dots: Vec<(f64, f64)> = m.targets.iter().map(|t| (t.col, t.row)).collect();
                    Ok((label, dots))
                });
                let failed = measured.is_err();
                if send.send((i, began, measured)).is_err() || failed {
                    return;
                }
            }
        });
        let mut assigned = Vec::new();
        for (frame, began, measured) in receive {
            let (label, dots) = measured?;
            assigned.clear();
            assigned.resize(dots.len(), Assignment::Unassigned);
            identifier.identify_frame(&dots, &mut assigned);
            let identified: Vec<DotObservation> = dots
                .iter()
                .zip(&assigned)
                .filter_map(|(&(col, row), a)| match a {
                    Assignment::Ray { id, .. } => Some(DotObservation { id: *id, col, row }),
                    _ => None,
                })
                .collect();
            let points = reconstruct(rig, &identified, method, None, None)
                .with_context(|| format!("frame {label}"))?;
            let out = FramePoints {
                frame,
                label,
                dots: dots.len(),
                identified,
                points,
            };
            sink(&out)?;
            stats.frames += 1;
            stats.points += out.points.len();
            latency += began.elapsed();
        }
        Ok(())
    })?;
    stats.elapsed = start.elapsed();
    stats.mean_latency = latency / stats.frames.max(1) as u32;
    Ok(stats)
}

fn view<P: image::Primitive>(
    b: &image::ImageBuffer<image::Luma<P>, Vec<P>>,
    dn: f64,
) -> crate::measure::detect::GrayView<'_, P> {
    crate::measure::detect::GrayView {
        width: b.width() as usize,
        height: b.height() as usize,
        pixels: b.as_raw(),
        dn,
    }
}

/// Scan image files: frame label = file stem.
pub fn scan_files(
    rig: &SystemRig,
    identifier: &HostIdentifier,
    params: &MeasureParams,
    method: Method,
    files: &[PathBuf],
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
    scan(rig, identifier, params, method, files.len(), load, sink)
}

/// Scan timings (`deltaz bench-measure`): 60 frames of the paper rig's dots rendered on planes
/// 1690-1780 mm away, tilted up to 0.1 rad (768 × 512, radius 4 px, blur 1 px, noise 2 DN), scanned in process.
pub fn bench() -> Result<String> {
    use crate::simulate::objects::{object_dots, object_frame, Object};
    use crate::simulate::{images::true_rig, Scenario};
    let rig = true_rig(&Scenario::paper());
    let frames: Vec<_> = [
        (1690.0, 0.0),
        (1720.0, 0.05),
        (1750.0, -0.05),
        (1780.0, 0.1),
    ]
    .iter()
    .enumerate()
    .map(|(k, &(depth, tilt))| {
        let dots = object_dots(&rig, &Object::Plane { depth, tilt });
        object_frame(&rig, &dots, k as u64)
    })
    .collect();
    let depth = deltaz_shared::identify::DepthRange {
        near: 1600.0,
        far: 1860.0,
    };
    let identifier = host_identifier(&rig, depth, 1.0, 16.0)?;
    let count = 60;
    let load = |i: usize| {
        Ok((
            format!("f{i}"),
            LoadedImage::Eight(frames[i % frames.len()].clone()),
        ))
    };
    let stats = scan(
        &rig,
        &identifier,
        &MeasureParams::default(),
        Method::ClosestApproach,
        count,
        load,
        |_| Ok(()),
    )?;
    Ok(format!(
        "scan (in process, 768 x 512, {} dots per frame): {} frames in {:.2} s, {:.1} frames/s, latency {:.1} ms, {} points\n",
        stats.points / stats.frames.max(1),
        stats.frames,
        stats.elapsed.as_secs_f64(),
        stats.frames_per_second(),
        stats.mean_latency.as_secs_f64() * 1e3,
        stats.points
    ))
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
    /// Output folder: one PLY per frame.
    pub out: PathBuf,
    /// CSV `frame,image,point,X,Y,Z,miss` of all frames.
    pub csv: Option<PathBuf>,
    /// Intersection method.
    pub method: Method,
}

/// `deltaz scan`: one PLY per frame (`OUT/<label>.ply`), the CSV written when every frame
/// succeeded, a progress bar with frames/s.
pub fn scan_command(args: &ScanArgs) -> Result<ScanStats> {
    use crate::ply::{write_ply, Encoding};
    use std::io::Write;
    let (_, rig) = crate::system::SystemFile::load(&args.system)?;
    let cell = if rig.grid().width > 2000 { 32.0 } else { 16.0 };
    let identifier = host_identifier(&rig, args.depth, args.tolerance, cell)
        .with_context(|| args.system.display().to_string())?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("{}: cannot create", args.out.display()))?;
    let mut csv = match &args.csv {
        Some(path) => {
            let (pending, mut writer) = crate::reconstruct_stream::Pending::new(path, "csv")?;
            writeln!(writer, "frame,image,point,X,Y,Z,miss")?;
            Some((pending, writer))
        }
        None => None,
    };
    let bar = indicatif::ProgressBar::new(args.frames.len() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} frames, {per_sec} {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let sink = |f: &FramePoints| -> Result<()> {
        write_ply(
            &args.out.join(format!("{}.ply", f.label)),
            &f.points,
            Encoding::BinaryLittleEndian,
        )?;
        if let Some((pending, writer)) = &mut csv {
            for p in &f.points {
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
        bar.set_message(format!("{} of {} dots identified", f.points.len(), f.dots));
        Ok(())
    };
    let params = MeasureParams::default();
    let stats = scan_files(&rig, &identifier, &params, args.method, &args.frames, sink)?;
    bar.finish();
    if let Some((pending, writer)) = csv {
        pending.commit(writer)?;
    }
    Ok(stats)
}

/// Time the epipolar identification of the paper's 440 dots on a plane 1740 mm away: building
/// the lookup (once per calibration) and identifying a frame.
pub fn identification() -> String {
    use crate::simulate::objects::{object_dots, Object};
    use crate::simulate::{images::true_rig, Scenario};
    use deltaz_shared::identify::{DepthRange, Identifier};
    let rig = true_rig(&Scenario::paper());
    let plane = Object::Plane {
        depth: 1740.0,
        tilt: 0.0,
    };
    let dots: Vec<(f64, f64)> = object_dots(&rig, &plane).iter().map(|d| d.1).collect();
    let depth = DepthRange {
        near: 1680.0,
        far: 1800.0,
    };
    let start = Instant::now();
    let ident = Identifier::<f64, 512, 2048, 8192>::new(&rig, depth, 1.0, 16.0)
        .expect("the paper rig fits");
    let build = start.elapsed().as_secs_f64();
    let mut out = vec![Assignment::Unassigned; dots.len()];
    let rounds = 200;
    let start = Instant::now();
    let mut identified = 0;
    for _ in 0..rounds {
        identified = ident.identify_frame(&dots, &mut out);
    }
    let per_frame = start.elapsed().as_secs_f64() / f64::from(rounds);
    format!(
        "identification (paper rig, 1680-1800 mm, 1 px): lookup built in {:.2} ms ({} entries); {identified} of {} dots in {:.1} µs per frame ({:.2} µs per dot)\n",
        build * 1e3,
        ident.entries(),
        dots.len(),
        per_frame * 1e6,
        per_frame * 1e6 / dots.len() as f64
    )
}
