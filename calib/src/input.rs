//! Plain input types: what the CLI crate makes of its files.

use nalgebra::Vector3;

/// A control point with known coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct ControlPoint {
    /// Its label.
    pub point: String,
    /// Coordinates (mm).
    pub xyz: Vector3<f64>,
    /// Standard deviation of each coordinate (mm); 0 = fixed (error-free).
    pub sigma: f64,
}

/// One image measurement of a target (control or tie point).
#[derive(Debug, Clone, PartialEq)]
pub struct Measurement {
    /// The image's label.
    pub image: String,
    /// The point's label.
    pub point: String,
    /// Pixel column.
    pub col: f64,
    /// Pixel row (downwards).
    pub row: f64,
}

/// The distinct image labels of measurements, in order of first appearance.
pub fn image_labels(measurements: &[Measurement]) -> Vec<String> {
    let mut seen = std::collections::HashSet::new();
    measurements
        .iter()
        .filter(|m| seen.insert(m.image.as_str()))
        .map(|m| m.image.clone())
        .collect()
}
