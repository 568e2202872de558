//! The deltaz host: the heavy work (calibration, simulation, accuracy assessment) and the link to
//! the device.
#![deny(missing_docs)]

pub mod accuracy;
pub mod board_calibration;
pub mod calibration_plots;
pub mod camera_calibration;
pub mod cli;
pub mod demo;
pub mod device_cli;
pub mod export;
pub mod image_calibration;
pub mod io;
pub mod link;
pub mod measure;
pub mod object_accuracy;
pub mod parallel;
pub mod pattern;
pub mod plates;
pub mod plots;
pub mod ply;
pub mod reconstruct_stream;
pub mod render;
pub mod residuals;
pub mod scan;
pub mod simulate;
pub mod system;
pub mod system_bench;
pub mod target_field;

pub use deltaz_calib::{bundle, compare, projector_calibration, reconstruct, resection};
