//! The whole-system adjustment: the camera's inner orientation, the exterior orientation of every
//! field and plate image, the control coordinates of field and plate, the projector centre and
//! its rays in one least-squares problem, with the image noise of each observation group
//! estimated (variance component estimation) and the covariance of everything a reconstructed
//! point depends on.
//!
//! Datum: the camera system of the instrument (x right, y up, z backwards). Each plate image k
//! has the pose (R_k, X0_k) of the camera in the plate's frame, so the plate surface Z = 0 is the
//! plane n_k · x = −Z0_k with n_k = R_k e3 in the camera system. A ray is the line
//!
//! ```text
//! x(z) = P + o + (z − P_z) (a, b, 1)      o = (q_x, q_y, 0) for the non-central model, else 0
//! ```
//!
//! and its dot in image k is the camera's image of the line's intersection with that plane.
//! In the non-central model P is not an unknown: moving P by δ and every offset o by −δ (and
//! P_z by δ with o by δ (a, b, 0)) leaves every line where it is, three datum defects that made
//! its normal equations singular. P stays at its start (the ΔZ centre of the plane points), the
//! datum of the offsets, with zero covariance; the lines, all a point depends on, are free.
//! The field images' poses and targets are in the field's own frame, that of its control (of a
//! free network: the bundle's datum, whose fixed pose parameters stay fixed here).
//! Observations and weights: plate targets, dots and field targets in the image (σ per group,
//! estimated), control coordinates of the plate and the field (their σ), and where the camera
//! comes from ([`CameraSource`]): jointly from its field images in the same adjustment
//! (`calibrate system`), or as a prior with the covariance of a previous camera calibration (so
//! `calibrate camera` then `calibrate projector` is one adjustment, sequentially). Unknowns:
//! [free inner | plate poses | field poses | P (central) | plate control] (the reduced
//! system), per ray 2 (central) or 4 (non-central) parameters and per field target its 3 coordinates, both
//! eliminated by the Schur complement as in the bundle (`elimination`). Variance components:
//! σ_g² ← σ_g² vᵀ_g P_g v_g / r_g, r_g the group's sum of redundancy numbers, until they settle;
//! the covariances then use the estimated σ.
//!
//! The plate frame as an option: the control frame as the plate stood in one image (the datum
//! image: the one whose camera position the adjustment determines best), with that image's pose
//! and its covariance with everything else in the core, so a point's σ in the plate frame
//! includes the transform's share ([`Frame`]).
//!
//! Incomplete data: a ray seen on one plate has no redundancy but the central model still
//! determines it (the centre and one point); the non-central model cannot, and leaves it out.

mod elimination;
mod normal_equations;
mod points;

use crate::bundle::problem::Problem;
use crate::input::ControlPoint;
use crate::projector_calibration::{centre_by_delta_z, DotObservation, PlanePoint};
use crate::residual::{inner_from_array, inner_to_array, INNER, POSE};
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use deltaz_shared::collinearity::ExteriorOrientation;
use elimination::{covariance, reduce, Kind, Local, GROUPS};
use nalgebra::{DMatrix, Vector2, Vector3};
use normal_equations::{assemble, step};
pub use points::{CoreSplit, PointShares, SystemPoint};
use std::collections::BTreeMap;

/// One plate image: its resected pose (the start), the targets it sees and its dots.
#[derive(Debug, Clone, PartialEq)]
pub struct PlateObservations {
    /// The image's label.
    pub image: String,
    /// The camera's pose in the plate frame (from resection).
    pub start: ExteriorOrientation<f64>,
    /// Targets: observed pixel and index into the control.
    pub targets: Vec<(Vector2<f64>, usize)>,
    /// The projected dots.
    pub dots: Vec<DotObservation>,
}

/// The camera calibration as a prior: which inner parameters are free (order f, cx, cy, k1, k2,
/// k3, p1, p2) and their covariance (mm², in that order).
#[derive(Debug, Clone, PartialEq)]
pub struct CameraPrior {
    /// Free inner parameters.
    pub free: [bool; INNER],
    /// Covariance of the free ones.
    pub covariance: DMatrix<f64>,
}

/// How the camera's inner orientation enters the adjustment.
#[derive(Debug, Clone)]
pub enum CameraSource<'a> {
    /// Held fixed.
    Fixed,
    /// A previous camera calibration as a prior with its covariance (sequential).
    Prior(CameraPrior),
    /// Its field images in the same adjustment (joint): the bundle's problem gives the
    /// observations, the field control, which parameters are free (inner, and the poses' datum
    /// of a free network) and, adjusted, the start.
    Field(&'a Problem),
}

/// What the adjustment needs.
#[derive(Debug, Clone)]
pub struct SystemInput<'a> {
    /// The raster.
    pub grid: PixelGrid<f64>,
    /// The calibrated inner orientation.
    pub inner: InnerOrientation<f64>,
    /// Where the camera comes from (with `Field`, `inner` is the bundle's).
    pub camera: CameraSource<'a>,
    /// The plate's control points.
    pub control: &'a [ControlPoint],
    /// The plate images.
    pub plates: Vec<PlateObservations>,
    /// Every ray a free line (4 parameters) instead of a line through the centre (2).
    pub noncentral: bool,
    /// Start value of the image noise of every group (px).
    pub image_sigma_px: f64,
}

/// Why the adjustment failed.
#[derive(Debug, Clone, PartialEq)]
pub enum SystemError {
    /// Fewer than two plate images.
    TooFewPlates(usize),
    /// No ray is seen on two plates, so the centre is undetermined.
    NoCentre,
    /// The normal equations are singular.
    Singular,
    /// A ray misses a plate or a point falls behind the camera.
    Geometry(String),
}

impl std::fmt::Display for SystemError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SystemError::TooFewPlates(n) => {
                write!(
                    f,
                    "the system adjustment needs at least two plate images, got {n}"
                )
            }
            SystemError::NoCentre => {
                f.write_str("no ray is seen on two plates: the projector centre is undetermined")
            }
            SystemError::Singular => f.write_str(
                "the system's normal equations are singular (weak or insufficient geometry)",
            ),
            SystemError::Geometry(why) => f.write_str(why),
        }
    }
}

impl std::error::Error for SystemError {}

/// One adjusted ray.
#[derive(Debug, Clone, PartialEq)]
pub struct AdjustedRay {
    /// Ray id.
    pub id: u16,
    /// a, b (slopes dx/dz, dy/dz) and, non-central, q_x, q_y (mm).
    pub params: Vec<f64>,
    /// Plates it was seen on.
    pub planes: usize,
    /// Covariance of `params`.
    pub covariance: DMatrix<f64>,
    /// Covariance of `params` with the core parameters [free inner | P] (rows: params).
    pub cross: DMatrix<f64>,
    /// RMS of its dots' image residuals (px).
    pub rms_px: f64,
    /// RMS distance of its plate points from the line (mm).
    pub miss_rms: f64,
    /// Largest distance of its plate points from the line (mm).
    pub miss_max: f64,
}

impl AdjustedRay {
    /// The unit direction towards the scene (−z) and the offset from the centre.
    pub fn line(&self) -> (Vector3<f64>, Vector3<f64>) {
        line_of(&Vector3::zeros(), &self.params)
    }
}

/// A ray's unit direction and a point on it, from the centre and its parameters.
fn line_of(centre: &Vector3<f64>, params: &[f64]) -> (Vector3<f64>, Vector3<f64>) {
    let offset = match params.len() {
        4 => Vector3::new(params[2], params[3], 0.0),
        _ => Vector3::zeros(),
    };
    (
        -Vector3::new(params[0], params[1], 1.0).normalize(),
        centre + offset,
    )
}

/// What a reconstructed point and its σ depend on: the camera, the projector in the camera
/// system, and their covariance (the core [free inner | P | datum pose] and per ray its own block
/// and its covariance with the core), with the image noise of the dots. Stored in `system.json`.
#[derive(Debug, Clone, PartialEq)]
pub struct SystemModel {
    /// Inner orientation.
    pub inner: InnerOrientation<f64>,
    /// Which inner parameters were adjusted (the core's first entries, in this order).
    pub inner_free: Vec<usize>,
    /// Projector centre (camera system, mm).
    pub centre: Vector3<f64>,
    /// The rays, sorted by id.
    pub rays: Vec<AdjustedRay>,
    /// Covariance of the core [free inner | P | datum pose (κ, φ, ω, X0, Y0, Z0) if any].
    pub core_covariance: DMatrix<f64>,
    /// Estimated image noise of the dots (px).
    pub sigma_dots_px: f64,
    /// The plate frame's datum image, if the model carries one.
    pub datum: Option<Datum>,
}

/// The plate image whose plate frame is offered as the points' frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Datum {
    /// The image's label.
    pub image: String,
    /// The camera's adjusted pose in that plate frame.
    pub pose: ExteriorOrientation<f64>,
}

/// The frame a point is given in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Frame {
    /// The camera system (the instrument's own frame, the default).
    Camera,
    /// The plate (control) frame of the datum image, the transform's covariance propagated.
    Plate,
}

/// The adjusted system.
#[derive(Debug, Clone)]
pub struct SystemAdjustment {
    /// The camera and projector with their covariance.
    pub model: SystemModel,
    /// Plate image poses.
    pub poses: Vec<ExteriorOrientation<f64>>,
    /// Estimated image noise of the plate targets (px).
    pub sigma_targets_px: f64,
    /// Estimated image noise of the field targets (px), when they were in the adjustment.
    pub sigma_field_px: Option<f64>,
    /// Redundancy of the plate targets, the dots and the field targets.
    pub redundancy: [f64; GROUPS],
    /// Rays seen on one plate only (determined by the central model, without redundancy).
    pub single_plane: Vec<u16>,
    /// Rays left out (seen on one plate, non-central model).
    pub left_out: Vec<u16>,
    /// Gauss-Newton iterations over all variance-component rounds.
    pub iterations: usize,
}

impl SystemModel {
    /// σ of the projector centre (mm).
    pub fn centre_sigma(&self) -> Vector3<f64> {
        let k = self.inner_free.len();
        Vector3::from_fn(|a, _| self.core_covariance[(k + a, k + a)].sqrt())
    }

    /// The covariance of [core | ray params] for ray `index`.
    pub fn ray_parameter_covariance(&self, index: usize) -> DMatrix<f64> {
        let ray = &self.rays[index];
        let (k, m) = (self.core_covariance.nrows(), ray.params.len());
        let mut cov = DMatrix::zeros(k + m, k + m);
        cov.view_mut((0, 0), (k, k))
            .copy_from(&self.core_covariance);
        cov.view_mut((k, k), (m, m)).copy_from(&ray.covariance);
        cov.view_mut((k, 0), (m, k)).copy_from(&ray.cross);
        cov.view_mut((0, k), (k, m))
            .copy_from(&ray.cross.transpose());
        cov
    }
}

/// The state: everything the residuals depend on.
#[derive(Debug, Clone)]
struct State {
    inner: [f64; INNER],
    poses: Vec<ExteriorOrientation<f64>>,
    field_poses: Vec<ExteriorOrientation<f64>>,
    centre: Vector3<f64>,
    control: Vec<Vector3<f64>>,
    rays: Vec<Vec<f64>>,
    field_points: Vec<Vector3<f64>>,
}

/// Index layout of the reduced (global) system: [free inner | plate poses | free field pose
/// parameters | P | plate control], P absent for the non-central model (its datum).
struct Layout {
    inner: Vec<usize>,
    plates: usize,
    field: Vec<[Option<usize>; POSE]>,
    /// The first index after the field poses.
    field_end: usize,
    centre: Option<usize>,
    control: usize,
}

impl Layout {
    fn new(
        inner: Vec<usize>,
        plates: usize,
        pose_free: &[[bool; POSE]],
        central: bool,
        control: usize,
    ) -> Self {
        let mut next = inner.len() + POSE * plates;
        let field = pose_free
            .iter()
            .map(|free| {
                std::array::from_fn(|a| {
                    free[a].then(|| {
                        next += 1;
                        next - 1
                    })
                })
            })
            .collect();
        Self {
            inner,
            plates,
            field,
            field_end: next,
            centre: central.then_some(next),
            control,
        }
    }
    fn pose(&self, k: usize) -> usize {
        self.inner.len() + POSE * k
    }
    /// The indices of P (None: held fixed).
    fn centre(&self) -> [Option<usize>; 3] {
        std::array::from_fn(|a| self.centre.map(|c| c + a))
    }
    fn point(&self, j: usize) -> usize {
        self.field_end + if self.centre.is_some() { 3 } else { 0 } + 3 * j
    }
    fn size(&self) -> usize {
        self.point(self.control)
    }
    /// The eliminated kinds: the rays (`ray_sizes`) with [inner | plate poses | P], the field
    /// targets (`field_points`) with [inner | field poses].
    fn kinds(&self, ray_sizes: Vec<usize>, field_points: usize) -> [Kind; 2] {
        let n = self.size();
        let rays = (0..self.pose(self.plates))
            .chain(self.centre().into_iter().flatten())
            .collect();
        let field = (0..self.inner.len())
            .chain(self.pose(self.plates)..self.field_end)
            .collect();
        [
            Kind::new(n, rays, ray_sizes),
            Kind::new(n, field, vec![3; field_points]),
        ]
    }
}

/// The eliminated kinds.
const RAYS: usize = 0;
const FIELD: usize = 1;
/// The variance-component groups.
const PLATE_TARGETS: usize = 0;
const DOTS: usize = 1;
const FIELD_TARGETS: usize = 2;

/// Everything fixed during the adjustment.
struct Setup<'a> {
    input: &'a SystemInput<'a>,
    field: Option<&'a Problem>,
    layout: Layout,
    kinds: [Kind; 2],
    ray_index: BTreeMap<u16, usize>,
    inner0: [f64; INNER],
    prior_weight: Option<DMatrix<f64>>,
}
/// The point where a ray (centre, params) meets plate `pose`'s surface, in the plate frame.
fn dot_point(
    pose: &ExteriorOrientation<f64>,
    centre: &Vector3<f64>,
    params: &[f64],
) -> Option<Vector3<f64>> {
    let r = pose.r_cam_world();
    let normal: Vector3<f64> = r.column(2).into();
    let offset = match params.len() {
        4 => Vector3::new(params[2], params[3], 0.0),
        _ => Vector3::zeros(),
    };
    let base = centre + offset;
    let u = Vector3::new(params[0], params[1], 1.0);
    let s = (-pose.centre.z - normal.dot(&base)) / normal.dot(&u);
    let hit = base + u * s;
    s.is_finite().then(|| pose.camera_to_world(&hit))
}

fn pose_array(p: &ExteriorOrientation<f64>) -> [f64; 6] {
    [p.kappa, p.phi, p.omega, p.centre.x, p.centre.y, p.centre.z]
}

fn pose_from(a: [f64; 6]) -> ExteriorOrientation<f64> {
    ExteriorOrientation {
        kappa: a[0],
        phi: a[1],
        omega: a[2],
        centre: Vector3::new(a[3], a[4], a[5]),
    }
}

/// ∂(plate point)/∂[pose (6) | P (3) | ray params (m)] by central differences.
fn dot_point_jacobian(
    pose: &ExteriorOrientation<f64>,
    centre: &Vector3<f64>,
    params: &[f64],
) -> Option<DMatrix<f64>> {
    let m = params.len();
    let mut jac = DMatrix::zeros(3, 9 + m);
    let base = pose_array(pose);
    for k in 0..6 {
        let h = if k < 3 { 1e-7 } else { 1e-4 };
        let (mut up, mut down) = (base, base);
        up[k] += h;
        down[k] -= h;
        let d = (dot_point(&pose_from(up), centre, params)?
            - dot_point(&pose_from(down), centre, params)?)
            / (2.0 * h);
        jac.set_column(k, &d);
    }
    for k in 0..3 {
        let mut step = Vector3::zeros();
        step[k] = 1e-4;
        let d = (dot_point(pose, &(centre + step), params)?
            - dot_point(pose, &(centre - step), params)?)
            / 2e-4;
        jac.set_column(6 + k, &d);
    }
    for k in 0..m {
        let h = if k < 2 { 1e-7 } else { 1e-4 };
        let (mut up, mut down) = (params.to_vec(), params.to_vec());
        up[k] += h;
        down[k] -= h;
        let d = (dot_point(pose, centre, &up)? - dot_point(pose, centre, &down)?) / (2.0 * h);
        jac.set_column(9 + k, &d);
    }
    Some(jac)
}

/// The whole adjustment (see the module docs). The start comes from the resected poses, the
/// ΔZ method on the plane points in the camera system and, joint, the bundle's values.
pub fn adjust_system(input: &SystemInput) -> Result<SystemAdjustment, SystemError> {
    let plates = &input.plates;
    if plates.len() < 2 {
        return Err(SystemError::TooFewPlates(plates.len()));
    }
    let px = input.grid.pixel_size;
    // Plane points in the camera system, per ray.
    let mut by_ray: BTreeMap<u16, Vec<PlanePoint>> = BTreeMap::new();
    for (k, plate) in plates.iter().enumerate() {
        let camera = deltaz_shared::collinearity::Camera {
            grid: input.grid,
            inner: input.inner,
            exterior: plate.start,
        };
        let plane = crate::projector_calibration::Plane::at_z(0.0);
        for dot in &plate.dots {
            let on_plate =
                crate::projector_calibration::dot_on_plate(&camera, &plane, dot.col, dot.row)
                    .map_err(|e| {
                        SystemError::Geometry(format!(
                            "image {:?}, ray {}: {e}",
                            plate.image, dot.id
                        ))
                    })?;
            by_ray.entry(dot.id).or_default().push(PlanePoint {
                plane: k,
                point: plate.start.world_to_camera(&on_plate),
                sigma: 1.0,
            });
        }
    }
    let multi: BTreeMap<u16, Vec<PlanePoint>> = by_ray
        .iter()
        .filter(|(_, p)| p.len() >= 2)
        .map(|(id, p)| (*id, p.clone()))
        .collect();
    if multi.is_empty() {
        return Err(SystemError::NoCentre);
    }
    let (centre, _) = centre_by_delta_z(&multi).map_err(|_| SystemError::NoCentre)?;
    let single_plane: Vec<u16> = by_ray
        .iter()
        .filter(|(_, p)| p.len() < 2)
        .map(|(id, _)| *id)
        .collect();
    let left_out: Vec<u16> = if input.noncentral {
        single_plane.clone()
    } else {
        Vec::new()
    };
    let ray_ids: Vec<u16> = by_ray
        .keys()
        .copied()
        .filter(|id| !left_out.contains(id))
        .collect();
    let ray_index: BTreeMap<u16, usize> =
        ray_ids.iter().enumerate().map(|(i, id)| (*id, i)).collect();
    let rays: Vec<Vec<f64>> = ray_ids
        .iter()
        .map(|id| start_line(&centre, &by_ray[id], input.noncentral))
        .collect();
    let (free, field) = match &input.camera {
        CameraSource::Fixed => ([false; INNER], None),
        CameraSource::Prior(prior) => (prior.free, None),
        CameraSource::Field(problem) => (problem.free.inner, Some(*problem)),
    };
    let inner_free: Vec<usize> = (0..INNER).filter(|k| free[*k]).collect();
    let pose_free = field.map_or(&[][..], |f| &f.pose_free[..]);
    let layout = Layout::new(
        inner_free.clone(),
        plates.len(),
        pose_free,
        !input.noncentral,
        input.control.len(),
    );
    let kinds = layout.kinds(
        rays.iter().map(Vec::len).collect(),
        field.map_or(0, |f| f.xyz.len()),
    );
    let prior_weight = match &input.camera {
        CameraSource::Prior(prior) => Some(
            prior
                .covariance
                .clone()
                .try_inverse()
                .ok_or(SystemError::Singular)?,
        ),
        _ => None,
    };
    let inner0 = inner_to_array(&input.inner);
    let setup = Setup {
        input,
        field,
        layout,
        kinds,
        ray_index,
        inner0,
        prior_weight,
    };
    let mut state = State {
        inner: inner0,
        poses: plates.iter().map(|p| p.start).collect(),
        field_poses: field.map_or_else(Vec::new, |f| f.poses.clone()),
        centre,
        control: input.control.iter().map(|c| c.xyz).collect(),
        rays,
        field_points: field.map_or_else(Vec::new, |f| f.xyz.clone()),
    };
    let mut sigma = [input.image_sigma_px * px; GROUPS];
    let mut iterations = 0;
    let mut result = None;
    for _round in 0..8 {
        // Gauss-Newton to convergence with the current weights.
        let mut normal = assemble(&setup, &state, &sigma)?;
        for _ in 0..30 {
            iterations += 1;
            let reduced = reduce(&normal, &setup.kinds)?;
            let chol = crate::dense::cholesky(reduced.s.clone()).ok_or(SystemError::Singular)?;
            let dg = chol.solve(&reduced.b);
            let dl = reduced.back_substitute(&normal, &setup.kinds, &dg);
            let total = normal.total();
            let mut scale = 1.0;
            let mut accepted = false;
            while scale > 1e-4 {
                let trial = step(&state, &setup.layout, &dg, &dl, scale);
                if let Ok(n) = assemble(&setup, &trial, &sigma) {
                    if n.total() <= total * (1.0 + 1e-12) {
                        state = trial;
                        normal = n;
                        accepted = true;
                        break;
                    }
                }
                scale /= 2.0;
            }
            if !accepted || total - normal.total() < 1e-10 * total {
                break;
            }
        }
        // Redundancy numbers per group, and the covariance.
        let reduced = reduce(&normal, &setup.kinds)?;
        let cov = covariance(&setup.kinds, &reduced)?;
        let red = cov.redundancy(&normal, &setup.kinds, &sigma);
        let mut settled = true;
        for g in 0..GROUPS {
            if red[g] > 1.0 {
                let factor = normal.cost[g] / red[g];
                if (factor - 1.0).abs() > 1e-2 {
                    settled = false;
                }
                sigma[g] *= factor.sqrt();
            }
        }
        result = Some((normal, cov, red));
        if settled {
            break;
        }
    }
    let (normal, cov, red) = result.ok_or(SystemError::Singular)?;
    let layout = &setup.layout;
    // The datum image: the smallest variance of the camera position in the plate frame.
    let position_variance = |k: usize| {
        (3..6)
            .map(|a| cov.s_inv[(layout.pose(k) + a, layout.pose(k) + a)])
            .sum::<f64>()
    };
    let datum = (0..plates.len())
        .min_by(|a, b| position_variance(*a).total_cmp(&position_variance(*b)))
        .unwrap_or(0);
    // The core [free inner | P | datum pose] of the reduced covariance (P held fixed: zero).
    let core: Vec<Option<usize>> = (0..inner_free.len())
        .map(Some)
        .chain(layout.centre())
        .chain((0..6).map(|a| Some(layout.pose(datum) + a)))
        .collect();
    let core_covariance =
        DMatrix::from_fn(core.len(), core.len(), |a, b| match (core[a], core[b]) {
            (Some(i), Some(j)) => cov.s_inv[(i, j)],
            _ => 0.0,
        });
    let mut rms: Vec<(f64, usize)> = vec![(0.0, 0); ray_ids.len()];
    for row in &normal.rows {
        if let Some(Local {
            kind: RAYS, block, ..
        }) = &row.local
        {
            rms[*block].0 += row.value.norm_squared();
            rms[*block].1 += 1;
        }
    }
    // Miss distances: each dot's camera ray met with its adjusted plate, from the adjusted line.
    let inner_adjusted = inner_from_array(state.inner);
    let mut misses: Vec<Vec<f64>> = vec![Vec::new(); ray_ids.len()];
    for (k, plate) in plates.iter().enumerate() {
        let camera = deltaz_shared::collinearity::Camera {
            grid: input.grid,
            inner: inner_adjusted,
            exterior: state.poses[k],
        };
        let plane = crate::projector_calibration::Plane::at_z(0.0);
        for dot in &plate.dots {
            let Some(&r) = setup.ray_index.get(&dot.id) else {
                continue;
            };
            if let Ok(x) =
                crate::projector_calibration::dot_on_plate(&camera, &plane, dot.col, dot.row)
            {
                let line = line_of(&state.centre, &state.rays[r]);
                let x = state.poses[k].world_to_camera(&x);
                misses[r].push(crate::projector_calibration::miss_distance(
                    &line.1, &line.0, &x,
                ));
            }
        }
    }
    let adjusted = ray_ids
        .iter()
        .enumerate()
        .map(|(r, id)| {
            let (own, cross) = cov.block(&setup.kinds, RAYS, r, &core);
            AdjustedRay {
                id: *id,
                params: state.rays[r].clone(),
                planes: by_ray[id].len(),
                covariance: own,
                cross,
                rms_px: (rms[r].0 / (2 * rms[r].1.max(1)) as f64).sqrt() / px,
                miss_rms: (misses[r].iter().map(|m| m * m).sum::<f64>()
                    / misses[r].len().max(1) as f64)
                    .sqrt(),
                miss_max: misses[r].iter().copied().fold(0.0, f64::max),
            }
        })
        .collect();
    Ok(SystemAdjustment {
        model: SystemModel {
            inner: inner_from_array(state.inner),
            inner_free,
            centre: state.centre,
            rays: adjusted,
            core_covariance,
            sigma_dots_px: sigma[DOTS] / px,
            datum: Some(Datum {
                image: plates[datum].image.clone(),
                pose: state.poses[datum],
            }),
        },
        poses: state.poses,
        sigma_targets_px: sigma[PLATE_TARGETS] / px,
        sigma_field_px: field.map(|_| sigma[FIELD_TARGETS] / px),
        redundancy: red,
        single_plane,
        left_out,
        iterations,
    })
}
/// A ray's start: slopes of the line through the centre fitted to its points, and for the
/// non-central model the offset at the centre's z.
fn start_line(centre: &Vector3<f64>, points: &[PlanePoint], noncentral: bool) -> Vec<f64> {
    if noncentral {
        let lines = crate::projector_calibration::noncentral_lines(
            &BTreeMap::from([(0u16, points.to_vec())]),
            centre,
        );
        let (direction, offset) = lines[&0];
        vec![
            direction.x / direction.z,
            direction.y / direction.z,
            offset.x,
            offset.y,
        ]
    } else {
        let d = crate::projector_calibration::direction_cosines(centre, points);
        vec![d.x / d.z, d.y / d.z]
    }
}
