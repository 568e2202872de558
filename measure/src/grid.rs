//! Dot identification without a calibrated projector (projector calibration, section 5): the
//! pattern's grid topology walked out from one distinct marker dot.
//!
//! Pattern requirement: the dots form a regular grid (rows × columns, any id per node), one dot
//! at a known node is markedly larger than the others (the *marker*), and the plate is flat or
//! gently curved so that the image of the grid changes its step only slowly from dot to dot. The
//! walk starts at the marker with the two step vectors taken from its nearest neighbours (the
//! column step the one closest to the given image direction of the columns), then predicts every
//! neighbour node from the local steps, takes the only dot within 0.4 of a step (none if two),
//! and learns the local steps from what it found where that sits near the prediction. A dot reached as two different nodes is dropped, never guessed.

use nalgebra::Vector2;
use std::collections::VecDeque;

/// A grid node (row, column).
pub type Node = (i32, i32);

/// Label every dot with its grid node, or `None` where the walk could not reach it or reached it
/// twice inconsistently. `marker` is the index of the marker dot, `marker_node` its node,
/// `col_dir` the approximate image direction in which the column index grows, and `row_dir` that
/// of the row index; `nodes` bounds the grid (rows, columns).
pub fn walk_grid(
    dots: &[Vector2<f64>],
    marker: usize,
    marker_node: Node,
    col_dir: Vector2<f64>,
    row_dir: Vector2<f64>,
    nodes: (i32, i32),
) -> Vec<Option<Node>> {
    let mut label: Vec<Option<Node>> = vec![None; dots.len()];
    let mut inconsistent = vec![false; dots.len()];
    let Some((col_step, row_step)) = initial_steps(dots, marker, col_dir, row_dir) else {
        return label;
    };
    label[marker] = Some(marker_node);
    let mut queue = VecDeque::from([(marker, col_step, row_step)]);
    while let Some((i, cs, rs)) = queue.pop_front() {
        let (r, c) = label[i].expect("queued dots are labelled");
        for (dr, dc, step) in [(0, 1, cs), (0, -1, -cs), (1, 0, rs), (-1, 0, -rs)] {
            let node = (r + dr, c + dc);
            if node.0 < 0 || node.1 < 0 || node.0 >= nodes.0 || node.1 >= nodes.1 {
                continue;
            }
            let predicted = dots[i] + step;
            let Some(j) = nearest(dots, predicted, 0.4 * step.norm()) else {
                continue;
            };
            match label[j] {
                Some(existing) if existing != node => inconsistent[j] = true,
                Some(_) => {}
                None => {
                    label[j] = Some(node);
                    // The local steps, learnt from what was found along this direction when it
                    // sits close to the prediction (an off-grid dot teaches nothing).
                    let found = dots[j] - dots[i];
                    let learn = (found - step).norm() <= 0.15 * step.norm();
                    let (ncs, nrs) = if !learn {
                        (cs, rs)
                    } else if dc != 0 {
                        (found * f64::from(dc), rs)
                    } else {
                        (cs, found * f64::from(dr))
                    };
                    queue.push_back((j, ncs, nrs));
                }
            }
        }
    }
    for (l, bad) in label.iter_mut().zip(&inconsistent) {
        if *bad {
            *l = None;
        }
    }
    label
}

/// The marker's column and row steps from its four nearest neighbours.
fn initial_steps(
    dots: &[Vector2<f64>],
    marker: usize,
    col_dir: Vector2<f64>,
    row_dir: Vector2<f64>,
) -> Option<(Vector2<f64>, Vector2<f64>)> {
    let mut near: Vec<Vector2<f64>> = dots
        .iter()
        .enumerate()
        .filter(|&(j, _)| j != marker)
        .map(|(_, d)| d - dots[marker])
        .collect();
    if near.len() < 4 {
        return None;
    }
    near.sort_by(|a, b| a.norm_squared().total_cmp(&b.norm_squared()));
    let four = &near[..4];
    let best = |dir: Vector2<f64>| {
        four.iter()
            .copied()
            .max_by(|a, b| a.normalize().dot(&dir).total_cmp(&b.normalize().dot(&dir)))
    };
    let (cs, rs) = (best(col_dir.normalize())?, best(row_dir.normalize())?);
    (cs != rs).then_some((cs, rs))
}

/// The one dot within `within` of `p`; `None` if there is none or more than one.
fn nearest(dots: &[Vector2<f64>], p: Vector2<f64>, within: f64) -> Option<usize> {
    let mut hits = dots
        .iter()
        .enumerate()
        .filter(|(_, d)| (*d - p).norm() <= within)
        .map(|(j, _)| j);
    let first = hits.next()?;
    hits.next().is_none().then_some(first)
}
