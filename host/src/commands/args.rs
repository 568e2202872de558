//! Argument groups several subcommands share, and the parsers of their values.

use crate::report::console::Output;
use crate::workflows::observations::FolderArgs;
use deltaz_calib::system_adjustment::Frame;
use deltaz_measure::detect::Polarity;
use deltaz_shared::rig::Method;
use std::path::{Path, PathBuf};

/// `--json` and `--quiet`.
#[derive(Debug, Clone, Copy, Default, clap::Args)]
pub struct OutputArgs {
    /// Print the result as one JSON object on stdout (status and progress stay on stderr).
    #[arg(long)]
    pub json: bool,
    /// No status lines or progress on stderr (errors are still printed).
    #[arg(long)]
    pub quiet: bool,
}

impl From<OutputArgs> for Output {
    fn from(a: OutputArgs) -> Self {
        Output {
            json: a.json,
            quiet: a.quiet,
        }
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

/// A `--flag` value that must be a positive finite number (σ, tolerances, distances).
pub fn positive(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        Ok(v) => Err(format!("{v} is not a positive finite number")),
        Err(_) => Err(format!("{text:?} is not a number")),
    }
}

/// A `--pixel-size` value (mm): positive, finite and at most [`MAX_PIXEL_SIZE_MM`] (a pixel
/// of 1 mm is already no camera's; 1 gives photo coordinates in pixels).
pub fn pixel_size(text: &str) -> Result<f64, String> {
    let v = positive(text)?;
    if v > MAX_PIXEL_SIZE_MM {
        return Err(format!(
            "{} mm is not a pixel size (at most {MAX_PIXEL_SIZE_MM} mm)",
            text.trim()
        ));
    }
    Ok(v)
}

/// The largest `--pixel-size` accepted (mm).
pub const MAX_PIXEL_SIZE_MM: f64 = 1.0;

/// `--dark` / `--bright`: the targets' polarity, the same in every command that measures
/// images. The default: dark with a circle-grid board (printed dark circles on white), bright
/// otherwise (projected dots, the simulated targets).
#[derive(Debug, Clone, Copy, Default, clap::Args)]
pub struct PolarityArgs {
    /// Targets are darker than the background (the default with --board).
    #[arg(long, conflicts_with = "bright")]
    pub dark: bool,
    /// Targets are brighter than the background (the default without --board).
    #[arg(long)]
    pub bright: bool,
}

impl PolarityArgs {
    /// The polarity asked for, or the default for a board (`board`) or other targets.
    pub fn polarity(self, board: bool) -> Polarity {
        match (self.dark, self.bright, board) {
            (true, _, _) | (false, false, true) => Polarity::Dark,
            _ => Polarity::Bright,
        }
    }
}

/// [`positive`] for the device's single-precision parameters.
pub fn positive_f32(text: &str) -> Result<f32, String> {
    positive(text).map(|v| v as f32)
}

/// A `--flag A,B` value: two comma-separated numbers.
pub fn pair<T: std::str::FromStr>(text: &str) -> Result<[T; 2], String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let parse = |s: &str| s.parse::<T>().map_err(|_| format!("{s:?} is not a number"));
    match parts[..] {
        [a, b] => Ok([parse(a)?, parse(b)?]),
        _ => Err(format!("{text:?} is not two comma-separated numbers A,B")),
    }
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

/// Observations measured from a folder of images instead of an observations CSV.
#[derive(Debug, Clone, clap::Args)]
pub struct ImageFolder {
    /// Measure the targets in this folder's images (PNG, TIFF, JPEG) instead of --obs:
    /// control targets identified by the layout of --control from its distinct (larger)
    /// targets; the observations are written next to --out (*.obs.csv).
    #[arg(long, conflicts_with = "obs")]
    pub images: Option<PathBuf>,
    /// With --images: only the files whose names start with this.
    #[arg(long, default_value = "", requires = "images")]
    pub only: String,
    /// With --images: the distinct (larger) control targets, comma-separated labels
    /// (default: the ones `simulate --images` renders larger).
    #[arg(long, value_delimiter = ',', requires = "images")]
    pub distinct: Option<Vec<String>>,
    /// With --images: tolerance (px) of the layout match.
    #[arg(long, default_value_t = 8.0, value_parser = positive, allow_negative_numbers = true)]
    pub tolerance: f64,
    #[command(flatten)]
    pub polarity: PolarityArgs,
}

impl ImageFolder {
    /// The folder's measuring arguments with this control layout, or `None` without --images.
    pub fn with_control(self, control: &Path) -> Option<FolderArgs> {
        Some(FolderArgs {
            dir: self.images?,
            prefix: self.only,
            control: control.to_path_buf(),
            distinct: self.distinct,
            tolerance_px: self.tolerance,
            polarity: self.polarity.polarity(false),
        })
    }
}
