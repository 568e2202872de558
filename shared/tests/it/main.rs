//! The shared crate's integration tests, one binary: each module is one former test file.
mod blob_golden;
mod identify;
mod protocol_golden;
mod rig;
