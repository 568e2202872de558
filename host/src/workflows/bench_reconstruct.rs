//! `deltaz bench-reconstruct`: how long `reconstruct` takes for the same dots split over few
//! and over many images (the time must not grow with the number of images), beside the numpy
//! script `scripts/reconstruct_numpy.py` (loadtxt and eqs 6-9, vectorised) on the same file in
//! the same run, whose points are checked against deltaz's.

use super::reconstruct::{reconstruct_stream, ReconstructArgs};
use crate::io::atomic::write_json_atomic;
use crate::io::ply::read_cloud;
use crate::io::system_file::{SystemFile, SystemRig};
use crate::report::console::Output;
use crate::simulate::dot_stream::{rays_on_sensor, true_system, write_dots};
use crate::simulate::Scenario;
use anyhow::{bail, Context, Result};
use deltaz_shared::rig::Method;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The numpy reference, run with `python3` from the bench's scratch folder.
const NUMPY_SCRIPT: &str = include_str!("../../../scripts/reconstruct_numpy.py");

/// The depths of the dots (mm from the camera): the paper rig's plates.
pub const DEPTHS: [f64; 2] = [1650.0, 1850.0];

/// A scratch folder, removed with everything in it when dropped.
struct Scratch(PathBuf);

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The paper rig with a denser pattern (25 × 24 dots at 0.8 of its spacing, over about the
/// same extent), so that 500 of its rays stay on the sensor: the dots of 10⁶ over 2,000 images.
pub fn scenario() -> Scenario {
    let mut scenario = Scenario::paper();
    let pattern = &mut scenario.rig.pattern;
    (pattern.rows, pattern.cols) = (25, 24);
    pattern.col_step = pattern.col_step.map(|v| 0.8 * v);
    pattern.row_step = pattern.row_step.map(|v| 0.8 * v);
    scenario
}

/// The inputs of a scaling run: `system.json` of the rig of [`scenario`] in a folder, and the
/// rays whose dots stay on the sensor over [`DEPTHS`], as many as the most dots per image.
pub struct ScalingInputs {
    /// The system file.
    pub system: PathBuf,
    rig: SystemRig,
    rays: Vec<u16>,
}

impl ScalingInputs {
    /// Writes `dir/system.json` for runs of up to `most_per_image` dots per image.
    pub fn new(dir: &Path, most_per_image: usize) -> Result<Self> {
        let system = SystemFile::new(true_system(&scenario())?)?;
        let rig = system.content.rig()?;
        let mut rays = rays_on_sensor(&rig, DEPTHS);
        if most_per_image > rays.len() {
            bail!(
                "{most_per_image} dots per image need as many rays; the rig has {} on the sensor",
                rays.len()
            );
        }
        rays.truncate(most_per_image);
        let path = dir.join("system.json");
        write_json_atomic(&path, &system)?;
        Ok(Self {
            system: path,
            rig,
            rays,
        })
    }

    /// Writes `dir/dots_<images>.csv`: `dots` dots over `images` images, the same dots for any
    /// number of images ([`write_dots`]); its path.
    pub fn dots(&self, dir: &Path, dots: usize, images: usize) -> Result<PathBuf> {
        let path = dir.join(format!("dots_{images}.csv"));
        let group = self.rays.len();
        write_dots(&path, &self.rig, &self.rays, (dots, images), group, DEPTHS)?;
        Ok(path)
    }
}

/// Times `reconstruct` of `dots` dots over each of `image_counts` images and the numpy script
/// over the first; the report's text and one JSON record per run.
pub fn reconstruct_scaling(
    dots: usize,
    image_counts: &[usize],
    output: Output,
) -> Result<(String, Vec<serde_json::Value>)> {
    let fewest = image_counts.iter().copied().min().unwrap_or(1).max(1);
    let scratch = Scratch(
        std::env::temp_dir().join(format!("deltaz-bench-reconstruct.{}", std::process::id())),
    );
    std::fs::create_dir_all(&scratch.0)
        .with_context(|| format!("{}: cannot create", scratch.0.display()))?;
    let dir = scratch.0.as_path();
    let inputs = ScalingInputs::new(dir, dots.div_ceil(fewest))?;
    let system_path = inputs.system.clone();
    let mut text = String::new();
    let mut runs = Vec::new();
    for &images in image_counts {
        let progress = output.progress(format!("writing {dots} dots over {images} images"));
        let obs = inputs.dots(dir, dots, images)?;
        progress.set_message(format!("reconstructing {dots} dots over {images} images"));
        let out = dir.join("cloud.ply");
        let start = Instant::now();
        let summary = reconstruct_stream(&ReconstructArgs {
            system: system_path.clone(),
            obs: obs.clone(),
            out: out.clone(),
            csv: None,
            ascii: false,
            sigma_px: None,
            method: Method::Paper,
            frame: None,
        })?;
        let seconds = start.elapsed().as_secs_f64();
        progress.finish_and_clear();
        text += &format!(
            "reconstruct: {} dots over {} images: {seconds:.3} s ({:.0} dots/s)\n",
            summary.points,
            summary.images,
            summary.points as f64 / seconds
        );
        let mut run = serde_json::json!({
            "what": "reconstruct",
            "dots": summary.points,
            "images": summary.images,
            "seconds": seconds,
        });
        if images == fewest {
            let progress = output.progress("the numpy script on the same dots".into());
            let numpy = numpy_run(dir, &system_path, &obs, &out);
            progress.finish_and_clear();
            match numpy {
                Ok(numpy) => {
                    text += &format!(
                        "numpy (loadtxt, eqs 6-9): {dots} dots: {:.3} s ({:.3} s after Python and \
                         numpy started): deltaz takes {:.2}× its time ({:.2}×); the points agree \
                         to {:.1e} mm\n",
                        numpy.seconds,
                        numpy.script_seconds,
                        seconds / numpy.seconds,
                        seconds / numpy.script_seconds,
                        numpy.largest_mm
                    );
                    run["numpy_seconds"] = numpy.seconds.into();
                    run["numpy_script_seconds"] = numpy.script_seconds.into();
                    run["numpy_largest_difference_mm"] = numpy.largest_mm.into();
                }
                Err(e) => text += &format!("numpy: not run ({e:#})\n"),
            }
        }
        runs.push(run);
    }
    if let (Some(first), Some(last)) = (runs.first(), runs.last()) {
        if runs.len() > 1 {
            let ratio =
                last["seconds"].as_f64().unwrap_or(0.0) / first["seconds"].as_f64().unwrap_or(1.0);
            text += &format!(
                "time over {} images / over {} images: {ratio:.2}\n",
                last["images"], first["images"]
            );
        }
    }
    Ok((text, runs))
}

/// A run of the numpy script.
struct NumpyRun {
    /// Seconds of the whole process (Python's start and numpy's import included).
    seconds: f64,
    /// Seconds the script measured itself (reading, computing, writing).
    script_seconds: f64,
    /// The largest difference of its points from deltaz's (mm).
    largest_mm: f64,
}

/// Runs the numpy script on `obs` and compares its points with deltaz's cloud `cloud`.
fn numpy_run(dir: &Path, system: &Path, obs: &Path, cloud: &Path) -> Result<NumpyRun> {
    let script = dir.join("reconstruct_numpy.py");
    std::fs::write(&script, NUMPY_SCRIPT)
        .with_context(|| format!("{}: cannot write", script.display()))?;
    let points = dir.join("numpy_points.npy");
    let start = Instant::now();
    let run = std::process::Command::new("python3")
        .arg(&script)
        .args([system, obs, &points])
        .output()
        .context("python3")?;
    let seconds = start.elapsed().as_secs_f64();
    if !run.status.success() {
        bail!("{}", String::from_utf8_lossy(&run.stderr).trim());
    }
    // "N dots in S s"
    let said = String::from_utf8_lossy(&run.stdout);
    let script_seconds = said
        .split_whitespace()
        .nth(3)
        .and_then(|s| s.parse::<f64>().ok())
        .with_context(|| format!("the numpy script said {said:?}"))?;
    let numpy = npy_points(&points)?;
    let deltaz = read_cloud(cloud)?;
    if numpy.len() != deltaz.vertices.len() {
        bail!(
            "numpy gave {} points, deltaz {}",
            numpy.len(),
            deltaz.vertices.len()
        );
    }
    let largest = numpy
        .iter()
        .zip(&deltaz.vertices)
        .map(|(a, v)| (nalgebra::Vector3::from(*a) - v.point).amax())
        .fold(0.0, f64::max);
    Ok(NumpyRun {
        seconds,
        script_seconds,
        largest_mm: largest,
    })
}

/// The rows of an N × 3 little-endian float64 `.npy` file (numpy's format 1.0).
fn npy_points(path: &Path) -> Result<Vec<[f64; 3]>> {
    let bytes = std::fs::read(path).with_context(|| format!("{}", path.display()))?;
    let bad = || anyhow::anyhow!("{}: not an N × 3 float64 .npy file", path.display());
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(bad());
    }
    let header_len = usize::from(u16::from_le_bytes([bytes[8], bytes[9]]));
    let header = std::str::from_utf8(bytes.get(10..10 + header_len).ok_or_else(bad)?)?;
    if !header.contains("'<f8'") || !header.contains("'fortran_order': False") {
        return Err(bad());
    }
    let data = &bytes[10 + header_len..];
    if data.len() % 24 != 0 {
        return Err(bad());
    }
    Ok(data
        .chunks_exact(24)
        .map(|row| {
            let value = |k: usize| {
                let mut b = [0u8; 8];
                b.copy_from_slice(&row[8 * k..8 * k + 8]);
                f64::from_le_bytes(b)
            };
            [value(0), value(1), value(2)]
        })
        .collect())
}
