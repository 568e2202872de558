//! The bodies of the `compare`, `reconstruct`, `calibrate projector`, `calibrate system` and `demo`
//! subcommands
//! (argument parsing stays in `main.rs`).

use crate::bundle::{calibrate, CalibrationOptions};
use crate::camera_calibration::build_problem;
use crate::compare::{assess, match_points};
use crate::io::atomic::write_atomic;
use crate::io::camera_file::read_camera;
use crate::io::control::read_control;
use crate::io::observations::{read_observations, Observation, PointKind};
use crate::plates::{plate_images, plate_observations, resect_all};
use crate::projector_calibration::{
    calibrate_projector as calibrate_projector_images, check_raised_control, DotObservation, Model,
};
use crate::system::SystemContent;
use crate::system::{SystemFile, Warnings};
use anyhow::{bail, Result};
use deltaz_calib::system_adjustment::{adjust_system, CameraSource, Frame, SystemInput};
use deltaz_shared::rig::Method;
use std::path::{Path, PathBuf};

/// How a command reports: text for people or one JSON object on stdout; status and progress on
/// stderr unless `--quiet`.
#[derive(Debug, Clone, Copy, Default, clap::Args)]
pub struct Output {
    /// Print the result as one JSON object on stdout (status and progress stay on stderr).
    #[arg(long)]
    pub json: bool,
    /// No status lines or progress on stderr (errors are still printed).
    #[arg(long)]
    pub quiet: bool,
}

impl Output {
    /// A status line on stderr.
    pub fn status(&self, line: impl std::fmt::Display) {
        if !self.quiet {
            eprintln!("{line}");
        }
    }

    /// The result on stdout: `text` for people, or `json`.
    pub fn result(&self, text: &str, json: &serde_json::Value) -> Result<()> {
        if self.json {
            println!("{}", serde_json::to_string_pretty(json)?);
        } else {
            print!("{text}");
        }
        Ok(())
    }

    /// Progress of a step that may take more than a second: a spinner on a terminal, a plain
    /// line when stderr is not one, nothing with `--quiet`. Finish it with
    /// `finish_and_clear`.
    pub fn progress(&self, message: String) -> indicatif::ProgressBar {
        use std::io::IsTerminal;
        if self.quiet {
            return indicatif::ProgressBar::hidden();
        }
        if !std::io::stderr().is_terminal() {
            eprintln!("{message} ...");
            return indicatif::ProgressBar::hidden();
        }
        let bar = indicatif::ProgressBar::new_spinner().with_message(message);
        bar.enable_steady_tick(std::time::Duration::from_millis(120));
        bar
    }
}

/// The calibrated camera for people: the estimated parameters with σ and units, then σ0, RMS
/// (per coordinate) and the rejected observations.
pub fn camera_summary(file: &crate::io::camera_file::CameraFile, free: &[bool; 8]) -> String {
    use crate::io::camera_file::INNER_NAMES;
    const UNITS: [&str; 8] = ["mm", "mm", "mm", "mm⁻²", "mm⁻⁴", "mm⁻⁶", "mm⁻¹", "mm⁻¹"];
    let (values, sigma) = (file.inner.to_array(), file.sigma.to_array());
    let mut text = String::new();
    for k in (0..8).filter(|k| free[*k]) {
        let (name, unit) = (INNER_NAMES[k], UNITS[k]);
        text += &if k < 3 {
            format!("{name:>3} = {:9.4} ± {:.4} {unit}\n", values[k], sigma[k])
        } else {
            format!(
                "{name:>3} = {:10.3e} ± {:.2e} {unit}\n",
                values[k], sigma[k]
            )
        };
    }
    text += &format!(
        "σ0 = {:.4} mm in the image, RMS {:.3} px per coordinate ({:.3} px per point), \
         {} iterations, {} rejected, {} correlations > 0.9\n",
        file.sigma0.unwrap_or(f64::NAN),
        file.rms_px.unwrap_or(f64::NAN),
        file.rms_px.unwrap_or(f64::NAN) * 2f64.sqrt(),
        file.iterations.unwrap_or(0),
        file.rejected.len(),
        file.correlations.len()
    );
    for r in &file.rejected {
        text += &format!(
            "rejected: image {} point {} ({:.1} px)\n",
            r.image, r.point, r.residual_px
        );
    }
    text
}

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

/// Labelled points of a CSV `point,X,Y,Z` or a PLY cloud (by its extension).
pub fn read_points(path: &Path) -> Result<Vec<(String, nalgebra::Vector3<f64>)>> {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("ply"))
    {
        return Ok(crate::ply::read_points(path)?);
    }
    Ok(read_control(path)?
        .into_iter()
        .map(|c| (c.point, c.xyz))
        .collect())
}

/// Refuses points that (nearly) lie on one line: the similarity's rotation about that line
/// would be arbitrary. The spread across the line must be at least 1e-3 of the spread along it.
fn check_not_collinear(path: &Path, points: &[nalgebra::Vector3<f64>]) -> Result<()> {
    let n = points.len().max(1) as f64;
    let mean = points.iter().sum::<nalgebra::Vector3<f64>>() / n;
    let scatter = points
        .iter()
        .map(|p| (p - mean) * (p - mean).transpose())
        .sum::<nalgebra::Matrix3<f64>>();
    let mut spread = scatter.symmetric_eigenvalues().map(|v| v.max(0.0).sqrt());
    spread.as_mut_slice().sort_by(|a, b| b.total_cmp(a));
    if spread[1] < 1e-3 * spread[0] {
        bail!(
            "{}: the matched points are (nearly) collinear (spread {:.3e} mm across their line, \
             {:.3e} mm along it): the rotation about that line is undetermined",
            path.display(),
            spread[1],
            spread[0]
        );
    }
    Ok(())
}

/// `deltaz compare`.
pub fn compare(reconstructed: &Path, reference: &Path, output: Output) -> Result<()> {
    let matched =
        match_points(&read_points(reconstructed)?, &read_points(reference)?).map_err(|e| {
            anyhow::anyhow!(
                "{} against {}: {e:#}",
                reconstructed.display(),
                reference.display()
            )
        })?;
    check_not_collinear(reconstructed, &matched.reconstructed)?;
    check_not_collinear(reference, &matched.reference)?;
    let a = assess(&matched.reconstructed, &matched.reference)?;
    output.result(&a.to_text(&matched.labels), &a.to_json(&matched.labels))
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

/// `deltaz reconstruct`: streamed ([`crate::reconstruct_stream`]), nothing written on failure.
pub fn reconstruct(args: &ReconstructArgs, output: Output) -> Result<()> {
    let progress = output.progress(format!("reconstructing {}", args.obs.display()));
    let s = crate::reconstruct_stream::reconstruct_stream(args)?;
    progress.finish_and_clear();
    output.result(
        &format!(
            "{} points from {} images, miss distance RMS {:.3} mm, in the {} (mm) -> {}\n",
            s.points,
            s.images,
            s.miss_rms,
            s.frame,
            args.out.display()
        ),
        &serde_json::json!({
            "points": s.points,
            "images": s.images,
            "miss_rms_mm": s.miss_rms,
            "frame": s.frame,
            "fingerprint": s.fingerprint,
            "out": args.out,
            "csv": args.csv,
        }),
    )
}

/// Arguments of `deltaz calibrate projector`.
#[derive(Debug, Clone)]
pub struct ProjectorArgs {
    /// camera.json.
    pub camera: PathBuf,
    /// The plate's control CSV.
    pub control: PathBuf,
    /// Plate observations CSV.
    pub obs: PathBuf,
    /// system.json to write.
    pub out: PathBuf,
    /// The projector model.
    pub model: Model,
    /// Image noise (px).
    pub image_sigma_px: f64,
    /// Directory of SVG plots, if any.
    pub plots: Option<PathBuf>,
    /// Left-out images and rays are errors.
    pub strict: bool,
}

/// `deltaz calibrate projector`: resection per image (step 4), steps 5-7 (or the models beyond),
/// system.json written atomically only when everything succeeded. Images too poorly controlled
/// to resect and rays seen on one plate are left out (or, central models, determined through the
/// centre) and listed on stderr and in the file; `strict` makes them errors.
pub fn calibrate_projector(args: &ProjectorArgs, output: Output) -> Result<()> {
    let ProjectorArgs {
        camera,
        control,
        obs,
        out,
        model,
        image_sigma_px,
        plots,
        strict,
    } = args;
    let (model, image_sigma_px, strict) = (*model, *image_sigma_px, *strict);
    let camera = read_camera(camera)?;
    let (grid, inner) = (camera.grid(), camera.inner());
    let control_points = read_control(control)?;
    let labelled: Vec<_> = control_points
        .iter()
        .map(|c| (c.point.clone(), c.xyz))
        .collect();
    check_raised_control(&labelled).map_err(|e| anyhow::anyhow!("{}: {e}", control.display()))?;
    let observations = read_observations(obs)?;
    let progress = output.progress(format!("calibrating the projector from {}", obs.display()));
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
    progress.finish_and_clear();
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
    if let Some(dir) = plots {
        let rays: Vec<_> = projector
            .rays
            .iter()
            .map(|r| (r.id, r.miss_rms, r.miss_max))
            .collect();
        let svg = crate::plots::ray_misses(&rays)?;
        crate::plots::write_plots(dir, &[("ray_misses.svg", svg)])?;
        output.status(format!("plot -> {}", dir.join("ray_misses.svg").display()));
    }
    let worst = projector
        .rays
        .iter()
        .max_by(|a, b| a.miss_rms.total_cmp(&b.miss_rms));
    let c = &projector.centre;
    let cs = &projector.centre_sigma;
    output.result(
        &format!(
            "{model:?} model: projector centre ({:.2}, {:.2}, {:.2}) ± ({:.2}, {:.2}, {:.2}) mm \
             in the rig frame, {} rays{}; fingerprint {} -> {}\n",
            c[0],
            c[1],
            c[2],
            cs[0],
            cs[1],
            cs[2],
            projector.rays.len(),
            worst.map_or(String::new(), |w| format!(
                ", worst ray {} misses its plane points by {:.3} mm RMS",
                w.id, w.miss_rms
            )),
            file.fingerprint,
            out.display()
        ),
        &serde_json::json!({
            "model": format!("{model:?}").to_lowercase(),
            "centre_mm": c.as_slice(),
            "centre_sigma_mm": cs.as_slice(),
            "rays": projector.rays.len(),
            "worst_ray": worst.map(|w| serde_json::json!({"id": w.id, "miss_rms_mm": w.miss_rms})),
            "fingerprint": file.fingerprint,
            "out": out,
        }),
    )
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

/// `deltaz calibrate system`: the camera by bundle adjustment and the plate images by resection
/// (the starts), then the camera's inner orientation, the field and plate images, both controls
/// and the projector in one whole-system adjustment with a variance component per group (field
/// targets, plate targets, dots); system.json in the camera system with the covariance a
/// point's σ needs. Images that cannot be resected and rays seen on one plate are listed (in the file
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
    let progress = Output::default().progress(format!(
        "calibrating the system from {} and {}",
        args.camera_obs.display(),
        args.obs.display()
    ));
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
        camera: CameraSource::Field(&camera.problem),
        control: &control,
        plates,
        noncentral: args.noncentral,
        image_sigma_px: 0.5,
    })
    .map_err(|e| in_file(&e))?;
    progress.finish_and_clear();
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
        "system: centre {:.3?} mm (σ {:.3?}) in the camera system, {} rays; σ0 field targets \
         {:.3} px, plate targets {:.3} px, dots {:.3} px; fingerprint {} -> {}",
        m.centre.as_slice(),
        m.centre_sigma().as_slice(),
        m.rays.len(),
        adjustment.sigma_field_px.unwrap_or(f64::NAN),
        adjustment.sigma_targets_px,
        m.sigma_dots_px,
        file.fingerprint,
        args.out.display()
    );
    Ok(())
}
