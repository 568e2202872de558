//! `truth.json` ("deltaz.truth/1"): every true parameter of a simulation.

use super::Scenario;
use crate::io::camera_file::{InnerParams, PoseParams, Station};
use crate::simulate::pattern::PatternRay;
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::ExteriorOrientation;
use deltaz_shared::projector::{Projector, ProjectorRay};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// The format tag of `truth.json`.
pub const TRUTH_FORMAT: &str = "deltaz.truth/1";

/// A labelled point.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[allow(non_snake_case)]
pub struct TruthPoint {
    /// Label.
    pub point: String,
    /// X (mm).
    pub X: f64,
    /// Y (mm).
    pub Y: f64,
    /// Z (mm).
    pub Z: f64,
}

impl TruthPoint {
    /// A labelled point from a vector.
    pub fn new(point: &str, xyz: &Vector3<f64>) -> Self {
        Self {
            point: point.to_owned(),
            X: xyz.x,
            Y: xyz.y,
            Z: xyz.z,
        }
    }

    /// The coordinates.
    pub fn xyz(&self) -> Vector3<f64> {
        Vector3::new(self.X, self.Y, self.Z)
    }
}

/// The true camera (keys of camera.json).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TruthCamera {
    /// Inner orientation (the keys of camera.json's `inner`).
    pub inner: InnerParams,
    /// Pixel size (mm).
    pub pixel_size: f64,
    /// [width, height] (pixels).
    pub image_size: [u32; 2],
    /// Pixel [col, row] of the photo origin.
    pub origin: [f64; 2],
}

/// A rigid motion X' = rotation · X + translation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Motion {
    /// Rotation matrix, row by row.
    pub rotation: [[f64; 3]; 3],
    /// Translation (mm).
    pub translation: [f64; 3],
}

impl Motion {
    /// X' = rotation · X + translation.
    pub fn apply(&self, x: &Vector3<f64>) -> Vector3<f64> {
        Matrix3::from(self.rotation).transpose() * x + Vector3::from(self.translation)
    }
}

/// One plate image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TruthPlateImage {
    /// Image label (p1, p2, …).
    pub image: String,
    /// The camera's exterior orientation in the plate frame (Table 2 for the paper).
    pub camera: PoseParams,
    /// Plate frame → global frame (the 1st plate image's): X_G = R1ᵀ R_k (X_P − X0_k) + X0_1.
    pub plate_to_global: Motion,
}

/// The calibration plate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TruthPlate {
    /// Its images.
    pub images: Vec<TruthPlateImage>,
}

/// One projector ray, in the camera system and in the global frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TruthRay {
    /// Ray id.
    pub id: u16,
    /// Grid row of its dot on the slide.
    pub row: u16,
    /// Grid column of its dot on the slide.
    pub col: u16,
    /// Unit direction (l, m, n) in the camera system.
    pub camera: [f64; 3],
    /// Offset of the ray's point from the projector centre, camera system (mm).
    pub offset_camera: [f64; 3],
    /// Unit direction (l, m, n) in the global frame.
    pub global: [f64; 3],
    /// Offset of the ray's point from the projector centre, global frame (mm).
    pub offset_global: [f64; 3],
}

/// The projector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TruthProjector {
    /// Centre in the camera system (Table 3's first line for the paper).
    pub centre_camera: [f64; 3],
    /// Centre in the global frame (Table 3's second line for the paper).
    pub centre_global: [f64; 3],
    /// The camera's pose in the global frame (the 1st plate image's pose).
    pub camera_global: PoseParams,
    /// The rays, sorted by id.
    pub rays: Vec<TruthRay>,
}

/// An observation made a gross error.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TruthOutlier {
    /// Image label.
    pub image: String,
    /// Point label.
    pub point: String,
}

/// The noise that was added.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TruthNoise {
    /// σ of image coordinates (px).
    pub image_sigma_px: f64,
    /// σ of the field's control coordinates (mm).
    pub control_sigma_mm: f64,
    /// σ of the plate's control coordinates (mm).
    pub plate_control_sigma_mm: f64,
    /// The target-field observations made gross errors.
    pub outliers: Vec<TruthOutlier>,
}

/// Every true parameter of a simulation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Truth {
    /// Always [`TRUTH_FORMAT`].
    pub format: String,
    /// The scenario's name.
    pub scenario: String,
    /// The seed.
    pub seed: u64,
    /// The camera.
    pub camera: TruthCamera,
    /// The target field's stations (field frame).
    pub stations: Vec<Station>,
    /// True coordinates of field targets (field frame) and plate control (plate frame).
    pub points: Vec<TruthPoint>,
    /// The plate images.
    pub plate: TruthPlate,
    /// The projector.
    pub projector: TruthProjector,
    /// The noise.
    pub noise: TruthNoise,
}

impl Truth {
    pub(super) fn new(
        scenario: &Scenario,
        seed: u64,
        stations: Vec<Station>,
        points: Vec<TruthPoint>,
        rays: &[PatternRay],
        outliers: Vec<TruthOutlier>,
    ) -> Self {
        let first: ExteriorOrientation<f64> = scenario.plate.images[0].into();
        let r1 = first.r_cam_world();
        let images = scenario
            .plate
            .images
            .iter()
            .enumerate()
            .map(|(k, pose)| {
                let eo: ExteriorOrientation<f64> = (*pose).into();
                let rotation = r1.transpose() * eo.r_cam_world();
                let translation = first.centre - rotation * eo.centre;
                TruthPlateImage {
                    image: format!("p{}", k + 1),
                    camera: *pose,
                    plate_to_global: Motion {
                        rotation: rotation.transpose().into(),
                        translation: translation.into(),
                    },
                }
            })
            .collect();
        let centre_camera = Vector3::from(scenario.rig.projector_centre);
        let to_global = |v: &Vector3<f64>| -> [f64; 3] { (r1.transpose() * v).into() };
        let rays = rays
            .iter()
            .map(|r| TruthRay {
                id: r.id,
                row: r.row,
                col: r.col,
                camera: r.direction.into(),
                offset_camera: r.offset.into(),
                global: to_global(&r.direction),
                offset_global: to_global(&r.offset),
            })
            .collect();
        Truth {
            format: TRUTH_FORMAT.into(),
            scenario: scenario.name.clone(),
            seed,
            camera: TruthCamera {
                inner: scenario.camera.inner,
                pixel_size: scenario.camera.pixel_size,
                image_size: scenario.camera.image_size,
                origin: scenario.camera.origin,
            },
            stations,
            points,
            plate: TruthPlate { images },
            projector: TruthProjector {
                centre_camera: centre_camera.into(),
                centre_global: first.camera_to_world(&centre_camera).into(),
                camera_global: scenario.plate.images[0],
                rays,
            },
            noise: TruthNoise {
                image_sigma_px: scenario.noise.image_sigma_px,
                control_sigma_mm: scenario.field.control_sigma,
                plate_control_sigma_mm: scenario.plate.control_sigma,
                outliers,
            },
        }
    }

    /// The true pixel mapping.
    pub fn grid(&self) -> PixelGrid<f64> {
        PixelGrid {
            pixel_size: self.camera.pixel_size,
            width: self.camera.image_size[0],
            height: self.camera.image_size[1],
            origin_col: self.camera.origin[0],
            origin_row: self.camera.origin[1],
        }
    }

    /// The true inner orientation.
    pub fn inner(&self) -> InnerOrientation<f64> {
        self.camera.inner.into()
    }

    /// The true projector in the camera system (centre, directions and offsets).
    pub fn projector_camera(
        &self,
    ) -> deltaz_shared::Result<Projector<f64, Vec<ProjectorRay<f64>>>> {
        let p = &self.projector;
        let rays = p.rays.iter().map(|r| ProjectorRay {
            id: r.id,
            direction: Vector3::from(r.camera),
            offset: Vector3::from(r.offset_camera),
        });
        Projector::new(Vector3::from(p.centre_camera), rays.collect())
    }

    /// The true projector in the global frame (the 1st plate image's, as the paper's Tables 3
    /// and 4).
    pub fn projector_global(
        &self,
    ) -> deltaz_shared::Result<Projector<f64, Vec<ProjectorRay<f64>>>> {
        let p = &self.projector;
        let rays = p.rays.iter().map(|r| ProjectorRay {
            id: r.id,
            direction: Vector3::from(r.global),
            offset: Vector3::from(r.offset_global),
        });
        Projector::new(Vector3::from(p.centre_global), rays.collect())
    }

    /// A true point by label.
    pub fn point(&self, label: &str) -> Option<Vector3<f64>> {
        self.points
            .iter()
            .find(|p| p.point == label)
            .map(TruthPoint::xyz)
    }
}
