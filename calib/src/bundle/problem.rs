//! The bundle adjustment problem: parameter blocks, which of them are free, the state layout,
//! and the observations (mrcal's naming: state p, measurements x, J = ∂x/∂p).
//!
//! State: the *camera* part (free inner parameters, then the free pose parameters image by image)
//! followed by the *points* (3 per point). The solver eliminates the points (Schur complement), so
//! the layout is queried through [`Problem::state_index_inner`], [`Problem::state_index_pose`] and
//! [`Problem::num_states_camera`], never hard-coded.

use crate::residual::{inner_from_array, inner_to_array, INNER, INNER_NAMES, POSE};
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::ExteriorOrientation;
use nalgebra::{Vector2, Vector3};

/// Which inner parameters are estimated (the rest are held at their values).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FreeParameters {
    /// f, cx, cy, k1, k2, k3, p1, p2.
    pub inner: [bool; INNER],
}

impl Default for FreeParameters {
    /// The paper's set (Table 1): f, cx, cy, k1.
    fn default() -> Self {
        Self {
            inner: [true, true, true, true, false, false, false, false],
        }
    }
}

/// One image observation in the problem.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProblemObservation {
    /// Image index.
    pub image: usize,
    /// Point index.
    pub point: usize,
    /// Observed photo coordinates (mm).
    pub photo: Vector2<f64>,
    /// Index into the caller's observation list.
    pub source: usize,
    /// False once rejected as a gross error.
    pub active: bool,
}

/// A control point's observed coordinates and σ (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ControlObservation {
    /// Coordinates (mm).
    pub xyz: Vector3<f64>,
    /// σ per coordinate (mm); 0 = fixed (weighted as 1e-6 mm).
    pub sigma: f64,
}

/// The bundle adjustment problem.
#[derive(Debug, Clone)]
pub struct Problem {
    /// Pixel mapping (not adjusted).
    pub grid: PixelGrid<f64>,
    /// Inner orientation (current values).
    pub inner: InnerOrientation<f64>,
    /// Which inner parameters are free.
    pub free: FreeParameters,
    /// Image labels.
    pub images: Vec<String>,
    /// Exterior orientation per image (current values).
    pub poses: Vec<ExteriorOrientation<f64>>,
    /// Which pose parameters are free per image (κ, φ, ω, X0, Y0, Z0).
    pub pose_free: Vec<[bool; POSE]>,
    /// Point labels.
    pub points: Vec<String>,
    /// Point coordinates (current values).
    pub xyz: Vec<Vector3<f64>>,
    /// Control observation of each point, if any.
    pub control: Vec<Option<ControlObservation>>,
    /// Image observations.
    pub observations: Vec<ProblemObservation>,
    /// A priori σ of image coordinates (mm): image observations have weight 1, control
    /// (σ_image / σ_control)².
    pub image_sigma_mm: f64,
}

impl Problem {
    /// The state index of inner parameter `k` (order f, cx, cy, k1, k2, k3, p1, p2), if free.
    pub fn state_index_inner(&self, k: usize) -> Option<usize> {
        self.free.inner[k].then(|| self.free.inner[..k].iter().filter(|f| **f).count())
    }

    /// Number of free inner parameters.
    pub fn num_states_inner(&self) -> usize {
        self.free.inner.iter().filter(|f| **f).count()
    }

    /// The state index of pose parameter `k` (κ, φ, ω, X0, Y0, Z0) of image `i`, if free.
    pub fn state_index_pose(&self, i: usize, k: usize) -> Option<usize> {
        if !self.pose_free[i][k] {
            return None;
        }
        let before: usize = self.pose_free[..i]
            .iter()
            .map(|f| f.iter().filter(|x| **x).count())
            .sum();
        let within = self.pose_free[i][..k].iter().filter(|x| **x).count();
        Some(self.num_states_inner() + before + within)
    }

    /// Number of camera states (free inner + free pose parameters).
    pub fn num_states_camera(&self) -> usize {
        self.num_states_inner()
            + self
                .pose_free
                .iter()
                .map(|f| f.iter().filter(|x| **x).count())
                .sum::<usize>()
    }

    /// The state index of coordinate `k` of point `j`.
    pub fn state_index_point(&self, j: usize, k: usize) -> usize {
        self.num_states_camera() + 3 * j + k
    }

    /// The weight of a control observation relative to an image observation.
    pub fn control_weight(&self, c: &ControlObservation) -> f64 {
        (self.image_sigma_mm / c.sigma.max(1e-6)).powi(2)
    }

    /// Readable names of the camera states, by state index ("f", "s3.Z0", …).
    pub fn camera_state_names(&self) -> Vec<String> {
        const POSE_NAMES: [&str; POSE] = ["kappa", "phi", "omega", "X0", "Y0", "Z0"];
        let mut names = vec![String::new(); self.num_states_camera()];
        for (k, name) in INNER_NAMES.iter().enumerate() {
            if let Some(s) = self.state_index_inner(k) {
                names[s] = (*name).to_owned();
            }
        }
        let mut s = self.num_states_inner();
        for (image, free) in self.images.iter().zip(&self.pose_free) {
            for (name, _) in POSE_NAMES.iter().zip(free).filter(|(_, f)| **f) {
                names[s] = format!("{image}.{name}");
                s += 1;
            }
        }
        names
    }

    /// Applies a camera-state step and point steps.
    pub fn apply(&mut self, camera_step: &[f64], point_steps: &[Vector3<f64>]) {
        let mut a = inner_to_array(&self.inner);
        for (k, value) in a.iter_mut().enumerate() {
            if let Some(s) = self.state_index_inner(k) {
                *value += camera_step[s];
            }
        }
        self.inner = inner_from_array(a);
        for i in 0..self.poses.len() {
            let step: [f64; POSE] = std::array::from_fn(|k| {
                self.state_index_pose(i, k).map_or(0.0, |s| camera_step[s])
            });
            let pose = &mut self.poses[i];
            pose.kappa += step[0];
            pose.phi += step[1];
            pose.omega += step[2];
            pose.centre += Vector3::new(step[3], step[4], step[5]);
        }
        for (x, d) in self.xyz.iter_mut().zip(point_steps) {
            *x += d;
        }
    }
}
