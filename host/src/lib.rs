//! The deltaz host: the `deltaz` command line over libraries, in layers that import only
//! downwards (checked by the `module_graph` test of `deltaz-tests`):
//!
//! | layer | modules | what |
//! |---|---|---|
//! | commands | [`commands`] | one file per subcommand: its clap arguments and an `exec` that maps files and options to one workflow call |
//! | station | [`station`] | the operator's station (`deltaz station`): its threads, web server and page, over the workflows |
//! | workflows | [`workflows`] | the chains, each written once: field → camera, plates → projector, both → system, images → observations, frames → points, the demo |
//! | libraries | [`io`], [`link`], [`simulate`], [`report`] | file formats, the device link, simulation, reports and plots: free of clap and of the command line |
//! | crates | `deltaz-calib`, `deltaz-measure`, `deltaz-shared` | the calibration core, image measurement, the camera/projector model and the wire protocol |
#![deny(missing_docs)]

pub mod commands;
pub mod io;
pub mod link;
pub mod report;
pub mod simulate;
pub mod station;
pub mod workflows;
