//! The deltaz host: the heavy work (calibration, simulation, accuracy assessment) and the link to
//! the device.
#![deny(missing_docs)]

pub mod bundle;
pub mod io;
pub mod measure;
pub mod resection;
pub mod simulate;
