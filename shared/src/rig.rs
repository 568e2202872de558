//! The calibrated system: camera and projector together, ready to turn an observed dot
//! (ray id, pixel position) into a 3D point (section 2).
//!
//! Everything is held in a frame parallel to the world whose origin is the camera's perspective
//! centre X0: the projector centre is stored as X_p − X0, computed once (in f64 on the host). The
//! differences that decide the point are then small numbers, so the f32 path on the device
//! agrees with the host's f64 path to well under a micrometre at 2 m.

use crate::camera::{InnerOrientation, PixelGrid};
use crate::collinearity::{camera_ray_direction, ExteriorOrientation};
use crate::intersection::{closest_approach, intersect_paper, Intersection};
use crate::projector::{Projector, ProjectorRay, Ray};
use crate::Result;
use nalgebra::{Matrix3, RealField, Vector3};

/// How the two rays are intersected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// Eqs (8)-(9): X and Z equations only, as in the paper.
    Paper,
    /// Least-squares closest approach on all three coordinates.
    ClosestApproach,
}

/// A calibrated camera-projector system, centred on the camera (see the module docs).
#[derive(Debug, Clone)]
pub struct Rig<T: RealField, S> {
    grid: PixelGrid<T>,
    inner: InnerOrientation<T>,
    r_cam_world: Matrix3<T>,
    camera_centre: Vector3<T>,
    projector: Projector<T, S>,
}

impl<T: RealField + Copy, S: AsRef<[ProjectorRay<T>]>> Rig<T, S> {
    /// A rig from world-frame parameters. The projector is recentred on the camera here, in `T`:
    /// build in f64 and use [`Rig::from_centred`] to make an f32 rig.
    pub fn new(
        grid: PixelGrid<T>,
        inner: InnerOrientation<T>,
        exterior: &ExteriorOrientation<T>,
        projector: Projector<T, S>,
    ) -> Self {
        let camera_centre = exterior.centre;
        Self {
            grid,
            inner,
            r_cam_world: exterior.r_cam_world(),
            camera_centre,
            projector: projector.shifted(-camera_centre),
        }
    }

    /// A rig from parameters already centred: `projector`'s centre is X_p − X0.
    pub fn from_centred(
        grid: PixelGrid<T>,
        inner: InnerOrientation<T>,
        r_cam_world: Matrix3<T>,
        camera_centre: Vector3<T>,
        projector: Projector<T, S>,
    ) -> Self {
        Self {
            grid,
            inner,
            r_cam_world,
            camera_centre,
            projector,
        }
    }

    /// The camera's perspective centre X0 (world, mm).
    pub fn camera_centre(&self) -> Vector3<T> {
        self.camera_centre
    }

    /// R of eq. (2) (world → camera).
    pub fn r_cam_world(&self) -> &Matrix3<T> {
        &self.r_cam_world
    }

    /// The projector, its centre relative to the camera centre (X_p − X0).
    pub fn projector_centred(&self) -> &Projector<T, S> {
        &self.projector
    }

    /// The raster.
    pub fn grid(&self) -> &PixelGrid<T> {
        &self.grid
    }

    /// The inner orientation.
    pub fn inner(&self) -> &InnerOrientation<T> {
        &self.inner
    }

    /// The camera ray through an observed pixel (eqs 6-7), its origin at the frame origin (X0).
    pub fn camera_ray(&self, col: T, row: T) -> Ray<T> {
        let refined = self.inner.refine(self.grid.pixel_to_photo(col, row));
        Ray {
            point: Vector3::zeros(),
            direction: camera_ray_direction(&self.r_cam_world, self.inner.f, refined),
        }
    }

    /// The world point of dot `id` observed at pixel (col, row), with λ, λp and the miss distance.
    pub fn reconstruct(&self, id: u16, col: T, row: T, method: Method) -> Result<Intersection<T>> {
        let projector = self.projector.ray(id)?;
        let camera = self.camera_ray(col, row);
        let mut hit = match method {
            Method::Paper => intersect_paper(&camera, &projector)?,
            Method::ClosestApproach => closest_approach(&camera, &projector)?,
        };
        hit.point += self.camera_centre;
        Ok(hit)
    }
}
