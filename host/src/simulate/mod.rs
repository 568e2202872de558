//! The simulator: a [`Scenario`] and a seed → image observations, control files and the truth
//! (section 6.1: simulations to design a rig and to test the calibration).
//!
//! Frames: the target field has its own frame; the plate frame has the plate surface at Z = 0;
//! the rig (camera + projector) moves between plate images while the plate stays. The *global*
//! frame of the paper (section 5.2, errata) is the 1st plate image's: the camera keeps its 1st pose
//! and the plate of image k is moved by X_G = R1ᵀ R_k (X_P − X0_k) + X0_1 (for pure translations
//! the plate of image k lies at Z ≈ 100 (k − 1)).

pub mod back;
pub mod back_frames;
pub mod images;
pub mod objects;
pub mod pattern;
pub mod scenario;
pub mod truth;

pub use scenario::Scenario;
pub use truth::Truth;

use crate::io::camera_file::{CameraFile, PoseParams, Station};
use crate::io::control::ControlPoint;
use crate::io::observations::{Observation, PointKind};
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::{Camera, ExteriorOrientation};
use deltaz_shared::rotation::{angles_from_matrix, rotation_matrix};
use nalgebra::{Matrix3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use std::path::Path;
use truth::{TruthOutlier, TruthPoint};

/// Everything a simulation produces, in memory.
#[derive(Debug, Clone)]
pub struct Simulation {
    /// The sensor a calibration starts from (pixel mapping, approximate f).
    pub camera_init: CameraFile,
    /// Target-field observations (the camera calibration images).
    pub camera_obs: Vec<Observation>,
    /// Target-field control (noisy coordinates with their σ).
    pub camera_control: Vec<ControlPoint>,
    /// Plate images: control targets and projected dots.
    pub plate_obs: Vec<Observation>,
    /// Plate control (noisy coordinates with their σ).
    pub plate_control: Vec<ControlPoint>,
    /// Every true parameter.
    pub truth: Truth,
}

/// The true camera of a scenario.
pub fn true_camera(scenario: &Scenario) -> (PixelGrid<f64>, InnerOrientation<f64>) {
    let c = &scenario.camera;
    let grid = PixelGrid {
        pixel_size: c.pixel_size,
        width: c.image_size[0],
        height: c.image_size[1],
        origin_col: c.origin[0],
        origin_row: c.origin[1],
    };
    (grid, c.inner.into())
}

/// The target field's true coordinates, labelled T01, T02, ….
pub fn field_targets(scenario: &Scenario) -> Vec<(String, Vector3<f64>)> {
    let f = &scenario.field;
    let [nx, ny] = f.grid;
    let mut out = Vec::new();
    for j in 0..ny {
        for i in 0..nx {
            let x = f.size[0] * (f64::from(i) / f64::from((nx - 1).max(1)) - 0.5);
            let y = f.size[1] * (f64::from(j) / f64::from((ny - 1).max(1)) - 0.5);
            // A fixed scatter of heights over 0..relief (a permutation of five levels).
            let level = f64::from((i * 3 + j * 7 + (i * j) % 3) % 5) / 4.0;
            out.push((
                format!("T{:02}", out.len() + 1),
                Vector3::new(x, y, f.relief * level),
            ));
        }
    }
    out
}

/// The calibration plate's control points (plate frame), labelled C01, C02, ….
pub fn plate_targets(scenario: &Scenario) -> Vec<(String, Vector3<f64>)> {
    let control = scenario.plate.control.iter().enumerate();
    control
        .map(|(i, c)| (format!("C{:02}", i + 1), Vector3::from(*c)))
        .collect()
}

/// The stations' true exterior orientations, labelled s1, s2, …: the first looks straight down
/// on the field's centre, the others sit on a cone of half-angle `convergence` and look at it.
pub fn field_stations(scenario: &Scenario) -> Vec<(String, ExteriorOrientation<f64>)> {
    let s = &scenario.stations;
    let target = Vector3::new(0.0, 0.0, scenario.field.relief / 2.0);
    (0..s.count)
        .map(|k| {
            let (tilt, azimuth) = if k == 0 {
                (0.0, 0.0)
            } else {
                let n = f64::from(s.count - 1);
                (s.convergence, std::f64::consts::TAU * f64::from(k - 1) / n)
            };
            let dir = Vector3::new(
                tilt.sin() * azimuth.cos(),
                tilt.sin() * azimuth.sin(),
                tilt.cos(),
            );
            let centre = target + dir * s.distance;
            let roll = if s.rolls.is_empty() {
                0.0
            } else {
                s.rolls[k as usize % s.rolls.len()]
            };
            (format!("s{}", k + 1), look_at(centre, target, roll))
        })
        .collect()
}

/// The exterior orientation of a camera at `centre` looking at `target` (image y towards world
/// +Y as far as possible), rolled by `roll` about its viewing axis.
fn look_at(centre: Vector3<f64>, target: Vector3<f64>, roll: f64) -> ExteriorOrientation<f64> {
    let z = (centre - target).normalize(); // the camera looks along −z
    let up = if z.y.abs() < 0.9 {
        Vector3::y()
    } else {
        Vector3::x()
    };
    let x = up.cross(&z).normalize();
    let y = z.cross(&x);
    let (sr, cr) = roll.sin_cos();
    let (xr, yr) = (x * cr + y * sr, y * cr - x * sr);
    let r = Matrix3::from_rows(&[xr.transpose(), yr.transpose(), z.transpose()]);
    let (kappa, phi, omega) = angles_from_matrix(&r);
    ExteriorOrientation {
        kappa,
        phi,
        omega,
        centre,
    }
}

/// Adds image noise (and, with probability `outlier_rate`, a gross error) to a pixel position.
struct Noise {
    rng: ChaCha8Rng,
    sigma_px: f64,
    outlier_rate: f64,
    outlier_px: [f64; 2],
}

impl Noise {
    fn pixel(&mut self, (col, row): (f64, f64), outliers: bool) -> ((f64, f64), bool) {
        let (mut c, mut r) = (
            col + self.coordinate(self.sigma_px),
            row + self.coordinate(self.sigma_px),
        );
        let gross = outliers && self.rng.random_bool(self.outlier_rate.clamp(0.0, 1.0));
        if gross {
            let size = self
                .rng
                .random_range(self.outlier_px[0]..=self.outlier_px[1]);
            let angle = self.rng.random_range(0.0..std::f64::consts::TAU);
            c += size * angle.cos();
            r += size * angle.sin();
        }
        ((c, r), gross)
    }

    fn coordinate(&mut self, sigma: f64) -> f64 {
        let z: f64 = StandardNormal.sample(&mut self.rng);
        sigma * z
    }
}

/// Simulates a scenario with a seed: deterministic for a given (scenario, seed). The scenario
/// must pass [`Scenario::validate`] (files are validated when read).
pub fn simulate(scenario: &Scenario, seed: u64) -> Simulation {
    let (grid, inner) = true_camera(scenario);
    let mut noise = Noise {
        rng: ChaCha8Rng::seed_from_u64(seed),
        sigma_px: scenario.noise.image_sigma_px,
        outlier_rate: scenario.noise.outlier_rate,
        outlier_px: scenario.noise.outlier_px,
    };
    let mut outliers = Vec::new();

    // Target field images.
    let targets = field_targets(scenario);
    let stations = field_stations(scenario);
    let mut camera_obs = Vec::new();
    for (image, exterior) in &stations {
        let camera = Camera {
            grid,
            inner,
            exterior: *exterior,
        };
        for (point, xyz) in &targets {
            if let Some(pixel) = visible(&camera, xyz) {
                let Some(((col, row), gross)) = on_sensor(&grid, noise.pixel(pixel, true)) else {
                    continue;
                };
                if gross {
                    outliers.push(TruthOutlier {
                        image: image.clone(),
                        point: point.clone(),
                    });
                }
                camera_obs.push(Observation::target(image, point, col, row));
            }
        }
    }
    let camera_control = targets
        .iter()
        .map(|(point, xyz)| {
            let s = scenario.field.control_sigma;
            ControlPoint {
                point: point.clone(),
                xyz: xyz + Vector3::from_fn(|_, _| noise.coordinate(s)),
                sigma: s,
            }
        })
        .collect();

    // Plate images: control targets, then the dots of every ray that hits the plate in view.
    let rig = &scenario.rig;
    let [pk, pp, po] = rig.projector_angles;
    let r_cam_proj = rotation_matrix(pk, pp, po);
    let rays = rig.pattern.rays(&r_cam_proj);
    let centre_cam = Vector3::from(rig.projector_centre);
    let plate_control_true = plate_targets(scenario);
    let mut plate_obs = Vec::new();
    for (k, pose) in scenario.plate.images.iter().enumerate() {
        let image = format!("p{}", k + 1);
        let camera = Camera {
            grid,
            inner,
            exterior: (*pose).into(),
        };
        for (point, xyz) in &plate_control_true {
            if let Some(pixel) = visible(&camera, xyz) {
                let Some(((col, row), _)) = on_sensor(&grid, noise.pixel(pixel, false)) else {
                    continue;
                };
                plate_obs.push(Observation::target(&image, point, col, row));
            }
        }
        let r_world_cam = camera.exterior.r_cam_world().transpose();
        for ray in &rays {
            let start = r_world_cam * (centre_cam + ray.offset) + camera.exterior.centre;
            let dir = r_world_cam * ray.direction;
            let lambda = -start.z / dir.z;
            if lambda.is_nan() || lambda <= 0.0 {
                continue;
            }
            let hit = start + dir * lambda;
            let [x0, x1, y0, y1] = scenario.plate.extent;
            if !(x0..=x1).contains(&hit.x) || !(y0..=y1).contains(&hit.y) {
                continue;
            }
            if let Some(pixel) = visible(&camera, &hit) {
                let Some(((col, row), _)) = on_sensor(&grid, noise.pixel(pixel, false)) else {
                    continue;
                };
                let mut o = Observation::target(&image, &ray.id.to_string(), col, row);
                o.kind = PointKind::Dot;
                plate_obs.push(o);
            }
        }
    }
    let plate_control = plate_control_true
        .iter()
        .map(|(point, xyz)| {
            let s = scenario.plate.control_sigma;
            ControlPoint {
                point: point.clone(),
                xyz: xyz + Vector3::from_fn(|_, _| noise.coordinate(s)),
                sigma: s,
            }
        })
        .collect();

    let init = InnerOrientation::ideal(scenario.camera.init_f);
    let truth = Truth::new(
        scenario,
        seed,
        stations
            .iter()
            .map(|(image, eo)| Station {
                image: image.clone(),
                pose: PoseParams::from(*eo),
                sigma: None,
                sigma0: None,
                rms_px: None,
                observations: None,
            })
            .collect(),
        targets
            .iter()
            .chain(&plate_control_true)
            .map(|(p, x)| TruthPoint::new(p, x))
            .collect(),
        &rays,
        outliers,
    );
    Simulation {
        camera_init: CameraFile::init(&grid, init),
        camera_obs,
        camera_control,
        plate_obs,
        plate_control,
        truth,
    }
}

/// The exact pixel position of a world point if it is in front of the camera and on the sensor.
fn visible(camera: &Camera<f64>, world: &Vector3<f64>) -> Option<(f64, f64)> {
    let (col, row) = camera.world_to_pixel(world).ok()?;
    camera.grid.contains(col, row).then_some((col, row))
}

/// A noisy observation if it is still on the sensor (a camera sees nothing beyond its edge).
fn on_sensor(grid: &PixelGrid<f64>, observed: ((f64, f64), bool)) -> Option<((f64, f64), bool)> {
    let (col, row) = observed.0;
    grid.contains(col, row).then_some(observed)
}

/// Writes a simulation's six files into `dir` (created if needed), each atomically.
pub fn write_simulation(dir: &Path, sim: &Simulation) -> anyhow::Result<()> {
    use crate::io::{atomic, camera_file, control, observations};
    std::fs::create_dir_all(dir)?;
    camera_file::write_camera(&dir.join("camera_init.json"), &sim.camera_init)?;
    observations::write_observations(&dir.join("camera_obs.csv"), &sim.camera_obs)?;
    control::write_control(&dir.join("camera_control.csv"), &sim.camera_control)?;
    observations::write_observations(&dir.join("plate_obs.csv"), &sim.plate_obs)?;
    control::write_control(&dir.join("plate_control.csv"), &sim.plate_control)?;
    atomic::write_json_atomic(&dir.join("truth.json"), &sim.truth)?;
    Ok(())
}

/// The `back` scenario's TOML (`host/scenarios/back.toml`), built in.
const BACK_TOML: &str = include_str!("../../scenarios/back.toml");

/// A scenario by name (`paper`, `desk`, `back`) or from a TOML file.
pub fn load_scenario(name_or_path: &str) -> anyhow::Result<Scenario> {
    match name_or_path {
        "paper" => return Ok(Scenario::paper()),
        "desk" => return Ok(Scenario::desk()),
        "back" => return Scenario::from_toml(BACK_TOML).map_err(|e| anyhow::anyhow!("back: {e}")),
        _ => {}
    }
    let text = std::fs::read_to_string(name_or_path)
        .map_err(|e| anyhow::anyhow!("{name_or_path}: {e}"))?;
    Scenario::from_toml(&text).map_err(|e| anyhow::anyhow!("{name_or_path}: {e}"))
}

/// What [`write_scenario`] wrote.
#[derive(Debug, Clone)]
pub struct Written {
    /// The simulation whose files were written.
    pub simulation: Simulation,
    /// With images: how many of each were rendered.
    pub rendered: Option<RenderedCounts>,
}

/// How many images [`write_scenario`] rendered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RenderedCounts {
    /// Field and plate images.
    pub images: usize,
    /// Test object frames.
    pub objects: usize,
    /// Frames of the scenario's back (`images/back/`).
    pub back: usize,
}

/// Simulate `scenario` with `seed` into the directory `out`, all or nothing: the observation,
/// control and truth files ([`write_simulation`]), the `extra` files (name, content) and, with
/// `images`, the rendered field and plate images ([`images::write_images`]), test objects
/// ([`objects::write_objects`]) and the frames of the scenario's back
/// ([`back_frames::write_back_frames`]).
pub fn write_scenario(
    out: &Path,
    scenario: &Scenario,
    seed: u64,
    images: Option<&images::ImageSpec>,
    extra: &[(&str, &[u8])],
) -> anyhow::Result<Written> {
    let simulation = simulate(scenario, seed);
    let rendered = crate::io::atomic::write_dir_all_or_nothing(out, |dir| {
        write_simulation(dir, &simulation)?;
        for (name, content) in extra {
            std::fs::write(dir.join(name), content)?;
        }
        let Some(spec) = images else {
            return Ok(None);
        };
        Ok(Some(RenderedCounts {
            images: images::write_images(scenario, seed, spec, dir)?,
            objects: objects::write_objects(scenario, seed, dir)?,
            back: back_frames::write_back_frames(scenario, seed, spec, dir)?,
        }))
    })?;
    Ok(Written {
        simulation,
        rendered,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use deltaz_shared::projector::{Projector, ProjectorRay};
    use deltaz_shared::rig::{Method, Rig};

    fn quiet_paper() -> Scenario {
        let mut s = Scenario::paper();
        s.noise.image_sigma_px = 0.0;
        s
    }

    fn v(a: [f64; 3]) -> Vector3<f64> {
        Vector3::from(a)
    }

    /// Table 3's global projector centre and Table 4's directions come out of the camera-system
    /// truth through the 1st plate image's pose.
    #[test]
    fn paper_truth_in_global_frame_matches_tables_3_and_4() {
        use deltaz_shared::paper::{TABLE3_GLOBAL, TABLE4};
        let truth = simulate(&quiet_paper(), 1).truth;
        let c = v(truth.projector.centre_global);
        assert!((c - Vector3::from(TABLE3_GLOBAL)).amax() < 0.01, "{c}");
        for (id, (_, d)) in crate::simulate::pattern::TABLE4_IDS.into_iter().zip(TABLE4) {
            let ray = truth.projector.rays.iter().find(|r| r.id == id).unwrap();
            assert!(
                (v(ray.global) - v(d).normalize()).amax() < 1e-12,
                "ray {id}"
            );
        }
        assert_eq!(truth.projector.rays.len(), 440);
    }

    /// Without noise, every dot of every plate image lies on its true ray in the global frame
    /// once the plate is moved by `plate_to_global`, and reconstructs onto the plate (Z = 0) with
    /// the shared rig in the plate frame; also with projector distortion and non-central rays.
    #[test]
    fn noise_free_dots_lie_on_their_rays_and_the_plate() {
        let central = simulate(&quiet_paper(), 1);
        dots_on_rays_and_plate(&central);
        let mut warped = quiet_paper();
        warped.rig.pattern.distortion = 0.5;
        warped.rig.pattern.noncentral_mm = 30.0;
        let sim = simulate(&warped, 1);
        dots_on_rays_and_plate(&sim);
        let offsets = sim
            .truth
            .projector
            .rays
            .iter()
            .map(|r| v(r.offset_camera).norm());
        assert!(offsets.fold(0.0, f64::max) > 5.0);
        // Distortion moves the dots by pixels, most near the pattern's edge.
        let moved = sim
            .plate_obs
            .iter()
            .filter_map(|a| {
                let b = central
                    .plate_obs
                    .iter()
                    .find(|b| b.image == a.image && b.point == a.point)?;
                Some(((a.col - b.col).powi(2) + (a.row - b.row).powi(2)).sqrt())
            })
            .fold(0.0, f64::max);
        assert!(moved > 3.0, "{moved}");
    }

    fn dots_on_rays_and_plate(sim: &Simulation) {
        let truth = &sim.truth;
        let in_camera = truth.projector_camera().unwrap();
        let global = truth.projector_global().unwrap();
        let mut checked = 0;
        for img in &truth.plate.images {
            // The projector in this image's plate frame, through the camera's pose.
            let eo: ExteriorOrientation<f64> = img.camera.into();
            let r_world_cam = eo.r_cam_world().transpose();
            let rays: Vec<ProjectorRay<f64>> = in_camera
                .rays()
                .iter()
                .map(|r| ProjectorRay {
                    direction: r_world_cam * r.direction,
                    offset: r_world_cam * r.offset,
                    ..*r
                })
                .collect();
            let centre = eo.camera_to_world(&in_camera.centre());
            let projector = Projector::new(centre, rays).unwrap();
            let rig = Rig::new(truth.grid(), truth.inner(), &eo, projector);
            for o in sim.plate_obs.iter().filter(|o| o.image == img.image) {
                let Some(id) = o.ray_id() else { continue };
                let hit = rig
                    .reconstruct(id, o.col, o.row, Method::ClosestApproach)
                    .unwrap();
                assert!(
                    hit.point.z.abs() < 1e-6,
                    "dot {id} in {}: {}",
                    img.image,
                    hit.point
                );
                // The same point in the global frame lies on the global ray.
                let g = img.plate_to_global.apply(&hit.point);
                let ray = global.ray(id).unwrap();
                let from = g - ray.point;
                let miss = (from - ray.direction * from.dot(&ray.direction)).norm();
                assert!(miss < 1e-6, "dot {id}: {miss} mm off its global ray");
                checked += 1;
            }
        }
        let dots = sim
            .plate_obs
            .iter()
            .filter(|o| o.ray_id().is_some())
            .count();
        assert_eq!(checked, dots);
        assert!(dots > 3 * 400, "{dots} dots");
    }

    /// The same seed gives the same data; the image noise has the scenario's σ.
    #[test]
    fn seeded_noise_has_the_stated_sigma() {
        let quiet = simulate(&quiet_paper(), 5);
        let a = simulate(&Scenario::paper(), 5);
        let b = simulate(&Scenario::paper(), 5);
        assert_eq!(a.camera_obs, b.camera_obs);
        assert_ne!(a.camera_obs, simulate(&Scenario::paper(), 6).camera_obs);
        let d: Vec<f64> = a
            .camera_obs
            .iter()
            .chain(&a.plate_obs)
            .zip(quiet.camera_obs.iter().chain(&quiet.plate_obs))
            .flat_map(|(n, q)| [n.col - q.col, n.row - q.row])
            .collect();
        let sd = (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt();
        // ~3600 samples: the sample σ is within 5% of 0.5 px with overwhelming probability.
        assert!((sd - 0.5).abs() < 0.025, "σ {sd}");
    }

    #[test]
    fn outliers_are_recorded_and_displaced() {
        let mut s = quiet_paper();
        s.noise.outlier_rate = 0.05;
        let sim = simulate(&s, 3);
        let quiet = simulate(&quiet_paper(), 3);
        let outliers = &sim.truth.noise.outliers;
        assert!(!outliers.is_empty());
        for (n, q) in sim.camera_obs.iter().zip(&quiet.camera_obs) {
            let d = ((n.col - q.col).powi(2) + (n.row - q.row).powi(2)).sqrt();
            let listed = outliers
                .iter()
                .any(|o| o.image == n.image && o.point == n.point);
            assert_eq!(listed, d > 1e-9, "{} {}", n.image, n.point);
            assert!(!listed || (5.0 - 1e-9..=20.0 + 1e-9).contains(&d));
        }
    }

    #[test]
    fn example_scenarios_parse_and_see_every_dot() {
        Scenario::paper().validate().unwrap();
        for name in ["modern_12mp", "desk_rig"] {
            let path = format!("{}/scenarios/{name}.toml", env!("CARGO_MANIFEST_DIR"));
            let s = load_scenario(&path).unwrap();
            let sim = simulate(&s, s.seed);
            let dots = sim
                .plate_obs
                .iter()
                .filter(|o| o.ray_id().is_some())
                .count();
            assert_eq!(dots, 440 * s.plate.images.len(), "{name}");
            assert!(
                sim.camera_obs.len() > 40 * s.stations.count as usize,
                "{name}"
            );
        }
        let e = Scenario::from_toml("name = 'x'\n[camera]\nbogus = 1\n").unwrap_err();
        assert!(e.to_string().contains("bogus"), "{e}");
        let text = std::fs::read_to_string(format!(
            "{}/scenarios/desk_rig.toml",
            env!("CARGO_MANIFEST_DIR")
        ))
        .unwrap();
        let e = Scenario::from_toml(&text.replace("cols = 22", "cols = 120")).unwrap_err();
        assert!(e.to_string().contains("at most 100 columns"), "{e}");
    }

    #[test]
    fn writes_all_files() {
        let dir = tempfile::tempdir().unwrap();
        let sim = simulate(&Scenario::paper(), 1);
        write_simulation(dir.path(), &sim).unwrap();
        let obs = crate::io::observations::read_observations(&dir.path().join("plate_obs.csv"));
        assert_eq!(obs.unwrap().len(), sim.plate_obs.len());
        let text = std::fs::read_to_string(dir.path().join("truth.json")).unwrap();
        let back: Truth = serde_json::from_str(&text).unwrap();
        assert_eq!(back.camera.inner.f, 46.981);
        let init = crate::io::camera_file::read_camera(&dir.path().join("camera_init.json"));
        assert_eq!(init.unwrap().inner.f, 46.0);
    }
}
