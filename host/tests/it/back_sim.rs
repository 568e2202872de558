//! The back model's dots as a scan gives them: each dot's own noise (σ mostly along the
//! camera's line of sight) and the calibration's error common to all points of a scan.

use deltaz_host::simulate::back::{BackModel, Lattice, LatticeDot, Part};
use deltaz_surface::{CommonShare, Frame, ScanPoint};
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// The noise of a scan (mm, rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Noise {
    /// σ along the camera's line of sight.
    pub depth: f64,
    /// σ across it.
    pub lateral: f64,
    /// σ of the common shift (each axis).
    pub common_shift: f64,
    /// σ of the common rotation about the camera's y axis through the back's centre.
    pub common_tilt: f64,
}

impl Noise {
    /// The issue's: 0.4 mm in depth, and a common share.
    pub fn issue() -> Self {
        Self {
            depth: 0.4,
            lateral: 0.1,
            common_shift: 0.3,
            common_tilt: 0.1f64.to_radians(),
        }
    }
}

/// The back's centre, which the common rotation turns about.
const CENTRE: Vector3<f64> = Vector3::new(0.0, 0.0, -1500.0);

/// A point's common-share sensitivity: a shift, and a rotation about y through the centre.
fn sensitivity(p: &Vector3<f64>) -> DMatrix<f64> {
    let turn = Vector3::y().cross(&(p - CENTRE));
    DMatrix::from_fn(3, 4, |r, c| if c < 3 { f64::from(r == c) } else { turn[r] })
}

/// The common share's covariance.
fn common_covariance(noise: &Noise) -> DMatrix<f64> {
    let s = noise.common_shift.powi(2);
    DMatrix::from_diagonal(&DVector::from_vec(vec![s, s, s, noise.common_tilt.powi(2)]))
}

/// A draw of the common error δ of one scan.
pub fn common_draw(noise: &Noise, rng: &mut ChaCha8Rng) -> DVector<f64> {
    let sd = common_covariance(noise).map_diagonal(f64::sqrt);
    sd.map(|s| s * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, rng))
}

/// The dots on the back (the arms too) measured: true point + own noise + G δ; `calibration`
/// is the fingerprint.
pub fn frame(dots: &[LatticeDot], noise: &Noise, delta: &DVector<f64>, rng: &mut ChaCha8Rng) -> Frame {
    let mut g_all = DMatrix::zeros(3 * dots.len(), 4);
    let points = dots
        .iter()
        .enumerate()
        .map(|(i, d)| {
            let p = d.hit.point;
            let sight = p.normalize();
            let along = sight * sight.transpose();
            let cov = along * noise.depth.powi(2) + (Matrix3::identity() - along) * noise.lateral.powi(2);
            let own = cov.cholesky().unwrap().l() * Vector3::from_fn(|_, _| <StandardNormal as Distribution<f64>>::sample(&StandardNormal, rng));
            let g = sensitivity(&p);
            g_all.rows_mut(3 * i, 3).copy_from(&g);
            let common = &g * delta;
            ScanPoint {
                position: p + own + Vector3::new(common[0], common[1], common[2]),
                covariance: cov,
                ray: d.ray,
            }
        })
        .collect();
    Frame {
        points,
        calibration: Some(0x00de_17a2),
        common: CommonShare::Core {
            covariance: common_covariance(noise),
            sensitivity: g_all,
        },
    }
}

/// A seeded generator for draw `k` of a test.
pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// The dots a projector lattice `spacing` apart puts on `model`, the back's only.
pub fn back_dots(model: &BackModel, spacing: f64) -> Vec<LatticeDot> {
    model.sample(&Lattice::beside_camera(spacing))
}

/// Whether any dot lies on an arm.
pub fn on_arms(dots: &[LatticeDot]) -> usize {
    dots.iter().filter(|d| d.hit.part == Part::Arm).count()
}
