//! The bodies of the `compare`, `reconstruct`, `calibrate projector`, `calibrate system` and `demo`
//! subcommands
//! (argument parsing stays in `main.rs`).

use crate::bundle::{calibrate, CalibrationOptions};
use crate::camera_calibration::{build_problem, camera_prior};
use crate::compare::{assess, match_points};
use crate::io::atomic::write_atomic;
use crate::io::camera_file::read_camera;
use crate::io::control::read_control;
use crate::io::observations::{read_observations, Observation, PointKind};
use crate::plates::{plate_images, plate_observations, resect_all};
use crate::ply::{write_ply, Encoding};
use crate::projector_calibration::{
    calibrate_projector as calibrate_projector_images, check_raised_control, DotObservation, Model,
};
use crate::reconstruct::reconstruct as reconstruct_points;
use crate::system::SystemContent;
use crate::system::{SystemFile, Warnings};
use anyhow::{bail, Result};
use deltaz_calib::system_adjustment::{adjust_system, Frame, SystemInput};
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

/// `--frame` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum FrameArg {
    /// The camera system (the instrument's own frame).
    Camera,
    /// The plate (control) frame of the datum image.
    Plate,
}

impl From<FrameArg> for Frame {
    fn from(f: FrameArg) -> Self {
        match f {
            FrameArg::Camera => Frame::Camera,
            FrameArg::Plate => Frame::Plate,
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
    /// The points' frame.
    pub frame: FrameArg,
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

/// `deltaz reconstruct`: everything is computed before anything is written.
pub fn reconstruct(args: &ReconstructArgs) -> Result<()> {
    let (system, rig) = SystemFile::load(&args.system)?;
    let calibration = system.line_covariances();
    let obs = read_observations(&args.obs)?;
    let dots = dot_observations(&args.obs, &obs)?;
    let plain: Vec<DotObservation> = dots.iter().map(|(_, d)| *d).collect();
    let model = system
        .content
        .model()
        .map_err(|e| anyhow::anyhow!("{}: {e:#}", args.system.display()))?;
    let mut points = reconstruct_points(
        &rig,
        &plain,
        args.method.into(),
        args.sigma_px.filter(|_| model.is_none()),
        Some(&calibration),
    )
    .map_err(|e| anyhow::anyhow!("{}: {e:#}", args.obs.display()))?;
    if args.frame == FrameArg::Plate && model.is_none() {
        bail!(
            "{}: --frame plate needs the covariance of `calibrate system`",
            args.system.display()
        );
    }
    // With the whole-system adjustment's covariance every point gets its σ (camera, projector
    // and the dots' estimated image noise, or --sigma-px); in the plate frame with the
    // transform's share.
    if let Some(mut model) = model {
        if let Some(s) = args.sigma_px {
            model.sigma_dots_px = s;
        }
        for (p, dot) in points.iter_mut().zip(&plain) {
            let q = model
                .reconstruct(rig.grid(), dot, args.method.into(), args.frame.into())
                .map_err(|e| anyhow::anyhow!("{}: {e}", args.obs.display()))?;
            if args.frame == FrameArg::Plate {
                p.point = q.point;
            }
            p.sigma = Some((q.image + q.calibration).diagonal().map(f64::sqrt));
        }
    }
    let csv = args.csv.as_ref().map(|_| {
        let mut text = String::from("image,point,X,Y,Z,miss");
        if points.iter().any(|p| p.sigma.is_some()) {
            text += ",sigma_X,sigma_Y,sigma_Z";
        }
        text.push('\n');
        for ((image, _), p) in dots.iter().zip(&points) {
            text += &format!(
                "{image},{},{},{},{},{}",
                p.id, p.point.x, p.point.y, p.point.z, p.miss
            );
            if let Some(s) = p.sigma {
                text += &format!(",{},{},{}", s.x, s.y, s.z);
            }
            text.push('\n');
        }
        text
    });
    let encoding = if args.ascii {
        Encoding::Ascii
    } else {
        Encoding::BinaryLittleEndian
    };
    write_ply(&args.out, &points, encoding)?;
    if let (Some(path), Some(text)) = (&args.csv, csv) {
        write_atomic(path, text.as_bytes())?;
    }
    println!("{} points -> {}", points.len(), args.out.display());
    Ok(())
}

/// `deltaz calibrate projector`: resection per image (step 4), steps 5-7 (or the models beyond),
/// system.json written atomically only when everything succeeded. Images too poorly controlled
/// to resect and rays seen on one plate are left out (or, central models, determined through the
/// centre) and listed on stderr and in the file; `strict` makes them errors.
pub fn calibrate_projector(
    camera: &Path,
    control: &Path,
    obs: &Path,
    out: &Path,
    model: Model,
    image_sigma_px: f64,
    strict: bool,
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
    let resected = resect_all(obs, &grid, &inner, &observations, &control_points)?;
    let poses: Vec<_> = resected
        .results
        .iter()
        .map(|(image, r)| (image.clone(), r.exterior))
        .collect();
    let in_file = |e: &dyn std::fmt::Display| anyhow::anyhow!("{}: {e:#}", obs.display());
    let images = plate_images(&observations, &poses).map_err(|e| in_file(&e))?;
    let projector = calibrate_projector_images(&grid, &inner, &images, model, image_sigma_px)
        .map_err(|e| in_file(&e))?;
    let warnings = Warnings {
        left_out_images: resected.left_out,
        single_plane_rays: projector.single_plane.clone(),
        left_out_rays: projector.left_out.clone(),
    };
    report_warnings(obs, &warnings, strict)?;
    let mut content = SystemContent::new(grid, inner, images[0].exterior, &projector);
    content.warnings = warnings;
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

/// Left-out images and rays: an error naming them with `strict`, else one warning line each on
/// stderr.
fn report_warnings(obs: &Path, warnings: &Warnings, strict: bool) -> Result<()> {
    if strict && !warnings.is_empty() {
        bail!(
            "{}: --strict: {}",
            obs.display(),
            warnings.lines().join("; ")
        );
    }
    for line in warnings.lines() {
        eprintln!("warning: {line}");
    }
    Ok(())
}

/// Arguments of `deltaz calibrate system`.
#[derive(Debug, Clone)]
pub struct SystemArgs {
    /// camera_init.json.
    pub init: PathBuf,
    /// Field target observations.
    pub camera_obs: PathBuf,
    /// Field control (None: free network).
    pub camera_control: Option<PathBuf>,
    /// Plate control.
    pub control: PathBuf,
    /// Plate observations (targets and dots).
    pub obs: PathBuf,
    /// Output system.json.
    pub out: PathBuf,
    /// Every ray a free line.
    pub noncentral: bool,
    /// Left-out images and rays are errors.
    pub strict: bool,
}

/// `deltaz calibrate system`: the camera by bundle adjustment, then the plate images, the
/// control, the projector and the camera (its calibration as a prior with its covariance) in
/// one whole-system adjustment; system.json in the camera system with the covariance a point's
/// σ needs. Images that cannot be resected and rays seen on one plate are listed (in the file
/// too); `--strict` makes them errors. Nothing is written if anything fails.
pub fn calibrate_system(args: &SystemArgs) -> Result<()> {
    let start = read_camera(&args.init)?;
    let grid = start.grid();
    let field = read_observations(&args.camera_obs)?;
    let field_control = match &args.camera_control {
        Some(path) => read_control(path)?,
        None => Vec::new(),
    };
    let options = CalibrationOptions::default();
    let problem = build_problem(
        &args.camera_obs,
        &grid,
        &start.inner(),
        &field,
        &field_control,
        &options,
    )?;
    let camera = calibrate(problem, &options)
        .map_err(|e| anyhow::anyhow!("{}: bundle adjustment: {e}", args.camera_obs.display()))?;
    let inner = camera.problem.inner;
    let control = read_control(&args.control)?;
    let observations = read_observations(&args.obs)?;
    let resected = resect_all(&args.obs, &grid, &inner, &observations, &control)?;
    let in_file = |e: &dyn std::fmt::Display| anyhow::anyhow!("{}: {e:#}", args.obs.display());
    let plates =
        plate_observations(&observations, &control, &resected.results).map_err(|e| in_file(&e))?;
    let adjustment = adjust_system(&SystemInput {
        grid,
        inner,
        camera: Some(camera_prior(&camera)),
        control: &control,
        plates,
        noncentral: args.noncentral,
        image_sigma_px: 0.5,
    })
    .map_err(|e| in_file(&e))?;
    let warnings = Warnings {
        left_out_images: resected.left_out,
        single_plane_rays: if args.noncentral {
            Vec::new()
        } else {
            adjustment.single_plane.clone()
        },
        left_out_rays: adjustment.left_out.clone(),
    };
    report_warnings(&args.obs, &warnings, args.strict)?;
    let content = SystemContent::from_adjustment(grid, &adjustment, args.noncentral, warnings);
    content.rig()?;
    let file = SystemFile::new(content)?;
    write_atomic(&args.out, file.to_json()?.as_bytes())?;
    let m = &adjustment.model;
    println!(
        "system: centre {:.3?} mm (σ {:.3?}) in the camera system, {} rays; σ0 targets {:.3} px, \
         dots {:.3} px; fingerprint {} -> {}",
        m.centre.as_slice(),
        m.centre_sigma().as_slice(),
        m.rays.len(),
        adjustment.sigma_targets_px,
        m.sigma_dots_px,
        file.fingerprint,
        args.out.display()
    );
    Ok(())
}
