//! The `deltaz` binary, run as a user runs it.

use std::path::Path;
use std::process::{Command, Output};

/// `deltaz ARGS` in the test's working directory.
pub fn deltaz(args: &[&str]) -> Output {
    deltaz_in(Path::new("."), args)
}

/// `deltaz ARGS` in `dir`.
pub fn deltaz_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run deltaz")
}

/// `deltaz ARGS` in `dir`, which must succeed (its stderr in the failure).
pub fn deltaz_ok(dir: &Path, args: &[&str]) -> Output {
    let out = deltaz_in(dir, args);
    assert!(
        out.status.success(),
        "deltaz {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// The words of a command line (no quoting).
pub fn words(line: &str) -> Vec<&str> {
    line.split_whitespace().collect()
}
