//! The compact fixed-point forms of a dot (4 bytes), a centroid (a delta-coded id and a dot) and
//! of a computed point (3 bytes).

use super::delta::Keyed;
use crate::Error;
use nalgebra::RealField;
use serde::{de::Error as _, Deserialize, Deserializer, Serialize, Serializer};
use simba::scalar::SupersetOf;

/// Fraction bits of the centroid fixed point for a `width` × `height` sensor: the most (up to 8)
/// such that (max(width, height) + 1) · 2^bits still fits a u16. 6 bits (1/64 pixel) for the
/// paper's 768 × 512 camera.
pub fn centroid_fraction_bits(width: u32, height: u32) -> u8 {
    let extent = u64::from(width.max(height)) + 1;
    (0..=8u8)
        .rev()
        .find(|&bits| extent << bits <= u64::from(u16::MAX))
        .unwrap_or(0)
}

/// A dot's sub-pixel position in fixed point: col and row hold (pixel + 0.5) · 2^bits rounded,
/// `bits` from [`centroid_fraction_bits`] for the calibrated sensor. On the wire 4 bytes: col,
/// row, each u16 little endian.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dot {
    /// Column in fixed point.
    pub col: u16,
    /// Row in fixed point.
    pub row: u16,
}

impl Dot {
    /// The dot at pixel position (col, row), or `None` when it is NaN or off the range of the
    /// fixed point (−0.5 .. 65535/2^bits − 0.5).
    pub fn from_pixel(col: f64, row: f64, bits: u8) -> Option<Self> {
        let scale = f64::from(1u32 << bits);
        let fixed = |v: f64| {
            let raw = libm::round((v + 0.5) * scale);
            (0.0..=f64::from(u16::MAX))
                .contains(&raw)
                .then_some(raw as u16)
        };
        Some(Self {
            col: fixed(col)?,
            row: fixed(row)?,
        })
    }

    /// The pixel position (col, row) the fixed point stands for, exact in f32 and f64.
    /// Computed in f32 (no f64 on the device): raw / 2^bits − ½ has at most 17 significant
    /// bits, so it is exact and widening it to f64 changes nothing.
    pub fn pixel<T: RealField + Copy + SupersetOf<f32>>(&self, bits: u8) -> (T, T) {
        let scale = (1u32 << bits) as f32;
        let v = |raw: u16| -> T { nalgebra::convert(f32::from(raw) / scale - 0.5) };
        (v(self.col), v(self.row))
    }
}

impl Dot {
    /// Whether the dot lies on a `width` × `height` sensor ([`crate::camera::PixelGrid::contains`]
    /// of its pixel), in integers: raw / 2^bits − ½ lies in −½ ..= width − ½ exactly when raw ≤
    /// width · 2^bits (raw ≥ 0 always).
    pub fn on_sensor(&self, width: u32, height: u32, bits: u8) -> bool {
        let fits = |raw: u16, extent: u32| u64::from(raw) <= u64::from(extent) << bits;
        fits(self.col, width) && fits(self.row, height)
    }
}

impl Serialize for Dot {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let [a, b] = self.col.to_le_bytes();
        let [c, d] = self.row.to_le_bytes();
        [a, b, c, d].serialize(s)
    }
}

impl<'de> Deserialize<'de> for Dot {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let [a, b, c, e] = <[u8; 4]>::deserialize(d)?;
        Ok(Self {
            col: u16::from_le_bytes([a, b]),
            row: u16::from_le_bytes([c, e]),
        })
    }
}

/// One observed dot with its projector ray id. In a `Compute` request the id is delta-coded
/// (see [`super::delta`]: one byte for ids sorted ascending) and the position follows as a
/// [`Dot`]: 5 bytes a centroid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Centroid {
    /// The ray id (row·100 + col of the pattern).
    pub id: u16,
    /// Column in fixed point (see [`Dot`]).
    pub col: u16,
    /// Row in fixed point (see [`Dot`]).
    pub row: u16,
}

impl Centroid {
    /// The centroid of a pixel position (col, row), or `None` when it is NaN or off the range
    /// of the fixed point (see [`Dot::from_pixel`]).
    pub fn from_pixel(id: u16, col: f64, row: f64, bits: u8) -> Option<Self> {
        let Dot { col, row } = Dot::from_pixel(col, row, bits)?;
        Some(Self { id, col, row })
    }

    /// The pixel position (col, row) the fixed point stands for, exact in f32 and f64.
    pub fn pixel<T: RealField + Copy + SupersetOf<f32>>(&self, bits: u8) -> (T, T) {
        self.dot().pixel(bits)
    }

    /// The position without the id.
    pub fn dot(&self) -> Dot {
        Dot {
            col: self.col,
            row: self.row,
        }
    }
}

impl Keyed for Centroid {
    type Rest = Dot;

    fn id(&self) -> u16 {
        self.id
    }

    fn rest(&self) -> Dot {
        self.dot()
    }

    fn join(id: u16, dot: Dot) -> Self {
        Self {
            id,
            col: dot.col,
            row: dot.row,
        }
    }
}

/// Why a centroid has no point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PointStatus {
    /// The calibration has no ray with this id.
    UnknownRay,
    /// The camera and projector rays are (nearly) parallel.
    Degenerate,
    /// The point lies behind the camera or farther than 16 m along its axis.
    OutOfRange,
    /// Identification: no ray's epipolar segment passes within tolerance of the dot.
    Unassigned,
    /// Identification: two or more segments pass within tolerance (the id is the closest ray).
    Ambiguous,
    /// Identification: another dot of the frame was assigned the same ray (the id is that ray;
    /// the host finds these).
    Conflict,
    /// The centroid lies off the calibration's sensor (more than half a pixel outside).
    OffSensor,
}

impl PointStatus {
    /// The status of a reconstruction's error.
    pub fn of(error: Error) -> Self {
        match error {
            Error::UnknownRay(_) => PointStatus::UnknownRay,
            _ => PointStatus::Degenerate,
        }
    }
}

/// Units per millimetre of a depth: 2¹⁰ (0.98 µm).
pub const DEPTH_UNITS_PER_MM: f64 = 1024.0;
/// The largest depth code (16,384 mm less 17 units); the codes above it are statuses.
const DEPTH_LIMIT: u32 = 0xFF_FFEF;
const STATUSES: [(u32, PointStatus); 7] = [
    (0xFF_FFF0, PointStatus::UnknownRay),
    (0xFF_FFF1, PointStatus::Degenerate),
    (0xFF_FFF2, PointStatus::OutOfRange),
    (0xFF_FFF3, PointStatus::Unassigned),
    (0xFF_FFF4, PointStatus::Ambiguous),
    (0xFF_FFF5, PointStatus::Conflict),
    (0xFF_FFF6, PointStatus::OffSensor),
];

/// The device's answer for one centroid: the depth of its point, λ·f of eqs (6)-(8) (the
/// distance in front of the camera along its axis, −z of the camera system), or why there is
/// none. The host, which holds the calibration in f64, places the point from the depth
/// ([`crate::rig::Rig::reconstruct_at_depth`]): the same point and miss distance as the
/// device's intersection, to the depth's quantisation. On the wire 3 bytes, u24 little endian:
/// the depth in units of 2⁻¹⁰ mm (0 ..= 0xFF_FFEF), or a status (0xFF_FFF0 unknown ray,
/// 0xFF_FFF1 degenerate, 0xFF_FFF2 out of range, 0xFF_FFF3 unassigned, 0xFF_FFF4 ambiguous,
/// 0xFF_FFF5 conflict, 0xFF_FFF6 off the sensor).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PointResult {
    /// A point at this depth (units of 2⁻¹⁰ mm, at most 0xFF_FFEF).
    Depth(u32),
    /// No point.
    Failed(PointStatus),
}

impl PointResult {
    /// Quantise a depth (mm), rounding half up, in f32 (the device's FPU arithmetic): the
    /// truncation t of 2·depth·2¹⁰ (scaling by a power of two is exact, one VCVT) is twice the
    /// units, plus one when their fraction is at least ½, so t/2 + t%2 is the rounded units.
    /// A depth behind the camera, beyond the codes or NaN is out of range.
    pub fn from_depth(depth: f32) -> Self {
        // Negative or NaN (incomparable) is refused here.
        if depth
            .partial_cmp(&0.0)
            .is_none_or(core::cmp::Ordering::is_lt)
        {
            return Self::Failed(PointStatus::OutOfRange);
        }
        // Saturates at u32::MAX for ∞ or a huge depth, beyond the codes.
        let twice = (depth * (2.0 * DEPTH_UNITS_PER_MM as f32)) as u32;
        match twice / 2 + twice % 2 {
            units @ 0..=DEPTH_LIMIT => Self::Depth(units),
            _ => Self::Failed(PointStatus::OutOfRange),
        }
    }

    /// The result of a reconstruction that failed.
    pub fn from_error(error: Error) -> Self {
        Self::Failed(PointStatus::of(error))
    }

    /// The depth in mm, if there is a point.
    pub fn depth_mm(&self) -> Option<f64> {
        match self {
            Self::Depth(units) => Some(f64::from(*units) / DEPTH_UNITS_PER_MM),
            Self::Failed(_) => None,
        }
    }

    #[inline]
    pub(super) fn to_bytes(self) -> [u8; 3] {
        let code = match self {
            Self::Depth(units) => units,
            Self::Failed(status) => STATUSES
                .iter()
                .find(|(_, s)| *s == status)
                .map_or(0xFF_FFFF, |(code, _)| *code),
        };
        let [a, b, c, _] = code.to_le_bytes();
        [a, b, c]
    }

    fn from_bytes([a, b, c]: [u8; 3]) -> Option<Self> {
        match u32::from_le_bytes([a, b, c, 0]) {
            units @ 0..=DEPTH_LIMIT => Some(Self::Depth(units)),
            code => STATUSES
                .iter()
                .find(|(c, _)| *c == code)
                .map(|(_, s)| Self::Failed(*s)),
        }
    }
}

impl Serialize for PointResult {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        self.to_bytes().serialize(s)
    }
}

impl<'de> Deserialize<'de> for PointResult {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        Self::from_bytes(<[u8; 3]>::deserialize(d)?)
            .ok_or_else(|| D::Error::custom("unknown point status"))
    }
}

/// The device's answer for one unlabelled dot: the ray it was identified as and its point, or a
/// status. The id is the ray (a point, or a reconstruction status), the closest ray
/// ([`PointStatus::Ambiguous`]), or 0 ([`PointStatus::Unassigned`]). On the wire the
/// delta-coded id (see [`super::delta`]) and the 3 bytes of the [`PointResult`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct IdentifiedPoint {
    /// The ray id (see above).
    pub id: u16,
    /// The point or the status.
    pub result: PointResult,
}

impl Keyed for IdentifiedPoint {
    type Rest = PointResult;

    fn id(&self) -> u16 {
        self.id
    }

    fn rest(&self) -> PointResult {
        self.result
    }

    fn join(id: u16, result: PointResult) -> Self {
        Self { id, result }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fraction_bits_fit_the_sensor() {
        assert_eq!(centroid_fraction_bits(768, 512), 6);
        assert_eq!(centroid_fraction_bits(4096, 3000), 3);
        assert_eq!(centroid_fraction_bits(200, 100), 8);
        // Corner pixel centres and edges survive the round trip exactly at the grid's scale.
        let bits = centroid_fraction_bits(768, 512);
        let c = Centroid::from_pixel(7, 767.5, -0.5, bits).unwrap();
        assert_eq!(c.pixel::<f64>(bits), (767.5, -0.5));
        assert_eq!(Centroid::from_pixel(7, -0.6, 0.0, bits), None);
        assert_eq!(Centroid::from_pixel(7, f64::NAN, 0.0, bits), None);
        let c = Centroid::from_pixel(1, 100.123, 200.9, bits).unwrap();
        let (col, row) = c.pixel::<f64>(bits);
        assert!((col - 100.123).abs() <= 1.0 / 128.0 && (row - 200.9).abs() <= 1.0 / 128.0);
        assert_eq!(c.pixel::<f32>(bits), (col as f32, row as f32));
        // On the sensor in fixed point exactly when the grid says so.
        let grid = crate::camera::PixelGrid {
            pixel_size: 0.01,
            width: 768,
            height: 512,
            origin_col: 384.0,
            origin_row: 256.0,
        };
        for raw in [
            0,
            1,
            767 * 64,
            768 * 64 - 1,
            768 * 64,
            768 * 64 + 1,
            512 * 64,
            u16::MAX,
        ] {
            for dot in [Dot { col: raw, row: 0 }, Dot { col: 0, row: raw }] {
                let (col, row) = dot.pixel::<f64>(bits);
                assert_eq!(
                    dot.on_sensor(768, 512, bits),
                    grid.contains(col, row),
                    "{dot:?}"
                );
            }
        }
    }

    #[test]
    fn depth_quantisation_and_bytes() {
        let p = PointResult::from_depth(1500.25 + 0.4 / 1024.0);
        assert_eq!(p, PointResult::Depth(1500 * 1024 + 256));
        assert_eq!(p.to_bytes(), [0x00, 0x71, 0x17]);
        assert_eq!(PointResult::from_bytes(p.to_bytes()), Some(p));
        assert_eq!(p.depth_mm(), Some(1500.25));
        // Half a unit rounds up; the camera's own plane is depth 0.
        assert_eq!(PointResult::from_depth(0.5 / 1024.0), PointResult::Depth(1));
        assert_eq!(PointResult::from_depth(0.0), PointResult::Depth(0));
        // The last code inside the range, the first beyond, behind the camera, NaN, ∞.
        let edge = (f64::from(DEPTH_LIMIT) / DEPTH_UNITS_PER_MM) as f32;
        assert_eq!(
            PointResult::from_depth(edge),
            PointResult::Depth(DEPTH_LIMIT)
        );
        let beyond = edge + 1.0 / 1024.0;
        for out in [
            beyond,
            -1.0 / 4096.0,
            f32::NAN,
            f32::INFINITY,
            -f32::INFINITY,
        ] {
            assert_eq!(
                PointResult::from_depth(out),
                PointResult::Failed(PointStatus::OutOfRange),
                "{out}"
            );
        }
        for (code, status) in STATUSES {
            let failed = PointResult::Failed(status);
            assert_eq!(failed.to_bytes(), code.to_le_bytes()[..3]);
            assert_eq!(PointResult::from_bytes(failed.to_bytes()), Some(failed));
        }
        assert_eq!(
            PointResult::from_bytes([0xF5, 0xFF, 0xFF]),
            Some(PointResult::Failed(PointStatus::Conflict))
        );
        for unknown in [[0xF7, 0xFF, 0xFF], [0xFF, 0xFF, 0xFF]] {
            assert_eq!(PointResult::from_bytes(unknown), None);
        }
    }
}
