//! The normal equations of a state (every observation linearised, on all cores for the field
//! images' many, then accumulated by [`Normal::new`]) and the state moved by a step.

use super::elimination::{Linear, Local, Normal, GROUPS};
use super::{
    dot_point, dot_point_jacobian, pose_array, pose_from, Layout, Setup, State, SystemError, DOTS,
    FIELD, FIELD_TARGETS, PLATE_TARGETS, RAYS,
};
use crate::residual::{image_residual, inner_from_array, POSE};
use nalgebra::{DMatrix, DVector, Vector2};
use rayon::prelude::*;

/// The state moved by `scale` × the step (global `dg`, per kind the blocks' `dl`).
pub(super) fn step(
    state: &State,
    layout: &Layout,
    dg: &DVector<f64>,
    dl: &[Vec<DVector<f64>>],
    scale: f64,
) -> State {
    let mut next = state.clone();
    for (slot, &k) in layout.inner.iter().enumerate() {
        next.inner[k] += scale * dg[slot];
    }
    for (k, pose) in next.poses.iter_mut().enumerate() {
        let mut a = pose_array(pose);
        for (i, v) in a.iter_mut().enumerate() {
            *v += scale * dg[layout.pose(k) + i];
        }
        *pose = pose_from(a);
    }
    for (pose, free) in next.field_poses.iter_mut().zip(&layout.field) {
        let mut a = pose_array(pose);
        for (v, at) in a.iter_mut().zip(free) {
            if let Some(i) = at {
                *v += scale * dg[*i];
            }
        }
        *pose = pose_from(a);
    }
    for (a, at) in layout.centre().iter().enumerate() {
        if let Some(i) = at {
            next.centre[a] += scale * dg[*i];
        }
    }
    for (j, x) in next.control.iter_mut().enumerate() {
        for a in 0..3 {
            x[a] += scale * dg[layout.point(j) + a];
        }
    }
    for (params, d) in next.rays.iter_mut().zip(&dl[RAYS]) {
        for (p, v) in params.iter_mut().zip(d.iter()) {
            *p += scale * v;
        }
    }
    for (x, d) in next.field_points.iter_mut().zip(&dl[FIELD]) {
        *x += d * scale;
    }
    next
}

/// The global columns of an image residual: the free inner parameters, then the pose's free
/// parameters at their indices `pose` (None: held fixed).
fn image_columns(
    layout: &Layout,
    r: &crate::residual::ImageResidual,
    pose: &[Option<usize>; POSE],
) -> Vec<(usize, Vector2<f64>)> {
    let mut global: Vec<(usize, Vector2<f64>)> = layout
        .inner
        .iter()
        .enumerate()
        .map(|(slot, &k)| (slot, r.d_inner.column(k).into_owned()))
        .collect();
    for (a, at) in pose.iter().enumerate() {
        if let Some(i) = at {
            global.push((*i, r.d_pose.column(a).into_owned()));
        }
    }
    global
}

/// Linearises every observation and accumulates the normal equations (weights from σ per
/// group: plate targets, dots, field targets; control by its σ; the inner orientation by the
/// prior).
pub(super) fn assemble(
    setup: &Setup,
    state: &State,
    sigma: &[f64; GROUPS],
) -> Result<Normal, SystemError> {
    let Setup { input, layout, .. } = setup;
    let inner = inner_from_array(state.inner);
    let mut rows = Vec::new();
    for (k, plate) in input.plates.iter().enumerate() {
        let pose = &state.poses[k];
        let at: [Option<usize>; POSE] = std::array::from_fn(|a| Some(layout.pose(k) + a));
        for (pixel, j) in &plate.targets {
            let photo = input.grid.pixel_to_photo(pixel.x, pixel.y);
            let r = image_residual(&inner, &photo, pose, &state.control[*j]);
            if r.z_cam >= 0.0 {
                return Err(SystemError::Geometry(format!(
                    "image {:?}: control point {} lies behind the camera",
                    plate.image, input.control[*j].point
                )));
            }
            let mut global = image_columns(layout, &r, &at);
            for a in 0..3 {
                global.push((layout.point(*j) + a, r.d_point.column(a).into_owned()));
            }
            rows.push(Linear {
                value: r.value,
                global,
                local: None,
                group: PLATE_TARGETS,
            });
        }
        for dot in &plate.dots {
            let Some(&ri) = setup.ray_index.get(&dot.id) else {
                continue;
            };
            let params = &state.rays[ri];
            let geometry = || {
                SystemError::Geometry(format!(
                    "image {:?}: ray {} does not meet the plate",
                    plate.image, dot.id
                ))
            };
            let x = dot_point(pose, &state.centre, params).ok_or_else(geometry)?;
            let jx = dot_point_jacobian(pose, &state.centre, params).ok_or_else(geometry)?;
            let photo = input.grid.pixel_to_photo(dot.col, dot.row);
            let r = image_residual(&inner, &photo, pose, &x);
            if r.z_cam >= 0.0 {
                return Err(geometry());
            }
            // The dot's plate point moves with the pose, the centre and the ray.
            let through = DMatrix::from_fn(2, 3, |a, b| r.d_point[(a, b)]) * &jx;
            let mut global = image_columns(layout, &r, &at);
            for (a, (_, d)) in global.iter_mut().skip(layout.inner.len()).enumerate() {
                *d += Vector2::new(through[(0, a)], through[(1, a)]);
            }
            for (a, at) in layout.centre().iter().enumerate() {
                if let Some(i) = at {
                    global.push((*i, Vector2::new(through[(0, 6 + a)], through[(1, 6 + a)])));
                }
            }
            rows.push(Linear {
                value: r.value,
                global,
                local: Some(Local {
                    kind: RAYS,
                    block: ri,
                    d: through.columns(9, params.len()).into_owned(),
                }),
                group: DOTS,
            });
        }
    }
    if let Some(field) = setup.field {
        // The field observations (the most) on all cores, kept in order (the first error too).
        let active: Vec<_> = field.observations.iter().filter(|o| o.active).collect();
        let field_rows: Vec<Result<Linear, SystemError>> = active
            .par_iter()
            .map(|o| {
                let r = image_residual(
                    &inner,
                    &o.photo,
                    &state.field_poses[o.image],
                    &state.field_points[o.point],
                );
                if r.z_cam >= 0.0 {
                    return Err(SystemError::Geometry(format!(
                        "field image {:?}: target {} lies behind the camera",
                        field.images[o.image], field.points[o.point]
                    )));
                }
                Ok(Linear {
                    value: r.value,
                    global: image_columns(layout, &r, &layout.field[o.image]),
                    local: Some(Local {
                        kind: FIELD,
                        block: o.point,
                        d: DMatrix::from_fn(2, 3, |a, b| r.d_point[(a, b)]),
                    }),
                    group: FIELD_TARGETS,
                })
            })
            .collect();
        rows.extend(field_rows.into_iter().collect::<Result<Vec<_>, _>>()?);
    }
    let mut normal = Normal::new(layout.size(), &setup.kinds, rows, sigma);
    // Control coordinates of the plate and the field, and the inner orientation's prior.
    for (j, c) in input.control.iter().enumerate() {
        let w = 1.0 / c.sigma.max(1e-6).powi(2);
        let at: Vec<usize> = (0..3).map(|a| layout.point(j) + a).collect();
        let d = DVector::from_column_slice((state.control[j] - c.xyz).as_slice());
        normal.global_prior(&at, &(DMatrix::identity(3, 3) * w), &d);
    }
    if let Some(field) = setup.field {
        for (j, c) in field.control.iter().enumerate() {
            if let Some(c) = c {
                let d = DVector::from_column_slice((state.field_points[j] - c.xyz).as_slice());
                normal.local_prior(FIELD, j, 1.0 / c.sigma.max(1e-6).powi(2), &d);
            }
        }
    }
    if let Some(p) = &setup.prior_weight {
        let d = DVector::from_iterator(
            layout.inner.len(),
            layout
                .inner
                .iter()
                .map(|&k| state.inner[k] - setup.inner0[k]),
        );
        let at: Vec<usize> = (0..layout.inner.len()).collect();
        normal.global_prior(&at, p, &d);
    }
    Ok(normal)
}
