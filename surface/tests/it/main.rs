//! deltaz-surface's integration tests.
