//! The host crate's integration tests, one binary: each module is one former test file.
mod accuracy;
mod cli_calibration;
mod compare_cli;
mod demo;
mod device_cli;
mod identify;
mod images_cli;
mod images_to_points;
mod link_errors;
mod link_in_process;
mod measure;
mod measure_cli;
mod objects;
mod projector_cli;
mod scan;
mod simulate_images;
