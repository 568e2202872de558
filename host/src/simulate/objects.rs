//! Test objects never used in calibration (`deltaz simulate --images` writes them into
//! `images/objects/`): a sphere of known radius, a plane at a depth and tilt no plate had and the
//! torso surface, several frames each, as the camera sees the true projector's dots on them, with
//! every dot's true ray, pixel and surface point in `images/objects/truth.csv` and the objects
//! themselves in `images/objects/objects.json`.
//!
//! Everything is in the camera-centred frame of [`super::images::true_rig`] (camera at the
//! origin, looking along −Z). Dots are drawn as circles centred on their true pixels.

use super::images::{camera_at_origin, true_rig};
use super::Scenario;
use crate::io::system_file::SystemRig;
use anyhow::Result;
use deltaz_measure::render::{Background, Scene, Spot};
use nalgebra::Vector3;
use serde::Serialize;
use std::io::Write;
use std::path::Path;

/// A dot on an object: its ray id, its true pixel (col, row) and its true surface point.
pub type ObjectDot = (u16, (f64, f64), Vector3<f64>);

/// A test object in the camera-centred frame (mm, rad).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Object {
    /// The plane n·x = −depth, n = (sin tilt, 0, cos tilt).
    Plane {
        /// Distance from the camera along the plane's normal.
        depth: f64,
        /// Rotation about the camera's Y axis.
        tilt: f64,
    },
    /// A sphere.
    Sphere {
        /// Its centre.
        centre: [f64; 3],
        /// Its radius.
        radius: f64,
    },
    /// The torso ([`torso_height`]) facing the camera: its base plane `depth`
    /// away, its back up to 135 mm nearer, centred on the optical axis.
    Torso {
        /// Distance of the base plane.
        depth: f64,
    },
}

impl Object {
    /// The torso's height above its base plane at (x, y).
    fn torso_relief(x: f64, y: f64) -> f64 {
        torso_height(x + 375.0, y + 365.0) - 200.0
    }

    /// Where the ray `start + t dir` (t > 0) first meets the surface, with the surface's outward
    /// unit normal there.
    pub fn hit(
        &self,
        start: &Vector3<f64>,
        dir: &Vector3<f64>,
    ) -> Option<(Vector3<f64>, Vector3<f64>)> {
        match *self {
            Object::Plane { depth, tilt } => {
                let n = Vector3::new(tilt.sin(), 0.0, tilt.cos());
                let t = (-depth - n.dot(start)) / n.dot(dir);
                (t > 0.0).then(|| (start + dir * t, n))
            }
            Object::Sphere { centre, radius } => {
                let c = Vector3::from(centre);
                let d = dir.normalize();
                let s = start - c;
                let b = s.dot(&d);
                let disc = b * b - (s.norm_squared() - radius * radius);
                let t = -b - disc.sqrt();
                (disc > 0.0 && t > 0.0).then(|| {
                    let x = start + d * t;
                    (x, (x - c) / radius)
                })
            }
            Object::Torso { depth } => {
                let above = |p: &Vector3<f64>| p.z + depth - Self::torso_relief(p.x, p.y);
                let (mut lo, mut hi) = (0.0, (-(depth + 50.0) - start.z) / dir.z);
                if hi.is_nan()
                    || hi <= 0.0
                    || above(start) <= 0.0
                    || above(&(start + dir * hi)) >= 0.0
                {
                    return None;
                }
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if above(&(start + dir * mid)) > 0.0 {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                let x = start + dir * (0.5 * (lo + hi));
                let h = 1e-3;
                let dx = (Self::torso_relief(x.x + h, x.y) - Self::torso_relief(x.x - h, x.y))
                    / (2.0 * h);
                let dy = (Self::torso_relief(x.x, x.y + h) - Self::torso_relief(x.x, x.y - h))
                    / (2.0 * h);
                Some((x, Vector3::new(-dx, -dy, 1.0).normalize()))
            }
        }
    }
}

/// The torso-like surface in the 1st plate image's frame (mm): a back 1.4-1.6 m from the camera,
/// rounded across (X), a spine groove, and a gentle lordosis along Y, on the plane Z = 200.
pub fn torso_height(x: f64, y: f64) -> f64 {
    let (cx, cy) = (375.0, 365.0);
    let u = ((x - cx) / 330.0).clamp(-1.0, 1.0);
    let across = 110.0 * (1.0 - u * u).sqrt();
    let spine = -12.0 * (-((x - cx) / 35.0).powi(2)).exp();
    let along = 25.0 * (std::f64::consts::PI * (y - cy) / 900.0).cos();
    200.0 + across + spine + along
}

/// The dots of `rig`'s projector on `object` that the camera sees (the surface facing it,
/// within 60° of the line of sight, so that no dots merge; at least 10 pixels inside the sensor).
pub fn object_dots(rig: &SystemRig, object: &Object) -> Vec<ObjectDot> {
    let camera = camera_at_origin(rig);
    let projector = rig.projector_centred();
    let (w, h) = (f64::from(rig.grid().width), f64::from(rig.grid().height));
    projector
        .rays()
        .iter()
        .filter_map(|r| {
            let (x, normal) = object.hit(&(projector.centre() + r.offset), &r.direction)?;
            if normal.dot(&-x.normalize()) < 0.5 {
                return None;
            }
            let (col, row) = camera.world_to_pixel(&x).ok()?;
            let inside = col > 10.0 && row > 10.0 && col < w - 11.0 && row < h - 11.0;
            inside.then(|| (r.id, (col, row), x + rig.camera_centre()))
        })
        .collect()
}

/// The frame the camera sees of `dots`: radius 4 px, 150 DN over a flat 30 DN, blur 1 px,
/// noise 2 DN.
pub fn object_frame(rig: &SystemRig, dots: &[ObjectDot], seed: u64) -> image::GrayImage {
    Scene {
        width: rig.grid().width as usize,
        height: rig.grid().height as usize,
        spots: dots
            .iter()
            .map(|(_, (c, r), _)| Spot::circle(*c, *r, 4.0, 150.0))
            .collect(),
        background: Background::flat(30.0),
        falloff: 0.2,
        blur_sigma: 1.0,
        noise_sigma: 2.0,
        seed,
    }
    .render()
    .to_u8()
}

/// Three frames each of a sphere (radius 300 mm, its front 40-80 mm nearer than `depth`), a plane and the torso about `depth` mm from
/// the camera, each frame moved a little: (name, object).
pub fn test_objects(depth: f64) -> Vec<(String, Object)> {
    let mut objects = Vec::new();
    for k in 0..3 {
        let s = f64::from(k) - 1.0;
        objects.push((
            format!("sphere_{k}"),
            Object::Sphere {
                centre: [40.0 * s, -30.0 * s, -(depth + 240.0 + 20.0 * s)],
                radius: 300.0,
            },
        ));
        objects.push((
            format!("plane_{k}"),
            Object::Plane {
                depth: depth + 15.0 * s,
                tilt: 0.1 + 0.04 * s,
            },
        ));
        objects.push((
            format!("torso_{k}"),
            Object::Torso {
                depth: depth + 60.0 + 20.0 * s,
            },
        ));
    }
    objects
}

/// The plates' mean distance from the camera (mm): where the test objects are put.
pub fn plate_depth(scenario: &Scenario) -> f64 {
    let images = &scenario.plate.images;
    images.iter().map(|p| p.Z0).sum::<f64>() / images.len().max(1) as f64
}

/// Render [`test_objects`] at the [`plate_depth`] of `scenario`, seen by its [`true_rig`], into
/// `dir/images/objects/` (`sphere_0.png`, …) with their truth (`truth.csv`: object, ray, col, row,
/// x, y, z in the camera-centred frame; `objects.json`); returns the number of frames.
pub fn write_objects(scenario: &Scenario, seed: u64, dir: &Path) -> Result<usize> {
    let out = dir.join("images").join("objects");
    std::fs::create_dir_all(&out)?;
    let rig = true_rig(scenario);
    let rig = &rig;
    let objects = test_objects(plate_depth(scenario));
    let mut truth = std::io::BufWriter::new(std::fs::File::create(out.join("truth.csv"))?);
    writeln!(truth, "object,ray,col,row,x,y,z")?;
    for (k, (name, object)) in objects.iter().enumerate() {
        let dots = object_dots(rig, object);
        object_frame(rig, &dots, seed.wrapping_mul(1000).wrapping_add(k as u64))
            .save(out.join(format!("{name}.png")))?;
        for (id, (c, r), x) in &dots {
            writeln!(
                truth,
                "{name},{id},{c:.6},{r:.6},{:.6},{:.6},{:.6}",
                x.x, x.y, x.z
            )?;
        }
    }
    truth.flush()?;
    let named: std::collections::BTreeMap<_, _> = objects.iter().cloned().collect();
    std::fs::write(
        out.join("objects.json"),
        serde_json::to_string_pretty(&named)?,
    )?;
    Ok(objects.len())
}
