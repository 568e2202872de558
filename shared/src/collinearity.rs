//! Exterior orientation (eq. 3), the collinearity projection (eq. 1) and the camera ray
//! (eqs 4, 6, 7).

use crate::camera::{InnerOrientation, PixelGrid};
use crate::rotation::rotation_matrix;
use crate::{Error, Result};
use nalgebra::{Matrix3, RealField, Vector2, Vector3};

/// Eq. (3): the exterior orientation [κ, φ, ω, X0, Y0, Z0] of a camera (rad, mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExteriorOrientation<T: RealField> {
    /// κ (rad), rotation about z.
    pub kappa: T,
    /// φ (rad), rotation about y.
    pub phi: T,
    /// ω (rad), rotation about x.
    pub omega: T,
    /// The perspective centre (X0, Y0, Z0) in world coordinates (mm).
    pub centre: Vector3<T>,
}

impl<T: RealField + Copy> ExteriorOrientation<T> {
    /// R of eq. (2) for these angles: `x_cam = R (X − X0)`.
    pub fn r_cam_world(&self) -> Matrix3<T> {
        rotation_matrix(self.kappa, self.phi, self.omega)
    }

    /// A world point in the camera system: x_cam = R (X − X0).
    pub fn world_to_camera(&self, world: &Vector3<T>) -> Vector3<T> {
        self.r_cam_world() * (world - self.centre)
    }

    /// A camera-system point in world coordinates: X = Rᵀ x_cam + X0.
    pub fn camera_to_world(&self, cam: &Vector3<T>) -> Vector3<T> {
        self.r_cam_world().transpose() * cam + self.centre
    }
}

/// Eq. (1): refined image coordinates (mm) of a point given in the camera system,
/// x = −f · x_cam / z_cam, y = −f · y_cam / z_cam. A point at or behind the principal plane
/// (z_cam ≥ 0) has no image.
pub fn project_camera_point<T: RealField + Copy>(f: T, cam: &Vector3<T>) -> Result<Vector2<T>> {
    if cam.z.partial_cmp(&T::zero()) != Some(core::cmp::Ordering::Less) {
        return Err(Error::BehindCamera);
    }
    Ok(Vector2::new(-f * cam.x / cam.z, -f * cam.y / cam.z))
}

/// Eq. (7): the direction (u, v, w) of the camera ray through refined image coordinates, in the
/// world system: (u, v, w)ᵀ = Rᵀ (x, y, −f)ᵀ. With eq. (6) the ray is X = X0 + λ (u, v, w).
pub fn camera_ray_direction<T: RealField + Copy>(
    r_cam_world: &Matrix3<T>,
    f: T,
    refined: Vector2<T>,
) -> Vector3<T> {
    r_cam_world.transpose() * Vector3::new(refined.x, refined.y, -f)
}

/// A complete camera: raster, inner and exterior orientation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera<T: RealField> {
    /// Pixel ↔ photo coordinates.
    pub grid: PixelGrid<T>,
    /// Focal length, principal point, distortion.
    pub inner: InnerOrientation<T>,
    /// Pose in the world.
    pub exterior: ExteriorOrientation<T>,
}

impl<T: RealField + Copy> Camera<T> {
    /// Eq. (1) through to pixels: the observed pixel position (col, row) of a world point,
    /// distortion and principal point included.
    pub fn world_to_pixel(&self, world: &Vector3<T>) -> Result<(T, T)> {
        let refined = project_camera_point(self.inner.f, &self.exterior.world_to_camera(world))?;
        Ok(self.grid.photo_to_pixel(self.inner.unrefine(refined)?))
    }

    /// Refined image coordinates (mm) of an observed pixel position.
    pub fn pixel_to_refined(&self, col: T, row: T) -> Vector2<T> {
        self.inner.refine(self.grid.pixel_to_photo(col, row))
    }

    /// Eqs (6)-(7): the world direction (u, v, w) of the ray through an observed pixel; the ray is
    /// X = X0 + λ (u, v, w).
    pub fn pixel_to_ray_direction(&self, col: T, row: T) -> Vector3<T> {
        camera_ray_direction(
            &self.exterior.r_cam_world(),
            self.inner.f,
            self.pixel_to_refined(col, row),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projection_and_ray_agree() {
        use crate::paper::{table2_exterior, DC40_GRID, TABLE1_INNER};
        let cam = Camera {
            grid: DC40_GRID,
            inner: TABLE1_INNER,
            exterior: table2_exterior(0),
        };
        let world = Vector3::new(310.0, 83.0, 200.0);
        let (c, r) = cam.world_to_pixel(&world).unwrap();
        let dir = cam.pixel_to_ray_direction(c, r);
        let lambda = (world.z - cam.exterior.centre.z) / dir.z;
        let back = cam.exterior.centre + dir * lambda;
        assert!((back - world).norm() < 1e-9, "{back} vs {world}");
        let behind = Vector3::new(375.0, 364.0, 1900.0);
        assert_eq!(cam.world_to_pixel(&behind), Err(Error::BehindCamera));
    }
}
