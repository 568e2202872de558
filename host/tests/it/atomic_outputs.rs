//! Where outputs go (`io::atomic`, the one place every command writes through): an output path
//! that is a symbolic link writes the link's target and keeps the link; an output that is a
//! device node or a fifo is refused before anything is written, never replaced; an interrupted
//! command (SIGINT) leaves no temporary file behind.

use crate::cli::deltaz_in;
use deltaz_host::workflows::bench_reconstruct::ScalingInputs;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The files in `dir` whose names hold `.tmp` (the temporaries of `io::atomic`).
fn temporaries(dir: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.file_name().unwrap().to_string_lossy().contains(".tmp"))
        .collect()
}

/// A folder with a system (`system.json`) and `dots` dots over `images` images (`dots.csv`).
fn reconstruct_inputs(dots: usize, images: usize) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let inputs = ScalingInputs::new(dir.path(), dots / images).unwrap();
    let obs = inputs.dots(dir.path(), dots, images).unwrap();
    std::fs::rename(obs, dir.path().join("dots.csv")).unwrap();
    dir
}

#[cfg(unix)]
#[test]
fn outputs_write_through_symbolic_links() {
    use std::os::unix::fs::symlink;
    let dir = reconstruct_inputs(2_000, 10);
    let d = dir.path();
    std::fs::create_dir(d.join("real")).unwrap();
    // A link to an existing file, and a relative link whose target does not exist yet.
    std::fs::write(d.join("real/old.ply"), "old").unwrap();
    symlink("real/old.ply", d.join("cloud.ply")).unwrap();
    symlink("real/new.csv", d.join("cloud.csv")).unwrap();
    let out = deltaz_in(
        d,
        &[
            "reconstruct",
            "--system",
            "system.json",
            "--obs",
            "dots.csv",
            "--out",
            "cloud.ply",
            "--csv",
            "cloud.csv",
        ],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for (link, target) in [("cloud.ply", "real/old.ply"), ("cloud.csv", "real/new.csv")] {
        let meta = std::fs::symlink_metadata(d.join(link)).unwrap();
        assert!(meta.file_type().is_symlink(), "{link} was replaced");
        assert_eq!(std::fs::read_link(d.join(link)).unwrap(), Path::new(target));
    }
    let cloud = std::fs::read(d.join("real/old.ply")).unwrap();
    assert!(
        cloud.starts_with(b"ply\n"),
        "the link's target was not written"
    );
    let csv = std::fs::read_to_string(d.join("real/new.csv")).unwrap();
    assert_eq!(csv.lines().count(), 2 + 2_000);
    assert!(temporaries(d).is_empty() && temporaries(&d.join("real")).is_empty());
    // Staged outputs (several files renamed together) follow links too.
    symlink("real/camera.yml", d.join("camera.yml")).unwrap();
    let out = deltaz_in(
        d,
        &[
            "export",
            "opencv",
            "--system",
            "system.json",
            "--out",
            "camera.yml",
        ],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(std::fs::symlink_metadata(d.join("camera.yml"))
        .unwrap()
        .file_type()
        .is_symlink());
    assert!(std::fs::read_to_string(d.join("real/camera.yml"))
        .unwrap()
        .contains("camera_matrix"));
}

/// A device node or a fifo as an output is refused by name and kind, and stays what it was.
#[cfg(unix)]
#[test]
fn device_nodes_and_fifos_are_refused_not_replaced() {
    use std::os::unix::fs::FileTypeExt;
    let dir = reconstruct_inputs(1_000, 10);
    let d = dir.path();
    let fifo = d.join("fifo.ply");
    let made = Command::new("mkfifo").arg(&fifo).status();
    let fifo_made = made.is_ok_and(|s| s.success());
    // /dev/null directly and through a link; the fifo when mkfifo is there.
    std::os::unix::fs::symlink("/dev/null", d.join("null.ply")).unwrap();
    let mut cases = vec![
        (
            "/dev/null",
            "/dev/null: cannot write: it is a character device",
        ),
        (
            "null.ply",
            "null.ply: cannot write: it is a character device (the link's target /dev/null)",
        ),
    ];
    if fifo_made {
        cases.push((
            "fifo.ply",
            "fifo.ply: cannot write: it is a fifo, not a regular file",
        ));
    }
    for (target, expect) in cases {
        for args in [
            vec![
                "reconstruct",
                "--system",
                "system.json",
                "--obs",
                "dots.csv",
                "--out",
                target,
            ],
            vec![
                "export",
                "opencv",
                "--system",
                "system.json",
                "--out",
                target,
            ],
        ] {
            let out = deltaz_in(d, &args);
            let stderr = String::from_utf8_lossy(&out.stderr);
            assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
            assert!(stderr.contains(expect), "{args:?}: {stderr}");
        }
    }
    let null = std::fs::metadata("/dev/null").unwrap();
    assert!(null.file_type().is_char_device());
    if fifo_made {
        assert!(std::fs::symlink_metadata(&fifo)
            .unwrap()
            .file_type()
            .is_fifo());
    }
    assert!(temporaries(d).is_empty(), "{:?}", temporaries(d));
}

/// SIGINT while the outputs are being written: the command ends by the signal, and neither
/// its temporaries nor an output are left.
#[cfg(unix)]
#[test]
fn an_interrupted_command_leaves_no_temporary_file() {
    use std::os::unix::process::ExitStatusExt;
    let dir = reconstruct_inputs(1_000_000, 2_000);
    let d = dir.path();
    let mut child = Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .args([
            "reconstruct",
            "--system",
            "system.json",
            "--obs",
            "dots.csv",
        ])
        .args(["--out", "cloud.ply", "--csv", "cloud.csv", "--quiet"])
        .current_dir(d)
        .spawn()
        .unwrap();
    // Wait until the temporaries exist (the vertices go to one from the first batch on).
    let mut seen = Vec::new();
    for _ in 0..2_000 {
        seen = temporaries(d);
        if seen.len() >= 2 {
            break;
        }
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    assert!(seen.len() >= 2, "no temporaries seen: {seen:?}");
    let pid = child.id() as libc::pid_t;
    // SAFETY: kill only sends a signal to the child this test started and has not waited for.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGINT) }, 0);
    let status = child.wait().unwrap();
    assert_eq!(status.signal(), Some(libc::SIGINT), "{status:?}");
    assert!(
        temporaries(d).is_empty(),
        "left behind: {:?}",
        temporaries(d)
    );
    assert!(!d.join("cloud.ply").exists() && !d.join("cloud.csv").exists());
}
