//! Control points: CSV `point,X,Y,Z,sigma` (mm; `sigma` optional, 0 = fixed).

use super::atomic::write_atomic;
use super::text_field;
use super::{csv_text, header_columns, number_field, optional_column, record_line, records};
use super::{FileError, Result};
use nalgebra::Vector3;
use std::borrow::Cow;
use std::collections::{HashMap, HashSet};
use std::path::Path;

pub use deltaz_calib::input::ControlPoint;

/// The largest control coordinate accepted (mm, 10 km): beyond it a value is a typing error and
/// would ruin the adjustment's conditioning.
pub const MAX_COORDINATE_MM: f64 = 1e7;

/// Reads a control file, checking columns, finite numbers within ±[`MAX_COORDINATE_MM`],
/// sigma ≥ 0 and unique labels. A points file with an `image` column (`reconstruct --csv`) over
/// several images labels each point `frame:point`, the frame the index of its image in the
/// order the images first appear, as a cloud's `frame` property numbers them
/// ([`super::ply::read_points`]): the same ray in two images is two points.
pub fn read_control(path: &Path) -> Result<Vec<ControlPoint>> {
    let (header, rows) = records(path)?;
    let [cp, cx, cy, cz] = header_columns(path, &header, ["point", "X", "Y", "Z"])?;
    let cs = optional_column(&header, "sigma");
    let ci = optional_column(&header, "image");
    let mut frames: HashMap<&str, usize> = HashMap::new();
    if let Some(ci) = ci {
        for record in &rows {
            let image = text_field(path, record, ci, "image")?;
            let next = frames.len();
            frames.entry(image).or_insert(next);
        }
    }
    let frame_of = |record: &csv::StringRecord| {
        let image = record.get(ci?)?.trim();
        frames.get(image).copied().filter(|_| frames.len() > 1)
    };
    let mut seen = HashSet::new();
    let mut out = Vec::with_capacity(rows.len());
    for record in &rows {
        let line = record_line(record);
        let label = text_field(path, record, cp, "point")?;
        let point = match frame_of(record) {
            Some(frame) => format!("{frame}:{label}"),
            None => label.to_owned(),
        };
        let xyz = Vector3::new(
            number_field(path, record, cx, "X")?,
            number_field(path, record, cy, "Y")?,
            number_field(path, record, cz, "Z")?,
        );
        let sigma = match cs {
            Some(c) if record.get(c).is_some_and(|s| !s.is_empty()) => {
                number_field(path, record, c, "sigma")?
            }
            _ => 0.0,
        };
        if let Some((name, v)) = ["X", "Y", "Z"]
            .into_iter()
            .zip(xyz.iter())
            .find(|(_, v)| v.abs() > MAX_COORDINATE_MM)
        {
            return Err(FileError::at(
                path,
                line,
                format!("`{name}` is {v:e} mm, beyond ±{MAX_COORDINATE_MM:e} mm"),
            ));
        }
        if sigma < 0.0 {
            return Err(FileError::at(path, line, "`sigma` is negative"));
        }
        if !seen.insert(point.clone()) {
            return Err(FileError::at(
                path,
                line,
                format!("duplicate control point {point:?}"),
            ));
        }
        out.push(ControlPoint { point, xyz, sigma });
    }
    if out.is_empty() {
        return Err(FileError::whole(path, "no control points"));
    }
    Ok(out)
}

/// The CSV text of control points.
pub fn control_csv(points: &[ControlPoint]) -> String {
    csv_text(
        &["point", "X", "Y", "Z", "sigma"],
        points.iter().map(|p| {
            vec![
                Cow::from(p.point.as_str()),
                Cow::from(format!("{:.4}", p.xyz.x)),
                Cow::from(format!("{:.4}", p.xyz.y)),
                Cow::from(format!("{:.4}", p.xyz.z)),
                Cow::from(p.sigma.to_string()),
            ]
        }),
    )
}

/// Writes control points atomically.
pub fn write_control(path: &Path, points: &[ControlPoint]) -> Result<()> {
    write_atomic(path, control_csv(points).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(text: &str) -> (tempfile::TempDir, std::path::PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("control.csv");
        std::fs::write(&path, text).unwrap();
        (dir, path)
    }

    #[test]
    fn reads_optional_sigma() {
        let (_d, path) = file("point,X,Y,Z,sigma\nC1,1,2,3,0.1\nC2,4,5,6,\n");
        let c = read_control(&path).unwrap();
        assert_eq!(c[0].xyz, Vector3::new(1.0, 2.0, 3.0));
        assert_eq!((c[0].sigma, c[1].sigma), (0.1, 0.0));
        let (_d2, path2) = file("point,X,Y,Z\nC1,1,2,3\n");
        assert_eq!(read_control(&path2).unwrap()[0].sigma, 0.0);
    }

    #[test]
    fn round_trip() {
        let pts = vec![ControlPoint {
            point: "C07".into(),
            xyz: Vector3::new(250.0, -180.125, 200.0),
            sigma: 0.1,
        }];
        let (_d, path) = file("");
        write_control(&path, &pts).unwrap();
        assert_eq!(read_control(&path).unwrap(), pts);
    }

    #[test]
    fn errors_name_file_line_and_problem() {
        let cases = [
            ("point,X,Z\nC1,1,2\n", ":1: missing column `Y`"),
            (
                "point,X,Y,Z\nC1,1,2,3\nC1,1,2,3\n",
                ":3: duplicate control point",
            ),
            ("point,X,Y,Z,sigma\nC1,1,inf,3,0\n", ":2: `Y` is not finite"),
            ("point,X,Y,Z\nC1,1e308,2,3\n", ":2: `X` is 1e308 mm, beyond"),
            (
                "point,X,Y,Z,sigma\nC1,1,2,3,-1\n",
                ":2: `sigma` is negative",
            ),
        ];
        for (text, expect) in cases {
            let (_d, path) = file(text);
            let e = read_control(&path).unwrap_err().to_string();
            assert!(
                e.contains("control.csv") && e.contains(expect),
                "{e} lacks {expect}"
            );
        }
    }
}
