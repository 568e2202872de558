//! The chains from inputs to results, each written once, between the commands and the
//! libraries: field → camera ([`camera`], [`board`]), plates → projector ([`plates`],
//! [`projector`]), both → system ([`system`]), images → observations ([`observations`]), dots →
//! points ([`reconstruct`], [`scan`], [`stream`] through a [`device`]), clouds → a back's
//! analysis ([`back`], in memory from its images [`back_scan`]), and the experiments on
//! simulated rigs ([`accuracy`], [`bench`](mod@bench), [`bench_reconstruct`], [`demo`]).

pub mod accuracy;
pub mod back;
pub mod back_scan;
pub mod bench;
pub mod bench_reconstruct;
pub mod board;
pub mod camera;
pub mod demo;
pub mod device;
pub mod observations;
pub mod plates;
pub mod projector;
pub mod reconstruct;
pub mod scan;
pub mod stream;
pub mod system;
