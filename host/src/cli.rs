//! The bodies of the `compare`, `reconstruct`, `calibrate projector` and `calibrate system`
//! subcommands, with their arguments (flattened into `main.rs`'s command line).

use crate::bundle::{calibrate, CalibrationOptions};
use crate::calibration_plots::{control_residuals, system_plots, PlateView, Plot};
use crate::camera_calibration::build_problem;
use crate::compare::{assess, match_points};
use crate::io::camera_file::read_camera;
use crate::io::control::read_control;
use crate::io::observations::{read_observations, Observation, PointKind};
use crate::plates::{plate_images, plate_observations, resect_all};
use crate::plots::write_with_plots;
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

    /// Progress of `len` items: a bar with the rate on a terminal, one plain line when stderr
    /// is not one, nothing with `--quiet`. Finish it with `finish_and_clear`.
    pub fn counter(&self, message: String, len: u64) -> indicatif::ProgressBar {
        use std::io::IsTerminal;
        if self.quiet || !std::io::stderr().is_terminal() {
            self.status(format!("{message} ..."));
            return indicatif::ProgressBar::hidden();
        }
        let bar = indicatif::ProgressBar::new(len).with_message(message);
        bar.set_style(
            indicatif::ProgressStyle::with_template("{msg}: {bar:40} {pos}/{len}, {per_sec}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar
    }
}

/// A `--flag` value that must be a positive finite number (σ, tolerances, distances).
pub fn positive(text: &str) -> std::result::Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        Ok(v) => Err(format!("{v} is not a positive finite number")),
        Err(_) => Err(format!("{text:?} is not a number")),
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
#[derive(Debug, Clone, clap::Args)]
pub struct ReconstructArgs {
    /// The calibrated system (system.json).
    #[arg(long)]
    pub system: PathBuf,
    /// Dot observations.
    #[arg(long)]
    pub obs: PathBuf,
    /// Output PLY file.
    #[arg(long)]
    pub out: PathBuf,
    /// Also write a CSV `image,point,X,Y,Z,miss[,sigma_X,sigma_Y,sigma_Z]` here (mm).
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// ASCII PLY instead of binary.
    #[arg(long)]
    pub ascii: bool,
    /// Image noise (px, > 0): adds the propagated σ of every point (mm).
    #[arg(long, value_parser = positive, allow_negative_numbers = true)]
    pub sigma_px: Option<f64>,
    /// Intersection: eqs (8)-(9) (`paper`) or the closest approach (`closest`).
    #[arg(long, default_value = "closest")]
    pub method: MethodArg,
    /// The points' frame: `camera` (the instrument's own) or `plate` (the control frame of
    /// the datum plate image of `calibrate system`, the transform's σ included).
    #[arg(long, default_value = "camera")]
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

/// Arguments of `deltaz calibrate projector` (but for where the observations come from).
#[derive(Debug, Clone, clap::Args)]
pub struct ProjectorArgs {
    /// camera.json (inner orientation and pixel mapping).
    #[arg(long)]
    pub camera: PathBuf,
    /// The plate's control CSV (point,X,Y,Z,sigma; plate surface at Z = 0).
    #[arg(long)]
    pub control: PathBuf,
    /// Output system.json.
    #[arg(long)]
    pub out: PathBuf,
    /// `joint` (the whole-system adjustment with the camera as a prior: the σ of camera,
    /// poses, projector and dots), `noncentral` (the same, every ray a free line) or `paper`
    /// (eqs 11-14; its σ from the dots alone, camera and poses taken as exact).
    #[arg(long, default_value = "joint")]
    pub model: Model,
    /// Image noise (px, > 0): `paper` weights the plane points and gives the rays' covariances
    /// with it; `joint` and `noncentral` start from it and estimate it.
    #[arg(long, default_value_t = 0.5, value_parser = positive, allow_negative_numbers = true)]
    pub image_sigma_px: f64,
    /// `--plots DIR`.
    #[command(flatten)]
    pub plots: PlotsArg,
    /// Images that cannot be resected and rays seen on one plate are errors.
    #[arg(long)]
    pub strict: bool,
}

impl PlotsArg {
    /// Says on stderr how many plots went where.
    pub fn report(&self, plots: &[Plot], output: Output) {
        if let Some(dir) = &self.plots {
            output.status(format!("{} plots -> {}", plots.len(), dir.display()));
        }
    }

    /// Writes `files` and, with `--plots`, the plots `make` draws, all or nothing, and says
    /// where the plots went.
    pub fn write_with(
        &self,
        files: &[(&Path, &[u8])],
        make: impl FnOnce() -> Result<Vec<Plot>>,
        output: Output,
    ) -> Result<()> {
        let made = match self.plots {
            Some(_) => make()?,
            None => Vec::new(),
        };
        write_with_plots(files, self.plots.as_deref(), &made)?;
        self.report(&made, output);
        Ok(())
    }
}

/// `--plots DIR` of the calibration commands.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct PlotsArg {
    /// Also write SVG plots into this directory: image residual vectors per image, their
    /// histogram against the normal distribution, and (projector, system) the rays' miss
    /// distances and an accuracy map of every plate image (its dots off the plate, mm).
    #[arg(long)]
    pub plots: Option<PathBuf>,
}

/// `deltaz calibrate projector`: resection per image (step 4), then the projector with the
/// camera of `--camera` taken as its prior (`joint`, `noncentral`: the whole-system adjustment
/// without the field images, so the camera's covariance and the plate poses' uncertainty reach
/// the projector and every point's σ, as in `calibrate system`; the system in the camera
/// system), or the paper's steps 5-7 (`paper`: camera and poses taken as exact, the 1st plate
/// image's frame). system.json is written atomically only when everything succeeded. Images
/// too poorly controlled to resect and rays seen on one plate are left out (or, central models,
/// determined through the centre) and listed on stderr and in the file; `strict` makes them
/// errors.
pub fn calibrate_projector(args: &ProjectorArgs, obs: &Path, output: Output) -> Result<()> {
    let ProjectorArgs {
        camera,
        control,
        out,
        model,
        image_sigma_px,
        plots,
        strict,
    } = args;
    let (model, image_sigma_px, strict) = (*model, *image_sigma_px, *strict);
    let camera_path = camera;
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
    let in_file = |e: &dyn std::fmt::Display| anyhow::anyhow!("{}: {e:#}", obs.display());
    let left_out_images = resected.left_out.clone();
    // The system, the camera it ends with, and each plate image's pose and dots.
    let (content, inner, views) = if model == Model::Paper {
        let poses: Vec<_> = resected
            .results
            .iter()
            .map(|(image, r)| (image.clone(), r.exterior))
            .collect();
        let images = plate_images(&observations, &poses).map_err(|e| in_file(&e))?;
        let projector = calibrate_projector_images(&grid, &inner, &images, model, image_sigma_px)
            .map_err(|e| in_file(&e))?;
        let mut content = SystemContent::new(grid, inner, images[0].exterior, &projector);
        content.warnings = Warnings {
            left_out_images,
            single_plane_rays: projector.single_plane.clone(),
            left_out_rays: projector.left_out.clone(),
        };
        let views = poses
            .into_iter()
            .zip(images)
            .map(|((image, exterior), i)| (image, exterior, i.dots));
        (content, inner, views.collect::<Vec<_>>())
    } else {
        let prior = camera.prior();
        if prior.is_some() && camera.covariance.is_none() {
            eprintln!(
                "warning: {}: no `covariance` (written by an older deltaz): the camera's prior \
                 takes its σ without their correlations; calibrate the camera again for the \
                 stated σ to hold",
                camera_path.display()
            );
        }
        let noncentral = model == Model::Noncentral;
        let plates = plate_observations(&observations, &control_points, &resected.results)
            .map_err(|e| in_file(&e))?;
        let adjustment = adjust_system(&SystemInput {
            grid,
            inner,
            camera: prior.map_or(CameraSource::Fixed, CameraSource::Prior),
            control: &control_points,
            plates: plates.clone(),
            noncentral,
            image_sigma_px,
        })
        .map_err(|e| in_file(&e))?;
        let warnings = Warnings {
            left_out_images,
            single_plane_rays: if noncentral {
                Vec::new()
            } else {
                adjustment.single_plane.clone()
            },
            left_out_rays: adjustment.left_out.clone(),
        };
        let content = SystemContent::from_adjustment(grid, &adjustment, noncentral, warnings);
        let views = plates
            .into_iter()
            .zip(&adjustment.poses)
            .map(|(p, exterior)| (p.image, *exterior, p.dots));
        (content, adjustment.model.inner, views.collect::<Vec<_>>())
    };
    progress.finish_and_clear();
    report_warnings(obs, &content.warnings, strict)?;
    let rig = content.rig()?;
    let file = SystemFile::new(content)?;
    let json = file.to_json()?;
    let projector = &file.content.projector;
    let make = || {
        let rays: Vec<_> = (projector.rays.iter())
            .map(|r| (r.id, r.miss_rms, r.miss_max))
            .collect();
        let poses: Vec<_> = (views.iter())
            .map(|(image, exterior, _)| (image.clone(), *exterior))
            .collect();
        let plates: Vec<_> = (views.iter())
            .map(|(image, exterior, dots)| PlateView {
                image,
                exterior: *exterior,
                dots,
            })
            .collect();
        let residuals = control_residuals(&grid, &inner, &poses, &observations, &control_points);
        system_plots(&residuals, &grid, &rays, &rig, &plates)
    };
    plots.write_with(&[(out, json.as_bytes())], make, output)?;
    let worst = (projector.rays.iter()).max_by(|a, b| a.miss_rms.total_cmp(&b.miss_rms));
    let (c, cs) = (&projector.centre, &projector.centre_sigma);
    let frame = match projector.covariance {
        Some(_) => "camera system",
        None => "rig frame",
    };
    output.result(
        &format!(
            "{model:?} model: projector centre ({:.2}, {:.2}, {:.2}) ± ({:.2}, {:.2}, {:.2}) mm \
             in the {frame}, {} rays{}; fingerprint {} -> {}\n",
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
            "centre_mm": c,
            "centre_sigma_mm": cs,
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
#[derive(Debug, Clone, clap::Args)]
pub struct SystemArgs {
    /// The starting sensor: camera_init.json (pixel mapping, approximate f).
    #[arg(long)]
    pub init: PathBuf,
    /// Target-field observations CSV.
    #[arg(long)]
    pub camera_obs: PathBuf,
    /// Target-field control CSV (without it the field network is free).
    #[arg(long)]
    pub camera_control: Option<PathBuf>,
    /// The plate's control CSV (point,X,Y,Z,sigma; plate surface at Z = 0).
    #[arg(long)]
    pub control: PathBuf,
    /// Plate observations CSV (`control` rows resect, `dot` rows calibrate the projector).
    #[arg(long)]
    pub obs: PathBuf,
    /// Output system.json.
    #[arg(long)]
    pub out: PathBuf,
    /// Every ray a free line (rays seen on one plate are then left out).
    #[arg(long)]
    pub noncentral: bool,
    /// Images that cannot be resected and rays seen on one plate are errors.
    #[arg(long)]
    pub strict: bool,
    /// `--plots DIR`.
    #[command(flatten)]
    pub plots: PlotsArg,
}

/// `deltaz calibrate system`: the camera by bundle adjustment and the plate images by resection
/// (the starts), then the camera's inner orientation, the field and plate images, both controls
/// and the projector in one whole-system adjustment with a variance component per group (field
/// targets, plate targets, dots); system.json in the camera system with the covariance a
/// point's σ needs. Images that cannot be resected and rays seen on one plate are listed (in the file
/// too); `--strict` makes them errors. Nothing is written if anything fails.
pub fn calibrate_system(args: &SystemArgs, output: Output) -> Result<()> {
    let start = read_camera(&args.init)?;
    let grid = start.grid();
    let field = read_observations(&args.camera_obs)?;
    let field_control = match &args.camera_control {
        Some(path) => read_control(path)?,
        None => Vec::new(),
    };
    let options = CalibrationOptions::default();
    let progress = output.progress(format!(
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
        plates: plates.clone(),
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
    let rig = content.rig()?;
    let file = SystemFile::new(content)?;
    let json = file.to_json()?;
    let make = || {
        let residuals = crate::residuals::residuals(&camera, &field);
        let rays: Vec<_> = adjustment
            .model
            .rays
            .iter()
            .map(|r| (r.id, r.miss_rms, r.miss_max))
            .collect();
        let views: Vec<_> = plates
            .iter()
            .zip(&adjustment.poses)
            .map(|(p, exterior)| PlateView {
                image: &p.image,
                exterior: *exterior,
                dots: &p.dots,
            })
            .collect();
        system_plots(&residuals, &grid, &rays, &rig, &views)
    };
    args.plots
        .write_with(&[(&args.out, json.as_bytes())], make, output)?;
    let m = &adjustment.model;
    let sigma = m.centre_sigma();
    output.result(
        &format!(
            "system: projector centre ({:.2}, {:.2}, {:.2}) ± ({:.2}, {:.2}, {:.2}) mm in the \
             camera system, {} rays; σ0 field targets {}, plate targets {:.3} px, dots {:.3} px; \
             fingerprint {} -> {}\n",
            m.centre.x,
            m.centre.y,
            m.centre.z,
            sigma.x,
            sigma.y,
            sigma.z,
            m.rays.len(),
            adjustment
                .sigma_field_px
                .map_or_else(|| "–".to_owned(), |s| format!("{s:.3} px")),
            adjustment.sigma_targets_px,
            m.sigma_dots_px,
            file.fingerprint,
            args.out.display()
        ),
        &serde_json::json!({
            "centre_mm": m.centre.as_slice(),
            "centre_sigma_mm": sigma.as_slice(),
            "rays": m.rays.len(),
            "sigma_field_px": adjustment.sigma_field_px,
            "sigma_targets_px": adjustment.sigma_targets_px,
            "sigma_dots_px": m.sigma_dots_px,
            "fingerprint": file.fingerprint,
            "out": args.out,
        }),
    )
}
