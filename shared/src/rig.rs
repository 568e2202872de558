//! The calibrated system: camera and projector together, ready to turn an observed dot
//! (ray id, pixel position) into a 3D point (section 2).
//!
//! Everything is held in a frame parallel to the world whose origin is the camera's perspective
//! centre X0: the projector centre is stored as X_p − X0, computed once (in f64 on the host). The
//! differences that decide the point are then small numbers, so the f32 path on the device
//! agrees with the host's f64 path to well under a micrometre at 2 m.

use crate::camera::{InnerOrientation, PixelGrid};
use crate::collinearity::{camera_ray_direction, project_camera_point, ExteriorOrientation};
use crate::intersection::{
    closest_approach, closest_approach_at, closest_lambdas, intersect_paper, lambdas_eq8_eq9,
    paper_at, Intersection,
};
use crate::projector::{Projector, ProjectorRay, Ray, RayCursor, RayStore};
use crate::{Error, Result};
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

impl<T: RealField + Copy, S: RayStore<T>> Rig<T, S> {
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

    /// Check the rig is a usable calibration (the one validation every reader of a calibration
    /// uses): every number finite, f and the pixel size positive, a sensor of at least one
    /// pixel, at least one ray. The rays themselves were checked by [`Projector::new`] (sorted,
    /// unit to [`crate::projector::UNIT_TOLERANCE`]).
    pub fn validate(&self) -> Result<()> {
        let g = &self.grid;
        let i = &self.inner;
        let finite = [g.pixel_size, g.origin_col, g.origin_row]
            .into_iter()
            .chain([i.f, i.cx, i.cy, i.k1, i.k2, i.k3, i.p1, i.p2])
            .chain(self.r_cam_world.iter().copied())
            .chain(self.camera_centre.iter().copied())
            .all(|v| v.is_finite());
        if !finite {
            return Err(Error::NotFinite);
        }
        if !(g.pixel_size > T::zero() && i.f > T::zero()) || g.width == 0 || g.height == 0 {
            return Err(Error::InvalidCalibration);
        }
        if self.projector.store().count() == 0 {
            return Err(Error::InvalidCalibration);
        }
        Ok(())
    }

    /// Eq. (1) through to pixels for a point given relative to the camera centre (world axes,
    /// mm): its observed pixel position (col, row), distortion included.
    pub fn pixel_of_centred(&self, point: &Vector3<T>) -> Result<(T, T)> {
        let cam = self.r_cam_world * point;
        let refined = project_camera_point(self.inner.f, &cam)?;
        Ok(self.grid.photo_to_pixel(self.inner.unrefine(refined)?))
    }

    /// The forward projection of a dot: where ray `id` meets the surface at distance `depth`
    /// from the camera centre along its viewing axis (camera-system z = −depth), relative to
    /// the camera centre (world axes, mm).
    pub fn point_at_depth(&self, id: u16, depth: T) -> Result<Vector3<T>> {
        let line = self.projector.ray(id)?;
        let along = self.r_cam_world.row(2);
        // Camera-system z along the ray: z(λ) = z0 + λ dz.
        let (z0, dz) = (
            along.dot(&line.point.transpose()),
            along.dot(&line.direction.transpose()),
        );
        if dz.abs() < crate::lit(1e-12) {
            return Err(Error::DegenerateGeometry);
        }
        Ok(line.at((-depth - z0) / dz))
    }

    /// [`Rig::point_at_depth`] imaged: the pixel (col, row) of dot `id` on a surface at `depth`.
    pub fn pixel_at_depth(&self, id: u16, depth: T) -> Result<(T, T)> {
        self.pixel_of_centred(&self.point_at_depth(id, depth)?)
    }

    /// The world point of dot `id` observed at pixel (col, row), with λ, λp and the miss distance.
    pub fn reconstruct(&self, id: u16, col: T, row: T, method: Method) -> Result<Intersection<T>> {
        self.reconstruct_from(&mut RayCursor::default(), id, col, row, method)
    }

    /// [`Rig::reconstruct`] for a batch sorted by ray id: the ray is found from `cursor` (see
    /// [`Projector::ray_from`]).
    pub fn reconstruct_from(
        &self,
        cursor: &mut RayCursor,
        id: u16,
        col: T,
        row: T,
        method: Method,
    ) -> Result<Intersection<T>> {
        let projector = self.projector.ray_from(cursor, id)?;
        let camera = self.camera_ray(col, row);
        let mut hit = match method {
            Method::Paper => intersect_paper(&camera, &projector)?,
            Method::ClosestApproach => closest_approach(&camera, &projector)?,
        };
        hit.point += self.camera_centre;
        Ok(hit)
    }

    /// [`Rig::reconstruct`] given the depth of the point (mm in front of the camera along its
    /// axis, λ·f of eqs 6-7: a device's answer, see
    /// [`crate::protocol::PointResult`]): λ = depth / f on the camera ray through (col, row),
    /// λp and the point from it by `method` ([`paper_at`], [`closest_approach_at`]), which
    /// is [`Rig::reconstruct`]'s point and miss distance when the depth is its.
    pub fn reconstruct_at_depth(
        &self,
        id: u16,
        col: T,
        row: T,
        depth: T,
        method: Method,
    ) -> Result<Intersection<T>> {
        let projector = self.projector.ray(id)?;
        let camera = self.camera_ray(col, row);
        let lambda = depth / self.inner.f;
        let mut hit = match method {
            Method::Paper => paper_at(&camera, &projector, lambda)?,
            Method::ClosestApproach => closest_approach_at(&camera, &projector, lambda)?,
        };
        hit.point += self.camera_centre;
        Ok(hit)
    }

    /// The depth of dot `id` observed at pixel (col, row), the ray found from `cursor`: λ·f of
    /// [`Rig::reconstruct_from`]'s intersection (mm in front of the camera along its axis; eqs
    /// 6-7: −z of the camera system is λ·f), without its point (what a device answers).
    pub fn depth_from(
        &self,
        cursor: &mut RayCursor,
        id: u16,
        col: T,
        row: T,
        method: Method,
    ) -> Result<T> {
        let projector = self.projector.ray_from(cursor, id)?;
        let camera = self.camera_ray(col, row);
        let (lambda, _) = match method {
            Method::Paper => lambdas_eq8_eq9(&camera, &projector)?,
            Method::ClosestApproach => closest_lambdas(&camera, &projector)?,
        };
        Ok(lambda * self.inner.f)
    }
}

impl<S: AsRef<[ProjectorRay<f64>]>> Rig<f64, S> {
    /// The device's f32 rig, cast as an upload does: centred in f64 first (the projector centre
    /// is X_p − X0), then every parameter rounded to f32; the camera centre too (the device
    /// answers depths, which the host places in f64, see [`Rig::reconstruct_at_depth`]). The
    /// rays are collected into `C` (a `Vec`, or a `heapless::Vec` large enough).
    pub fn cast<C>(&self) -> Result<Rig<f32, C>>
    where
        C: FromIterator<ProjectorRay<f32>> + AsRef<[ProjectorRay<f32>]>,
    {
        let c = |v: f64| v as f32;
        let g = &self.grid;
        let grid = PixelGrid {
            pixel_size: c(g.pixel_size),
            width: g.width,
            height: g.height,
            origin_col: c(g.origin_col),
            origin_row: c(g.origin_row),
        };
        let rays = self
            .projector
            .rays()
            .iter()
            .map(|r| ProjectorRay {
                id: r.id,
                direction: r.direction.map(c),
                offset: r.offset.map(c),
            })
            .collect();
        let projector = Projector::new(self.projector.centre().map(c), rays)?;
        Ok(Rig::from_centred(
            grid,
            self.inner.cast(),
            self.r_cam_world.map(c),
            self.camera_centre.map(c),
            projector,
        ))
    }
}
