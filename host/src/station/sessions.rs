//! Captured sessions under the station's data folder: `DATA/<subject>/<time>/` holds
//! `session.json` (subject, time, the calibration's fingerprint, the frames), `centroids.csv`
//! (every measured dot of every frame, with its state and ray), the clouds (`clouds/fNN.ply`,
//! one per frame with points, as `deltaz scan` writes them), and the back analysis of those
//! clouds, `analysis.json` and `report.html`, exactly as `deltaz analyse back --cloud
//! clouds/f00.ply ... --system system.json` run in the session's folder writes them.
//!
//! Names from the page never leave the data folder: a subject id is 1-64 letters, digits, `-`
//! or `_` (not starting with `-`), a session a time stamp `YYYYMMDDTHHMMSSZ` with an optional
//! `-N`, a file one of [`SESSION_FILES`]; anything else is refused before a path is built.
//! A session is written whole into a staging folder of its own, then renamed into place in one
//! step, never over an existing session: two stations on one data folder (or two captures in
//! one second) get two complete sessions, and a failed capture leaves nothing.

use super::live::{dot_states, unix_ms, DotState};
use super::state::KeptFrame;
use crate::io::analysis_file::read_report;
use crate::io::ply::{encode_with, CloudInfo, Encoding};
use crate::report::back_report::{analysis_note, comparison_notes, report_html};
use crate::workflows::back::{analyse_with, Calibration, PointSigma};
use anyhow::{bail, Context, Result};
use deltaz_surface::{compare, Options};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::SystemTime;

/// The format tag of `session.json`.
pub const SESSION_FORMAT: &str = "deltaz.session/1";

/// The files of a session the page may fetch.
pub const SESSION_FILES: [&str; 4] = [
    "report.html",
    "analysis.json",
    "session.json",
    "centroids.csv",
];

/// A subject id from the page, if it is one: 1-64 ASCII letters, digits, `-` or `_`, not
/// starting with `-`.
pub fn subject_id(text: &str) -> Result<&str> {
    let ok = (1..=64).contains(&text.len())
        && !text.starts_with('-')
        && text
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_');
    if !ok {
        bail!(
            "subject id {text:?} refused: use 1-64 letters, digits, '-' or '_' (not starting \
             with '-')"
        );
    }
    Ok(text)
}

/// A session name from the page, if it is one: `YYYYMMDDTHHMMSSZ` or that with `-N`.
pub fn session_name(text: &str) -> Result<&str> {
    let (stamp, suffix) = text.split_once('-').unwrap_or((text, "1"));
    let b = stamp.as_bytes();
    let ok = b.len() == 16
        && b[..8].iter().all(u8::is_ascii_digit)
        && b[8] == b'T'
        && b[9..15].iter().all(u8::is_ascii_digit)
        && b[15] == b'Z'
        && (1..=3).contains(&suffix.len())
        && suffix.bytes().all(|c| c.is_ascii_digit());
    if !ok {
        bail!("session {text:?} refused: not a session name (YYYYMMDDTHHMMSSZ[-N])");
    }
    Ok(text)
}

/// A session file name from the page, if it is one of [`SESSION_FILES`].
pub fn session_file(text: &str) -> Result<&'static str> {
    SESSION_FILES
        .iter()
        .find(|&&f| f == text)
        .copied()
        .with_context(|| format!("file {text:?} refused: a session holds {SESSION_FILES:?}"))
}

/// `t` as a UTC time stamp `YYYYMMDDTHHMMSSZ`.
pub fn utc_stamp(t: SystemTime) -> String {
    let secs = t
        .duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let (days, rest) = (secs / 86_400, secs % 86_400);
    // Civil date from days since 1970-01-01 (H. Hinnant's algorithm).
    let z = days as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}{month:02}{day:02}T{:02}{:02}{:02}Z",
        rest / 3600,
        rest / 60 % 60,
        rest % 60
    )
}

/// One frame of a session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionFrame {
    /// The frame's label.
    pub label: String,
    /// When it was read (ms since the Unix epoch).
    pub read_ms: f64,
    /// Dots measured.
    pub dots: usize,
    /// Points.
    pub points: usize,
    /// Its cloud (relative to the session), if it had points.
    pub cloud: Option<String>,
}

/// `session.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Session {
    /// Always [`SESSION_FORMAT`].
    pub format: String,
    /// The subject's id.
    pub subject: String,
    /// The session's name (its folder).
    pub name: String,
    /// When it was captured (UTC, `YYYYMMDDTHHMMSSZ`).
    pub time: String,
    /// The calibration's fingerprint.
    pub fingerprint: String,
    /// `standing` or `forward-bent`.
    pub posture: String,
    /// The frames of the burst.
    pub frames: Vec<SessionFrame>,
    /// The largest surface rotation and its σ (°).
    pub rotation_max_deg: [f64; 2],
    /// What the report says the reader must know of the analysis, if anything
    /// ([`analysis_note`]).
    #[serde(default, alias = "line_note", skip_serializing_if = "Option::is_none")]
    pub analysis_note: Option<String>,
}

/// What a capture needs besides its frames.
pub struct CaptureSetup<'a> {
    /// The data folder.
    pub data: &'a Path,
    /// The calibration the frames were measured with.
    pub calibration: &'a Calibration,
    /// The step the device quantised the centroids to (px).
    pub centroid_step_px: Option<f64>,
}

/// Analysis options for a posture name from the page.
pub fn posture_options(posture: &str) -> Result<Options> {
    match posture {
        "standing" => Ok(Options::standing()),
        "forward-bent" => Ok(Options::forward_bent()),
        other => bail!("posture {other:?} refused: standing or forward-bent"),
    }
}

/// Saves `frames` (the burst) as a session of `subject` captured at `time`: written whole in a
/// staging folder, analysed there, then renamed into `DATA/<subject>/<time>[-N]`.
pub fn save_session(
    setup: &CaptureSetup,
    subject: &str,
    posture: &str,
    time: SystemTime,
    frames: &[KeptFrame],
) -> Result<Session> {
    let subject = subject_id(subject)?;
    let options = posture_options(posture)?;
    if frames.iter().all(|f| f.found.points.is_empty()) {
        bail!("nothing to capture: no frame with points yet");
    }
    let subject_dir = setup.data.join(subject);
    std::fs::create_dir_all(&subject_dir)
        .with_context(|| format!("{}: cannot create", subject_dir.display()))?;
    static STAGING: AtomicU64 = AtomicU64::new(0);
    let staging = setup.data.join(format!(
        ".staging-{}-{}-{}",
        std::process::id(),
        STAGING.fetch_add(1, Ordering::Relaxed),
        unix_ms(SystemTime::now()) as u64
    ));
    std::fs::create_dir(&staging)
        .with_context(|| format!("{}: cannot create", staging.display()))?;
    let result = fill(setup, &staging, subject, posture, &options, time, frames)
        .and_then(|session| place(&staging, &subject_dir, session));
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&staging);
    }
    result
}

/// Writes the session's files into `dir` and analyses its clouds there.
fn fill(
    setup: &CaptureSetup,
    dir: &Path,
    subject: &str,
    posture: &str,
    options: &Options,
    time: SystemTime,
    frames: &[KeptFrame],
) -> Result<Session> {
    let c = setup.calibration;
    let info = CloudInfo {
        frame: c.file().content.frame.to_string(),
        fingerprint: Some(c.fingerprint().to_owned()),
        frames: None,
        centroid_step_px: setup.centroid_step_px,
    };
    std::fs::create_dir(dir.join("clouds"))?;
    let mut csv = String::from("frame,label,col,row,state,ray\n");
    let (mut listed, mut clouds) = (Vec::new(), Vec::new());
    for (k, f) in frames.iter().enumerate() {
        let states = dot_states(&f.dots, &f.found);
        let ray_of: std::collections::HashMap<_, u16> = f
            .found
            .identified
            .iter()
            .map(|d| ((d.col.to_bits(), d.row.to_bits()), d.id))
            .collect();
        for (&(col, row), state) in f.dots.iter().zip(&states) {
            let state = match state {
                DotState::Identified => "identified",
                DotState::NotIdentified => "not-identified",
            };
            let ray = ray_of
                .get(&(col.to_bits(), row.to_bits()))
                .map_or(String::new(), u16::to_string);
            let _ = writeln!(csv, "{k},{},{col},{row},{state},{ray}", f.label);
        }
        let cloud = (!f.found.points.is_empty()).then(|| format!("clouds/f{k:02}.ply"));
        if let Some(name) = &cloud {
            let bytes = encode_with(&f.found.points, Encoding::BinaryLittleEndian, &info);
            std::fs::write(dir.join(name), bytes)
                .with_context(|| format!("{}: cannot write", dir.join(name).display()))?;
            clouds.push(PathBuf::from(name));
        }
        listed.push(SessionFrame {
            label: f.label.clone(),
            read_ms: unix_ms(f.read_at),
            dots: f.dots.len(),
            points: f.found.points.len(),
            cloud,
        });
    }
    std::fs::write(dir.join("centroids.csv"), csv)?;
    let absolute: Vec<PathBuf> = clouds.iter().map(|p| dir.join(p)).collect();
    let mut report =
        analyse_with(&absolute, PointSigma::Calibration(c), None, options).map_err(|e| {
            // The staging folder's paths mean nothing to the operator.
            let text = format!("{e:#}").replace(&format!("{}/", dir.display()), "");
            anyhow::anyhow!("the burst cannot be analysed: {text}")
        })?;
    report.clouds = clouds;
    let json = serde_json::to_string_pretty(&report)? + "\n";
    std::fs::write(dir.join("analysis.json"), json)?;
    std::fs::write(dir.join("report.html"), report_html(&report)?)?;
    let a = &report.analysis;
    let session = Session {
        format: SESSION_FORMAT.to_owned(),
        subject: subject.to_owned(),
        name: String::new(),
        time: utc_stamp(time),
        fingerprint: c.fingerprint().to_owned(),
        posture: posture.to_owned(),
        frames: listed,
        rotation_max_deg: [a.rotation_max_deg, a.rotation_max_deg_sigma],
        analysis_note: analysis_note(a),
    };
    Ok(session)
}

/// Renames the filled `staging` folder to `subject_dir/<time>`, or `<time>-2`, `-3`, ... when
/// that name is taken (by another station, or a capture in the same second); `session.json`
/// is written with the name first.
fn place(staging: &Path, subject_dir: &Path, mut session: Session) -> Result<Session> {
    for n in 1..=999 {
        let name = match n {
            1 => session.time.clone(),
            n => format!("{}-{n}", session.time),
        };
        if subject_dir.join(&name).exists() {
            continue;
        }
        session.name = name.clone();
        let json = serde_json::to_string_pretty(&session)? + "\n";
        std::fs::write(staging.join("session.json"), json)?;
        // rename(2) onto an existing non-empty folder fails: a name another station took
        // between the check and here is not overwritten.
        match std::fs::rename(staging, subject_dir.join(&name)) {
            Ok(()) => return Ok(session),
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::AlreadyExists | std::io::ErrorKind::DirectoryNotEmpty
                ) => {}
            Err(e) => {
                return Err(e).with_context(|| {
                    format!("{}: cannot create", subject_dir.join(&name).display())
                })
            }
        }
    }
    bail!(
        "{}: 999 sessions in one second: none more",
        subject_dir.display()
    )
}

/// Reads a session's `session.json`.
pub fn read_session(dir: &Path) -> Result<Session> {
    let path = dir.join("session.json");
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read {}", path.display()))?;
    let session: Session = serde_json::from_str(&text)
        .with_context(|| format!("{}: not a valid session.json", path.display()))?;
    if session.format != SESSION_FORMAT {
        bail!(
            "{}: format {:?}, expected {SESSION_FORMAT:?}",
            path.display(),
            session.format
        );
    }
    Ok(session)
}

/// The subjects with a folder under `data`, sorted.
pub fn subjects(data: &Path) -> Result<Vec<String>> {
    let mut out: Vec<String> = match std::fs::read_dir(data) {
        Ok(entries) => entries
            .filter_map(|e| e.ok())
            .filter(|e| e.path().is_dir())
            .filter_map(|e| e.file_name().into_string().ok())
            .filter(|n| subject_id(n).is_ok())
            .collect(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
        Err(e) => return Err(e).with_context(|| format!("{}: cannot read", data.display())),
    };
    out.sort();
    Ok(out)
}

/// The complete sessions of `subject`, oldest first.
pub fn sessions(data: &Path, subject: &str) -> Result<Vec<Session>> {
    let dir = data.join(subject_id(subject)?);
    let mut out = Vec::new();
    if let Ok(entries) = std::fs::read_dir(&dir) {
        for entry in entries.filter_map(|e| e.ok()) {
            let name = entry.file_name().to_string_lossy().into_owned();
            if session_name(&name).is_ok() {
                out.push(read_session(&entry.path())?);
            }
        }
    }
    out.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(out)
}

/// The folder of session `name` of `subject` (both checked).
pub fn session_dir(data: &Path, subject: &str, name: &str) -> Result<PathBuf> {
    let dir = data.join(subject_id(subject)?).join(session_name(name)?);
    if !dir.join("session.json").is_file() {
        bail!("no session {name} of subject {subject}");
    }
    Ok(dir)
}

/// The follow-up of two sessions of `subject`, as `deltaz analyse compare` gives it: the
/// change of each measure and profile with its σ and whether it exceeds the noise, and the
/// notes its reader must know.
pub fn compare_sessions(
    data: &Path,
    subject: &str,
    before: &str,
    after: &str,
) -> Result<serde_json::Value> {
    let a = read_report(&session_dir(data, subject, before)?.join("analysis.json"))?;
    let b = read_report(&session_dir(data, subject, after)?.join("analysis.json"))?;
    let c = compare(&a.analysis, &b.analysis);
    let mut json = serde_json::to_value(&c)?;
    json["before"] = serde_json::json!(before);
    json["after"] = serde_json::json!(after);
    json["calibrations"] = serde_json::json!([a.fingerprint, b.fingerprint]);
    json["notes"] = serde_json::json!(comparison_notes(&c, [(before, &a), (after, &b)]));
    Ok(json)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn names_from_the_page_stay_inside() {
        for good in ["s01", "Anna_B", "x-1", "A"] {
            assert_eq!(subject_id(good).unwrap(), good);
        }
        for bad in [
            "",
            "..",
            "../x",
            "a/b",
            "-rf",
            ".hidden",
            "a b",
            "é",
            &"x".repeat(65),
        ] {
            assert!(subject_id(bad).is_err(), "{bad:?}");
        }
        for good in [
            "20261202T131500Z",
            "20261202T131500Z-2",
            "20261202T131500Z-999",
        ] {
            assert_eq!(session_name(good).unwrap(), good);
        }
        for bad in [
            "",
            "..",
            "20261202T131500Z/..",
            "20261202T131500Z-",
            "2026120T131500Z",
            "20261202T131500Z-1000",
            "../20261202T131500Z",
        ] {
            assert!(session_name(bad).is_err(), "{bad:?}");
        }
        assert_eq!(session_file("report.html").unwrap(), "report.html");
        for bad in ["../session.json", "clouds/f00.ply", "report.html/..", ""] {
            assert!(session_file(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn time_stamps_are_utc() {
        let at = |s: u64| utc_stamp(SystemTime::UNIX_EPOCH + Duration::from_secs(s));
        assert_eq!(at(0), "19700101T000000Z");
        // 2000-02-29 12:34:56 UTC (a leap day), and 2026-12-02 13:15:00 UTC.
        assert_eq!(at(951_827_696), "20000229T123456Z");
        assert_eq!(at(1_796_217_300), "20261202T131500Z");
    }
}
