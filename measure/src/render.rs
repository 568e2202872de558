//! A renderer of synthetic target images: circular targets and projected dots imaged as ellipses
//! (exact area coverage by supersampling), defocus blur, uneven illumination, a non-uniform
//! background and sensor noise, written as 8- or 16-bit PNG.
//!
//! Intensities are in DN of an 8-bit scale (0..255); 16-bit output multiplies by 257. A pixel
//! (col, row) covers [col − ½, col + ½] × [row − ½, row + ½]: (0, 0) is the centre of the top-left
//! pixel, as in every deltaz file.

use anyhow::{Context, Result};
use image::{ImageBuffer, Luma};
use rand::rngs::StdRng;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use std::path::Path;

/// One imaged target or dot: a filled ellipse of uniform brightness.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spot {
    /// Centre column (pixels).
    pub col: f64,
    /// Centre row (pixels).
    pub row: f64,
    /// Semi-axis along `angle` (pixels).
    pub semi_a: f64,
    /// Semi-axis across `angle` (pixels).
    pub semi_b: f64,
    /// Direction of `semi_a`, from the column axis towards the row axis (rad).
    pub angle: f64,
    /// Brightness above the background before illumination falloff (DN; negative: a dark target).
    pub amplitude: f64,
}

impl Spot {
    /// A circular spot.
    pub fn circle(col: f64, row: f64, radius: f64, amplitude: f64) -> Self {
        Self {
            col,
            row,
            semi_a: radius,
            semi_b: radius,
            angle: 0.0,
            amplitude,
        }
    }

    /// A point's coordinates along the ellipse's axes over their semi-axes, by the sine and
    /// cosine of its `angle`: inside where u² + v² < 1.
    fn normalised(&self, (s, c): (f64, f64), col: f64, row: f64) -> (f64, f64) {
        let (dx, dy) = (col - self.col, row - self.row);
        (
            (c * dx + s * dy) / self.semi_a,
            (-s * dx + c * dy) / self.semi_b,
        )
    }

    /// Approximate signed distance (pixels) of a point from the ellipse's edge, negative inside:
    /// d = (ρ − 1)/|∇ρ| with ρ the ellipse's normalised radius; exact for circles.
    fn signed_distance(&self, col: f64, row: f64) -> f64 {
        let (u, v) = self.normalised(self.angle.sin_cos(), col, row);
        let rho = u.hypot(v);
        let grad = (u / self.semi_a).hypot(v / self.semi_b);
        if grad < 1e-12 {
            return -self.semi_b.min(self.semi_a);
        }
        (rho - 1.0) * rho / grad
    }
}

/// The smooth background: level + linear gradient + a low-frequency ripple (DN).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Background {
    /// Level at the image centre (DN).
    pub level: f64,
    /// Change per pixel along columns (DN/pixel).
    pub slope_col: f64,
    /// Change per pixel along rows (DN/pixel).
    pub slope_row: f64,
    /// Amplitude of the ripple sin(2πc/P)·cos(2πr/P) (DN).
    pub ripple: f64,
    /// Period P of the ripple (pixels).
    pub ripple_period: f64,
}

impl Background {
    /// A flat background.
    pub fn flat(level: f64) -> Self {
        Self {
            level,
            slope_col: 0.0,
            slope_row: 0.0,
            ripple: 0.0,
            ripple_period: 1.0,
        }
    }

    fn at(&self, col: f64, row: f64, width: usize, height: usize) -> f64 {
        let tau = std::f64::consts::TAU;
        let (dc, dr) = (col - width as f64 / 2.0, row - height as f64 / 2.0);
        self.level
            + self.slope_col * dc
            + self.slope_row * dr
            + self.ripple
                * (tau * col / self.ripple_period).sin()
                * (tau * row / self.ripple_period).cos()
    }
}

/// Sample bit depth of the written image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BitDepth {
    /// 8 bit, 0..255.
    Eight,
    /// 16 bit, 0..65535 (DN × 257).
    Sixteen,
}

/// Everything that makes an image.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// Width (pixels).
    pub width: usize,
    /// Height (pixels).
    pub height: usize,
    /// The targets and dots.
    pub spots: Vec<Spot>,
    /// The background.
    pub background: Background,
    /// Uneven illumination: spot brightness falls by this fraction from the centre to the corners
    /// (quadratically in the distance).
    pub falloff: f64,
    /// Defocus blur, σ of a Gaussian (pixels); 0 for none.
    pub blur_sigma: f64,
    /// Sensor noise σ (DN), Gaussian, independent per pixel.
    pub noise_sigma: f64,
    /// Noise seed.
    pub seed: u64,
}

/// Sub-samples per pixel side where an edge crosses a pixel (the area error is below 1/16² of a
/// pixel per edge pixel, unbiased in position).
const SUPERSAMPLE: usize = 16;

/// A rendered image in floating-point DN (before quantisation).
#[derive(Debug, Clone, PartialEq)]
pub struct Rendered {
    /// Width (pixels).
    pub width: usize,
    /// Height (pixels).
    pub height: usize,
    /// Row-major DN values.
    pub pixels: Vec<f64>,
}

impl Scene {
    /// The illumination factor of `spot`: 1 at the image centre, 1 − `falloff` at the corners.
    pub fn illumination(&self, spot: &Spot) -> f64 {
        let (half_w, half_h) = (self.width as f64 / 2.0, self.height as f64 / 2.0);
        let corner2 = half_w * half_w + half_h * half_h;
        1.0 - self.falloff * ((spot.col - half_w).powi(2) + (spot.row - half_h).powi(2)) / corner2
    }

    /// Render: area coverage of every spot × illumination, blurred, plus background and noise.
    pub fn render(&self) -> Rendered {
        let (w, h) = (self.width, self.height);
        let mut spots = vec![0.0; w * h];
        for spot in &self.spots {
            let gain = spot.amplitude * self.illumination(spot);
            let reach = spot.semi_a.max(spot.semi_b) + 1.0;
            let c0 = (spot.col - reach).floor().max(0.0) as usize;
            let r0 = (spot.row - reach).floor().max(0.0) as usize;
            let c1 = ((spot.col + reach).ceil() as usize).min(w.saturating_sub(1));
            let r1 = ((spot.row + reach).ceil() as usize).min(h.saturating_sub(1));
            for r in r0..=r1 {
                for c in c0..=c1 {
                    spots[r * w + c] += gain * coverage(spot, c as f64, r as f64);
                }
            }
        }
        if self.blur_sigma > 0.0 {
            gaussian_blur(&mut spots, w, h, self.blur_sigma);
        }
        let mut rng = StdRng::seed_from_u64(self.seed);
        let noise = Normal::new(0.0, self.noise_sigma.max(0.0)).expect("σ ≥ 0 is valid");
        for r in 0..h {
            for c in 0..w {
                let i = r * w + c;
                spots[i] += self.background.at(c as f64, r as f64, w, h) + noise.sample(&mut rng);
            }
        }
        Rendered {
            width: w,
            height: h,
            pixels: spots,
        }
    }
}

/// Fraction of pixel (col, row) inside the spot.
fn coverage(spot: &Spot, col: f64, row: f64) -> f64 {
    let d = spot.signed_distance(col, row);
    if d < -1.0 {
        return 1.0;
    }
    if d > 1.0 {
        return 0.0;
    }
    let step = 1.0 / SUPERSAMPLE as f64;
    let turn = spot.angle.sin_cos();
    let mut inside = 0usize;
    for i in 0..SUPERSAMPLE {
        for j in 0..SUPERSAMPLE {
            let x = col - 0.5 + (i as f64 + 0.5) * step;
            let y = row - 0.5 + (j as f64 + 0.5) * step;
            let (u, v) = spot.normalised(turn, x, y);
            if u * u + v * v < 1.0 {
                inside += 1;
            }
        }
    }
    inside as f64 / (SUPERSAMPLE * SUPERSAMPLE) as f64
}

/// Separable Gaussian blur (kernel ±4σ, normalised; borders clamp).
fn gaussian_blur(pixels: &mut [f64], w: usize, h: usize, sigma: f64) {
    let radius = (4.0 * sigma).ceil() as isize;
    let kernel: Vec<f64> = (-radius..=radius)
        .map(|k| (-(k * k) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = kernel.iter().sum();
    let kernel: Vec<f64> = kernel.iter().map(|k| k / sum).collect();
    let mut line = Vec::new();
    let mut pass = |pixels: &mut [f64], n: usize, stride: usize, count: usize, step: usize| {
        for l in 0..count {
            line.clear();
            line.extend((0..n).map(|i| pixels[l * step + i * stride]));
            for i in 0..n {
                let mut acc = 0.0;
                for (k, weight) in kernel.iter().enumerate() {
                    let j = (i as isize + k as isize - radius).clamp(0, n as isize - 1) as usize;
                    acc += weight * line[j];
                }
                pixels[l * step + i * stride] = acc;
            }
        }
    };
    pass(pixels, w, 1, h, w);
    pass(pixels, h, w, w, 1);
}

impl Rendered {
    /// Quantised to 8 bit (rounded, clamped to 0..255).
    pub fn to_u8(&self) -> ImageBuffer<Luma<u8>, Vec<u8>> {
        let data = self
            .pixels
            .iter()
            .map(|v| v.round().clamp(0.0, 255.0) as u8)
            .collect();
        ImageBuffer::from_raw(self.width as u32, self.height as u32, data)
            .expect("buffer size matches")
    }

    /// Quantised to 16 bit (DN × 257, rounded, clamped to 0..65535).
    pub fn to_u16(&self) -> ImageBuffer<Luma<u16>, Vec<u16>> {
        let data = self
            .pixels
            .iter()
            .map(|v| (v * 257.0).round().clamp(0.0, 65535.0) as u16)
            .collect();
        ImageBuffer::from_raw(self.width as u32, self.height as u32, data)
            .expect("buffer size matches")
    }

    /// Write as PNG: to a temporary file in the same directory, then renamed.
    pub fn save_png(&self, path: &Path, depth: BitDepth) -> Result<()> {
        let tmp = path.with_extension("png.tmp");
        let written = match depth {
            BitDepth::Eight => self.to_u8().save_with_format(&tmp, image::ImageFormat::Png),
            BitDepth::Sixteen => self
                .to_u16()
                .save_with_format(&tmp, image::ImageFormat::Png),
        };
        written.with_context(|| format!("writing {}", tmp.display()))?;
        std::fs::rename(&tmp, path).with_context(|| format!("renaming to {}", path.display()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Area coverage integrates to the ellipse's area, and the intensity centroid of a noise-free
    /// render is the ellipse centre (to the supersampling's precision).
    #[test]
    fn coverage_area_and_centre() {
        let spot = Spot {
            col: 20.3,
            row: 17.65,
            semi_a: 6.0,
            semi_b: 4.0,
            angle: 0.6,
            amplitude: 100.0,
        };
        let scene = Scene {
            width: 40,
            height: 36,
            spots: vec![spot],
            background: Background::flat(0.0),
            falloff: 0.0,
            blur_sigma: 1.0,
            noise_sigma: 0.0,
            seed: 1,
        };
        let img = scene.render();
        let (mut sum, mut sc, mut sr) = (0.0, 0.0, 0.0);
        for r in 0..img.height {
            for c in 0..img.width {
                let v = img.pixels[r * img.width + c];
                sum += v;
                sc += v * c as f64;
                sr += v * r as f64;
            }
        }
        let area = std::f64::consts::PI * 24.0;
        assert!((sum / 100.0 - area).abs() < 0.02, "area {}", sum / 100.0);
        assert!((sc / sum - 20.3).abs() < 2e-3 && (sr / sum - 17.65).abs() < 2e-3);
    }

    /// Noise has the σ asked for; 16-bit output is 257 × DN.
    #[test]
    fn noise_and_quantisation() {
        let scene = Scene {
            width: 200,
            height: 100,
            spots: vec![],
            background: Background::flat(100.0),
            falloff: 0.0,
            blur_sigma: 0.0,
            noise_sigma: 2.0,
            seed: 7,
        };
        let img = scene.render();
        let n = img.pixels.len() as f64;
        let mean = img.pixels.iter().sum::<f64>() / n;
        let sd = (img.pixels.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
        assert!(
            (mean - 100.0).abs() < 0.05 && (sd - 2.0).abs() < 0.05,
            "{mean} {sd}"
        );
        let v = img.pixels[5];
        assert_eq!(img.to_u16().get_pixel(5, 0)[0], (v * 257.0).round() as u16);
        assert_eq!(img.to_u8().get_pixel(5, 0)[0], v.round() as u8);
    }
}
