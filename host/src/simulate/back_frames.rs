//! Frames of a back through the image path: the dots any rig's projector casts on a
//! [`BackModel`], rendered as its camera sees them, with every dot's truth.
//!
//! The model lives in the camera system (x right, y up, z toward the camera, the camera at the
//! origin); a rig in another frame (the paper's plate frame) is carried into it through its
//! camera's pose, x_cam = R (X − X0). A ray's dot is seen when the camera's line of sight reaches
//! the same point (no arm or fold of the back in between) and neither the ray nor the line of
//! sight meets the surface more obliquely than [`MAX_INCIDENCE_DEG`] from its normal. Each dot
//! is drawn as the footprint of the projector's light cone ([`ImageSpec::dot_angle`]) on the
//! surface's tangent plane, imaged affinely about its centre's image (as the plate images'
//! dots, [`super::images`]), on the plate images' background, blur and noise. The `back`
//! scenario's `[back]` section ([`BackSpec`]) names the subject and its frames, standing and
//! bent forward, each swayed.

use super::back::{BackModel, Deformity, Part, Pose, Posture};
use super::images::{camera_at_origin, ellipse, on_sensor, scene, true_rig, ImageSpec};
use super::pattern::ID_STRIDE;
use super::Scenario;
use crate::io::system_file::SystemRig;
use anyhow::Result;
use deltaz_measure::render::{Rendered, Spot};
use nalgebra::{Vector2, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::Path;

/// Dots whose ray or line of sight meets the surface more obliquely than this (degrees from
/// the normal) are not drawn: their footprints smear into their neighbours'.
pub const MAX_INCIDENCE_DEG: f64 = 75.0;

/// A backdrop stands this far beyond the subject's distance at least (mm): clear of the trunk
/// and the arms, standing or bent forward.
const BACKDROP_BEHIND_MM: f64 = 150.0;

/// The subject of a scenario's back frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BackSpec {
    /// The deformity: `straight`, `thoracic`, `lumbar`, `double` or `severe`
    /// ([`Deformity::all`]).
    pub deformity: String,
    /// Distance of the back's centre from the camera (mm).
    pub distance: f64,
    /// Frames standing (`standing_0`, …).
    pub standing_frames: u32,
    /// Frames bent forward (`bent_0`, …).
    pub bent_frames: u32,
    /// The sway between frames: each frame's translation along each axis is uniform in ± this
    /// (mm) …
    pub sway_mm: f64,
    /// … and its rotation about each axis (degrees).
    pub sway_deg: f64,
    /// The working depth range [near, far] the rig identifies over (mm from the camera).
    pub depth_range: [f64; 2],
    /// The dots' brightness on the skin (DN), in place of the plate images'.
    pub dot_amplitude: f64,
    /// The sensor noise of the back frames (DN).
    pub noise_sigma: f64,
    /// A wall behind the subject, square to the camera's axis this far from the camera (mm);
    /// none if absent. Within the depth range its dots are identified (and the analysis leaves
    /// it out as a plane); beyond it some are identified to a wrong ray.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub backdrop: Option<f64>,
}

impl BackSpec {
    /// Checks the deformity's name, the frame counts (at most 100 each), the sway (≥ 0), the
    /// depth range (0 < near < distance < far) and the backdrop (behind the subject).
    pub fn validate(&self) -> Result<()> {
        let names: Vec<&str> = Deformity::all().iter().map(|d| d.name).collect();
        anyhow::ensure!(
            Deformity::named(&self.deformity).is_some(),
            "back.deformity `{}` is none of {}",
            self.deformity,
            names.join(", ")
        );
        anyhow::ensure!(
            self.standing_frames <= 100 && self.bent_frames <= 100,
            "back: at most 100 frames of each posture"
        );
        anyhow::ensure!(
            self.sway_mm >= 0.0 && self.sway_deg >= 0.0,
            "back: the sway must not be negative"
        );
        let [near, far] = self.depth_range;
        anyhow::ensure!(
            0.0 < near && near < self.distance && self.distance < far,
            "back.depth_range must hold the back: 0 < near < distance < far"
        );
        anyhow::ensure!(
            self.dot_amplitude > 0.0 && self.noise_sigma >= 0.0,
            "back: dot_amplitude must be positive and noise_sigma not negative"
        );
        if let Some(wall) = self.backdrop {
            anyhow::ensure!(
                wall > self.distance + BACKDROP_BEHIND_MM,
                "back.backdrop {wall} mm must stand behind the subject: more than \
                 {BACKDROP_BEHIND_MM} mm beyond its distance ({} mm)",
                self.distance
            );
        }
        Ok(())
    }

    /// The look of the back frames: the plate images' (`plates`) with the dots' brightness on
    /// the skin and the frames' sensor noise.
    pub fn image_spec(&self, plates: &ImageSpec) -> ImageSpec {
        ImageSpec {
            dot_amplitude: self.dot_amplitude,
            noise_sigma: self.noise_sigma,
            ..*plates
        }
    }

    /// The frames' models, labelled `standing_k` and `bent_k`, each swayed by a draw of the
    /// sway (seeded by `seed`).
    pub fn models(&self, seed: u64) -> Vec<(String, BackModel)> {
        let deformity = Deformity::named(&self.deformity).unwrap_or_else(Deformity::straight);
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xbac4);
        let sway = |rng: &mut ChaCha8Rng| {
            let mut draw = |half: f64| {
                Vector3::from_fn(|_, _| {
                    if half > 0.0 {
                        rng.random_range(-half..=half)
                    } else {
                        0.0
                    }
                })
            };
            let rotation = draw(self.sway_deg.to_radians());
            Pose {
                rotation,
                translation: draw(self.sway_mm),
            }
        };
        let standing = BackModel {
            distance: self.distance,
            backdrop: self.backdrop,
            ..BackModel::standing(deformity.clone())
        };
        let bent = BackModel {
            posture: Posture::ForwardBent,
            ..standing.clone()
        };
        let mut models = Vec::new();
        for (name, base, count) in [
            ("standing", &standing, self.standing_frames),
            ("bent", &bent, self.bent_frames),
        ] {
            for k in 0..count {
                models.push((format!("{name}_{k}"), base.with_pose(sway(&mut rng))));
            }
        }
        models
    }
}

/// A dot on the back as the camera sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BackDot {
    /// Its ray.
    pub id: u16,
    /// The image of its centre (col, row; px).
    pub pixel: (f64, f64),
    /// Its true point (camera system, mm).
    pub point: Vector3<f64>,
    /// What it lies on.
    pub part: Part,
}

/// A rendered frame of a back.
#[derive(Debug, Clone)]
pub struct BackFrame {
    /// Its label.
    pub label: String,
    /// The model it shows (the truth).
    pub model: BackModel,
    /// The dots drawn.
    pub dots: Vec<BackDot>,
    /// The image.
    pub image: Rendered,
}

/// The dots of `rig`'s projector on `model` its camera sees, each with the spot it makes in the
/// image (`spec`'s light cone, the marker node's larger).
pub fn back_spots(rig: &SystemRig, model: &BackModel, spec: &ImageSpec) -> Vec<(BackDot, Spot)> {
    let camera = camera_at_origin(rig);
    let r = rig.r_cam_world();
    let projector = rig.projector_centred();
    let cos_max = MAX_INCIDENCE_DEG.to_radians().cos();
    let marker = spec.marker_node.map(|(row, col)| row * ID_STRIDE + col);
    let pixel = |x: &Vector3<f64>| {
        let (c, r) = camera.world_to_pixel(x).ok()?;
        Some(Vector2::new(c, r))
    };
    projector
        .rays()
        .iter()
        .filter_map(|ray| {
            let start = r * (projector.centre() + ray.offset);
            let dir = (r * ray.direction).normalize();
            let hit = model.hit(&start, &dir)?;
            let sight = hit.point.normalize();
            let seen = model.hit(&Vector3::zeros(), &sight)?;
            let lit = -hit.normal.dot(&dir) > cos_max;
            let faced = -hit.normal.dot(&sight) > cos_max;
            if (seen.point - hit.point).norm() > 0.5 || !lit || !faced {
                return None;
            }
            // The light cone's footprint on the tangent plane, imaged about the centre.
            let on_plane = |d: Vector3<f64>| {
                let t = hit.normal.dot(&(hit.point - start)) / hit.normal.dot(&d);
                pixel(&(start + d * t))
            };
            let e1 = dir.cross(&Vector3::y()).normalize();
            let e2 = dir.cross(&e1);
            let a = spec.dot_angle
                * if marker == Some(ray.id) {
                    spec.marker_scale
                } else {
                    1.0
                };
            let half = |e: Vector3<f64>| {
                Some(
                    (on_plane((dir + e * a).normalize())? - on_plane((dir - e * a).normalize())?)
                        / 2.0,
                )
            };
            let centre = pixel(&hit.point)?;
            let spot = ellipse(
                (centre.x, centre.y),
                half(e1)?,
                half(e2)?,
                spec.dot_amplitude,
            );
            on_sensor(&camera, &spot).then_some((
                BackDot {
                    id: ray.id,
                    pixel: (centre.x, centre.y),
                    point: hit.point,
                    part: hit.part,
                },
                spot,
            ))
        })
        .collect()
}

/// `model` seen through `rig` (any rig: the back scenario's, the paper's), rendered with
/// `spec` and noise seeded by `seed`.
pub fn render_back(
    rig: &SystemRig,
    label: &str,
    model: &BackModel,
    spec: &ImageSpec,
    seed: u64,
) -> BackFrame {
    let (dots, spots): (Vec<_>, Vec<_>) = back_spots(rig, model, spec).into_iter().unzip();
    let image = scene(&camera_at_origin(rig), spots, spec, seed).render();
    BackFrame {
        label: label.to_owned(),
        model: model.clone(),
        dots,
        image,
    }
}

/// [`render_back`] of each labelled model, in parallel; frame k's noise seeded by
/// `seed`·1000 + 500 + k.
pub fn render_backs(
    rig: &SystemRig,
    models: &[(String, BackModel)],
    spec: &ImageSpec,
    seed: u64,
) -> Vec<BackFrame> {
    models
        .par_iter()
        .enumerate()
        .map(|(k, (label, model))| {
            let noise = seed.wrapping_mul(1000).wrapping_add(500 + k as u64);
            render_back(rig, label, model, spec, noise)
        })
        .collect()
}

/// Render the frames of `scenario`'s `[back]` (none without it), seen by its [`true_rig`] and
/// drawn as [`BackSpec::image_spec`] of the plate images' `spec`, into `dir/images/back/` (`standing_0.png`, …, `bent_0.png`, …) with their truth:
/// `truth.csv` (frame, ray, col, row, x, y, z in the camera system, part) and `back.json` (the
/// subject, the depth range and each frame's posture and sway); returns the number of frames.
pub fn write_back_frames(
    scenario: &Scenario,
    seed: u64,
    spec: &ImageSpec,
    dir: &Path,
) -> Result<usize> {
    let Some(back) = &scenario.back else {
        return Ok(0);
    };
    let out = dir.join("images").join("back");
    std::fs::create_dir_all(&out)?;
    let models = back.models(seed);
    let spec = &back.image_spec(spec);
    let frames = render_backs(&true_rig(scenario), &models, spec, seed);
    let mut truth = std::io::BufWriter::new(std::fs::File::create(out.join("truth.csv"))?);
    writeln!(truth, "frame,ray,col,row,x,y,z,part")?;
    let mut listed = Vec::new();
    for f in &frames {
        f.image
            .save_png(&out.join(format!("{}.png", f.label)), spec.depth)?;
        for d in &f.dots {
            let part = match d.part {
                Part::Back => "back",
                Part::Arm => "arm",
                Part::Backdrop => "backdrop",
            };
            let (x, (c, r)) = (d.point, d.pixel);
            writeln!(
                truth,
                "{},{},{c:.6},{r:.6},{:.6},{:.6},{:.6},{part}",
                f.label, d.id, x.x, x.y, x.z
            )?;
        }
        let pose = f.model.pose;
        listed.push(serde_json::json!({
            "frame": f.label,
            "posture": match f.model.posture {
                Posture::Standing => "standing",
                Posture::ForwardBent => "forward-bent",
            },
            "dots": f.dots.len(),
            "sway_rotation_deg": pose.rotation.map(f64::to_degrees).as_slice(),
            "sway_translation_mm": pose.translation.as_slice(),
        }));
    }
    truth.flush()?;
    let json = serde_json::json!({
        "deformity": back.deformity,
        "distance_mm": back.distance,
        "depth_range_mm": back.depth_range,
        "frames": listed,
    });
    std::fs::write(
        out.join("back.json"),
        serde_json::to_string_pretty(&json)? + "\n",
    )?;
    Ok(frames.len())
}
