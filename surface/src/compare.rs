//! A follow-up: the change of each index and profile between two analyses of one subject,
//! with its σ, and which changes exceed measurement noise.
//!
//! The two scans are independent measurements: a change's σ is √(σ₁² + σ₂²). Three shares
//! of σ lean alike in two scans of one back, so this overstates a change's σ where they
//! weigh: a calibration shared by both (its common share cancels in part), the sampling terms
//! for surface detail between the dots (where the dots fall alike on the back), and what
//! choosing a largest value adds (the same values compete in both). A change exceeds the noise
//! when it is larger than [`Comparison::threshold`] σ (1.96: 5 % of changes from noise alone
//! are flagged). Profiles are compared at the first analysis'
//! levels, the second's interpolated between its two nearest levels (its σ taken as the
//! interpolated σ, as if the two levels' errors were fully correlated).
//!
//! The largest rotation, lateral deviation and scoliometer reading are compared as magnitudes
//! (named `|field|`): each is the signed value of largest magnitude over the levels, and where
//! two levels of opposite sign are within the noise of each other (a double curve) which one
//! it is, and so its sign, is chance: compared signed, two scans of one back then differ by
//! twice the value, far beyond its σ.
//!
//! The surface is smoothed over a length that follows the dot spacing (its knots are a spacing
//! apart), so two analyses whose spacings differ (the subject nearer or farther from the
//! projector) measure the back at different scales: on the real backs, the same points
//! analysed with a smoothing a third longer (15 against 20 mm spacing) move the symmetry line
//! of 8 scans of 20 by an RMS of 1.0-2.5 σ of the change, one a tenth longer only one by more
//! than 1 σ. [`Comparison::scales_differ`] says so beyond [`SCALE_TOLERANCE`].

use crate::analysis::{BackAnalysis, Level};
use serde::{Deserialize, Serialize};

/// One value's change.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Change {
    /// What changed (the analysis' field name).
    pub name: String,
    /// Its value before.
    pub before: f64,
    /// After.
    pub after: f64,
    /// after − before.
    pub change: f64,
    /// The change's σ.
    pub sigma: f64,
    /// Whether |change| exceeds the threshold × σ.
    pub exceeds_noise: bool,
}

/// The profiles' change at one level.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LevelChange {
    /// The level (the first analysis').
    pub y: f64,
    /// The symmetry point's change across (mm).
    pub symmetry_x: Change,
    /// The surface rotation's (degrees).
    pub rotation_deg: Change,
    /// The lateral deviation's (mm).
    pub lateral_deviation_mm: Change,
}

/// The comparison of two analyses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Comparison {
    /// Changes beyond this many σ exceed the noise.
    pub threshold: f64,
    /// The indices' changes (those both analyses have).
    pub indices: Vec<Change>,
    /// The profiles' changes at the levels both cover.
    pub levels: Vec<LevelChange>,
    /// The two analyses' dot spacings (mm), before and after.
    pub spacings_mm: [f64; 2],
    /// Whether the spacings differ by more than [`SCALE_TOLERANCE`]: the changes then hold
    /// the difference of scale too, beyond their σ.
    pub scales_differ: bool,
    /// Whether each analysis' symmetry line is mostly lost, before and after
    /// ([`BackAnalysis::line_mostly_lost`]): its measures describe a small part of the back,
    /// perhaps along a false axis, so a change may be the line's rather than the back's.
    #[serde(default)]
    pub lines_lost: [bool; 2],
}

/// The threshold of [`compare`].
pub const THRESHOLD: f64 = 1.96;

/// The share by which the larger of two analyses' dot spacings may exceed the smaller and the
/// two still be compared like for like.
pub const SCALE_TOLERANCE: f64 = 0.1;

fn change(name: &str, before: (f64, f64), after: (f64, f64)) -> Change {
    let (d, sigma) = (after.0 - before.0, before.1.hypot(after.1));
    Change {
        name: name.to_string(),
        before: before.0,
        after: after.0,
        change: d,
        sigma,
        exceeds_noise: d.abs() > THRESHOLD * sigma,
    }
}

type Profile = fn(&Level) -> (f64, f64);
type Index = fn(&BackAnalysis) -> Option<(f64, f64)>;

/// `after`'s profile interpolated at level y (None outside it or across a gap).
fn at(after: &[Level], y: f64, gap: f64, f: Profile) -> Option<(f64, f64)> {
    let k = after.windows(2).position(|w| w[0].y <= y && y <= w[1].y)?;
    let (l0, l1) = (&after[k], &after[k + 1]);
    if l1.y - l0.y > gap {
        return None;
    }
    let t = if l1.y > l0.y {
        (y - l0.y) / (l1.y - l0.y)
    } else {
        0.0
    };
    let ((v0, s0), (v1, s1)) = (f(l0), f(l1));
    Some((v0 + t * (v1 - v0), s0 + t * (s1 - s0)))
}

/// Compares two analyses of one subject (`before`, then `after`).
pub fn compare(before: &BackAnalysis, after: &BackAnalysis) -> Comparison {
    let pairs: [(&str, Index); 10] = [
        ("|rotation_max_deg|", |a| {
            Some((a.rotation_max_deg.abs(), a.rotation_max_deg_sigma))
        }),
        ("rotation_rms_deg", |a| {
            Some((a.rotation_rms_deg, a.rotation_rms_deg_sigma))
        }),
        ("|lateral_deviation_max_mm|", |a| {
            Some((
                a.lateral_deviation_max_mm.abs(),
                a.lateral_deviation_max_mm_sigma,
            ))
        }),
        ("lateral_deviation_rms_mm", |a| {
            Some((a.lateral_deviation_rms_mm, a.lateral_deviation_rms_mm_sigma))
        }),
        ("trunk_imbalance_mm", |a| {
            Some((a.trunk_imbalance_mm, a.trunk_imbalance_mm_sigma))
        }),
        ("trunk_inclination_deg", |a| {
            Some((a.trunk_inclination_deg, a.trunk_inclination_deg_sigma))
        }),
        ("kyphosis_deg", |a| a.kyphosis_deg.zip(a.kyphosis_deg_sigma)),
        ("lordosis_deg", |a| a.lordosis_deg.zip(a.lordosis_deg_sigma)),
        ("|atr_max_deg|", |a| {
            a.atr_max_deg.map(f64::abs).zip(a.atr_max_deg_sigma)
        }),
        ("asymmetry_max_mm", |a| {
            a.asymmetry_max_mm.zip(a.asymmetry_max_mm_sigma)
        }),
    ];
    let indices = pairs
        .iter()
        .filter_map(|(name, f)| Some(change(name, f(before)?, f(after)?)))
        .collect();
    let gap = 1.5 * after.spacing_mm.max(before.spacing_mm);
    let profiles: [(&str, Profile); 3] = [
        ("symmetry_x", |l| (l.symmetry_x, l.symmetry_x_sigma)),
        ("rotation_deg", |l| (l.rotation_deg, l.rotation_sigma_deg)),
        ("lateral_deviation_mm", |l| {
            (l.lateral_deviation_mm, l.lateral_deviation_sigma_mm)
        }),
    ];
    let levels = before
        .levels
        .iter()
        .filter_map(|l| {
            let [x, r, d] =
                profiles.map(|(name, f)| Some(change(name, f(l), at(&after.levels, l.y, gap, f)?)));
            Some(LevelChange {
                y: l.y,
                symmetry_x: x?,
                rotation_deg: r?,
                lateral_deviation_mm: d?,
            })
        })
        .collect();
    let spacings_mm = [before.spacing_mm, after.spacing_mm];
    Comparison {
        threshold: THRESHOLD,
        indices,
        levels,
        spacings_mm,
        scales_differ: spacings_mm[0].max(spacings_mm[1]) / spacings_mm[0].min(spacings_mm[1])
            - 1.0
            > SCALE_TOLERANCE,
        lines_lost: [before.line_mostly_lost(), after.line_mostly_lost()],
    }
}
