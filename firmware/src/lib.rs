//! The deltaz device logic, independent of any board: it builds and is tested on the host, and
//! the board binaries in `src/bin/` are thin shells around it.
//!
//! - [`device`]: requests in, responses out (the f32 rig, uploads, compute, stats);
//! - [`server`]: the framing around it over any embedded-io serial port;
//! - [`store`]: the power-fail safe two-slot calibration store over a `NorFlash`;
//! - [`ram_flash`]: a NOR flash in RAM with power cuts, for the host and the tests;
//! - [`smoke`]: the boot-time smoke computation.
#![cfg_attr(target_os = "none", no_std)]
#![deny(missing_docs)]

pub mod device;
pub mod ram_flash;
pub mod server;
pub mod smoke;
pub mod store;
