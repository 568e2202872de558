//! What a target field, its plates and their photographs agree on, whoever made them (the
//! simulator renders by it, the measurement relies on it): which control targets are made
//! distinct, so a layout file alone says which, and how a plate's projector-off image is named.

use nalgebra::{Vector2, Vector3};

/// The file-stem suffix of a plate image taken with the projector off (same pose as the image
/// without the suffix): its control targets are measured there, free of projected dots.
pub const CONTROL_SUFFIX: &str = "_control";

/// How many distinct targets [`distinct_targets`] picks.
pub const DISTINCT_COUNT: usize = 5;

/// The rule that picks the distinct targets of a layout: the most populated height level
/// (coordinates rounded to 1 mm), and there the `count` points nearest the level's centroid
/// (the ones most likely inside every image), ties broken by label.
pub fn distinct_targets(points: &[(String, Vector3<f64>)], count: usize) -> Vec<String> {
    let level = |p: &Vector3<f64>| p.z.round() as i64;
    let mut levels = std::collections::BTreeMap::<i64, usize>::new();
    for (_, p) in points {
        *levels.entry(level(p)).or_default() += 1;
    }
    let Some((&z, _)) = levels.iter().max_by_key(|&(z, n)| (*n, -*z)) else {
        return Vec::new();
    };
    let on_level: Vec<(&String, Vector2<f64>)> = points
        .iter()
        .filter(|(_, p)| level(p) == z)
        .map(|(l, p)| (l, Vector2::new(p.x.round(), p.y.round())))
        .collect();
    let centroid = on_level.iter().map(|(_, p)| p).sum::<Vector2<f64>>() / on_level.len() as f64;
    let mut ranked: Vec<_> = on_level
        .iter()
        .map(|(l, p)| ((p - centroid).norm_squared().round() as i64, *l))
        .collect();
    ranked.sort();
    ranked
        .into_iter()
        .take(count)
        .map(|(_, l)| l.clone())
        .collect()
}
