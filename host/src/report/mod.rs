//! What users read: results and progress on the console, a calibration's residuals, plots, and
//! the accuracy of scanned objects against their floor.

pub mod back_report;
pub mod calibration_plots;
pub mod console;
pub mod object_accuracy;
pub mod plot_parts;
pub mod plots;
pub mod residuals;
