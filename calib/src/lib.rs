//! The deltaz calibration core: camera calibration by bundle adjustment ([`bundle`]), space
//! resection ([`resection`]), projector calibration (the ΔZ method and beyond,
//! [`projector_calibration`]), the whole-system adjustment with variance components and the
//! covariance of every point ([`system_adjustment`]), reconstruction with σ ([`reconstruct`]),
//! and the comparison with reference points ([`compare`]). Plain input types ([`input`]); reading
//! and writing files is the CLI crate's business. Resection and bundle share the image residual
//! ([`residual`]) and do not import each other's internals.
#![deny(missing_docs)]

pub mod bundle;
pub mod compare;
pub mod dense;
pub mod input;
pub mod projector_calibration;
pub mod reconstruct;
pub mod resection;
pub mod residual;
pub mod system_adjustment;
