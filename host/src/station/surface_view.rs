//! The Surface panel: the back analysis ([`deltaz_surface::analyse`]) of the latest frames with
//! points, each point with its covariance from the calibration, drawn as the report draws it
//! (topography with contour lines and the symmetry line, the rotation profile with its σ band).
//! It runs in a thread of its own, at most half the time (after an analysis it waits as long as
//! the analysis took): frames arriving meanwhile are not held up, the next analysis takes the
//! newest.

use super::live::{unix_ms, Latest};
use super::state::{KeptFrame, Shared};
use crate::io::ply::Vertex;
use crate::report::back_report::{analysis_note, indices, surface_figures};
use crate::workflows::back::{fit_notes, with_calibration, Calibration};
use anyhow::{bail, Result};
use deltaz_surface::{analyse, BackAnalysis, Frame, Options};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, SystemTime};

/// Frames analysed together for the live surface.
pub const LIVE_FRAMES: usize = 3;

/// The frames of `kept` with points as the analysis takes them (`centroid_step_px`: the
/// device's quantisation of the centroids).
pub fn frames_of(
    kept: &[KeptFrame],
    calibration: &Calibration,
    centroid_step_px: Option<f64>,
) -> Result<Vec<Frame>> {
    kept.iter()
        .filter(|f| !f.found.points.is_empty())
        .map(|f| {
            let vertices: Vec<Vertex> = f
                .found
                .points
                .iter()
                .map(|p| Vertex {
                    point: p.point,
                    ray: Some(p.id),
                    frame: None,
                    sigma: None,
                })
                .collect();
            with_calibration(&vertices, centroid_step_px, calibration)
        })
        .collect()
}

/// The analysis of the last [`LIVE_FRAMES`] frames with points of `kept`, with what its
/// reader must know of the points it set aside ([`fit_notes`]).
pub fn live_analysis(
    kept: &[KeptFrame],
    calibration: &Calibration,
    centroid_step_px: Option<f64>,
) -> Result<(BackAnalysis, Vec<String>)> {
    let with_points: Vec<KeptFrame> = kept
        .iter()
        .filter(|f| !f.found.points.is_empty())
        .cloned()
        .collect();
    if with_points.is_empty() {
        bail!("no frame with points yet");
    }
    let last = &with_points[with_points.len().saturating_sub(LIVE_FRAMES)..];
    let frames = frames_of(last, calibration, centroid_step_px)?;
    let analysis = analyse(&frames, &Options::standing()).map_err(|e| anyhow::anyhow!("{e}"))?;
    let names: Vec<String> = last.iter().map(|f| format!("frame {}", f.label)).collect();
    let notes = fit_notes(&analysis, &frames, &names);
    Ok((analysis, notes))
}

/// The surface event: the figures and measures, or why there is no surface.
fn surface_json(kept: &[KeptFrame], analysis: Result<(BackAnalysis, Vec<String>)>) -> String {
    let latest = kept.last();
    let read_ms = latest.map(|f| unix_ms(f.read_at));
    let label = latest.map(|f| f.label.clone());
    let body = analysis.and_then(|(a, notes)| {
        let (topography, rotation) = surface_figures(&a)?;
        let measures: Vec<_> = indices(&a)
            .into_iter()
            .map(|(name, value, sigma, unit)| serde_json::json!([name, value, sigma, unit]))
            .collect();
        Ok(serde_json::json!({
            "frames": a.frames,
            "points": a.points,
            "points_apart": a.points_apart,
            "levels": a.levels.len(),
            "levels_left_out": a.levels_left_out.len(),
            "analysis_note": analysis_note(&a),
            "notes": notes,
            "rotation_max_deg": a.rotation_max_deg,
            "rotation_max_deg_sigma": a.rotation_max_deg_sigma,
            "topography_svg": topography,
            "rotation_svg": rotation,
            "measures": measures,
        }))
    });
    let mut json = body.unwrap_or_else(|e| serde_json::json!({ "error": format!("{e:#}") }));
    json["label"] = serde_json::json!(label);
    json["read_ms"] = serde_json::json!(read_ms);
    json["sent_ms"] = serde_json::json!(unix_ms(SystemTime::now()));
    json.to_string()
}

/// The surface thread: after each frame (`poke`), the newest frames analysed and published,
/// until `stop`.
pub fn analyse_frames(
    calibration: &Calibration,
    centroid_step_px: Option<f64>,
    shared: &Shared,
    poke: &Latest<()>,
    stop: &AtomicBool,
) {
    while !stop.load(Ordering::Relaxed) {
        if poke.take(Duration::from_millis(300)).is_none() {
            continue;
        }
        let began = std::time::Instant::now();
        let kept = shared.kept();
        let analysis = live_analysis(&kept, calibration, centroid_step_px);
        shared.publish_surface(surface_json(&kept, analysis));
        // At most half the time of a core: the live chain keeps its frame rate.
        std::thread::sleep(began.elapsed().min(Duration::from_secs(2)));
    }
}
