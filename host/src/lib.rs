//! The deltaz host: the heavy work (calibration, simulation, accuracy assessment) and the link to
//! the device.
#![deny(missing_docs)]

pub mod measure;
