//! `deltaz calibrate camera|projector|system`.

use super::{calibrate_camera, calibrate_projector, calibrate_system};
use anyhow::Result;

/// What to calibrate.
#[derive(clap::Subcommand)]
pub enum What {
    /// Projector calibration with the camera as a prior (the joint / non-central models: the
    /// whole-system adjustment without the field images; the camera system), or by the paper's
    /// ΔZ method (steps 4-7; the plate frame of the 1st plate image): writes system.json
    /// ("deltaz.system/2").
    Projector(calibrate_projector::Args),
    /// Camera and projector in one: the camera by bundle adjustment, then plates, control,
    /// projector and camera (as a prior) in one whole-system adjustment with variance components;
    /// system.json in the camera system with the covariance a point's σ needs.
    System(calibrate_system::Args),
    /// Camera calibration by self-calibrating bundle adjustment (f, cx, cy, k1 by default).
    Camera(calibrate_camera::Args),
}

/// Runs `deltaz calibrate`.
pub fn exec(what: What) -> Result<()> {
    match what {
        What::Projector(args) => calibrate_projector::exec(args),
        What::System(args) => calibrate_system::exec(args),
        What::Camera(args) => calibrate_camera::exec(args),
    }
}
