//! Rendered images of a scenario (`deltaz simulate --images`): the field images (circular
//! targets) and the plate images (control targets and projected dots), as PNG, with every true
//! centre in `images/centres.csv`.
//!
//! Each circular target and each dot is drawn as the affine image of its circle about the image
//! of its centre (the local Jacobian of the projection, distortion included), so the rendered
//! ellipse is centred on the true point: the perspective bias of circle centres is left out here
//! and bounded apart ([`deltaz_measure::perspective_bias`]: below 0.02 pixel at the paper's
//! geometry). Dots are the footprints of a light cone of half-angle [`ImageSpec::dot_angle`]
//! on the plate. The distinct control targets of [`distinct_targets`] are drawn
//! [`ImageSpec::distinct_scale`] times larger, for their identification by the known layout
//! ([`deltaz_measure::layout`]). Images carry blur, noise, uneven illumination and a non-uniform background
//! ([`deltaz_measure::render`]).

use super::{field_stations, field_targets, true_camera, Scenario};
use crate::io::observations::{write_observations, Observation, PointKind};
use anyhow::Result;
use deltaz_measure::render::{Background, BitDepth, Scene, Spot};
use deltaz_measure::target_field::{distinct_targets, CONTROL_SUFFIX, DISTINCT_COUNT};
use deltaz_shared::collinearity::{Camera, ExteriorOrientation};
use deltaz_shared::projector::{Projector, ProjectorRay};
use deltaz_shared::rig::Rig;
use deltaz_shared::rotation::rotation_matrix;
use nalgebra::{Matrix2, Vector2, Vector3};
use std::path::Path;

/// How the images look.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageSpec {
    /// Radius of the circular targets (mm).
    pub target_radius: f64,
    /// Half-angle of a projected dot's light cone (rad).
    pub dot_angle: f64,
    /// Target brightness above the background (DN).
    pub target_amplitude: f64,
    /// Dot brightness above the background (DN).
    pub dot_amplitude: f64,
    /// Defocus blur σ (pixels).
    pub blur_sigma: f64,
    /// Sensor noise σ (DN).
    pub noise_sigma: f64,
    /// Sample depth of the PNG files.
    pub depth: BitDepth,
    /// The grid node (row, column) whose dot is the marker, drawn `marker_scale` times larger
    /// (for identification by the grid topology, [`deltaz_measure::grid`]).
    pub marker_node: Option<(u16, u16)>,
    /// Size of the marker dot relative to the others.
    pub marker_scale: f64,
    /// Radius of the distinct control targets (those of
    /// [`deltaz_measure::target_field::distinct_targets`]) relative to the others.
    pub distinct_scale: f64,
}

impl Default for ImageSpec {
    fn default() -> Self {
        Self {
            target_radius: 8.0,
            dot_angle: 0.0035,
            target_amplitude: 180.0,
            dot_amplitude: 140.0,
            blur_sigma: 1.0,
            noise_sigma: 2.0,
            depth: BitDepth::Eight,
            marker_node: Some((10, 11)),
            marker_scale: 1.7,
            distinct_scale: 1.8,
        }
    }
}

/// The ellipse of a small circle: the images of centre ± radius along two directions.
pub(super) fn ellipse(
    centre: (f64, f64),
    a1: Vector2<f64>,
    a2: Vector2<f64>,
    amplitude: f64,
) -> Spot {
    let svd = Matrix2::from_columns(&[a1, a2]).svd(true, false);
    let u = svd.u.expect("asked for U");
    Spot {
        col: centre.0,
        row: centre.1,
        semi_a: svd.singular_values[0],
        semi_b: svd.singular_values[1],
        angle: u[(1, 0)].atan2(u[(0, 0)]),
        amplitude,
    }
}

/// A circular target facing +Z at `xyz` (`scale` times the spec's radius), if its ellipse lies
/// on the sensor.
fn target_spot(
    camera: &Camera<f64>,
    xyz: &Vector3<f64>,
    spec: &ImageSpec,
    scale: f64,
) -> Option<Spot> {
    let pix = |p: Vector3<f64>| {
        camera
            .world_to_pixel(&p)
            .ok()
            .map(|(c, r)| Vector2::new(c, r))
    };
    let centre = pix(*xyz)?;
    let r = spec.target_radius * scale;
    let half = |e: Vector3<f64>| Some((pix(xyz + e * r)? - pix(xyz - e * r)?) / 2.0);
    let spot = ellipse(
        (centre.x, centre.y),
        half(Vector3::x())?,
        half(Vector3::y())?,
        spec.target_amplitude,
    );
    on_sensor(camera, &spot).then_some(spot)
}

pub(super) fn on_sensor(camera: &Camera<f64>, spot: &Spot) -> bool {
    let m = spot.semi_a + 2.0;
    camera.grid.contains(spot.col - m, spot.row - m)
        && camera.grid.contains(spot.col + m, spot.row + m)
}

pub(super) fn scene(camera: &Camera<f64>, spots: Vec<Spot>, spec: &ImageSpec, seed: u64) -> Scene {
    let (w, h) = (camera.grid.width as usize, camera.grid.height as usize);
    Scene {
        width: w,
        height: h,
        spots,
        background: Background {
            level: 35.0,
            slope_col: 12.0 / w as f64,
            slope_row: -6.0 / h as f64,
            ripple: 4.0,
            ripple_period: w as f64 / 2.5,
        },
        falloff: 0.25,
        blur_sigma: spec.blur_sigma,
        noise_sigma: spec.noise_sigma,
        seed,
    }
}

/// The scenario's true camera and projector as a rig in the camera system (camera at the
/// origin, unrotated): all that dot identification needs.
pub fn true_rig(scenario: &Scenario) -> crate::io::system_file::SystemRig {
    let (grid, inner) = true_camera(scenario);
    let [k, p, o] = scenario.rig.projector_angles;
    let rays = scenario
        .rig
        .pattern
        .rays(&rotation_matrix(k, p, o))
        .iter()
        .map(|r| ProjectorRay {
            id: r.id,
            direction: r.direction,
            offset: r.offset,
        })
        .collect();
    let projector = Projector::new(Vector3::from(scenario.rig.projector_centre), rays)
        .expect("the pattern's rays are sorted unit vectors");
    let at_origin = ExteriorOrientation {
        kappa: 0.0,
        phi: 0.0,
        omega: 0.0,
        centre: Vector3::zeros(),
    };
    Rig::new(grid, inner, &at_origin, projector)
}

/// Render every field and plate image of `scenario` into `dir/images/` (`s1.png`, …, `p1.png`,
/// …, and each plate with the projector off, `p1_control.png`, …) and their true centres into `dir/images/centres.csv`; returns the number of images.
pub fn write_images(scenario: &Scenario, seed: u64, spec: &ImageSpec, dir: &Path) -> Result<usize> {
    let out = dir.join("images");
    std::fs::create_dir_all(&out)?;
    let (grid, inner) = true_camera(scenario);
    let mut centres = Vec::new();
    let mut count = 0;
    let save = |label: &str, camera: &Camera<f64>, spots: Vec<Spot>, k: u64| -> Result<()> {
        scene(camera, spots, spec, seed.wrapping_mul(1000).wrapping_add(k))
            .render()
            .save_png(&out.join(format!("{label}.png")), spec.depth)
    };

    let targets = field_targets(scenario);
    let distinct = |points: &[(String, Vector3<f64>)]| {
        let labels = distinct_targets(points, DISTINCT_COUNT);
        move |label: &str| {
            if labels.iter().any(|l| l == label) {
                spec.distinct_scale
            } else {
                1.0
            }
        }
    };
    let field_scale = distinct(&targets);
    for (k, (image, exterior)) in field_stations(scenario).iter().enumerate() {
        let camera = Camera {
            grid,
            inner,
            exterior: *exterior,
        };
        let mut spots = Vec::new();
        for (point, xyz) in &targets {
            if let Some(spot) = target_spot(&camera, xyz, spec, field_scale(point)) {
                centres.push(Observation::target(image, point, spot.col, spot.row));
                spots.push(spot);
            }
        }
        save(image, &camera, spots, k as u64)?;
        count += 1;
    }

    let rig = &scenario.rig;
    let [pk, pp, po] = rig.projector_angles;
    let rays = rig.pattern.rays(&rotation_matrix(pk, pp, po));
    let marker = spec.marker_node.map(|(r, c)| rig.pattern.id(r, c));
    let centre_cam = Vector3::from(rig.projector_centre);
    let plate_control = super::plate_targets(scenario);
    let plate_scale = distinct(&plate_control);
    for (k, pose) in scenario.plate.images.iter().enumerate() {
        let image = format!("p{}", k + 1);
        let camera = Camera {
            grid,
            inner,
            exterior: (*pose).into(),
        };
        let mut spots = Vec::new();
        for (label, c) in &plate_control {
            if let Some(spot) = target_spot(&camera, c, spec, plate_scale(label)) {
                centres.push(Observation::target(&image, label, spot.col, spot.row));
                spots.push(spot);
            }
        }
        let control_spots = spots.clone();
        let r_world_cam = camera.exterior.r_cam_world().transpose();
        let [x0, x1, y0, y1] = scenario.plate.extent;
        for ray in &rays {
            let start = r_world_cam * (centre_cam + ray.offset) + camera.exterior.centre;
            let dir = r_world_cam * ray.direction;
            // The plate (Z = 0) hit of a direction from the projector, if on the plate.
            let hit = |d: Vector3<f64>| {
                let t = -start.z / d.z;
                let p = start + d * t;
                (t > 0.0 && (x0..=x1).contains(&p.x) && (y0..=y1).contains(&p.y)).then_some(p)
            };
            let pix = |d: Vector3<f64>| {
                hit(d)
                    .and_then(|p| camera.world_to_pixel(&p).ok())
                    .map(|(c, r)| Vector2::new(c, r))
            };
            let e1 = dir.cross(&Vector3::y()).normalize();
            let e2 = dir.cross(&e1);
            let side = |e: Vector3<f64>| {
                let scale = if marker == Some(ray.id) {
                    spec.marker_scale
                } else {
                    1.0
                };
                let a = spec.dot_angle * scale;
                Some((pix((dir + e * a).normalize())? - pix((dir - e * a).normalize())?) / 2.0)
            };
            let (Some(c), Some(a1), Some(a2)) = (pix(dir), side(e1), side(e2)) else {
                continue;
            };
            let spot = ellipse((c.x, c.y), a1, a2, spec.dot_amplitude);
            if on_sensor(&camera, &spot) {
                let mut o = Observation::target(&image, &ray.id.to_string(), c.x, c.y);
                o.kind = PointKind::Dot;
                centres.push(o);
                spots.push(spot);
            }
        }
        // The same plate with the projector off: the control targets alone.
        save(
            &format!("{image}{CONTROL_SUFFIX}"),
            &camera,
            control_spots,
            200 + k as u64,
        )?;
        count += 1;
        save(&image, &camera, spots, 100 + k as u64)?;
        count += 1;
    }
    write_observations(&out.join("centres.csv"), &centres)?;
    Ok(count)
}

/// The rig's camera at the origin of the camera system, unrotated.
pub(crate) fn camera_at_origin(rig: &crate::io::system_file::SystemRig) -> Camera<f64> {
    Camera {
        grid: *rig.grid(),
        inner: *rig.inner(),
        exterior: ExteriorOrientation {
            kappa: 0.0,
            phi: 0.0,
            omega: 0.0,
            centre: Vector3::zeros(),
        },
    }
}
