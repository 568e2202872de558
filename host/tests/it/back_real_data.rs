//! The real scoliotic backs of `/work/shared/real-backs` (see its README): binary PLY in metres
//! in the scanner's frame, converted to the camera system (mm) and thinned to a dot pattern's
//! spacing. Never committed; the tests using them skip, saying so, when the folder is absent.

use deltaz_surface::{thin, Frame, ScanPoint};
use nalgebra::{Matrix3, Vector3};
use std::path::{Path, PathBuf};

/// Where the data lie (beside the repository, as the project's shared folder).
pub fn folder() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/real-backs");
    let alt = PathBuf::from("/work/shared/real-backs");
    [dir, alt]
        .into_iter()
        .find(|d| d.join("cobb_angles.csv").is_file())
}

/// The vertices of a binary little-endian PLY whose vertices start with float x, y, z.
pub fn read_ply(path: &Path) -> Result<Vec<Vector3<f64>>, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let end = b"end_header\n";
    let body = bytes
        .windows(end.len())
        .position(|w| w == end)
        .ok_or_else(|| format!("{}: no end_header", path.display()))?
        + end.len();
    let header =
        std::str::from_utf8(&bytes[..body]).map_err(|e| format!("{}: {e}", path.display()))?;
    if !header.contains("format binary_little_endian 1.0") {
        return Err(format!(
            "{}: not a binary little-endian PLY",
            path.display()
        ));
    }
    let mut count = 0usize;
    let mut properties = 0usize;
    let mut in_vertex = false;
    for line in header.lines() {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["element", "vertex", n] => {
                count = n
                    .parse()
                    .map_err(|_| format!("{}: bad vertex count {n}", path.display()))?;
                in_vertex = true;
            }
            ["element", ..] => in_vertex = false,
            ["property", "float", _] if in_vertex => properties += 1,
            ["property", ..] if in_vertex => {
                return Err(format!(
                    "{}: only float vertex properties are read ({line})",
                    path.display()
                ))
            }
            _ => {}
        }
    }
    let stride = 4 * properties;
    if properties < 3 || bytes.len() < body + count * stride {
        return Err(format!(
            "{}: {count} vertices of {properties} floats do not fit",
            path.display()
        ));
    }
    let f = |o: usize| f64::from(f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap()));
    Ok((0..count)
        .map(|i| {
            let o = body + i * stride;
            // Scanner (x right, y down, z away, m) → camera system (x right, y up, z toward, mm).
            Vector3::new(1000.0 * f(o), -1000.0 * f(o + 4), -1000.0 * f(o + 8))
        })
        .collect())
}

/// The primary Cobb angle of each patient (name, degrees).
pub fn cobb_angles(dir: &Path) -> Vec<(String, f64)> {
    let text = std::fs::read_to_string(dir.join("cobb_angles.csv")).unwrap();
    text.lines()
        .skip(1)
        .filter_map(|l| {
            let (name, cobb) = l.split_once(',')?;
            Some((name.trim().to_string(), cobb.trim().parse().ok()?))
        })
        .collect()
}

/// A scan thinned to `spacing` as a frame, each point with an isotropic σ of `sigma` (the
/// data carry none).
pub fn thinned(points: &[Vector3<f64>], spacing: f64, sigma: f64) -> Frame {
    let kept = thin(points, spacing);
    Frame::new(
        kept.into_iter()
            .map(|(i, ray)| ScanPoint {
                position: points[i],
                covariance: Matrix3::identity() * sigma * sigma,
                ray,
            })
            .collect(),
    )
}

/// Pearson's correlation.
pub fn correlation(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len() as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx).powi(2)).sum();
    let syy: f64 = y.iter().map(|b| (b - my).powi(2)).sum();
    sxy / (sxx * syy).sqrt()
}
