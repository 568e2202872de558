//! Image observations: CSV `image,point,col,row[,kind]`.
//!
//! `image` and `point` are labels (strings); projected dots use their numeric ray id as `point`.
//! `col`, `row` are pixel positions, (0, 0) the centre of the top-left pixel, row downwards. The
//! optional `kind` column says whether a point is a control target (`control`) or a projected dot
//! (`dot`); without it every point is a target.

use super::atomic::write_atomic;
use super::text_field;
use super::{csv_text, header_columns, number_field, optional_column, record_line, records};
use super::{FileError, Result};
use deltaz_calib::projector_calibration::DotObservation;
use std::borrow::Cow;
use std::collections::HashSet;
use std::path::Path;

/// What an observed point is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PointKind {
    /// A target (control point or tie point) with a label.
    Control,
    /// A projected dot; the label is its ray id.
    Dot,
}

impl PointKind {
    fn label(self) -> &'static str {
        match self {
            PointKind::Control => "control",
            PointKind::Dot => "dot",
        }
    }
}

/// One image measurement.
#[derive(Debug, Clone, PartialEq)]
pub struct Observation {
    /// The image's label.
    pub image: String,
    /// The point's label (a ray id for dots).
    pub point: String,
    /// Pixel column.
    pub col: f64,
    /// Pixel row (downwards).
    pub row: f64,
    /// Target or projected dot.
    pub kind: PointKind,
    /// The line of the file it came from (0 when made in memory).
    pub line: usize,
}

impl Observation {
    /// A target observation made in memory.
    pub fn target(image: &str, point: &str, col: f64, row: f64) -> Self {
        Self {
            image: image.to_owned(),
            point: point.to_owned(),
            col,
            row,
            kind: PointKind::Control,
            line: 0,
        }
    }

    /// The ray id of a dot observation, if it is a dot with a numeric label.
    pub fn ray_id(&self) -> Option<u16> {
        match self.kind {
            PointKind::Dot => self.point.parse().ok(),
            PointKind::Control => None,
        }
    }
}

/// The error for an observation at (col, row) on `line` of `path` when it lies off a
/// `width × height` px sensor (pixel centres 0..width − 1, 0..height − 1, ± half a pixel): an
/// observation of another camera, or of a resized image.
pub fn off_sensor(
    path: &Path,
    line: usize,
    (col, row): (f64, f64),
    (width, height): (u32, u32),
) -> Option<FileError> {
    let on = (-0.5..=f64::from(width) - 0.5).contains(&col)
        && (-0.5..=f64::from(height) - 0.5).contains(&row);
    (!on).then(|| {
        FileError::at(
            path,
            line,
            format!("({col}, {row}) is off the {width} × {height} sensor"),
        )
    })
}

/// Reads an observations file, checking: the columns `image,point,col,row` exist, numbers are
/// finite, `kind` (if present) is `control` or `dot`, a dot's label is a ray id, and no
/// (image, point) pair appears twice.
pub fn read_observations(path: &Path) -> Result<Vec<Observation>> {
    let (header, rows) = records(path)?;
    let [ci, cp, cc, cr] = header_columns(path, &header, ["image", "point", "col", "row"])?;
    let ck = optional_column(&header, "kind");
    let mut seen = HashSet::new();
    let mut out = Vec::with_capacity(rows.len());
    for record in &rows {
        let line = record_line(record);
        let image = text_field(path, record, ci, "image")?.to_owned();
        let point = text_field(path, record, cp, "point")?.to_owned();
        let col = number_field(path, record, cc, "col")?;
        let row = number_field(path, record, cr, "row")?;
        let kind = match ck.and_then(|k| record.get(k)) {
            None | Some("") | Some("control") => PointKind::Control,
            Some("dot") => PointKind::Dot,
            Some(other) => {
                return Err(FileError::at(
                    path,
                    line,
                    format!("`kind` must be `control` or `dot`, not {other:?}"),
                ))
            }
        };
        if kind == PointKind::Dot && point.parse::<u16>().is_err() {
            return Err(FileError::at(
                path,
                line,
                format!("dot {point:?} is not a ray id (0..65535)"),
            ));
        }
        if !seen.insert((image.clone(), point.clone())) {
            return Err(FileError::at(
                path,
                line,
                format!("duplicate observation of point {point:?} in image {image:?}"),
            ));
        }
        out.push(Observation {
            image,
            point,
            col,
            row,
            kind,
            line,
        });
    }
    if out.is_empty() {
        return Err(FileError::whole(path, "no observations"));
    }
    Ok(out)
}

/// The CSV text of observations; the `kind` column is written when any observation is a dot.
pub fn observations_csv(observations: &[Observation]) -> String {
    let with_kind = observations.iter().any(|o| o.kind == PointKind::Dot);
    let header: &[&str] = if with_kind {
        &["image", "point", "col", "row", "kind"]
    } else {
        &["image", "point", "col", "row"]
    };
    csv_text(
        header,
        observations.iter().map(|o| {
            let mut row: Vec<Cow<str>> = vec![
                Cow::from(o.image.as_str()),
                Cow::from(o.point.as_str()),
                Cow::from(format!("{:.4}", o.col)),
                Cow::from(format!("{:.4}", o.row)),
            ];
            if with_kind {
                row.push(Cow::from(o.kind.label()));
            }
            row
        }),
    )
}

/// Writes observations atomically.
pub fn write_observations(path: &Path, observations: &[Observation]) -> Result<()> {
    write_atomic(path, observations_csv(observations).as_bytes())
}

/// The image labels in order of first appearance.
pub fn image_labels(observations: &[Observation]) -> Vec<String> {
    let mut labels: Vec<String> = Vec::new();
    for o in observations {
        if !labels.contains(&o.image) {
            labels.push(o.image.clone());
        }
    }
    labels
}

/// The dot rows of an observations file (all rows when none is marked `dot`), each with its
/// image label; a label that is not a ray id names its line.
pub fn dot_observations(
    path: &Path,
    obs: &[Observation],
) -> anyhow::Result<Vec<(String, DotObservation)>> {
    let any_dot = obs.iter().any(|o| o.kind == PointKind::Dot);
    obs.iter()
        .filter(|o| !any_dot || o.kind == PointKind::Dot)
        .map(|o| {
            let id = o.point.parse::<u16>().map_err(|_| {
                FileError::at(path, o.line, format!("point {:?} is not a ray id", o.point))
            })?;
            Ok((
                o.image.clone(),
                DotObservation {
                    id,
                    col: o.col,
                    row: o.row,
                },
            ))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(text: &str) -> (tempfile::TempDir, std::path::PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("obs.csv");
        std::fs::write(&path, text).unwrap();
        (dir, path)
    }

    #[test]
    fn round_trip_with_dots() {
        let mut obs = vec![
            Observation::target("p1", "C01, \"left\"", 12.25, 300.5),
            Observation::target("p1", "203", 400.0, 10.125),
        ];
        obs[1].kind = PointKind::Dot;
        let (_d, path) = file("");
        write_observations(&path, &obs).unwrap();
        let back = read_observations(&path).unwrap();
        assert_eq!(back.len(), 2);
        assert_eq!(back[1].ray_id(), Some(203));
        assert_eq!((back[0].col, back[0].row, back[0].line), (12.25, 300.5, 2));
        assert_eq!(back[0].kind, PointKind::Control);
        assert_eq!(back[0].point, "C01, \"left\"");
    }

    #[test]
    fn errors_name_file_line_and_problem() {
        let cases = [
            ("image,point,col\ns1,T1,3\n", ":1: missing column `row`"),
            (
                "image,point,col,row\ns1,T1,3,4\ns1,T2,NaN,4\n",
                ":3: `col` is not finite",
            ),
            (
                "image,point,col,row\ns1,T1,3,x\n",
                ":2: `row` is not a number",
            ),
            (
                "image,point,col,row\ns1,T1,3,4\ns1,T1,5,6\n",
                ":3: duplicate observation",
            ),
            (
                "image,point,col,row,kind\ns1,A,3,4,dot\n",
                ":2: dot \"A\" is not a ray id",
            ),
            (
                "image,point,col,row\ns1,,3,4\n",
                ":2: missing value for `point`",
            ),
            (
                "image,point,col,row\r\ns1,T1,3,4\r\ns1,T2,3,x\r\n",
                ":3: `row` is not a number",
            ),
            (
                "image,point,col,row\ns1,T1,3,4\ns1,T2,3,4,5\n",
                ":3: 5 fields but the header has 4: a decimal comma",
            ),
        ];
        for (text, expect) in cases {
            let (_d, path) = file(text);
            let e = read_observations(&path).unwrap_err().to_string();
            assert!(
                e.contains("obs.csv") && e.contains(expect),
                "{e} lacks {expect}"
            );
        }
    }
}
