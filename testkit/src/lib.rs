//! Tests that need something outside the repository (a tool such as OpenCV or Chromium, a data
//! set in `../shared/`) call [`require`] first. When it is there the test runs. When it is not:
//!
//! - if the environment variable `DELTAZ_REQUIRE` names it (a comma-separated list; CI names the
//!   tools it installs), the test fails: a machine that should have it does not;
//! - otherwise the test is skipped visibly: a `SKIPPED` line goes to the terminal (past libtest's
//!   output capture) and, when `DELTAZ_SKIP_LOG` names a file, a line is appended to it, which
//!   `scripts/test` counts and lists after the run.
//!
//! Fixtures built into a folder shared by test processes go through [`fixture`].
#![deny(missing_docs)]

use std::io::Write;

/// Whether the test may run: `available` says whether `what` (a short name: "opencv",
/// "chromium", "real-images", ...) is there; `hint` says how to get it.
pub fn require(what: &str, available: bool, hint: &str) -> bool {
    if available {
        return true;
    }
    let test = std::thread::current().name().unwrap_or("a test").to_owned();
    let required = std::env::var("DELTAZ_REQUIRE").unwrap_or_default();
    if required.split(',').any(|r| r.trim() == what) {
        panic!("{test} needs {what}, which DELTAZ_REQUIRE says this machine has: {hint}");
    }
    let line = format!("SKIPPED {test}: {what} is missing ({hint})\n");
    // The terminal itself, not the test's captured stderr: a skip is seen where it happens.
    match std::fs::OpenOptions::new().write(true).open("/dev/tty") {
        Ok(mut tty) => {
            let _ = tty.write_all(line.as_bytes());
        }
        Err(_) => eprint!("{line}"),
    }
    if let Ok(log) = std::env::var("DELTAZ_SKIP_LOG") {
        if let Ok(mut file) = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(log)
        {
            let _ = file.write_all(line.as_bytes());
        }
    }
    false
}

/// Whether `python3` imports every module of `modules` (e.g. `["cv2", "numpy"]`).
pub fn python_has(modules: &[&str]) -> bool {
    std::process::Command::new("python3")
        .args(["-c", &format!("import {}", modules.join(", "))])
        .output()
        .is_ok_and(|o| o.status.success())
}

/// [`require`] for Python's OpenCV and numpy.
pub fn require_opencv() -> bool {
    require(
        "opencv",
        python_has(&["cv2", "numpy"]),
        "pip install opencv-python-headless numpy",
    )
}

/// The folder `../shared/NAME` beside the repository (third-party data, never committed), when
/// it is there; [`require`]d as `NAME`.
pub fn shared_data(name: &str) -> Option<std::path::PathBuf> {
    // testkit/ sits in the repository, which sits beside shared/.
    let repository = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).parent();
    let beside = repository.and_then(std::path::Path::parent);
    let dir = beside
        .unwrap_or(std::path::Path::new(".."))
        .join("shared")
        .join(name);
    let hint = format!("the data set at {}", dir.display());
    require(name, dir.is_dir(), &hint).then_some(dir)
}

/// Builds a fixture that lives in a folder every test process shares (under
/// `CARGO_TARGET_TMPDIR`), once per process: `build` runs under an exclusive lock on the file
/// `lock`, and the process then holds a shared lock on it until it exits, so that no other
/// process rebuilds the folder under it (cargo nextest runs each test in a process of its own;
/// a `OnceLock` alone guards a process). Call it from the fixture's `OnceLock`.
pub fn fixture<T>(lock: &std::path::Path, build: impl FnOnce() -> T) -> T {
    let file = std::fs::File::create(lock)
        .unwrap_or_else(|e| panic!("fixture lock {}: {e}", lock.display()));
    let locked = |r: std::io::Result<()>| r.unwrap_or_else(|e| panic!("{}: {e}", lock.display()));
    locked(file.lock());
    let built = build();
    // Another process may rebuild between these two: it builds the same, and this one reads
    // only once it holds the shared lock, after that build.
    locked(file.unlock());
    locked(file.lock_shared());
    // Held until the process exits.
    std::mem::forget(file);
    built
}
