//! The deltaz device logic, independent of any board: it builds and is tested on the host, and
//! the board binaries in `src/bin/` are thin shells around it.
//!
//! - [`device`]: requests in, responses out (the f32 rig, uploads, compute, stats);
//! - [`server`]: the framing around it over any embedded-io serial port;
//! - [`store`]: the power-fail safe two-slot calibration store over a `NorFlash`;
//! - [`rx_ring`]: the received bytes a board's RX interrupt queues for the serve loop;
//! - [`ram_flash`]: a NOR flash in RAM with power cuts, for the host and the tests;
//! - [`smoke`]: the boot-time smoke computation and its line;
//! - `logging`: the device's events to the `log` facade (feature `log`), or nothing;
//! - `probe` (board targets only): SysTick and the stack high-water mark.
#![cfg_attr(target_os = "none", no_std)]
#![deny(missing_docs)]

pub mod device;
mod logging;
#[cfg(target_os = "none")]
pub mod probe;
pub mod ram_flash;
pub mod rx_ring;
pub mod server;
pub mod smoke;
pub mod store;
