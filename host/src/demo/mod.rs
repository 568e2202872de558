//! `deltaz demo`: the whole system on the simulated paper rig, from rendered images
//! ([`images`], the default) or from simulated image observations ([`observations`],
//! `--observations`).

pub mod images;
pub mod observations;

use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::Vector3;

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
