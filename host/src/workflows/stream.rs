//! `deltaz device stream`: frames of centroids (an observations CSV, or simulated on the
//! system's plates) through the device into points, every dot accounted for.

use super::device::{connect, ensure_calibration, load_system, AnyDevice, LinkArgs, LoadedSystem};
use crate::io::atomic::write_all_atomic;
use crate::io::observations::{dot_observations, read_observations};
use crate::io::ply::{encode_with, CloudInfo, Encoding};
use crate::io::points_comment;
use crate::io::system_file::{SystemFrame, SystemRig};
use crate::link::{DeviceError, PointOutcome, WorldPoint};
use anyhow::{bail, Context, Result};
use deltaz_calib::reconstruct::ReconstructedPoint;
use deltaz_shared::intersection::closest_approach;
use deltaz_shared::projector::Ray;
use deltaz_shared::protocol::calibration::IdentifyParams;
use deltaz_shared::protocol::{PointStatus, MAX_BATCH};
use deltaz_shared::rig::Method;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Where `deltaz device stream` takes its centroids from.
#[derive(Debug, Clone)]
pub enum StreamSource {
    /// An observations CSV (`image,point,col,row[,kind]`; dot rows, point = ray id); one frame
    /// per image.
    Csv(PathBuf),
    /// `frames` simulated frames: the system's dots on three plates 100 mm apart in front of
    /// the camera, whatever the system's frame ([`simulated_plates`]).
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

/// What became of every dot a stream sent: a point, not identified, or no point, each by the device's reason.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DotCounts {
    /// Points.
    pub points: usize,
    /// Identification: no ray's epipolar segment within tolerance.
    pub unassigned: usize,
    /// Identification: two or more segments within tolerance.
    pub ambiguous: usize,
    /// Identification: another dot of the frame took the same ray.
    pub conflict: usize,
    /// No point: the calibration has no ray with the id.
    pub unknown_ray: usize,
    /// No point: camera and projector rays (nearly) parallel.
    pub degenerate: usize,
    /// No point: farther than the wire format's range from the camera.
    pub out_of_range: usize,
    /// No point: the centroid is off the sensor.
    pub off_sensor: usize,
}

impl DotCounts {
    /// Counts one dot's outcome.
    pub fn add(&mut self, outcome: &PointOutcome) {
        let n = match outcome {
            Ok(_) => &mut self.points,
            Err(PointStatus::Unassigned) => &mut self.unassigned,
            Err(PointStatus::Ambiguous) => &mut self.ambiguous,
            Err(PointStatus::Conflict) => &mut self.conflict,
            Err(PointStatus::UnknownRay) => &mut self.unknown_ray,
            Err(PointStatus::Degenerate) => &mut self.degenerate,
            Err(PointStatus::OutOfRange) => &mut self.out_of_range,
            Err(PointStatus::OffSensor) => &mut self.off_sensor,
        };
        *n += 1;
    }

    /// Dots not identified.
    pub fn unidentified(&self) -> usize {
        self.unassigned + self.ambiguous + self.conflict
    }

    /// Dots with a ray but no point.
    pub fn without_point(&self) -> usize {
        self.unknown_ray + self.degenerate + self.out_of_range + self.off_sensor
    }

    /// Every dot counted.
    pub fn dots(&self) -> usize {
        self.points + self.unidentified() + self.without_point()
    }

    /// For people: every dot accounted for, the three groups adding up to the dots sent.
    pub fn text(&self) -> String {
        format!(
            "{} dots: {} points, {} not identified ({} unassigned, {} ambiguous, {} conflicts), {} without a point \
             ({} unknown ray, {} degenerate, {} out of range, {} off the sensor)",
            self.dots(),
            self.points,
            self.unidentified(),
            self.unassigned,
            self.ambiguous,
            self.conflict,
            self.without_point(),
            self.unknown_ray,
            self.degenerate,
            self.out_of_range,
            self.off_sensor
        )
    }

    /// For machines.
    pub fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "dots": self.dots(),
            "points": self.points,
            "unidentified": self.unidentified(),
            "without_point": self.without_point(),
            "reasons": {
                "unassigned": self.unassigned,
                "ambiguous": self.ambiguous,
                "conflict": self.conflict,
                "unknown_ray": self.unknown_ray,
                "degenerate": self.degenerate,
                "out_of_range": self.out_of_range,
                "off_sensor": self.off_sensor,
            },
        })
    }
}

/// The frames of a stream: from the observations CSV, or simulated on the system's plates.
fn stream_frames(args: &StreamArgs, loaded: Option<&LoadedSystem>) -> Result<Vec<Frame>> {
    Ok(match &args.source {
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
            let Some((file, rig, _)) = loaded else {
                bail!("a simulated stream needs --system");
            };
            let plates = simulated_plates(rig, &file.content.frame)?;
            (0..*frames)
                .map(|k| (format!("sim{k}"), plates[k % 3].clone()))
                .collect()
        }
    })
}

/// `deltaz device stream`: frames in, points out, with a progress bar on a terminal; the PLY
/// and CSV are written together when every frame went through, else neither.
pub fn stream(args: &StreamArgs) -> Result<()> {
    // The system is loaded once and checked (its rays against the device's capacity) before
    // connecting.
    let loaded = args.system.as_deref().map(load_system).transpose()?;
    let mut device = connect(&args.link)?;
    if let (Some(system), Some((_, rig, fingerprint))) = (&args.system, &loaded) {
        ensure_calibration(
            &mut device,
            &args.link,
            (system, rig, *fingerprint),
            args.method,
            args.identification,
            false,
        )?;
    }
    let frames = stream_frames(args, loaded.as_ref())?;
    let fingerprint = match &loaded {
        Some((_, _, fingerprint)) => Some(*fingerprint),
        None => device.info()?.calibration.map(|c| c.fingerprint),
    };
    // The points are in the frame of the system the device holds (--out and --csv need it).
    let frame = loaded
        .as_ref()
        .map(|(file, _, _)| file.content.frame.to_string());
    let total: usize = frames.iter().map(|(_, f)| f.len()).sum();
    let bar = args.link.output.counter(
        format!("streaming {total} dots in {} frames", frames.len()),
        total as u64,
    );
    let start = Instant::now();
    let mut counts = DotCounts::default();
    let (mut points, mut point_frames) = (Vec::new(), Vec::new());
    let mut csv = match (&frame, fingerprint) {
        (Some(frame), Some(f)) => points_comment(frame, f),
        _ => String::new(),
    };
    csv += "image,point,X,Y,Z,miss\n";
    // Groups of frames, each pipelined (several requests in flight), between progress updates.
    for (g, group) in frames.chunks(STREAM_GROUP).enumerate() {
        let results = stream_group(&mut device, group, args.identify)?;
        for (k, ((image, _), results)) in group.iter().zip(results).enumerate() {
            for (id, r) in results {
                counts.add(&r);
                let Ok(WorldPoint { point, miss }) = r else {
                    continue;
                };
                csv += &format!("{image},{id},{},{},{},{miss}\n", point.x, point.y, point.z);
                points.push(ReconstructedPoint {
                    id,
                    point,
                    miss,
                    sigma: None,
                });
                point_frames.push((g * STREAM_GROUP + k) as u32);
            }
        }
        bar.set_position(counts.dots() as u64);
    }
    bar.finish_and_clear();
    let seconds = start.elapsed().as_secs_f64();
    let n = counts.dots();
    let (sent, received) = device.byte_counts();
    let line = device.line_counts();
    let bytes_per_dot = (sent + received) as f64 / n.max(1) as f64;
    let ply = args.out.as_ref().map(|_| {
        let info = CloudInfo {
            frame: frame.clone().unwrap_or_default(),
            fingerprint: fingerprint.map(|f| format!("{f:016x}")),
            frames: Some(point_frames),
            centroid_step_px: loaded.as_ref().map(|(_, rig, _)| {
                crate::link::centroid_step_px(rig.grid().width, rig.grid().height)
            }),
        };
        encode_with(&points, Encoding::BinaryLittleEndian, &info)
    });
    let files: Vec<(&Path, &[u8])> = [
        args.out.as_deref().zip(ply.as_deref()),
        args.csv.as_deref().map(|p| (p, csv.as_bytes())),
    ]
    .into_iter()
    .flatten()
    .collect();
    write_all_atomic(&files)?;
    if args.link.output.json {
        let stats = device.stats().context("reading the device's statistics")?;
        let mut json = counts.json();
        json["frames"] = frames.len().into();
        json["seconds"] = seconds.into();
        json["dots_per_s"] = (n as f64 / seconds).into();
        json["bytes_sent"] = sent.into();
        json["bytes_received"] = received.into();
        json["bytes_per_dot"] = bytes_per_dot.into();
        json["line"] = serde_json::json!({
            "resent": line.resent,
            "damaged": line.damaged,
            "unreadable": line.unreadable,
            "stale": line.stale,
        });
        json["stats"] = serde_json::json!({
            "requests": stats.requests,
            "bad_frames": stats.bad_frames,
            "points": stats.points,
            "last_compute_ticks": stats.last_compute_ticks,
            "last_compute_points": stats.last_compute_points,
            "stack_peak_bytes": stats.stack_peak,
        });
        println!("{json}");
    } else {
        println!(
            "{} in {} frames; {:.0} dots/s, {bytes_per_dot:.2} bytes per dot on the link",
            counts.text(),
            frames.len(),
            n as f64 / seconds,
        );
    }
    if line.resent > 0 {
        args.link.output.status(format!(
            "the link resent {} requests ({} damaged frames, {} unreadable, {} stale answers)",
            line.resent, line.damaged, line.unreadable, line.stale
        ));
    }
    Ok(())
}

/// The dots of three simulated plates, 100 mm apart, in front of the camera whatever the
/// system's frame: in a plate frame the planes Z = 0, 100, 200 mm of that frame (the
/// calibration plate and two beyond it); in the camera system planes across the camera's axis
/// at D, D + 100 and D + 200 mm, D the depth at which the pattern's middle ray passes the
/// camera's axis.
pub fn simulated_plates(rig: &SystemRig, frame: &SystemFrame) -> Result<[Vec<(u16, f64, f64)>; 3]> {
    let steps = [0.0, 100.0, 200.0];
    if let SystemFrame::Plate { .. } = frame {
        return Ok(steps.map(|z| plate_dots(rig, z)));
    }
    let projector = rig.projector_centred();
    let rays = projector.rays();
    let ray = rays.get(rays.len() / 2).context("the system has no rays")?;
    let axis = Ray {
        point: nalgebra::Vector3::zeros(),
        direction: rig.r_cam_world().transpose() * nalgebra::Vector3::new(0.0, 0.0, -1.0),
    };
    let line = projector
        .ray(ray.id)
        .map_err(|e| anyhow::anyhow!("ray {}: {e}", ray.id))?;
    let hit = closest_approach(&axis, &line)
        .map_err(|_| anyhow::anyhow!("the pattern's middle ray runs along the camera's axis"))?;
    if hit.lambda.is_nan() || hit.lambda <= 0.0 {
        bail!("the pattern's middle ray passes behind the camera");
    }
    Ok(steps.map(|step| depth_dots(rig, hit.lambda + step)))
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

/// The centroids of the rig's dots that the camera sees on the plate across its axis at
/// distance `depth` (mm).
fn depth_dots(rig: &SystemRig, depth: f64) -> Vec<(u16, f64, f64)> {
    rig.projector_centred()
        .rays()
        .iter()
        .filter_map(|ray| {
            let (col, row) = rig.pixel_at_depth(ray.id, depth).ok()?;
            rig.grid().contains(col, row).then_some((ray.id, col, row))
        })
        .collect()
}
