//! The real scoliotic backs of `../shared/real-backs` (see its README): binary PLY in metres
//! in the scanner's frame, converted to the camera system (mm) and thinned to a dot pattern's
//! spacing. Never committed; the tests using them skip, saying so, when the folder is absent.

use deltaz_surface::{thin, Frame, ScanPoint};
use nalgebra::{Matrix3, Vector3};
use std::path::{Path, PathBuf};

/// Where the data lie (`../shared/real-backs` beside the repository), or `None`: a visible skip.
pub fn folder() -> Option<PathBuf> {
    deltaz_testkit::shared_data("real-backs")
}

/// A scan's vertices (scanner frame: x right, y down, z away, m) in the camera system (x right,
/// y up, z toward the camera, mm).
pub fn read_ply(path: &Path) -> Result<Vec<Vector3<f64>>, String> {
    let points = deltaz_host::io::ply::read_points(path).map_err(|e| e.to_string())?;
    Ok(points
        .into_iter()
        .map(|(_, p)| Vector3::new(1000.0 * p.x, -1000.0 * p.y, -1000.0 * p.z))
        .collect())
}

/// The primary Cobb angle of each patient (name, degrees): every row of `cobb_angles.csv`
/// (a row that does not read panics, naming it: no patient is left out unseen).
pub fn cobb_angles(dir: &Path) -> Vec<(String, f64)> {
    let text = std::fs::read_to_string(dir.join("cobb_angles.csv")).unwrap();
    text.lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let (name, cobb) = l.split_once(',').unwrap_or((l, ""));
            let cobb = cobb
                .trim()
                .parse()
                .unwrap_or_else(|_| panic!("cobb_angles.csv: {l:?}"));
            (name.trim().to_string(), cobb)
        })
        .collect()
}

/// Where a dot lattice falls on a scan: its offset in the camera's x-y plane (in spacings)
/// and its turn about z (degrees).
#[derive(Debug, Clone, Copy, Default)]
pub struct Lattice {
    pub offset: [f64; 2],
    pub turn_deg: f64,
}

/// A scan thinned to `spacing` on `lattice` as a frame, each point with an isotropic σ of
/// `sigma` (the data carry none).
pub fn thinned(points: &[Vector3<f64>], spacing: f64, lattice: Lattice, sigma: f64) -> Frame {
    let (s, c) = lattice.turn_deg.to_radians().sin_cos();
    let [dx, dy] = lattice.offset.map(|o| o * spacing);
    let placed: Vec<Vector3<f64>> = points
        .iter()
        .map(|p| Vector3::new(c * p.x - s * p.y + dx, s * p.x + c * p.y + dy, p.z))
        .collect();
    Frame::new(
        thin(&placed, spacing)
            .into_iter()
            .map(|(i, ray)| ScanPoint {
                position: points[i],
                covariance: Matrix3::identity() * sigma * sigma,
                ray: Some(ray),
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
