//! `deltaz export opencv` on two rigs (the paper's DC40 with k1 > 0, the desk rig's 3 MP camera
//! with k1 < 0 and k2): OpenCV's projection, written out here as `cv2.projectPoints` computes it
//! (Rodrigues, then k1, k2, p1, p2, k3, then the camera matrix), reproduces deltaz's projection of
//! every observed control point, so the residuals too, within the refit error the file reports.

use crate::cli::{deltaz_ok, words};
use deltaz_host::io::camera_file::read_camera;
use deltaz_host::io::control::read_control;
use deltaz_host::io::observations::{image_labels, read_observations};
use deltaz_host::simulate::{simulate, write_simulation, Scenario};
use deltaz_shared::collinearity::Camera;
use nalgebra::{Matrix3, Vector3};

/// The numbers after `key:` (a scalar) or in the `data: [...]` of the `key: !!opencv-matrix`.
fn yaml_numbers(text: &str, key: &str) -> Vec<f64> {
    let start = text
        .find(&format!("\n{key}:"))
        .unwrap_or_else(|| panic!("no {key}"))
        + 1;
    let rest = &text[start + key.len() + 1..];
    let values = if rest.trim_start().starts_with("!!opencv-matrix") {
        let data = &rest[rest.find("data: [").unwrap() + 7..];
        &data[..data.find(']').unwrap()]
    } else {
        &rest[..rest.find('\n').unwrap()]
    };
    values
        .split(',')
        .map(|v| v.trim().parse().unwrap())
        .collect()
}

/// Rodrigues' formula: the rotation of `rvec` (axis × angle).
fn rodrigues(rvec: Vector3<f64>) -> Matrix3<f64> {
    let angle = rvec.norm();
    if angle == 0.0 {
        return Matrix3::identity();
    }
    let k = rvec / angle;
    let cross = k.cross_matrix();
    Matrix3::identity() + cross * angle.sin() + cross * cross * (1.0 - angle.cos())
}

/// cv2.projectPoints for one point.
fn project(k: &[f64], dist: &[f64], extrinsic: &[f64], world: Vector3<f64>) -> [f64; 2] {
    let r = rodrigues(Vector3::new(extrinsic[0], extrinsic[1], extrinsic[2]));
    let cam = r * world + Vector3::new(extrinsic[3], extrinsic[4], extrinsic[5]);
    let (x, y) = (cam.x / cam.z, cam.y / cam.z);
    let [k1, k2, p1, p2, k3] = [dist[0], dist[1], dist[2], dist[3], dist[4]];
    let r2 = x * x + y * y;
    let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
    let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
    let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
    [k[0] * xd + k[2], k[4] * yd + k[5]]
}

fn check(scenario: &Scenario, largest_refit_px: f64) {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_simulation(d, &simulate(scenario, 4)).unwrap();
    deltaz_ok(d, &words("calibrate camera --init camera_init.json --obs camera_obs.csv --control camera_control.csv --out camera.json --k2"));
    deltaz_ok(
        d,
        &words("export opencv --camera camera.json --out camera.yml"),
    );
    let yaml = std::fs::read_to_string(d.join("camera.yml")).unwrap();
    assert!(yaml.starts_with("%YAML:1.0\n---\n"));
    let camera = read_camera(&d.join("camera.json")).unwrap();
    let grid = camera.grid();
    assert_eq!(yaml_numbers(&yaml, "image_width"), [f64::from(grid.width)]);
    assert_eq!(
        yaml_numbers(&yaml, "image_height"),
        [f64::from(grid.height)]
    );
    let k = yaml_numbers(&yaml, "camera_matrix");
    let dist = yaml_numbers(&yaml, "distortion_coefficients");
    let extrinsics = yaml_numbers(&yaml, "extrinsic_parameters");
    let refit = yaml_numbers(&yaml, "distortion_refit_max_px")[0];
    assert!(refit < largest_refit_px, "refit error {refit} px");
    let observations = read_observations(&d.join("camera_obs.csv")).unwrap();
    let images = image_labels(&observations);
    assert_eq!(extrinsics.len(), 6 * images.len());
    let control = read_control(&d.join("camera_control.csv")).unwrap();
    let (mut worst, mut sum_sq, mut n) = (0.0f64, 0.0, 0.0);
    for o in &observations {
        let index = images.iter().position(|i| *i == o.image).unwrap();
        let station = &camera.stations[index];
        assert_eq!(
            station.image, o.image,
            "extrinsics in the order of the observations"
        );
        let xyz = control.iter().find(|c| c.point == o.point).unwrap().xyz;
        let ours = Camera {
            grid,
            inner: camera.inner(),
            exterior: station.pose.into(),
        }
        .world_to_pixel(&xyz)
        .unwrap();
        let cv = project(&k, &dist, &extrinsics[6 * index..6 * index + 6], xyz);
        let (ours_v, cv_v) = (
            [o.col - ours.0, o.row - ours.1],
            [o.col - cv[0], o.row - cv[1]],
        );
        worst = worst.max((ours_v[0] - cv_v[0]).hypot(ours_v[1] - cv_v[1]));
        sum_sq += cv_v[0].powi(2) + cv_v[1].powi(2);
        n += 2.0;
    }
    assert!(
        worst <= refit + 1e-6,
        "OpenCV differs by {worst} px, refit {refit} px"
    );
    // The residuals are the calibration's: OpenCV's per-coordinate RMS against the control is
    // near the file's (which uses the adjusted points), ~ the simulated noise.
    let rms = (sum_sq / n).sqrt();
    let stated = yaml_numbers(&yaml, "rms_per_coordinate_px")[0];
    assert!((rms / stated - 1.0).abs() < 0.2, "{rms} vs {stated}");
    let per_point = yaml_numbers(&yaml, "avg_reprojection_error")[0];
    assert!((per_point / stated - 2f64.sqrt()).abs() < 1e-9);
}

#[test]
fn opencv_projection_reproduces_the_residuals() {
    check(&Scenario::paper(), 0.01);
    let desk = Scenario::from_toml(include_str!("../../scenarios/desk_rig.toml")).unwrap();
    check(&desk, 0.05);
}

/// From system.json: one extrinsic row, the camera's pose in the system's frame, named `rig`.
#[test]
fn from_a_system_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut scenario = Scenario::paper();
    scenario.noise.image_sigma_px = 0.1;
    write_simulation(d, &simulate(&scenario, 2)).unwrap();
    deltaz_ok(d, &words("calibrate camera --init camera_init.json --obs camera_obs.csv --control camera_control.csv --out camera.json"));
    deltaz_ok(d, &words("calibrate projector --camera camera.json --control plate_control.csv --obs plate_obs.csv --out system.json --model paper"));
    deltaz_ok(
        d,
        &words("export opencv --system system.json --out system.yml"),
    );
    let yaml = std::fs::read_to_string(d.join("system.yml")).unwrap();
    assert!(yaml.contains("image_names: [ \"rig\" ]"), "{yaml}");
    let extrinsic = yaml_numbers(&yaml, "extrinsic_parameters");
    assert_eq!(extrinsic.len(), 6);
    // A `--model paper` system is in the 1st plate image's frame: its camera sits ~1843 mm above the plate
    // (Table 2), which OpenCV's tvec = −R X0 puts on its +z axis.
    assert!((extrinsic[5] - 1843.0).abs() < 20.0, "{extrinsic:?}");
}
