//! The calibrated projector (eq. 5): a perspective centre and a table of rays by id.
//!
//! The paper's model is *central*: every ray passes through the centre (X_p, Y_p, Z_p) with
//! direction cosines (l, m, n). A *non-central* model gives each ray its own point, stored as an
//! offset from the centre (zero in the central model), so both share one type.

use crate::{lit, Error, Result};
use nalgebra::{RealField, Vector3};

/// How far from 1 the length of a ray's direction may be (relative), everywhere a calibration
/// is read: it admits direction cosines printed to 6 decimals (|error| ≤ 1.5·10⁻⁶) and an f32
/// cast of a unit vector (≤ 3·10⁻⁷), and refuses anything not meant as a unit vector.
pub const UNIT_TOLERANCE: f64 = 1e-5;

/// A 3D line: a point on it and a direction (not necessarily unit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray<T: RealField> {
    /// A point on the line (mm).
    pub point: Vector3<T>,
    /// Its direction.
    pub direction: Vector3<T>,
}

impl<T: RealField + Copy> Ray<T> {
    /// Eq. (5): the point at parameter λ: X = X_p + λ (l, m, n).
    pub fn at(&self, lambda: T) -> Vector3<T> {
        self.point + self.direction * lambda
    }
}

/// One calibrated projector ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProjectorRay<T: RealField> {
    /// The ray's id (the dot's label in the pattern).
    pub id: u16,
    /// Direction cosines (l, m, n): a unit vector from the projector towards the scene.
    pub direction: Vector3<T>,
    /// The ray passes through centre + offset (mm); zero for the paper's central model.
    pub offset: Vector3<T>,
}

/// Where a lookup by [`Projector::ray_from`] left off: the index after the ray it found.
#[derive(Debug, Clone, Copy, Default)]
pub struct RayCursor {
    next: usize,
}

/// Where a projector keeps its rays, sorted by id: any slice-like storage of [`ProjectorRay`]s
/// (`[ProjectorRay; N]`, a slice, `heapless::Vec`, `Vec`), or a packed table such as the
/// device's [`crate::ray_table::RayTable`] that decodes a ray when asked.
pub trait RayStore<T: RealField> {
    /// The number of rays.
    fn count(&self) -> usize;
    /// The id of ray `k` (in id order), `None` beyond the last.
    fn id_at(&self, k: usize) -> Option<u16>;
    /// Ray `k`, `None` beyond the last.
    fn ray_at(&self, k: usize) -> Option<ProjectorRay<T>>;
    /// The index of the ray with id `id`, if there is one.
    fn find(&self, id: u16) -> Option<usize> {
        let (mut lo, mut hi) = (0, self.count());
        while lo < hi {
            let mid = lo + (hi - lo) / 2;
            match self.id_at(mid)?.cmp(&id) {
                core::cmp::Ordering::Less => lo = mid + 1,
                core::cmp::Ordering::Greater => hi = mid,
                core::cmp::Ordering::Equal => return Some(mid),
            }
        }
        None
    }
}

impl<T: RealField + Copy, S: AsRef<[ProjectorRay<T>]>> RayStore<T> for S {
    fn count(&self) -> usize {
        self.as_ref().len()
    }

    #[inline]
    fn id_at(&self, k: usize) -> Option<u16> {
        self.as_ref().get(k).map(|r| r.id)
    }

    #[inline]
    fn ray_at(&self, k: usize) -> Option<ProjectorRay<T>> {
        self.as_ref().get(k).copied()
    }

    fn find(&self, id: u16) -> Option<usize> {
        self.as_ref().binary_search_by_key(&id, |r| r.id).ok()
    }
}

/// The projector: a centre and rays sorted by id, in any [`RayStore`]: no allocator is needed.
#[derive(Debug, Clone, PartialEq)]
pub struct Projector<T: RealField, S> {
    centre: Vector3<T>,
    rays: S,
}

impl<T: RealField + Copy, S: AsRef<[ProjectorRay<T>]>> Projector<T, S> {
    /// A projector from its centre and its rays, checked: ids strictly increasing, every direction
    /// finite and of unit length (to [`UNIT_TOLERANCE`]), every offset finite.
    pub fn new(centre: Vector3<T>, rays: S) -> Result<Self> {
        if !centre.iter().all(|c| c.is_finite()) {
            return Err(Error::NotFinite);
        }
        let tol = lit::<T>(UNIT_TOLERANCE);
        let mut previous: Option<u16> = None;
        for ray in rays.as_ref() {
            if previous.is_some_and(|p| p >= ray.id) {
                return Err(Error::UnsortedRays);
            }
            previous = Some(ray.id);
            let finite = ray
                .direction
                .iter()
                .chain(ray.offset.iter())
                .all(|c| c.is_finite());
            if !finite || (crate::sqrt(ray.direction.norm_squared()) - T::one()).abs() > tol {
                return Err(Error::InvalidRay(ray.id));
            }
        }
        Ok(Self { centre, rays })
    }

    /// The rays, sorted by id.
    pub fn rays(&self) -> &[ProjectorRay<T>] {
        self.rays.as_ref()
    }
}

impl<T: RealField + Copy, S: RayStore<T>> Projector<T, S> {
    /// A projector over rays a [`Projector::new`] accepted before (a device's table, checked
    /// once when its calibration was loaded), without a second pass over them.
    pub fn from_checked(centre: Vector3<T>, rays: S) -> Self {
        Self { centre, rays }
    }

    /// The perspective centre (X_p, Y_p, Z_p), mm.
    pub fn centre(&self) -> Vector3<T> {
        self.centre
    }

    /// Eq. (5)'s line for a ray id: through centre + offset with direction (l, m, n).
    pub fn ray(&self, id: u16) -> Result<Ray<T>> {
        self.ray_from(&mut RayCursor::default(), id)
    }

    /// [`Projector::ray`] for a batch of ids sorted ascending (a labelled frame): the ray after
    /// the cursor (the last one found) is tried before a binary search, and the cursor moves
    /// past the ray found. Any order gives the same rays, only slower.
    pub fn ray_from(&self, cursor: &mut RayCursor, id: u16) -> Result<Ray<T>> {
        let rays = &self.rays;
        let index = match rays.id_at(cursor.next) {
            Some(next) if next == id => cursor.next,
            _ => rays.find(id).ok_or(Error::UnknownRay(id))?,
        };
        cursor.next = index + 1;
        let ray = rays.ray_at(index).ok_or(Error::UnknownRay(id))?;
        Ok(Ray {
            point: self.centre + ray.offset,
            direction: ray.direction,
        })
    }

    /// The ray store.
    pub fn store(&self) -> &S {
        &self.rays
    }

    /// The same projector with its centre moved by `shift` (rays unchanged), for example to put
    /// the origin at the camera's perspective centre.
    pub fn shifted(self, shift: Vector3<T>) -> Self {
        Self {
            centre: self.centre + shift,
            rays: self.rays,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ray(id: u16, l: f64, m: f64) -> ProjectorRay<f64> {
        let n = -(1.0 - l * l - m * m).sqrt();
        ProjectorRay {
            id,
            direction: Vector3::new(l, m, n),
            offset: Vector3::zeros(),
        }
    }

    #[test]
    fn lookup_by_id() {
        let rays = [
            ray(1, 0.09159, -0.17179),
            ray(2, 0.24040, -0.16860),
            ray(11, 0.09012, -0.02403),
        ];
        let p = Projector::new(Vector3::new(-114.601, 383.502, 1905.981), rays).unwrap();
        let r = p.ray(11).unwrap();
        assert_eq!(r.direction.x, 0.09012);
        assert_eq!(r.at(0.0), p.centre());
        assert_eq!(p.ray(3), Err(Error::UnknownRay(3)));
    }

    #[test]
    fn cursor_finds_the_rays_of_any_order() {
        let rays = [1, 2, 5, 6, 9].map(|id| ray(id, 0.01 * f64::from(id), 0.1));
        let p = Projector::new(Vector3::zeros(), rays).unwrap();
        // Sorted with gaps, repeats, backwards, an unknown id between known ones.
        for ids in [
            &[1, 2, 5, 6, 9][..],
            &[2, 6, 9],
            &[9, 5, 5, 1],
            &[5, 6, 1, 2, 9, 6],
        ] {
            let mut cursor = RayCursor::default();
            for &id in ids {
                assert_eq!(p.ray_from(&mut cursor, id), p.ray(id), "{ids:?}");
                assert_eq!(
                    p.ray_from(&mut cursor, id).unwrap().direction.x,
                    0.01 * f64::from(id)
                );
            }
        }
        let mut cursor = RayCursor::default();
        p.ray_from(&mut cursor, 2).unwrap();
        assert_eq!(p.ray_from(&mut cursor, 3), Err(Error::UnknownRay(3)));
        assert_eq!(p.ray_from(&mut cursor, 5).unwrap().direction.x, 0.05);
    }

    #[test]
    fn rejects_bad_tables() {
        let c = Vector3::zeros();
        assert_eq!(
            Projector::new(c, [ray(2, 0.1, 0.1), ray(1, 0.1, 0.1)]).err(),
            Some(Error::UnsortedRays)
        );
        let mut bad = ray(5, 0.1, 0.1);
        bad.direction *= 1.01;
        assert_eq!(Projector::new(c, [bad]).err(), Some(Error::InvalidRay(5)));
        bad.direction = Vector3::new(f64::NAN, 0.0, 1.0);
        assert_eq!(Projector::new(c, [bad]).err(), Some(Error::InvalidRay(5)));
    }
}
