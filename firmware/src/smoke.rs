//! The boot-time smoke computation: one intersection on the paper's rig (Tables 1-4), so a board
//! shows at once that the shared model runs on it.

use deltaz_shared::collinearity::Camera;
use deltaz_shared::paper::{
    table2_exterior, table4_direction, DC40_GRID, TABLE1_INNER, TABLE3_GLOBAL,
};
use deltaz_shared::projector::{Projector, ProjectorRay};
use deltaz_shared::rig::{Method, Rig};
use nalgebra::Vector3;

/// The id of the smoke dot, carrying Table 4's ray "12".
pub const RAY: u16 = 12;

/// Index of ray "12" in [`TABLE4`](deltaz_shared::paper::TABLE4).
const TABLE4_RAY_12: usize = 4;

/// The paper's camera: Table 1 inner orientation, Table 2's 1st-plane exterior orientation.
pub fn paper_camera() -> Camera<f64> {
    Camera {
        grid: DC40_GRID,
        inner: TABLE1_INNER,
        exterior: table2_exterior(0),
    }
}

/// The paper's rig in f64: [`paper_camera`], Table 3's projector centre and Table 4's ray "12".
pub fn paper_rig() -> Rig<f64, [ProjectorRay<f64>; 1]> {
    let Camera {
        grid,
        inner,
        exterior,
    } = paper_camera();
    let ray = ProjectorRay {
        id: RAY,
        direction: table4_direction(TABLE4_RAY_12),
        offset: Vector3::zeros(),
    };
    // Table 4's cosines normalised: a valid one-ray table.
    let projector = Projector::from_checked(Vector3::from(TABLE3_GLOBAL), [ray]);
    Rig::new(grid, inner, &exterior, projector)
}

/// [`paper_rig`] cast to f32 after centring in f64, as an upload does ([`Rig::cast`]).
pub fn paper_rig_f32() -> Option<Rig<f32, heapless::Vec<ProjectorRay<f32>, 1>>> {
    paper_rig().cast().ok()
}

/// The pixel (col, row) where the camera sees ray 12 hit the plate Z = 0 (f64).
pub fn smoke_pixel() -> Option<(f64, f64)> {
    let ray = paper_rig().projector_centred().ray(RAY).ok()?;
    let centre = paper_camera().exterior.centre;
    let on_plate = ray.at(-(ray.point.z + centre.z) / ray.direction.z) + centre;
    paper_camera().world_to_pixel(&on_plate).ok()
}

/// The smoke point in f32 (world mm), or `None` if the geometry were degenerate.
pub fn smoke_point() -> Option<Vector3<f32>> {
    let (col, row) = smoke_pixel()?;
    paper_rig_f32()?
        .reconstruct(RAY, col as f32, row as f32, Method::ClosestApproach)
        .ok()
        .map(|hit| hit.point)
}

/// The longest smoke line (three coordinates of up to 10 + 1 + 6 digits and a sign).
pub const SMOKE_LINE: usize = 80;

/// The line a board prints at boot: `deltaz smoke point X Y Z` in mm with 6 decimals, or
/// `deltaz smoke degenerate`, with a newline; returns its length in `out`. Written without
/// `core::fmt`, whose float formatting would bring panic paths into the firmware.
pub fn smoke_line(point: Option<Vector3<f32>>, out: &mut [u8; SMOKE_LINE]) -> usize {
    let mut line = Line { buf: out, len: 0 };
    match point {
        Some(p) => {
            line.push(b"deltaz smoke point");
            for v in [p.x, p.y, p.z] {
                line.push(b" ");
                line.decimal(v);
            }
        }
        None => line.push(b"deltaz smoke degenerate"),
    }
    line.push(b"\n");
    line.len
}

/// Bytes appended to a buffer (what does not fit is dropped).
struct Line<'a> {
    buf: &'a mut [u8],
    len: usize,
}

impl Line<'_> {
    fn push(&mut self, bytes: &[u8]) {
        for &b in bytes {
            if let Some(slot) = self.buf.get_mut(self.len) {
                *slot = b;
                self.len += 1;
            }
        }
    }

    /// `v` with 6 decimals (the fraction of |v| is exact in f32; scaled by 10⁶ and rounded);
    /// |v| clamped to 4·10⁹ (NaN too).
    fn decimal(&mut self, v: f32) {
        if v < 0.0 {
            self.push(b"-");
        }
        let a = v.abs().min(4.0e9);
        let mut whole = a as u32;
        let mut micro = ((a - whole as f32) * 1e6 + 0.5) as u32;
        if micro >= 1_000_000 {
            whole += 1;
            micro -= 1_000_000;
        }
        self.digits(whole, 1);
        self.push(b".");
        self.digits(micro, 6);
    }

    /// `n` in decimal, zero-padded to `width` digits.
    fn digits(&mut self, mut n: u32, width: usize) {
        let mut buf = [b'0'; 10];
        let mut used = 0;
        for slot in buf.iter_mut().rev() {
            *slot = b'0' + (n % 10) as u8;
            n /= 10;
            used += 1;
            if n == 0 && used >= width {
                break;
            }
        }
        self.push(buf.get(buf.len() - used..).unwrap_or_default());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smoke_line_prints_six_decimals() {
        let mut out = [0u8; SMOKE_LINE];
        let p = Vector3::new(-123.456_79_f32, 0.5, 1999.0);
        let n = smoke_line(Some(p), &mut out);
        let text = core::str::from_utf8(&out[..n]).unwrap();
        assert!(
            text.starts_with("deltaz smoke point ") && text.ends_with('\n'),
            "{text}"
        );
        let printed: Vec<f64> = text
            .split_whitespace()
            .skip(3)
            .map(|v| v.parse().unwrap())
            .collect();
        for (got, v) in printed.iter().zip([p.x, p.y, p.z]) {
            let want: f64 = format!("{v:.6}").parse().unwrap();
            assert!((got - want).abs() <= 1.5e-6, "{got} vs {want}");
        }
        assert_eq!(
            out[..n].split(|&b| b == b' ').nth(4),
            Some(&b"0.500000"[..])
        );
        assert_eq!(smoke_line(None, &mut out), 24);
        assert_eq!(&out[..24], b"deltaz smoke degenerate\n");
        // The widest coordinates fit.
        let wide = Vector3::repeat(-5.0e9f32);
        let n = smoke_line(Some(wide), &mut out);
        assert_eq!(n, 76);
        assert!(out[..n].ends_with(b" -4000000000.000000\n"));
    }
}
