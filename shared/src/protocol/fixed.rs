//! The compact fixed-point forms of a dot (4 bytes), a centroid (a delta-coded id and a dot) and
//! of a computed point (10 bytes).

use super::delta::Keyed;
use crate::Error;
use nalgebra::{RealField, Vector3};
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
    /// The point lies farther than 2048 mm from the camera centre along an axis.
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

/// Units per millimetre of a point coordinate: 2¹² (0.244 µm).
pub const POINT_UNITS_PER_MM: f64 = 4096.0;
/// Units per millimetre of the miss distance: 2⁸ (3.9 µm).
pub const MISS_UNITS_PER_MM: f64 = 256.0;
/// The largest miss code; it also stands for every larger miss (≥ 0.93 mm).
pub const MISS_SATURATED: u8 = 0xEF;
const LIMIT: f64 = 8_388_607.0; // 2^23 − 1
const UNKNOWN_RAY: u8 = 0xF0;
const DEGENERATE: u8 = 0xF1;
const OUT_OF_RANGE: u8 = 0xF2;
const UNASSIGNED: u8 = 0xF3;
const AMBIGUOUS: u8 = 0xF4;
const CONFLICT: u8 = 0xF5;
const OFF_SENSOR: u8 = 0xF6;

/// The device's answer for one centroid. On the wire 10 bytes: x, y, z as 24-bit signed little
/// endian in units of 2⁻¹² mm *relative to the camera centre* (world axes), then one byte that is
/// the miss distance in units of 2⁻⁸ mm (0 ..= 0xEF, saturating) or a status (0xF0 unknown ray,
/// 0xF1 degenerate, 0xF2 out of range, 0xF3 unassigned, 0xF4 ambiguous, 0xF5 conflict, 0xF6
/// off the sensor; the coordinates are then zero).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PointResult {
    /// A point.
    Point {
        /// Coordinates relative to the camera centre, units of 2⁻¹² mm, each within ±(2²³ − 1).
        xyz: [i32; 3],
        /// Miss distance code (units of 2⁻⁸ mm, saturating at [`MISS_SATURATED`]).
        miss: u8,
    },
    /// No point.
    Failed(PointStatus),
}

/// `libm::roundf(x) as i32` (halves away from zero) given `twice` = 2x, for |x| < 2^30,
/// without libm's software rounding (about 25 instructions, four times a point) and without a
/// float comparison: the truncation t of 2x (one VCVT) is ±2⌊|x|⌋, or ±(2⌊|x|⌋ + 1) when the
/// fraction of |x| is at least ½, and t/2 + t%2 (both truncating) is then |x| rounded half up
/// with x's sign. Beyond the range the conversion saturates, and so does the result (NaN
/// gives 0). The callers scale by a power of two times 2 at once (exact).
fn round_half_away(twice: f32) -> i32 {
    let t = twice as i32;
    t / 2 + t % 2
}

impl PointResult {
    /// Quantise a camera-centred point and its miss distance (mm), in f32 (the device's FPU
    /// arithmetic: scaling by a power of two is exact, so this equals the f64 quantisation).
    /// A coordinate whose units round beyond ±(2²³ − 1) is out of range, and so is a NaN one.
    pub fn from_camera_centred(point: &Vector3<f32>, miss: f32) -> Self {
        const UNITS: f32 = POINT_UNITS_PER_MM as f32;
        const LIMIT24: i32 = LIMIT as i32;
        // A NaN coordinate (or opposite infinities) makes the sum NaN; a lone infinity
        // saturates its conversion and fails the range test.
        if (point.x + point.y + point.z).is_nan() {
            return Self::Failed(PointStatus::OutOfRange);
        }
        let xyz = [point.x, point.y, point.z].map(|c| round_half_away(c * (2.0 * UNITS)));
        if xyz.iter().any(|u| !(-LIMIT24..=LIMIT24).contains(u)) {
            return Self::Failed(PointStatus::OutOfRange);
        }
        // Twice the units (NaN saturates).
        let twice = miss * (2.0 * MISS_UNITS_PER_MM as f32);
        let miss = if twice < 2.0 * f32::from(MISS_SATURATED) {
            round_half_away(twice).max(0) as u8
        } else {
            MISS_SATURATED
        };
        Self::Point { xyz, miss }
    }

    /// The result of a reconstruction: a point or the status of its error.
    pub fn from_error(error: Error) -> Self {
        Self::Failed(match error {
            Error::UnknownRay(_) => PointStatus::UnknownRay,
            _ => PointStatus::Degenerate,
        })
    }

    /// The camera-centred point in mm, if there is one.
    pub fn camera_centred_mm(&self) -> Option<Vector3<f64>> {
        match self {
            Self::Point { xyz, .. } => Some(Vector3::from(
                xyz.map(|u| f64::from(u) / POINT_UNITS_PER_MM),
            )),
            Self::Failed(_) => None,
        }
    }

    /// The miss distance in mm (a lower bound when saturated), if there is a point.
    pub fn miss_mm(&self) -> Option<f64> {
        match self {
            Self::Point { miss, .. } => Some(f64::from(*miss) / MISS_UNITS_PER_MM),
            Self::Failed(_) => None,
        }
    }

    #[inline]
    pub(super) fn to_bytes(self) -> [u8; 10] {
        let mut bytes = [0u8; 10];
        match self {
            Self::Point { xyz, miss } => {
                for (chunk, v) in bytes.chunks_exact_mut(3).zip(xyz) {
                    chunk.copy_from_slice(&v.to_le_bytes()[..3]);
                }
                bytes[9] = miss;
            }
            Self::Failed(status) => {
                bytes[9] = match status {
                    PointStatus::UnknownRay => UNKNOWN_RAY,
                    PointStatus::Degenerate => DEGENERATE,
                    PointStatus::OutOfRange => OUT_OF_RANGE,
                    PointStatus::Unassigned => UNASSIGNED,
                    PointStatus::Ambiguous => AMBIGUOUS,
                    PointStatus::Conflict => CONFLICT,
                    PointStatus::OffSensor => OFF_SENSOR,
                }
            }
        }
        bytes
    }

    fn from_bytes(bytes: [u8; 10]) -> Option<Self> {
        let i24 = |b: &[u8]| i32::from_le_bytes([0, b[0], b[1], b[2]]) >> 8;
        let status = |s| Some(Self::Failed(s));
        match bytes[9] {
            miss @ 0..=MISS_SATURATED => Some(Self::Point {
                xyz: [i24(&bytes[0..3]), i24(&bytes[3..6]), i24(&bytes[6..9])],
                miss,
            }),
            UNKNOWN_RAY => status(PointStatus::UnknownRay),
            DEGENERATE => status(PointStatus::Degenerate),
            OUT_OF_RANGE => status(PointStatus::OutOfRange),
            UNASSIGNED => status(PointStatus::Unassigned),
            AMBIGUOUS => status(PointStatus::Ambiguous),
            CONFLICT => status(PointStatus::Conflict),
            OFF_SENSOR => status(PointStatus::OffSensor),
            _ => None,
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
        Self::from_bytes(<[u8; 10]>::deserialize(d)?)
            .ok_or_else(|| D::Error::custom("unknown point status"))
    }
}

/// The device's answer for one unlabelled dot: the ray it was identified as and its point, or a
/// status. The id is the ray (a point, or a reconstruction status), the closest ray
/// ([`PointStatus::Ambiguous`]), or 0 ([`PointStatus::Unassigned`]). On the wire the delta-coded id (see [`super::delta`]) and the
/// 10 bytes of the [`PointResult`].
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
    fn rounding_is_libms() {
        let below_half = f32::from_bits(0.5f32.to_bits() - 1);
        let mut values = vec![0.0, -0.0, 0.5, -0.5, below_half, -below_half, 1.5, -2.5];
        values.extend([LIMIT as f32, -(LIMIT as f32), 8_388_606.5, -8_388_606.5]);
        values.extend([8_388_608.0, -8_388_608.0, 1.0e9, -1.0e9, 1.5e-45, -1.5e-45]);
        for k in -3000..3000 {
            let k = k as f32;
            values.extend([k + 0.5, k - 0.5, k + below_half, k * 1.37, k * 2796.2031]);
        }
        for x in values {
            assert_eq!(round_half_away(2.0 * x), libm::roundf(x) as i32, "{x}");
        }
    }

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
    fn point_quantisation_and_bytes() {
        let p = PointResult::from_camera_centred(&Vector3::new(-1.0, 2047.0, -0.5 / 4096.0), 0.01);
        assert_eq!(
            p,
            PointResult::Point {
                xyz: [-4096, 2047 * 4096, -1],
                miss: 3
            }
        );
        assert_eq!(
            p.to_bytes(),
            [0x00, 0xF0, 0xFF, 0x00, 0xF0, 0x7F, 0xFF, 0xFF, 0xFF, 0x03]
        );
        assert_eq!(PointResult::from_bytes(p.to_bytes()), Some(p));
        let far = PointResult::from_camera_centred(&Vector3::new(0.0, 2048.0, 0.0), 0.0);
        assert_eq!(far, PointResult::Failed(PointStatus::OutOfRange));
        // The last units inside the range (f32 holds whole units only out there).
        let edge = (LIMIT / POINT_UNITS_PER_MM) as f32;
        let inside = PointResult::from_camera_centred(&Vector3::new(edge, 0.0, -edge), 0.0);
        let mm = LIMIT / POINT_UNITS_PER_MM;
        assert_eq!(inside.camera_centred_mm(), Some(Vector3::new(mm, 0.0, -mm)));
        let beyond = PointResult::from_camera_centred(&Vector3::new(0.0, 0.0, -2048.0), 0.0);
        assert_eq!(beyond, PointResult::Failed(PointStatus::OutOfRange));
        for inf in [f32::INFINITY, f32::NEG_INFINITY] {
            let p = PointResult::from_camera_centred(&Vector3::new(1.0, inf, 0.0), 0.0);
            assert_eq!(p, PointResult::Failed(PointStatus::OutOfRange));
        }
        let nan = PointResult::from_camera_centred(&Vector3::new(f32::NAN, 0.0, 0.0), 0.0);
        assert_eq!(nan, PointResult::Failed(PointStatus::OutOfRange));
        let wide = PointResult::from_camera_centred(&Vector3::new(1.0, 1.0, 1.0), 5.0);
        assert_eq!(wide.miss_mm(), Some(f64::from(MISS_SATURATED) / 256.0));
        assert_eq!(
            PointResult::from_bytes([0, 0, 0, 0, 0, 0, 0, 0, 0, 0xF5]),
            Some(PointResult::Failed(PointStatus::Conflict))
        );
        assert_eq!(
            PointResult::from_bytes([0, 0, 0, 0, 0, 0, 0, 0, 0, 0xF6]),
            Some(PointResult::Failed(PointStatus::OffSensor))
        );
        assert_eq!(
            PointResult::from_bytes([0, 0, 0, 0, 0, 0, 0, 0, 0, 0xF7]),
            None
        );
    }
}
