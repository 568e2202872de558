//! The deltaz calibration core: camera calibration by bundle adjustment, space resection,
//! projector calibration (the ΔZ method and beyond), reconstruction with σ, and the comparison
//! with reference points. Plain input types and typed errors; reading and writing files is the
//! CLI crate's business.
#![deny(missing_docs)]

pub mod bundle;
pub mod compare;
pub mod input;
pub mod projector_calibration;
pub mod reconstruct;
pub mod resection;
pub mod residual;
pub mod system_adjustment;
