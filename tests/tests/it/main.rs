//! The tests crate's integration tests, one binary: each module is one former test file.
mod bad_frames;
mod device_accuracy;
mod device_capacity;
mod device_identify;
mod device_qemu;
mod firmware_smoke;
mod full_duplex;
mod link_budget;
mod link_noise;
mod module_graph;
mod nucleo_qemu;
mod upload_power_cut;
