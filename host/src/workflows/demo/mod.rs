//! `deltaz demo`: the whole system on the simulated paper rig, from rendered images
//! ([`images`], the default) or from simulated image observations ([`observations`],
//! `--observations`).

pub mod back;
pub mod images;
pub mod observations;

use crate::io::system_file::SystemFile;
use anyhow::Result;
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::Vector3;
use std::path::Path;

/// The demo's step bar on stderr.
fn bar(len: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template("{msg:36} [{bar:30}] {pos}/{len} {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}

fn v3(v: &Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

/// A JSON array of numbers as "a / b / c" with 3 decimals.
fn slashed(v: &serde_json::Value) -> String {
    v.as_array()
        .map(|a| {
            a.iter()
                .map(|x| format!("{:.3}", x.as_f64().unwrap_or(f64::NAN)))
                .collect::<Vec<_>>()
                .join(" / ")
        })
        .unwrap_or_default()
}

/// The demo's result files, written into `out` once everything is computed, all or nothing:
/// `cloud.ply`, `system.json`, the plots, `report.json`, `report.md` and the `extra` files
/// (name, content).
fn write_results(
    out: &Path,
    ply: &[u8],
    system: &SystemFile,
    plots: &[crate::report::calibration_plots::Plot],
    (report, md): (&serde_json::Value, &str),
    extra: &[(&str, &[u8])],
) -> Result<()> {
    let system = system.to_json()?;
    let report = serde_json::to_string_pretty(report)? + "\n";
    let mut files = vec![
        (out.join("cloud.ply"), ply),
        (out.join("system.json"), system.as_bytes()),
        (out.join("report.json"), report.as_bytes()),
        (out.join("report.md"), md.as_bytes()),
    ];
    files.extend(extra.iter().map(|(name, bytes)| (out.join(name), *bytes)));
    let files: Vec<(&Path, &[u8])> = files.iter().map(|(p, b)| (p.as_path(), *b)).collect();
    crate::report::plots::write_with_plots(&files, Some(out), plots)?;
    Ok(())
}
