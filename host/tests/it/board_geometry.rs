//! A board must match its declared geometry: rendered boards (a symmetric 7 × 7 grid and an
//! asymmetric 4 × 11 grid seen in perspective) are found whole under their own spec, and `deltaz
//! measure --board` refuses every other kind or size, naming the grid it found, and writes
//! nothing.

use deltaz_host::io::observations::read_observations;
use deltaz_measure::board::Board;
use deltaz_measure::render::{Background, BitDepth, Scene, Spot};
use nalgebra::{Matrix3, Vector3};
use std::path::Path;

/// A board of dark circles (30 px lattice unit, radius 7 px) through a perspective homography,
/// rendered 640 × 480 (blur 1 px, noise 2 DN) into `path`.
fn render_board(spec: &str, path: &Path) {
    let board: Board = spec.parse().unwrap();
    let h = Matrix3::new(1.0, 0.12, 200.0, -0.08, 0.95, 90.0, 0.0002, -0.0003, 1.0);
    let spots = board
        .circles()
        .map(|(r, c)| {
            let p = board.position(r, c) * 30.0 / board.spacing;
            let v = h * Vector3::new(p.x, p.y, 1.0);
            Spot::circle(v.x / v.z, v.y / v.z, 7.0, -130.0)
        })
        .collect();
    let scene = Scene {
        width: 640,
        height: 480,
        spots,
        background: Background::flat(190.0),
        falloff: 0.1,
        blur_sigma: 1.0,
        noise_sigma: 2.0,
        seed: 3,
    };
    scene.render().save_png(path, BitDepth::Eight).unwrap();
}

/// `deltaz measure IMAGE --dark --board SPEC --out OUT`: success, and stderr.
fn measure_board(image: &Path, spec: &str, out: &Path) -> (bool, String) {
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .arg("measure")
        .arg(image)
        .args(["--dark", "--board", spec, "--out"])
        .arg(out)
        .output()
        .unwrap();
    (
        run.status.success(),
        String::from_utf8_lossy(&run.stderr).into_owned(),
    )
}

#[test]
fn boards_of_another_kind_or_size_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    for (board, wrong, found) in [
        (
            "circles:7x7",
            &[
                "acircles:7x7",
                "circles:8x8",
                "circles:6x6",
                "circles:7x8",
                "acircles:4x7",
            ][..],
            "form a circles:7x7 grid",
        ),
        (
            "acircles:4x11",
            &[
                "circles:4x11",
                "circles:7x11",
                "acircles:4x12",
                "acircles:5x11",
                "acircles:4x10",
            ][..],
            "form an acircles:4x11 grid",
        ),
    ] {
        let image = dir.path().join(format!("{}.png", board.replace(':', "_")));
        render_board(board, &image);
        let out = dir.path().join("right.csv");
        let (ok, err) = measure_board(&image, board, &out);
        assert!(ok, "{board}: {err}");
        let spec: Board = board.parse().unwrap();
        assert_eq!(
            read_observations(&out).unwrap().len(),
            spec.circles().count()
        );
        for spec in wrong {
            let out = dir.path().join("wrong.csv");
            let (ok, err) = measure_board(&image, spec, &out);
            assert!(!ok, "{board} accepted as {spec}");
            assert!(
                err.contains(&format!("no {spec} board")) && err.contains(found),
                "{board} as {spec}: {err}"
            );
            assert!(!out.exists(), "{board} as {spec}: an output file");
        }
    }
}
