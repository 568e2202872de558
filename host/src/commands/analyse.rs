//! `deltaz analyse back|compare`.

use super::args::OutputArgs;
use crate::io::analysis_file::read_report;
use crate::io::atomic::write_all_atomic;
use crate::report::back_report::{
    analysis_note, comparison_notes, indices, plus_minus, points_text, posture_text, report_html,
};
use crate::report::console::Output;
use crate::workflows::back::analyse_clouds;
use anyhow::{bail, Result};
use deltaz_surface::{compare, Options};
use nalgebra::Vector3;
use std::path::PathBuf;

/// What to analyse.
#[derive(clap::Subcommand)]
pub enum What {
    /// A back from its scans: the clouds of one subject (several frames are registered and
    /// combined, their sway reported) into analysis.json and a self-contained report.html in
    /// OUT: the symmetry line, surface rotation along it, lateral deviation, trunk imbalance and
    /// inclination, skin angles, the sagittal profile, the asymmetry map, and bent forward the
    /// virtual scoliometer; every measure with its σ. Surface measurements, not a diagnosis.
    Back {
        /// A point cloud (PLY of `scan`, `reconstruct` or `device stream`, in the camera
        /// system; or a cloud from elsewhere, x y z in mm in the camera system, its points then
        /// meshed over what the camera sees); repeat for several frames (a cloud with a `frame`
        /// property holds several).
        #[arg(long = "cloud", required = true)]
        clouds: Vec<PathBuf>,
        /// The system the clouds were measured with (system.json of `calibrate system`): each
        /// point's covariance, the calibration's common share included. Without it the clouds'
        /// own σ (`sigma_*` properties) or --sigma is used.
        #[arg(long, conflicts_with = "sigma")]
        system: Option<PathBuf>,
        /// For clouds that carry no σ (from elsewhere): each point's σ on each axis, mm.
        #[arg(long, value_name = "MM")]
        sigma: Option<f64>,
        /// Thin each cloud to what a dot pattern MM apart would give (of each MM square of the
        /// camera's x-y plane, the point nearest its centre). A cloud whose points lie under 8 mm
        /// apart (another scanner's) is thinned without it, to 10 mm or three times its spacing.
        #[arg(long, value_name = "MM")]
        thin: Option<f64>,
        /// Output folder: analysis.json and report.html.
        #[arg(long)]
        out: PathBuf,
        /// Standing (`standing`) or bent forward (`forward-bent`: the scoliometer reading).
        #[arg(long, default_value = "standing")]
        posture: PostureArg,
        /// Standing: the vertical in the camera system (default 0,1,0).
        #[arg(long, value_parser = direction, allow_hyphen_values = true)]
        vertical: Option<[f64; 3]>,
        /// Bent forward: the trunk's axis toward the head in the camera system (default the
        /// back's longest direction, toward the image's left: the head to the left). A head
        /// taken the wrong way turns the scoliometer's and the rotation's signs.
        #[arg(long, value_parser = direction, allow_hyphen_values = true)]
        head: Option<[f64; 3]>,
        #[command(flatten)]
        output: OutputArgs,
    },
    /// The follow-up of two analyses of one subject (analysis.json, before then after): the
    /// change of each measure and profile with its σ, and which changes exceed the noise.
    Compare {
        /// The earlier analysis.json.
        before: PathBuf,
        /// The later analysis.json.
        after: PathBuf,
        #[command(flatten)]
        output: OutputArgs,
    },
}

/// `--posture` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PostureArg {
    /// Upright, back to the camera.
    Standing,
    /// Bent forward (Adams).
    ForwardBent,
}

/// A `--vertical` or `--head` value: a direction X,Y,Z in the camera system with a part across
/// the line of sight (z, toward the camera, is the analysis' depth).
fn direction(text: &str) -> Result<[f64; 3], String> {
    let parts: Result<Vec<f64>, _> = text.split(',').map(|s| s.trim().parse::<f64>()).collect();
    match parts.as_deref() {
        Ok(&[x, y, z]) if [x, y, z].iter().all(|v| v.is_finite()) => {
            // Zero, or without a part across z (the hypot of nought is nought).
            let across = x.hypot(y);
            if across <= 1e-9 * across.hypot(z) {
                Err(format!(
                    "{text:?} lies along the line of sight (z) or is no direction: it must lie \
                     across the image"
                ))
            } else {
                Ok([x, y, z])
            }
        }
        _ => Err(format!(
            "{text:?} is not three comma-separated numbers X,Y,Z"
        )),
    }
}

/// Runs `deltaz analyse`.
pub fn exec(what: What) -> Result<()> {
    match what {
        What::Back {
            clouds,
            system,
            sigma,
            thin,
            out,
            posture,
            vertical,
            head,
            output,
        } => {
            let output = Output::from(output);
            let options = match (posture, vertical, head) {
                (PostureArg::Standing, _, Some(_)) => bail!(
                    "--head is for a back bent forward (--posture forward-bent); standing, give \
                     --vertical"
                ),
                (PostureArg::ForwardBent, Some(_), _) => {
                    bail!("--vertical is for a back standing; bent forward, give --head")
                }
                (PostureArg::Standing, vertical, None) => Options {
                    vertical: vertical.map(Vector3::from),
                    ..Options::standing()
                },
                (PostureArg::ForwardBent, None, head) => Options {
                    axis: head.map(Vector3::from),
                    ..Options::forward_bent()
                },
            };
            let progress = output.progress(format!("analysing {} clouds", clouds.len()));
            let report = analyse_clouds(&clouds, system.as_deref(), sigma, thin, &options)?;
            progress.finish_and_clear();
            let json = serde_json::to_string_pretty(&report)? + "\n";
            let html = report_html(&report)?;
            std::fs::create_dir_all(&out)
                .map_err(|e| anyhow::anyhow!("{}: cannot create: {e}", out.display()))?;
            let (json_path, html_path) = (out.join("analysis.json"), out.join("report.html"));
            write_all_atomic(&[
                (json_path.as_path(), json.as_bytes()),
                (html_path.as_path(), html.as_bytes()),
            ])?;
            let a = &report.analysis;
            let mut text = format!(
                "{}; {} frames, {}, {} levels (surface measurements, not a diagnosis):\n",
                posture_text(a),
                a.frames,
                points_text(a),
                a.levels.len()
            );
            for (name, value, sigma, unit) in indices(a) {
                text += &format!("  {name}: {} {unit}\n", plus_minus(value, sigma));
            }
            for note in &report.notes {
                output.status(format!("note: {note}"));
            }
            if let Some(note) = analysis_note(a) {
                output.status(format!("note: {note}"));
            }
            text += &format!("-> {}, {}\n", json_path.display(), html_path.display());
            output.result(&text, &serde_json::to_value(&report)?)
        }
        What::Compare {
            before,
            after,
            output,
        } => {
            let output = Output::from(output);
            let (a, b) = (read_report(&before)?, read_report(&after)?);
            let c = compare(&a.analysis, &b.analysis);
            let names = [before.display().to_string(), after.display().to_string()];
            for note in comparison_notes(&c, [(&names[0], &a), (&names[1], &b)]) {
                output.status(format!("note: {note}"));
            }
            let mut text = format!(
                "changes from {} to {} (beyond {:.2} σ: exceeds the measurement noise):\n",
                before.display(),
                after.display(),
                c.threshold
            );
            for d in &c.indices {
                text += &format!(
                    "  {}: {:.2} → {:.2}, change {:+.2} ± {:.2}{}\n",
                    d.name,
                    d.before,
                    d.after,
                    d.change,
                    d.sigma,
                    if d.exceeds_noise {
                        "  exceeds the noise"
                    } else {
                        ""
                    }
                );
            }
            let beyond = c
                .levels
                .iter()
                .filter(|l| l.rotation_deg.exceeds_noise)
                .count();
            text += &format!(
                "  surface rotation: {beyond} of {} levels changed beyond the noise\n",
                c.levels.len()
            );
            output.result(&text, &serde_json::to_value(&c)?)
        }
    }
}
