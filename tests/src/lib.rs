//! Helpers for the end-to-end tests: building the firmware and running it under QEMU.
#![deny(missing_docs)]

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// The workspace root.
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ sits in the workspace")
        .to_path_buf()
}

/// The firmware ELF for `mps2-an386`, built once per test process with
/// `cargo build -p deltaz-firmware --target thumbv7em-none-eabihf --release`.
pub fn firmware_elf() -> PathBuf {
    static ELF: OnceLock<PathBuf> = OnceLock::new();
    ELF.get_or_init(|| {
        let root = workspace_root();
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let status = Command::new(cargo)
            .current_dir(&root)
            .args([
                "build",
                "-p",
                "deltaz-firmware",
                "--target",
                "thumbv7em-none-eabihf",
                "--release",
            ])
            .status()
            .expect("run cargo to build the firmware");
        assert!(status.success(), "the firmware build failed");
        let target = std::env::var_os("CARGO_TARGET_DIR")
            .map(PathBuf::from)
            .unwrap_or(root.join("target"));
        target.join("thumbv7em-none-eabihf/release/mps2_an386")
    })
    .clone()
}

/// Run the firmware under `qemu-system-arm -machine mps2-an386` with UART0 on stdout until its
/// output contains `marker` or `timeout` passes; returns what it printed. QEMU is killed after.
pub fn run_qemu_until(elf: &Path, marker: &str, timeout: Duration) -> String {
    let mut child = Command::new("qemu-system-arm")
        .args([
            "-machine",
            "mps2-an386",
            "-nographic",
            "-monitor",
            "none",
            "-serial",
            "stdio",
            "-kernel",
        ])
        .arg(elf)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("qemu-system-arm must be installed (apt-get install qemu-system-arm)");
    let mut stdout = child.stdout.take().expect("piped stdout");
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut buf = [0u8; 256];
        while let Ok(n) = stdout.read(&mut buf) {
            if n == 0 || tx.send(buf[..n].to_vec()).is_err() {
                break;
            }
        }
    });
    let start = Instant::now();
    let mut output = Vec::new();
    while !String::from_utf8_lossy(&output).contains(marker) && start.elapsed() < timeout {
        if let Ok(chunk) = rx.recv_timeout(Duration::from_millis(100)) {
            output.extend(chunk);
        }
    }
    let _ = child.kill();
    let _ = child.wait();
    String::from_utf8_lossy(&output).into_owned()
}
