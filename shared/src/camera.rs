//! Inner orientation: pixel ↔ photo coordinates and image refinement (principal point and
//! Brown-Conrady lens distortion, the close-range photogrammetry convention of Fraser).

use crate::{lit, sqrt, Error, Result};
use nalgebra::{Matrix2, RealField, Vector2};
use serde::{Deserialize, Serialize};

/// How pixels map to photo coordinates: the sensor's raster.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PixelGrid<T> {
    /// Pixel size s (mm), square pixels.
    pub pixel_size: T,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Column c0 of the photo-coordinate origin (pixels, may be fractional).
    pub origin_col: T,
    /// Row r0 of the photo-coordinate origin (pixels, may be fractional).
    pub origin_row: T,
}

impl<T: RealField + Copy> PixelGrid<T> {
    /// Photo coordinates (mm, y up) of a pixel position: x = (col − c0)·s, y = −(row − r0)·s.
    pub fn pixel_to_photo(&self, col: T, row: T) -> Vector2<T> {
        Vector2::new(
            (col - self.origin_col) * self.pixel_size,
            -(row - self.origin_row) * self.pixel_size,
        )
    }

    /// Pixel position (col, row) of photo coordinates (mm, y up); the inverse of
    /// [`PixelGrid::pixel_to_photo`].
    pub fn photo_to_pixel(&self, photo: Vector2<T>) -> (T, T) {
        (
            photo.x / self.pixel_size + self.origin_col,
            -photo.y / self.pixel_size + self.origin_row,
        )
    }

    /// Whether a pixel position lies on the sensor (pixel centres 0..w−1, 0..h−1, ± half a pixel).
    pub fn contains(&self, col: T, row: T) -> bool {
        let half = lit::<T>(0.5);
        col >= -half
            && row >= -half
            && col <= lit::<T>(f64::from(self.width)) - half
            && row <= lit::<T>(f64::from(self.height)) - half
    }
}

/// Camera inner orientation (mm): focal length, principal point and Brown-Conrady distortion.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct InnerOrientation<T> {
    /// Focal length f (mm).
    pub f: T,
    /// Principal point x offset cx (mm, photo coordinates).
    pub cx: T,
    /// Principal point y offset cy (mm, photo coordinates).
    pub cy: T,
    /// Radial distortion k1 (mm⁻²).
    pub k1: T,
    /// Radial distortion k2 (mm⁻⁴).
    pub k2: T,
    /// Radial distortion k3 (mm⁻⁶).
    pub k3: T,
    /// Decentring distortion p1 (mm⁻¹).
    pub p1: T,
    /// Decentring distortion p2 (mm⁻¹).
    pub p2: T,
}

impl<T: RealField + Copy> InnerOrientation<T> {
    /// An ideal camera of focal length `f`: no principal point offset, no distortion.
    pub fn ideal(f: T) -> Self {
        let z = T::zero();
        Self {
            f,
            cx: z,
            cy: z,
            k1: z,
            k2: z,
            k3: z,
            p1: z,
            p2: z,
        }
    }

    /// The same inner orientation in another scalar type.
    pub fn cast<U: RealField + Copy>(&self) -> InnerOrientation<U>
    where
        T: Into<f64>,
    {
        let c = |v: T| -> U { nalgebra::convert(v.into()) };
        InnerOrientation {
            f: c(self.f),
            cx: c(self.cx),
            cy: c(self.cy),
            k1: c(self.k1),
            k2: c(self.k2),
            k3: c(self.k3),
            p1: c(self.p1),
            p2: c(self.p2),
        }
    }

    /// The correction added to principal-point-reduced coordinates (x̄, ȳ):
    /// Δx = x̄(k1 r² + k2 r⁴ + k3 r⁶) + p1(r² + 2x̄²) + 2 p2 x̄ȳ,
    /// Δy = ȳ(k1 r² + k2 r⁴ + k3 r⁶) + p2(r² + 2ȳ²) + 2 p1 x̄ȳ, r² = x̄² + ȳ².
    pub fn distortion(&self, reduced: Vector2<T>) -> Vector2<T> {
        let (x, y) = (reduced.x, reduced.y);
        let two = lit::<T>(2.0);
        let r2 = x * x + y * y;
        let radial = r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        Vector2::new(
            x * radial + self.p1 * (r2 + two * x * x) + two * self.p2 * x * y,
            y * radial + self.p2 * (r2 + two * y * y) + two * self.p1 * x * y,
        )
    }

    /// Image refinement: observed photo coordinates (mm) → refined coordinates, those of eq. (1):
    /// x̄ = x − cx, ȳ = y − cy, refined = (x̄, ȳ) + [`distortion`](Self::distortion)(x̄, ȳ).
    pub fn refine(&self, observed: Vector2<T>) -> Vector2<T> {
        let reduced = observed - Vector2::new(self.cx, self.cy);
        reduced + self.distortion(reduced)
    }

    /// The inverse of [`refine`](Self::refine): refined coordinates → observed photo coordinates,
    /// by Newton's method on the 2 × 2 Jacobian of the refinement.
    pub fn unrefine(&self, refined: Vector2<T>) -> Result<Vector2<T>> {
        if !(refined.x.is_finite() && refined.y.is_finite()) {
            return Err(Error::NotFinite);
        }
        // 1e-13 relative in f64; a few ulps where the scalar cannot reach that (f32 on the device).
        let tol = lit::<T>(1e-13).max(T::default_epsilon() * lit::<T>(8.0))
            * (T::one() + sqrt(refined.norm_squared()));
        let mut reduced = refined;
        for _ in 0..30 {
            let residual = reduced + self.distortion(reduced) - refined;
            if sqrt(residual.norm_squared()) <= tol {
                return Ok(reduced + Vector2::new(self.cx, self.cy));
            }
            let step = self
                .refine_jacobian(reduced)
                .try_inverse()
                .ok_or(Error::RefinementDiverged)?
                * residual;
            reduced -= step;
        }
        Err(Error::RefinementDiverged)
    }

    /// ∂refined/∂reduced: the Jacobian of the refinement with respect to (x̄, ȳ).
    pub fn refine_jacobian(&self, reduced: Vector2<T>) -> Matrix2<T> {
        let (x, y) = (reduced.x, reduced.y);
        let (two, three) = (lit::<T>(2.0), lit::<T>(3.0));
        let r2 = x * x + y * y;
        let radial = r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        // d(radial)/d(r²)
        let dradial = self.k1 + r2 * (two * self.k2 + three * r2 * self.k3);
        let (dr2x, dr2y) = (two * x, two * y);
        let six = lit::<T>(6.0);
        Matrix2::new(
            T::one() + radial + x * dradial * dr2x + six * self.p1 * x + two * self.p2 * y,
            x * dradial * dr2y + two * self.p1 * y + two * self.p2 * x,
            y * dradial * dr2x + two * self.p2 * x + two * self.p1 * y,
            T::one() + radial + y * dradial * dr2y + six * self.p2 * y + two * self.p1 * x,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dc40() -> (PixelGrid<f64>, InnerOrientation<f64>) {
        let grid = PixelGrid {
            pixel_size: 0.045,
            width: 768,
            height: 512,
            origin_col: 378.0,
            origin_row: 252.0,
        };
        let inner = InnerOrientation {
            f: 46.981,
            cx: -0.133,
            cy: 0.208,
            k1: 0.000063,
            k2: -2e-8,
            k3: 1e-11,
            p1: 2e-5,
            p2: -1.5e-5,
        };
        (grid, inner)
    }

    #[test]
    fn pixel_photo_round_trip_and_axes() {
        let (grid, _) = dc40();
        let p = grid.pixel_to_photo(378.0 + 10.0, 252.0 + 20.0);
        assert!(
            (p.x - 0.45).abs() < 1e-12 && (p.y + 0.9).abs() < 1e-12,
            "y is up"
        );
        let (c, r) = grid.photo_to_pixel(p);
        assert!((c - 388.0).abs() < 1e-12 && (r - 272.0).abs() < 1e-12);
        assert!(grid.contains(-0.5, 511.5) && !grid.contains(767.6, 0.0));
    }

    /// Refinement and its inverse agree to 1e-9 mm over the whole frame.
    #[test]
    fn refinement_round_trip_whole_frame() {
        let (grid, inner) = dc40();
        let mut worst = 0.0_f64;
        for row in (0..512).step_by(7) {
            for col in (0..768).step_by(7) {
                let observed = grid.pixel_to_photo(f64::from(col), f64::from(row));
                let back = inner.unrefine(inner.refine(observed)).unwrap();
                worst = worst.max((back - observed).norm());
            }
        }
        assert!(worst < 1e-9, "worst round trip {worst} mm");
    }

    #[test]
    fn refinement_formula_and_jacobian() {
        let (_, inner) = dc40();
        let obs = Vector2::new(12.0, -7.5);
        let (x, y) = (obs.x - inner.cx, obs.y - inner.cy);
        let r2 = x * x + y * y;
        let radial = inner.k1 * r2 + inner.k2 * r2 * r2 + inner.k3 * r2 * r2 * r2;
        let expect_x = x + x * radial + inner.p1 * (r2 + 2.0 * x * x) + 2.0 * inner.p2 * x * y;
        let expect_y = y + y * radial + inner.p2 * (r2 + 2.0 * y * y) + 2.0 * inner.p1 * x * y;
        let refined = inner.refine(obs);
        assert!((refined.x - expect_x).abs() < 1e-14 && (refined.y - expect_y).abs() < 1e-14);
        let red = Vector2::new(x, y);
        let h = 1e-6;
        let j = inner.refine_jacobian(red);
        for k in 0..2 {
            let mut d = Vector2::zeros();
            d[k] = h;
            let num = (inner.refine(obs + d) - inner.refine(obs - d)) / (2.0 * h);
            assert!((num - j.column(k)).norm() < 1e-8);
        }
    }

    #[test]
    fn unrefine_rejects_nan() {
        let (_, inner) = dc40();
        assert_eq!(
            inner.unrefine(Vector2::new(f64::NAN, 0.0)),
            Err(Error::NotFinite)
        );
    }
}
