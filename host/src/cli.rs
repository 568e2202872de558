//! The bodies of the `compare`, `reconstruct`, `calibrate-projector` and `demo` subcommands
//! (argument parsing stays in `main.rs`).

use crate::compare::{assess, match_points};
use crate::io::atomic::write_atomic;
use crate::io::camera_file::read_camera;
use crate::io::control::read_control;
use crate::io::observations::{read_observations, Observation, PointKind};
use crate::projector_calibration::{
    calibrate_projector as calibrate_projector_images, check_raised_control, plate_images,
    DotObservation, Model,
};
use crate::resection::resect_images;
use crate::system::SystemContent;
use crate::system::SystemFile;
use anyhow::{bail, Result};
use deltaz_shared::rig::Method;
use std::path::{Path, PathBuf};

/// `--method` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum MethodArg {
    /// Eqs (8)-(9), X and Z only (the paper).
    Paper,
    /// Least-squares closest approach of the two rays.
    Closest,
}

impl From<MethodArg> for Method {
    fn from(m: MethodArg) -> Self {
        match m {
            MethodArg::Paper => Method::Paper,
            MethodArg::Closest => Method::ClosestApproach,
        }
    }
}

/// `deltaz compare`.
pub fn compare(reconstructed: &Path, reference: &Path, json: bool) -> Result<()> {
    let read = |p: &Path| -> Result<Vec<(String, nalgebra::Vector3<f64>)>> {
        Ok(read_control(p)?
            .into_iter()
            .map(|c| (c.point, c.xyz))
            .collect())
    };
    let matched = match_points(&read(reconstructed)?, &read(reference)?)?;
    let a = assess(&matched.reconstructed, &matched.reference)?;
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&a.to_json(&matched.labels))?
        );
    } else {
        print!("{}", a.to_text(&matched.labels));
    }
    Ok(())
}

/// Arguments of `deltaz reconstruct`.
#[derive(Debug, Clone)]
pub struct ReconstructArgs {
    /// system.json.
    pub system: PathBuf,
    /// Dot observations CSV.
    pub obs: PathBuf,
    /// PLY output.
    pub out: PathBuf,
    /// Optional CSV output.
    pub csv: Option<PathBuf>,
    /// ASCII PLY.
    pub ascii: bool,
    /// Image noise for σ.
    pub sigma_px: Option<f64>,
    /// Intersection method.
    pub method: MethodArg,
}

/// The dot rows of an observations file (all rows when none is marked `dot`), each label a ray
/// id; a label that is not one names its line.
pub fn dot_observations(path: &Path, obs: &[Observation]) -> Result<Vec<(String, DotObservation)>> {
    let any_dot = obs.iter().any(|o| o.kind == PointKind::Dot);
    obs.iter()
        .filter(|o| !any_dot || o.kind == PointKind::Dot)
        .map(|o| {
            let Ok(id) = o.point.parse::<u16>() else {
                bail!(
                    "{}:{}: point {:?} is not a ray id",
                    path.display(),
                    o.line,
                    o.point
                );
            };
            Ok((
                o.image.clone(),
                DotObservation {
                    id,
                    col: o.col,
                    row: o.row,
                },
            ))
        })
        .collect()
}

/// `deltaz reconstruct`: streamed ([`crate::reconstruct_stream`]), nothing written on failure.
pub fn reconstruct(args: &ReconstructArgs) -> Result<()> {
    let count = crate::reconstruct_stream::reconstruct_stream(args)?;
    println!("{count} points -> {}", args.out.display());
    Ok(())
}

/// `deltaz calibrate projector`: resection per image (step 4), steps 5-7 (or the models beyond),
/// system.json written atomically only when everything succeeded.
pub fn calibrate_projector(
    camera: &Path,
    control: &Path,
    obs: &Path,
    out: &Path,
    model: Model,
    image_sigma_px: f64,
) -> Result<()> {
    let camera = read_camera(camera)?;
    let (grid, inner) = (camera.grid(), camera.inner());
    let control_points = read_control(control)?;
    let labelled: Vec<_> = control_points
        .iter()
        .map(|c| (c.point.clone(), c.xyz))
        .collect();
    check_raised_control(&labelled).map_err(|e| anyhow::anyhow!("{}: {e}", control.display()))?;
    let observations = read_observations(obs)?;
    let poses: Vec<_> = resect_images(obs, &grid, &inner, &observations, &control_points)?
        .into_iter()
        .map(|(image, r)| (image, r.exterior))
        .collect();
    let images = plate_images(&observations, &poses)
        .map_err(|e| anyhow::anyhow!("{}: {e:#}", obs.display()))?;
    let projector = calibrate_projector_images(&grid, &inner, &images, model, image_sigma_px)
        .map_err(|e| anyhow::anyhow!("{}: {e:#}", obs.display()))?;
    let content = SystemContent::new(grid, inner, images[0].exterior, &projector);
    content.rig()?;
    let file = SystemFile::new(content)?;
    write_atomic(out, file.to_json()?.as_bytes())?;
    let worst = projector
        .rays
        .iter()
        .max_by(|a, b| a.miss_rms.total_cmp(&b.miss_rms));
    println!(
        "{:?} model: centre {:.3?} mm (σ {:.3?}), {} rays{}; fingerprint {} -> {}",
        model,
        projector.centre.as_slice(),
        projector.centre_sigma.as_slice(),
        projector.rays.len(),
        worst.map_or(String::new(), |w| format!(
            ", worst ray {} misses its plane points by {:.3} mm RMS",
            w.id, w.miss_rms
        )),
        file.fingerprint,
        out.display()
    );
    Ok(())
}
