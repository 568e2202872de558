//! deltaz-surface's integration tests.
mod analytic;
mod bad_input;
mod mesh;
