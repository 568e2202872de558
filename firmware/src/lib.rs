//! The deltaz device logic, independent of any board: it builds and is tested on the host, and
//! the board binaries in `src/bin/` are thin shells around it.
#![cfg_attr(target_os = "none", no_std)]
#![deny(missing_docs)]

pub mod smoke;
