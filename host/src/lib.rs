//! The deltaz host: the heavy work (calibration, simulation, accuracy assessment) and the link to
//! the device.
#![deny(missing_docs)]

pub mod accuracy;
pub mod board_calibration;
pub mod bundle;
pub mod cli;
pub mod compare;
pub mod demo;
pub mod device_cli;
pub mod io;
pub mod link;
pub mod measure;
pub mod ply;
pub mod projector_calibration;
pub mod reconstruct;
pub mod resection;
pub mod simulate;
pub mod svg;
pub mod system;
