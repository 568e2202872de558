//! The device's ray table: each projector ray packed as a small correction to a model of the
//! pattern, 8 bytes a central ray instead of 28 for an f32 [`ProjectorRay`].
//!
//! The model: every ray of a projector points into one half-space, so its direction is
//! (1, a, b) along the calibration's *dominant axis* (the world axis on which every ray's
//! component has one sign, the one giving the smallest slopes), permuted into place and signed:
//! d = sign · e_axis + a · e_(axis+1) + b · e_(axis+2). The slopes a, b are integers in units
//! of 2⁻ᵇⁱᵗˢ, each stored as a 24-bit difference from the middle of its range (the model's
//! `centre`), `bits` the most for which every slope stays an integer below 2²⁴ (exact in f32)
//! and every difference fits: 25 for the paper's slopes of 0.09-0.42, a step of 3·10⁻⁸ and a
//! rounding of at most 1.5·10⁻⁸, finer than an f32 unit vector's components, rounded once from
//! the host's f64.
//! The direction is not of unit length, which the intersection (eqs 6-9) does not need. A
//! non-central ray adds its offset from the centre: three 24-bit integers in 2⁻¹² mm (±2048 mm).
//!
//! | bytes | content |
//! |---|---|
//! | 0..2 | ray id (u16 LE) |
//! | 2..5 | a − centre (i24 LE, units of 2⁻ᵇⁱᵗˢ) |
//! | 5..8 | b − centre (i24 LE) |
//! | 8..17 | non-central only: the offset x, y, z (i24 LE, 2⁻¹² mm) |
//!
//! The records lie in one byte pool of `N` bytes, sorted by id: `N / 8` central rays or
//! `N / 17` non-central ones ([`RayTable::capacity`]).

use crate::projector::{ProjectorRay, RayStore};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Bytes of a central ray's record.
pub const CENTRAL_RECORD: usize = 8;
/// Bytes of a non-central ray's record.
pub const NONCENTRAL_RECORD: usize = 17;
/// Units per millimetre of a packed offset: 2¹².
pub const OFFSET_UNITS_PER_MM: f64 = 4096.0;
/// The largest magnitude of a 24-bit field.
const I24_MAX: i32 = (1 << 23) - 1;

/// How the rays of a calibration are packed (part of the calibration blob's header).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct RayModel {
    /// The dominant axis (0 = x, 1 = y, 2 = z, world axes).
    pub axis: u8,
    /// Whether the rays point towards the negative dominant axis.
    pub negative: bool,
    /// Fraction bits of the slopes: a slope is (its integer + `centre`) · 2⁻ᵇⁱᵗˢ.
    pub bits: u8,
    /// The middle of the slopes' ranges, in their units: a record holds a slope's difference
    /// from it, so the 24 bits cover the spread of the slopes, not their size.
    pub centre: [i32; 2],
    /// Whether the rays carry offsets (a non-central model).
    pub noncentral: bool,
}

/// Why rays cannot be packed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PackError {
    /// No axis has every ray's component of one sign (the rays span more than a half-space).
    NoDominantAxis,
    /// An offset lies beyond ±2048 mm.
    OffsetRange(u16),
}

impl RayModel {
    /// The model of rays `rays` (unit directions, any order): the axis on which every ray's
    /// component has one sign and the slopes are smallest, the most fraction bits that hold
    /// them, central when every offset is zero.
    pub fn fit(rays: &[ProjectorRay<f64>]) -> Result<Self, PackError> {
        // (largest slope, axis, negative, the slopes' ranges)
        let mut best: Option<(f64, u8, bool, [[f64; 2]; 2])> = None;
        for axis in 0..3u8 {
            let a = usize::from(axis);
            let negative = rays.first().is_some_and(|r| r.direction[a] < 0.0);
            let mut ranges = [[f64::MAX, f64::MIN]; 2];
            let mut ok = true;
            for r in rays {
                let d = r.direction[a];
                if !(d != 0.0 && (d < 0.0) == negative) {
                    ok = false;
                    break;
                }
                for (range, k) in ranges.iter_mut().zip(Self::others(a)) {
                    let v = r.direction[k] / d.abs();
                    *range = [range[0].min(v), range[1].max(v)];
                }
            }
            let slope = ranges
                .iter()
                .map(|[lo, hi]| lo.abs().max(hi.abs()))
                .fold(0.0, f64::max);
            if ok && best.is_none_or(|(s, ..)| slope < s) {
                best = Some((slope, axis, negative, ranges));
            }
        }
        let (slope, axis, negative, ranges) = best.ok_or(PackError::NoDominantAxis)?;
        // The most bits such that every slope is an integer below 2²⁴ in its units (exact in
        // f32) and its difference from the range's middle fits 24 bits signed.
        let spread = ranges
            .iter()
            .map(|[lo, hi]| (hi - lo) / 2.0)
            .fold(0.0, f64::max);
        let fits = |b: u8| {
            let scale = f64::from(1u32 << b);
            libm::round(slope * scale) < f64::from(1u32 << 24)
                && libm::round(spread * scale) + 1.0 <= f64::from(I24_MAX)
        };
        let bits = (0..=30u8).rev().find(|&b| fits(b)).unwrap_or(0);
        let scale = f64::from(1u32 << bits);
        let centre = ranges.map(|[lo, hi]| libm::round((lo + hi) / 2.0 * scale) as i32);
        let noncentral = rays.iter().any(|r| r.offset != Vector3::zeros());
        Ok(Self {
            axis,
            negative,
            bits,
            centre,
            noncentral,
        })
    }

    /// The two axes after `axis`, in cyclic order.
    fn others(axis: usize) -> [usize; 2] {
        [(axis + 1) % 3, (axis + 2) % 3]
    }

    /// Bytes of one record.
    pub fn record(&self) -> usize {
        if self.noncentral {
            NONCENTRAL_RECORD
        } else {
            CENTRAL_RECORD
        }
    }

    /// Pack one ray (f64, unit direction) into its record (the first [`RayModel::record`]
    /// bytes of the result).
    pub fn pack(&self, ray: &ProjectorRay<f64>) -> Result<[u8; NONCENTRAL_RECORD], PackError> {
        let a = usize::from(self.axis);
        let scale = f64::from(1u32 << self.bits);
        let d = ray.direction[a];
        let mut out = [0u8; NONCENTRAL_RECORD];
        out[..2].copy_from_slice(&ray.id.to_le_bytes());
        for ((k, field), centre) in Self::others(a).into_iter().zip([2, 5]).zip(self.centre) {
            let v = libm::round(ray.direction[k] / d.abs() * scale) - f64::from(centre);
            let v = v.clamp(-f64::from(I24_MAX), f64::from(I24_MAX)) as i32;
            out[field..field + 3].copy_from_slice(&v.to_le_bytes()[..3]);
        }
        if self.noncentral {
            for (k, field) in [8, 11, 14].into_iter().enumerate() {
                let v = libm::round(ray.offset[k] * OFFSET_UNITS_PER_MM);
                if v.is_nan() || v.abs() > f64::from(I24_MAX) {
                    return Err(PackError::OffsetRange(ray.id));
                }
                out[field..field + 3].copy_from_slice(&(v as i32).to_le_bytes()[..3]);
            }
        }
        Ok(out)
    }
}

/// Packed rays in a pool of `N` bytes, sorted by id (see the module docs).
#[derive(Debug, Clone)]
pub struct RayTable<const N: usize> {
    bytes: [u8; N],
    model: RayModel,
    count: usize,
    /// Bytes of a record ([`RayModel::record`]).
    size: usize,
    /// The slopes' unit, 2⁻ᵇⁱᵗˢ.
    unit: f32,
    /// The dominant component, ±1.
    sign: f32,
}

impl<const N: usize> Default for RayTable<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> RayTable<N> {
    /// An empty table.
    pub const fn new() -> Self {
        Self {
            bytes: [0; N],
            model: RayModel {
                axis: 2,
                negative: true,
                bits: 0,
                centre: [0, 0],
                noncentral: false,
            },
            count: 0,
            size: CENTRAL_RECORD,
            unit: 1.0,
            sign: -1.0,
        }
    }

    /// The most rays of a model: central or not.
    pub const fn capacity(noncentral: bool) -> usize {
        N / if noncentral {
            NONCENTRAL_RECORD
        } else {
            CENTRAL_RECORD
        }
    }

    /// Forget every ray and take rays of `model` from now on.
    pub fn clear(&mut self, model: RayModel) {
        self.model = model;
        self.count = 0;
        self.size = model.record();
        self.unit = 1.0 / (1u64 << model.bits) as f32;
        self.sign = if model.negative { -1.0 } else { 1.0 };
    }

    /// The model of the rays.
    pub fn model(&self) -> RayModel {
        self.model
    }

    /// Append a record (its first [`RayModel::record`] bytes); `false` when the pool is full,
    /// the record short, or its id not above the last one's.
    pub fn push(&mut self, record: &[u8]) -> bool {
        let size = self.size;
        let Some(record) = record.get(..size) else {
            return false;
        };
        let [a, b, ..] = *record else {
            return false;
        };
        let id = u16::from_le_bytes([a, b]);
        if self.count > 0 && (&*self).id_at(self.count - 1).is_none_or(|last| last >= id) {
            return false;
        }
        let at = self.count * size;
        let Some(slot) = self.bytes.get_mut(at..at + size) else {
            return false;
        };
        slot.copy_from_slice(record);
        self.count += 1;
        true
    }

    /// The first 8 bytes of record `k` (id and slopes).
    #[inline(always)]
    fn head(&self, k: usize) -> Option<&[u8; CENTRAL_RECORD]> {
        if k >= self.count {
            return None;
        }
        let at = k * self.size;
        self.bytes.get(at..at + CENTRAL_RECORD)?.try_into().ok()
    }

    /// The offset of non-central record `k` (mm).
    fn offset(&self, k: usize) -> Option<[f32; 3]> {
        let at = k * self.size + CENTRAL_RECORD;
        let b: &[u8; 9] = self.bytes.get(at..at + 9)?.try_into().ok()?;
        let mm = 1.0 / OFFSET_UNITS_PER_MM as f32;
        Some([
            i24([b[0], b[1], b[2]]) as f32 * mm,
            i24([b[3], b[4], b[5]]) as f32 * mm,
            i24([b[6], b[7], b[8]]) as f32 * mm,
        ])
    }
}

/// A 24-bit little-endian signed integer.
#[inline(always)]
fn i24([a, b, c]: [u8; 3]) -> i32 {
    i32::from_le_bytes([0, a, b, c]) >> 8
}

impl<const N: usize> RayStore<f32> for &RayTable<N> {
    fn count(&self) -> usize {
        self.count
    }

    #[inline(always)]
    fn id_at(&self, k: usize) -> Option<u16> {
        let r = self.head(k)?;
        Some(u16::from_le_bytes([r[0], r[1]]))
    }

    /// Ray `k`, unpacked: exact in f32 (24-bit integers times powers of two).
    #[inline(always)]
    fn ray_at(&self, k: usize) -> Option<ProjectorRay<f32>> {
        let r = self.head(k)?;
        // The difference plus the centre: an integer below 2²⁴, exact in f32.
        let [ca, cb] = self.model.centre;
        let a = i24([r[2], r[3], r[4]]).wrapping_add(ca) as f32 * self.unit;
        let b = i24([r[5], r[6], r[7]]).wrapping_add(cb) as f32 * self.unit;
        let s = self.sign;
        let direction = match self.model.axis {
            0 => Vector3::new(s, a, b),
            1 => Vector3::new(b, s, a),
            _ => Vector3::new(a, b, s),
        };
        let offset = if self.model.noncentral {
            Vector3::from(self.offset(k)?)
        } else {
            Vector3::zeros()
        };
        Some(ProjectorRay {
            id: u16::from_le_bytes([r[0], r[1]]),
            direction,
            offset,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ray(id: u16, x: f64, y: f64, offset: [f64; 3]) -> ProjectorRay<f64> {
        ProjectorRay {
            id,
            direction: Vector3::new(x, y, -1.0).normalize(),
            offset: Vector3::from(offset),
        }
    }

    /// Packed rays point where the f64 rays do to the slopes' rounding, 2⁻ᵇⁱᵗˢ⁻¹ each.
    #[test]
    fn packed_rays_keep_their_directions() {
        let rays: Vec<_> = (0..50u16)
            .map(|k| {
                ray(
                    k * 3 + 1,
                    0.42 - 0.017 * f64::from(k),
                    -0.17 + 0.006 * f64::from(k),
                    [0.0; 3],
                )
            })
            .collect();
        let model = RayModel::fit(&rays).unwrap();
        assert_eq!(
            (model.axis, model.negative, model.noncentral),
            (2, true, false)
        );
        // Slopes from −0.41 to 0.42: a spread of ±0.42 fits 24 bits in steps of 2⁻²⁴ (the
        // largest slope alone would allow 2⁻²⁵).
        assert_eq!(model.bits, 24);
        let mut table = RayTable::<{ 8 * 50 }>::new();
        table.clear(model);
        for r in &rays {
            assert!(table.push(&model.pack(r).unwrap()));
        }
        assert!(
            !table.push(&model.pack(&ray(999, 0.1, 0.1, [0.0; 3])).unwrap()),
            "full"
        );
        let store = &table;
        for (k, r) in rays.iter().enumerate() {
            let got: ProjectorRay<f32> = store.ray_at(k).unwrap();
            assert_eq!(got.id, r.id);
            let d = got.direction.map(f64::from);
            let angle = d.normalize().cross(&r.direction).norm();
            assert!(angle <= 1.5 * 0.5_f64.powi(25), "{angle}");
            assert_eq!(store.find(r.id), Some(k));
        }
        assert_eq!(store.find(2), None);
    }

    #[test]
    fn noncentral_offsets_and_refusals() {
        let rays = [
            ray(1, 0.1, 0.2, [0.5, -1.25, 3.0]),
            ray(2, -0.3, 0.1, [0.0; 3]),
        ];
        let model = RayModel::fit(&rays).unwrap();
        assert!(model.noncentral);
        let mut table = RayTable::<{ 17 * 2 }>::new();
        table.clear(model);
        assert_eq!(RayTable::<{ 17 * 2 }>::capacity(true), 2);
        for r in &rays {
            assert!(table.push(&model.pack(r).unwrap()));
        }
        // Out of order.
        assert!(!table.push(&model.pack(&rays[0]).unwrap()));
        let got: ProjectorRay<f32> = (&table).ray_at(0).unwrap();
        assert_eq!(got.offset, Vector3::new(0.5, -1.25, 3.0));
        let far = ray(3, 0.0, 0.0, [2048.0, 0.0, 0.0]);
        assert_eq!(model.pack(&far), Err(PackError::OffsetRange(3)));
        // Rays in opposite directions along every axis.
        let spread = [
            ray(1, 0.0, 0.0, [0.0; 3]),
            ProjectorRay {
                id: 2,
                direction: Vector3::new(0.0, 0.0, 1.0),
                offset: Vector3::zeros(),
            },
        ];
        assert_eq!(RayModel::fit(&spread), Err(PackError::NoDominantAxis));
    }
}
