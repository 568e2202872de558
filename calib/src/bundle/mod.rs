//! Camera calibration by self-calibrating bundle adjustment (section 6.2.1, Table 1).
//!
//! Unknowns: the inner orientation (f, cx, cy, k1 by default, as in the paper), one exterior
//! orientation per image and every target's coordinates. Control points enter as weighted
//! observations of their coordinates (their σ); with [`CalibrationOptions::free_network`] they
//! only give approximate values, and without control the network is free: in both cases the datum
//! is fixed by minimal constraints (the 1st image's pose and one coordinate of the 2nd image's
//! centre). Stations are initialised by space resection ([`crate::resection`]) on the control,
//! or without control by relative orientation ([`relative`]); tie points by intersection. Gross errors are removed by data
//! snooping: with the test value T = |v|² / (σ0² r̄) (r̄ the mean redundancy number), the
//! observations above both the threshold and a quarter of the largest T are rejected and the
//! adjustment is repeated, until no T exceeds the threshold (the largest errors go first, so they
//! do not drag good observations out with them; big data sets need few rounds). The threshold
//! is χ²₂ at 1 − 0.05/n for n observations, 2 ln(n / 0.05) (Bonferroni: a clean data set loses
//! nothing with 95 % probability), and at least χ²₂(0.999) = 13.8.

pub mod problem;
pub mod relative;
pub mod solver;

use crate::input::{image_labels, ControlPoint, Measurement};
use crate::resection::{resect, ResectionError};
use crate::residual::{image_residual, POSE};
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use nalgebra::{Vector2, Vector3};
use problem::{ControlObservation, FreeParameters, Problem, ProblemObservation};
use solver::{solve, Solution, SolveError, SolverOptions};
use std::collections::HashMap;

/// The data-snooping threshold for `n` observations (see the module docs).
pub fn snooping_threshold(n: usize) -> f64 {
    (2.0 * (n as f64 / 0.05).ln()).max(13.8155)
}

/// How to calibrate.
#[derive(Debug, Clone, Copy)]
pub struct CalibrationOptions {
    /// Which inner parameters are estimated.
    pub free: FreeParameters,
    /// A priori σ of image coordinates (px); sets the weight of control against images.
    pub image_sigma_px: f64,
    /// Control gives approximate values only; datum by minimal constraints.
    pub free_network: bool,
    /// Remove gross errors by data snooping.
    pub snooping: bool,
    /// LM stopping rules.
    pub solver: SolverOptions,
}

impl Default for CalibrationOptions {
    fn default() -> Self {
        Self {
            free: FreeParameters::default(),
            image_sigma_px: 0.5,
            free_network: false,
            snooping: true,
            solver: SolverOptions::default(),
        }
    }
}

/// A finished calibration.
#[derive(Debug, Clone)]
pub struct Calibration {
    /// The adjusted problem.
    pub problem: Problem,
    /// The last adjustment's statistics.
    pub solution: Solution,
    /// Rejected observations: (index into the caller's observations, residual in px).
    pub rejected: Vec<(usize, f64)>,
    /// LM iterations over all adjustments.
    pub iterations: usize,
}

/// Why a bundle problem cannot be built from its input.
#[derive(Debug, Clone, PartialEq)]
pub enum BuildError {
    /// Fewer than two images.
    TooFewImages(usize),
    /// A point without control seen in only one image; `measurement` indexes the input.
    UnknownPoint {
        /// Index into the measurements.
        measurement: usize,
        /// The point's label.
        point: String,
    },
    /// An image cannot be resected on its control.
    Resection {
        /// The image's label.
        image: String,
        /// Why.
        error: ResectionError,
    },
    /// The free network (no control) cannot be oriented.
    FreeNetwork(String),
    /// A tie point's rays are parallel.
    Parallel(String),
}

impl std::fmt::Display for BuildError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BuildError::TooFewImages(n) => write!(
                f,
                "only {n} image(s): self-calibration needs at least 2 (9 in the paper)"
            ),
            BuildError::UnknownPoint { point, .. } => write!(
                f,
                "unknown point {point:?}: not in the control file and seen in only one image"
            ),
            BuildError::Resection { image, error } => {
                write!(f, "image {image:?}: cannot resect: {error}")
            }
            BuildError::FreeNetwork(why) => f.write_str(why),
            BuildError::Parallel(point) => {
                write!(
                    f,
                    "point {point:?}: its rays are parallel, cannot intersect"
                )
            }
        }
    }
}

impl std::error::Error for BuildError {}

/// Builds the problem: checks the configuration, resects every image and intersects the tie
/// points. The observations' `source` index the measurements.
pub fn build_problem(
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    measurements: &[Measurement],
    control: &[ControlPoint],
    options: &CalibrationOptions,
) -> Result<Problem, BuildError> {
    let targets: Vec<(usize, &Measurement)> = measurements.iter().enumerate().collect();
    let images = image_labels(measurements);
    if images.len() < 2 {
        return Err(BuildError::TooFewImages(images.len()));
    }
    let known: HashMap<&str, &ControlPoint> =
        control.iter().map(|c| (c.point.as_str(), c)).collect();
    let mut points: Vec<String> = Vec::new();
    let mut point_index: HashMap<&str, usize> = HashMap::new();
    let mut seen_in: Vec<usize> = Vec::new();
    for (_, o) in &targets {
        let j = *point_index.entry(o.point.as_str()).or_insert_with(|| {
            points.push(o.point.clone());
            seen_in.push(0);
            points.len() - 1
        });
        seen_in[j] += 1;
    }
    for (n, o) in &targets {
        let j = point_index[o.point.as_str()];
        if !known.contains_key(o.point.as_str()) && seen_in[j] < 2 {
            return Err(BuildError::UnknownPoint {
                measurement: *n,
                point: o.point.clone(),
            });
        }
    }

    // Stations by resection from the control each image sees, or without control by relative
    // orientation and resection on the free network.
    let image_index: HashMap<&str, usize> = images
        .iter()
        .enumerate()
        .map(|(i, l)| (l.as_str(), i))
        .collect();
    let seen: Vec<relative::Seen> = targets
        .iter()
        .map(|(_, o)| {
            (
                image_index[o.image.as_str()],
                point_index[o.point.as_str()],
                grid.pixel_to_photo(o.col, o.row),
            )
        })
        .collect();
    let poses = if control.is_empty() {
        relative::initial_poses(grid, inner, &images, points.len(), &seen)
            .map_err(|e| BuildError::FreeNetwork(e.to_string()))?
    } else {
        let mut poses = Vec::with_capacity(images.len());
        for image in &images {
            let pts: Vec<(Vector2<f64>, Vector3<f64>)> = targets
                .iter()
                .filter(|(_, o)| &o.image == image)
                .filter_map(|(_, o)| {
                    known
                        .get(o.point.as_str())
                        .map(|c| (Vector2::new(o.col, o.row), c.xyz))
                })
                .collect();
            let r = resect(grid, inner, &pts).map_err(|error| BuildError::Resection {
                image: image.clone(),
                error,
            })?;
            poses.push(r.exterior);
        }
        poses
    };
    let problem_obs: Vec<ProblemObservation> = targets
        .iter()
        .map(|(n, o)| ProblemObservation {
            image: image_index[o.image.as_str()],
            point: point_index[o.point.as_str()],
            photo: grid.pixel_to_photo(o.col, o.row),
            source: *n,
            active: true,
        })
        .collect();

    // Points: control coordinates, or the intersection of their rays.
    let mut xyz = Vec::with_capacity(points.len());
    let mut control_obs = Vec::with_capacity(points.len());
    for (j, label) in points.iter().enumerate() {
        if let Some(c) = known.get(label.as_str()) {
            xyz.push(c.xyz);
            control_obs.push((!options.free_network).then_some(ControlObservation {
                xyz: c.xyz,
                sigma: c.sigma,
            }));
        } else {
            let posed: Vec<_> = poses.iter().copied().map(Some).collect();
            let rays = seen.iter().filter(|s| s.1 == j).map(|s| (s.0, s.2));
            let x = relative::intersect(inner, &posed, rays)
                .ok_or_else(|| BuildError::Parallel(label.clone()))?;
            xyz.push(x);
            control_obs.push(None);
        }
    }
    let mut pose_free = vec![[true; POSE]; images.len()];
    if options.free_network || control_obs.iter().all(|c| c.is_none()) {
        pose_free[0] = [false; POSE];
        let baseline = poses[1].centre - poses[0].centre;
        pose_free[1][3 + baseline.iamax()] = false;
    }
    Ok(Problem {
        grid: *grid,
        inner: *inner,
        free: options.free,
        images,
        poses,
        pose_free,
        points,
        xyz,
        control: control_obs,
        observations: problem_obs,
        image_sigma_mm: options.image_sigma_px * grid.pixel_size,
    })
}

/// Adjusts the problem, with data snooping if asked.
pub fn calibrate(
    mut problem: Problem,
    options: &CalibrationOptions,
) -> Result<Calibration, SolveError> {
    let mut rejected = Vec::new();
    let mut iterations = 0;
    loop {
        let solution = solve(&mut problem, &options.solver)?;
        iterations += solution.iterations;
        if !options.snooping {
            return Ok(Calibration {
                problem,
                solution,
                rejected,
                iterations,
            });
        }
        let equations = solution.redundancy as f64
            + (problem.num_states_camera() + 3 * problem.xyz.len()) as f64;
        let mean_redundancy = solution.redundancy as f64 / equations;
        let var = solution.sigma0 * solution.sigma0 * mean_redundancy;
        let mut active_per_point = vec![0usize; problem.xyz.len()];
        for o in problem.observations.iter().filter(|o| o.active) {
            active_per_point[o.point] += 1;
        }
        let tests: Vec<(usize, f64, f64)> = problem
            .observations
            .iter()
            .enumerate()
            .filter(|(_, o)| o.active)
            .filter(|(_, o)| problem.control[o.point].is_some() || active_per_point[o.point] > 2)
            .map(|(n, o)| {
                let r = image_residual(
                    &problem.inner,
                    &o.photo,
                    &problem.poses[o.image],
                    &problem.xyz[o.point],
                );
                (n, r.value.norm_squared() / var, r.value.norm())
            })
            .collect();
        let worst = tests.iter().map(|t| t.1).fold(0.0, f64::max);
        let threshold = snooping_threshold(problem.observations.len()).max(worst / 4.0);
        let budget = problem.observations.len() / 10;
        let mut batch: Vec<&(usize, f64, f64)> = tests.iter().filter(|t| t.1 > threshold).collect();
        if batch.is_empty() || rejected.len() >= budget {
            return Ok(Calibration {
                problem,
                solution,
                rejected,
                iterations,
            });
        }
        // The largest test values first, never more than 10 % of the observations in all.
        batch.sort_by(|a, b| b.1.total_cmp(&a.1));
        batch.truncate(budget - rejected.len());
        for &&(n, _, v) in &batch {
            problem.observations[n].active = false;
            rejected.push((problem.observations[n].source, v / problem.grid.pixel_size));
        }
    }
}

impl Calibration {
    /// σ of inner parameter `k` (0 if held fixed).
    pub fn inner_sigma(&self, k: usize) -> f64 {
        self.problem
            .state_index_inner(k)
            .map_or(0.0, |s| self.solution.camera_covariance[(s, s)].sqrt())
    }
}
