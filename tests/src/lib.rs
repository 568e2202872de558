//! Helpers for the end-to-end tests: building the firmware and running it under QEMU.
#![deny(missing_docs)]

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// xorshift64*: a seeded generator, enough for fuzzing and line noise.
pub struct Rng(pub u64);

impl Rng {
    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// A number below `n`.
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n
    }

    /// `n` random bytes.
    pub fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| self.next_u64() as u8).collect()
    }
}

/// The workspace root.
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ sits in the workspace")
        .to_path_buf()
}

/// `cargo build ARGS` in the workspace (once per `cache`, per test process): the file at
/// `built` below the target directory (`CARGO_TARGET_DIR`, or `target`).
fn built_once(cache: &'static OnceLock<PathBuf>, args: &[&str], built: &str) -> PathBuf {
    cache
        .get_or_init(|| {
            let root = workspace_root();
            let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
            let status = Command::new(cargo)
                .current_dir(&root)
                .arg("build")
                .args(args)
                .status()
                .unwrap_or_else(|e| panic!("run cargo to build {built}: {e}"));
            assert!(status.success(), "the build of {built} failed");
            let target = std::env::var_os("CARGO_TARGET_DIR")
                .map(PathBuf::from)
                .unwrap_or(root.join("target"));
            target.join(built)
        })
        .clone()
}

/// The firmware ELF for `mps2-an386`, built once per test process with
/// `cargo build -p deltaz-firmware --target thumbv7em-none-eabihf --release`.
pub fn firmware_elf() -> PathBuf {
    static ELF: OnceLock<PathBuf> = OnceLock::new();
    built_once(
        &ELF,
        &[
            "-p",
            "deltaz-firmware",
            "--target",
            "thumbv7em-none-eabihf",
            "--release",
        ],
        "thumbv7em-none-eabihf/release/mps2_an386",
    )
}

/// The real board's firmware ELF (`nucleo_f401re`), built once per test process with
/// `cargo build -p deltaz-firmware --target thumbv7em-none-eabihf --release --features
/// nucleo-f401re --bin nucleo_f401re`.
pub fn nucleo_elf() -> PathBuf {
    static ELF: OnceLock<PathBuf> = OnceLock::new();
    built_once(
        &ELF,
        &[
            "-p",
            "deltaz-firmware",
            "--target",
            "thumbv7em-none-eabihf",
            "--release",
            "--features",
            "nucleo-f401re",
            "--bin",
            "nucleo_f401re",
        ],
        "thumbv7em-none-eabihf/release/nucleo_f401re",
    )
}

/// The `deltaz` command-line program, built once per test process with `cargo build -p
/// deltaz-host --release --bin deltaz`.
pub fn deltaz_binary() -> PathBuf {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    built_once(
        &BIN,
        &["-p", "deltaz-host", "--release", "--bin", "deltaz"],
        "release/deltaz",
    )
}

/// The static RAM of a Cortex-M ELF (bytes): what its allocated sections at the RAM's base
/// (0x2000_0000 and up) occupy, initialised (`.data`) and zeroed (`.bss`, `.uninit`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StaticRam {
    /// Initialised data (copied from flash at boot).
    pub data: u64,
    /// Zeroed or uninitialised data.
    pub bss: u64,
}

/// [`StaticRam`] of the 32-bit little-endian ELF at `elf`, read from its section headers.
pub fn static_ram(elf: &Path) -> StaticRam {
    let bytes = std::fs::read(elf).expect("read the ELF");
    assert_eq!(
        &bytes[..6],
        b"\x7fELF\x01\x01",
        "a 32-bit little-endian ELF"
    );
    let u16_at = |at: usize| u64::from(u16::from_le_bytes([bytes[at], bytes[at + 1]]));
    let u32_at = |at: usize| u64::from(u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()));
    let (table, entry, count) = (u32_at(0x20), u16_at(0x2E), u16_at(0x30));
    const ALLOC: u64 = 2;
    const NOBITS: u64 = 8;
    let mut ram = StaticRam { data: 0, bss: 0 };
    for k in 0..count {
        let header = (table + k * entry) as usize;
        let (kind, flags) = (u32_at(header + 4), u32_at(header + 8));
        let (address, size) = (u32_at(header + 12), u32_at(header + 20));
        if flags & ALLOC == 0 || !(0x2000_0000..0x4000_0000).contains(&address) {
            continue;
        }
        if kind == NOBITS {
            ram.bss += size;
        } else {
            ram.data += size;
        }
    }
    ram
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

/// Helpers for the device tests: a calibrated rig with the full dot pattern and its centroids.
pub mod pattern {
    use deltaz_firmware::smoke::paper_camera;
    use deltaz_shared::projector::{Projector, ProjectorRay};
    use deltaz_shared::rig::Rig;
    use nalgebra::Vector3;

    /// Rows of the dot pattern.
    pub const ROWS: u16 = 20;
    /// Columns of the dot pattern.
    pub const COLS: u16 = 22;

    /// The paper's rig (Tables 1-3) with a 20 × 22 pattern of 440 rays, ids row·100 + col,
    /// whose directions span Table 4's: direction ∝ (tx, ty, −1) with tx from 0.0934 (ray 01)
    /// to 0.4237 (ray 03) over the columns and ty from −0.1751 (ray 01) to 0.1343 (ray 21) over
    /// the rows.
    pub fn pattern_rig() -> Rig<f64, Vec<ProjectorRay<f64>>> {
        let camera = paper_camera();
        let lerp = |a: f64, b: f64, i: u16, n: u16| a + (b - a) * f64::from(i) / f64::from(n - 1);
        let rays = (0..ROWS)
            .flat_map(|r| (0..COLS).map(move |c| (r, c)))
            .map(|(r, c)| ProjectorRay {
                id: r * 100 + c,
                direction: Vector3::new(
                    lerp(0.0934, 0.4237, c, COLS),
                    lerp(-0.1751, 0.1343, r, ROWS),
                    -1.0,
                )
                .normalize(),
                offset: Vector3::zeros(),
            })
            .collect();
        let projector = Projector::new(Vector3::new(-114.601, 383.502, 1905.981), rays)
            .expect("a sorted table of unit rays");
        Rig::new(camera.grid, camera.inner, &camera.exterior, projector)
    }

    /// The centroids `(id, col, row)` of every dot the camera sees on the plate Z = `z` (world),
    /// each shifted by `shift` pixels.
    pub fn plate_centroids(
        rig: &Rig<f64, Vec<ProjectorRay<f64>>>,
        z: f64,
        shift: (f64, f64),
    ) -> Vec<(u16, f64, f64)> {
        let camera = paper_camera();
        let x0 = rig.camera_centre();
        rig.projector_centred()
            .rays()
            .iter()
            .filter_map(|ray| {
                let line = rig.projector_centred().ray(ray.id).ok()?;
                let t = (z - x0.z - line.point.z) / line.direction.z;
                let (col, row) = camera.world_to_pixel(&(line.at(t) + x0)).ok()?;
                let (col, row) = (col + shift.0, row + shift.1);
                camera.grid.contains(col, row).then_some((ray.id, col, row))
            })
            .collect()
    }
}

/// Dots on a torso-like surface seen by the paper's rig (camera at the origin, the 440-dot
/// pattern with its rows turned as in Table 4): frames for identifying unlabelled dots.
pub mod torso {
    use deltaz_host::io::system_file::SystemRig;
    use deltaz_host::simulate::images::true_rig;
    use deltaz_host::simulate::Scenario;

    /// Distance of the wall behind the body from the camera (mm).
    pub const WALL: f64 = 1740.0;
    /// Height of the body's ridge above the wall (mm).
    pub const HEIGHT: f64 = 110.0;

    /// The paper scenario's true rig, centred on the camera.
    pub fn rig() -> SystemRig {
        true_rig(&Scenario::paper())
    }

    /// Distance from the camera of the surface at camera-system (x, y): a ridge along y,
    /// centred at x = `ridge`, lower towards its ends.
    fn depth(x: f64, y: f64, ridge: f64) -> f64 {
        let across = (-((x - ridge) / 220.0).powi(2)).exp();
        WALL - HEIGHT * across * (1.0 - (y / 900.0).powi(2))
    }

    /// The dots `(ray id, col, row)` the camera sees on the surface with its ridge at
    /// x = `ridge` (mm), each moved by `jitter` pixels in a direction that varies per dot.
    pub fn dots(rig: &SystemRig, ridge: f64, jitter: f64) -> Vec<(u16, f64, f64)> {
        let projector = rig.projector_centred();
        let r = rig.r_cam_world();
        projector
            .rays()
            .iter()
            .enumerate()
            .filter_map(|(k, ray)| {
                // Fixed-point iteration on the depth: the surface is flat enough to converge.
                let mut d = WALL;
                let mut p = rig.point_at_depth(ray.id, d).ok()?;
                for _ in 0..60 {
                    p = rig.point_at_depth(ray.id, d).ok()?;
                    let cam = r * p;
                    d = depth(cam.x, cam.y, ridge);
                }
                let (col, row) = rig.pixel_of_centred(&p).ok()?;
                let phase = k as f64 * 2.399;
                let (col, row) = (col + jitter * phase.cos(), row + jitter * phase.sin());
                rig.grid().contains(col, row).then_some((ray.id, col, row))
            })
            .collect()
    }
}

/// A simulated back-density rig: a 1,280 × 1,024 camera and a projector of 36 × 36 = 1,296
/// rays, about 20 mm apart on a back 1.65 m away, its lattice turned 9° against the 250 mm
/// baseline (along the image rows) so that the epipolar segments of neighbouring columns pass
/// 3.6 px apart: dots identify over the whole 1,400-1,900 mm range.
pub mod back_density {
    use deltaz_host::io::system_file::SystemRig;
    use deltaz_shared::camera::{InnerOrientation, PixelGrid};
    use deltaz_shared::collinearity::ExteriorOrientation;
    use deltaz_shared::projector::{Projector, ProjectorRay};
    use deltaz_shared::rig::Rig;
    use nalgebra::Vector3;

    /// Lattice rows and columns.
    pub const SIDE: u16 = 36;
    /// Nearest and farthest surface of the working range (mm from the camera).
    pub const RANGE: (f64, f64) = (1400.0, 1900.0);
    /// The plates: three distances spanning 400 mm.
    pub const PLATES: [f64; 3] = [1450.0, 1650.0, 1850.0];

    /// The rig, centred on the camera (world axes = camera axes: the camera looks along −z).
    /// Ray ids are row·100 + column. A little barrel distortion (k1) bends the segments in the
    /// observed image.
    pub fn rig() -> SystemRig {
        let grid = PixelGrid {
            pixel_size: 0.0053,
            width: 1280,
            height: 1024,
            origin_col: 639.5,
            origin_row: 511.5,
        };
        let inner = InnerOrientation {
            k1: -4.0e-4,
            ..InnerOrientation::ideal(10.0)
        };
        let exterior = ExteriorOrientation {
            kappa: 0.0,
            phi: 0.0,
            omega: 0.0,
            centre: Vector3::zeros(),
        };
        let centre = Vector3::new(250.0, 0.0, 0.0);
        let aim = Vector3::new(0.0, 0.0, -1650.0) - centre;
        // Lattice axes in the plane across the aim at 1.65 m: 20 mm apart, turned by 9°.
        let (s, c) = 9.0_f64.to_radians().sin_cos();
        let across = Vector3::new(aim.z, 0.0, -aim.x).normalize();
        let up = aim.cross(&across).normalize();
        let pitch = 20.0;
        let half = f64::from(SIDE - 1) / 2.0;
        let rays = (0..SIDE)
            .flat_map(|r| (0..SIDE).map(move |k| (r, k)))
            .map(|(r, k)| {
                let (x, y) = ((f64::from(k) - half) * pitch, (f64::from(r) - half) * pitch);
                let (x, y) = (c * x - s * y, s * x + c * y);
                ProjectorRay {
                    id: r * 100 + k,
                    direction: (aim + across * x + up * y).normalize(),
                    offset: Vector3::zeros(),
                }
            })
            .collect();
        let projector = Projector::new(centre, rays).expect("a sorted table of unit rays");
        Rig::new(grid, inner, &exterior, projector)
    }

    /// The dots `(ray id, col, row)` the camera sees on the plate at distance `depth` (mm, a
    /// plane across the camera's axis), each moved by `jitter` pixels in a direction that
    /// varies per dot.
    pub fn plate(rig: &SystemRig, depth: f64, jitter: f64) -> Vec<(u16, f64, f64)> {
        rig.projector_centred()
            .rays()
            .iter()
            .enumerate()
            .filter_map(|(k, ray)| {
                let (col, row) = rig.pixel_at_depth(ray.id, depth).ok()?;
                let phase = k as f64 * 2.399;
                let (col, row) = (col + jitter * phase.cos(), row + jitter * phase.sin());
                rig.grid().contains(col, row).then_some((ray.id, col, row))
            })
            .collect()
    }
}
