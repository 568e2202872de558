//! `analysis.json` ("deltaz.back/1"): a back analysis ([`deltaz_surface::BackAnalysis`]) with
//! what it was made from.

use anyhow::{bail, Context, Result};
use deltaz_surface::BackAnalysis;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The format tag of `analysis.json`.
pub const ANALYSIS_FORMAT: &str = "deltaz.back/1";

/// `analysis.json`: the analysis and what it was made from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BackReport {
    /// Always [`ANALYSIS_FORMAT`].
    pub format: String,
    /// The clouds analysed (their paths as given).
    pub clouds: Vec<PathBuf>,
    /// The calibration's fingerprint (16 hex digits), if the clouds name one.
    pub fingerprint: Option<String>,
    /// Where the points' covariance came from, in words.
    pub covariance: String,
    /// What was assumed of the clouds or done to them, in words (a cloud that does not say its
    /// frame, thinned or too dense); absent when nothing was.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<String>,
    /// The measures.
    #[serde(flatten)]
    pub analysis: BackAnalysis,
}

/// Reads an `analysis.json`.
pub fn read_report(path: &Path) -> Result<BackReport> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    match crate::io::format_tag(&text).as_deref() {
        Some(ANALYSIS_FORMAT) => {}
        Some(other) => bail!(
            "{}: format {other:?}, expected {ANALYSIS_FORMAT:?} (an analysis.json)",
            path.display()
        ),
        None => bail!("{}: not an analysis.json", path.display()),
    }
    serde_json::from_str(&text)
        .with_context(|| format!("{}: not a valid analysis.json", path.display()))
}
