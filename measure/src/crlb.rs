//! The Cramér-Rao lower bound of a rendered dot's centre: the smallest variance any unbiased
//! estimator of the centre can reach from the pixels' noise, the yardstick for the template fit.
//!
//! The model is the renderer's own noiseless image of one dot ([`crate::render`]) on a plane
//! background, with the parameters the template fit estimates ([`super::fit`]): centre (2),
//! ellipse (3, as the symmetric semi-axis matrix M = R diag(a, b) Rᵀ, smooth also for a circle),
//! amplitude, blur σ, and the background plane (level, two slopes). With independent Gaussian
//! pixel noise of variance σ², the Fisher information is
//!
//! F = Σ_pixels (∂I/∂θ)(∂I/∂θ)ᵀ / σ²
//!
//! and the bound on the centre is the centre block of F⁻¹ (the full matrix is inverted, so the
//! nuisance parameters cost the centre what they cost it). ∂I/∂θ are central differences of the
//! renderer's image: steps of [`STEP`] (pixels, DN or DN/pixel), large against the renderer's
//! supersampling grid of 1/16 px so that the area coverage's steps average out.

use crate::render::{Background, Scene, Spot};
use nalgebra::{SMatrix, SVector};

const N: usize = 10;

/// Variance of rounding to integer DN (a uniform error of one DN's width): 1/12 DN².
pub const QUANTISATION_VARIANCE: f64 = 1.0 / 12.0;

/// Central-difference step of every parameter (pixels for centre, axes and blur; DN and
/// DN/pixel for amplitude and background, where the image is linear).
pub const STEP: f64 = 0.2;

/// The bound's standard deviations of one dot's centre (pixels).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CentreBound {
    /// σ of the column.
    pub col: f64,
    /// σ of the row.
    pub row: f64,
}

impl CentreBound {
    /// The bound on the RMS distance from the true centre: √(σ_col² + σ_row²).
    pub fn radial(&self) -> f64 {
        self.col.hypot(self.row)
    }
}

/// The dot's parameters θ: col, row, m₁₁, m₁₂, m₂₂, amplitude, blur σ, background level,
/// column slope, row slope (in a window whose centre is the dot's pixel).
type Theta = SVector<f64, N>;

/// The noiseless window image for parameters `theta`.
fn window_image(theta: &Theta, size: usize) -> Vec<f64> {
    let (m11, m12, m22) = (theta[2], theta[3], theta[4]);
    let mean = 0.5 * (m11 + m22);
    let half = (0.25 * (m11 - m22).powi(2) + m12 * m12).sqrt();
    let spot = Spot {
        col: theta[0],
        row: theta[1],
        semi_a: mean + half,
        semi_b: mean - half,
        angle: 0.5 * (2.0 * m12).atan2(m11 - m22),
        amplitude: theta[5],
    };
    let scene = Scene {
        width: size,
        height: size,
        spots: vec![spot],
        background: Background {
            level: theta[7],
            slope_col: theta[8],
            slope_row: theta[9],
            ripple: 0.0,
            ripple_period: 1.0,
        },
        falloff: 0.0,
        blur_sigma: theta[6],
        noise_sigma: 0.0,
        seed: 0,
    };
    scene.render().pixels
}

/// The bound for spot `index` of `scene` (its illumination, blur and background slopes), over a
/// square window reaching `margin` pixels beyond the dot's larger semi-axis plus 1 px of blur,
/// for pixel noise of variance `noise_variance` (DN²; add [`QUANTISATION_VARIANCE`] for 8-bit
/// images). `None` when the Fisher matrix is singular.
///
/// The window is about the template fit's (its blob box grown by the margin), so the bound is
/// that of an estimator seeing the fit's pixels: with 10 px of margin instead of 3 the
/// background plane is better known and the bound falls by 4 % at radius 3 and 9 % at radius
/// 10 (a circle of 160 DN, blur σ 1 px); the central-difference step changes it by under 1 %
/// from 0.1 to 0.3 px.
pub fn centre_bound(
    scene: &Scene,
    index: usize,
    margin: usize,
    noise_variance: f64,
) -> Option<CentreBound> {
    let spot = scene.spots[index];
    let reach = spot.semi_a.max(spot.semi_b).ceil() as usize + 1 + margin;
    let size = 2 * reach + 1;
    let (s, c) = spot.angle.sin_cos();
    let (a, b) = (spot.semi_a, spot.semi_b);
    let theta = Theta::from_column_slice(&[
        reach as f64 + spot.col.fract(),
        reach as f64 + spot.row.fract(),
        a * c * c + b * s * s,
        (a - b) * s * c,
        a * s * s + b * c * c,
        spot.amplitude * scene.illumination(&spot),
        scene.blur_sigma,
        scene.background.level,
        scene.background.slope_col,
        scene.background.slope_row,
    ]);
    let columns: Vec<Vec<f64>> = (0..N)
        .map(|k| {
            let mut step = Theta::zeros();
            step[k] = STEP;
            let (plus, minus) = (
                window_image(&(theta + step), size),
                window_image(&(theta - step), size),
            );
            plus.iter()
                .zip(&minus)
                .map(|(p, m)| (p - m) / (2.0 * STEP))
                .collect()
        })
        .collect();
    let mut fisher = SMatrix::<f64, N, N>::zeros();
    for i in 0..N {
        for j in 0..=i {
            let f: f64 = columns[i].iter().zip(&columns[j]).map(|(x, y)| x * y).sum();
            fisher[(i, j)] = f / noise_variance;
            fisher[(j, i)] = f / noise_variance;
        }
    }
    let covariance = fisher.cholesky()?.inverse();
    Some(CentreBound {
        col: covariance[(0, 0)].sqrt(),
        row: covariance[(1, 1)].sqrt(),
    })
}

/// The bound on the RMS centre error over the dots `dots` of `scene` in its 8-bit image
/// (noise σ² + [`QUANTISATION_VARIANCE`]): √(mean of σ_col² + σ_row²). `None` when a dot's
/// Fisher matrix is singular or there are no dots.
pub fn rms_bound_8bit(
    scene: &Scene,
    dots: impl IntoIterator<Item = usize>,
    margin: usize,
) -> Option<f64> {
    let variance = scene.noise_sigma.powi(2) + QUANTISATION_VARIANCE;
    let (mut sum, mut count) = (0.0, 0);
    for i in dots {
        sum += centre_bound(scene, i, margin, variance)?.radial().powi(2);
        count += 1;
    }
    (count > 0).then(|| (sum / count as f64).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against the edge's information: a disc's rim of length 2πr, blurred to a Gaussian edge
    /// of width s = √(σ_blur² + 1/12) (blur and the pixel's width), gives each centre
    /// coordinate A² π r / (2√π s) / σ² (∂I/∂c = A cos φ g(d), Σ cos² φ = πr, ∫ g² = 1/(2√π s)).
    /// The nuisance parameters can only raise the bound above it; the bound scales with σ and
    /// falls as √r.
    #[test]
    fn bound_against_the_edge_information() {
        let scene = |radius: f64| Scene {
            width: 100,
            height: 100,
            spots: vec![Spot::circle(50.3, 49.6, radius, 160.0)],
            background: Background::flat(40.0),
            falloff: 0.0,
            blur_sigma: 1.0,
            noise_sigma: 2.0,
            seed: 0,
        };
        let b4 = centre_bound(&scene(4.0), 0, 3, 4.0).unwrap();
        let b4_noisier = centre_bound(&scene(4.0), 0, 3, 16.0).unwrap();
        let b8 = centre_bound(&scene(8.0), 0, 3, 4.0).unwrap();
        assert!((b4_noisier.col / b4.col - 2.0).abs() < 1e-9);
        // Circle: both axes alike (to the supersampling's precision).
        assert!((b4.col / b4.row - 1.0).abs() < 0.03, "{b4:?}");
        let edge = (1.0f64 + 1.0 / 12.0).sqrt();
        let pi = std::f64::consts::PI;
        let edge_bound = 2.0 / (160.0 * (pi * 4.0 / (2.0 * pi.sqrt() * edge)).sqrt());
        let excess = b4.col / edge_bound;
        assert!(excess > 1.0 && excess < 1.15, "{b4:?} vs {edge_bound}");
        // Twice the rim: the bound falls by about √2.
        let ratio = b4.col / b8.col;
        assert!(ratio > 1.25 && ratio < 1.6, "{ratio}");
    }
}
