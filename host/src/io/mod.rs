//! The files other tools and tests exchange: image observations (CSV), control points (CSV) and
//! the camera calibration (`camera.json`, "deltaz.camera/1").
//!
//! Readers fail with a [`FileError`] naming the file, the line and the problem; writers go through
//! [`atomic::write_atomic`], so a failed run never leaves a partial file behind.

pub mod atomic;
pub mod camera_file;
pub mod control;
pub mod observations;

use std::fmt;
use std::path::{Path, PathBuf};

/// A problem with an input or output file: which file, which line (1-based, when it is about
/// one line) and what is wrong.
#[derive(Debug, Clone, PartialEq)]
pub struct FileError {
    /// The file.
    pub path: PathBuf,
    /// The 1-based line the problem is on, if it is about one line.
    pub line: Option<usize>,
    /// What is wrong.
    pub problem: String,
}

impl FileError {
    /// A problem on one line of a file.
    pub fn at(path: &Path, line: usize, problem: impl Into<String>) -> Self {
        Self {
            path: path.to_path_buf(),
            line: Some(line),
            problem: problem.into(),
        }
    }

    /// A problem with a file as a whole.
    pub fn whole(path: &Path, problem: impl Into<String>) -> Self {
        Self {
            path: path.to_path_buf(),
            line: None,
            problem: problem.into(),
        }
    }
}

impl fmt::Display for FileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line {
            Some(line) => write!(f, "{}:{}: {}", self.path.display(), line, self.problem),
            None => write!(f, "{}: {}", self.path.display(), self.problem),
        }
    }
}

impl std::error::Error for FileError {}

/// The result of reading or writing a file.
pub type Result<T> = std::result::Result<T, FileError>;

/// The column positions of a CSV header, by name; `required` columns must be present.
pub(crate) fn header_columns<const N: usize>(
    path: &Path,
    header: &csv::StringRecord,
    required: [&str; N],
) -> Result<[usize; N]> {
    let mut found = [0; N];
    for (slot, name) in found.iter_mut().zip(required) {
        *slot = header
            .iter()
            .position(|h| h.trim() == name)
            .ok_or_else(|| FileError::at(path, 1, format!("missing column `{name}`")))?;
    }
    Ok(found)
}

/// An optional column's position.
pub(crate) fn optional_column(header: &csv::StringRecord, name: &str) -> Option<usize> {
    header.iter().position(|h| h.trim() == name)
}

/// A CSV reader over a file (headers on, whitespace trimmed, rows of varying length allowed so
/// that a short row gets our own error).
pub(crate) fn csv_reader(path: &Path) -> Result<csv::Reader<std::fs::File>> {
    let file = std::fs::File::open(path).map_err(|e| FileError::whole(path, e.to_string()))?;
    Ok(csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .flexible(true)
        .comment(Some(b'#'))
        .from_reader(file))
}

/// The 1-based line of a CSV record.
pub(crate) fn record_line(record: &csv::StringRecord) -> usize {
    record.position().map_or(0, |p| p.line() as usize)
}

/// A field of a record: present and non-empty.
pub(crate) fn text_field<'r>(
    path: &Path,
    record: &'r csv::StringRecord,
    column: usize,
    name: &str,
) -> Result<&'r str> {
    match record.get(column) {
        Some(v) if !v.is_empty() => Ok(v),
        _ => Err(FileError::at(
            path,
            record_line(record),
            format!("missing value for `{name}`"),
        )),
    }
}

/// A finite number in a field.
pub(crate) fn number_field(
    path: &Path,
    record: &csv::StringRecord,
    column: usize,
    name: &str,
) -> Result<f64> {
    let text = text_field(path, record, column, name)?;
    let value: f64 = text.parse().map_err(|_| {
        FileError::at(
            path,
            record_line(record),
            format!("`{name}` is not a number: {text:?}"),
        )
    })?;
    if !value.is_finite() {
        return Err(FileError::at(
            path,
            record_line(record),
            format!("`{name}` is not finite: {text}"),
        ));
    }
    Ok(value)
}

/// Reads every record of a CSV file, turning csv errors into [`FileError`]s.
pub(crate) fn records(path: &Path) -> Result<(csv::StringRecord, Vec<csv::StringRecord>)> {
    let mut reader = csv_reader(path)?;
    let header = reader
        .headers()
        .map_err(|e| FileError::at(path, 1, e.to_string()))?
        .clone();
    let mut rows = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|e| {
            let line = e.position().map_or(0, |p| p.line() as usize);
            FileError::at(path, line, e.to_string())
        })?;
        rows.push(record);
    }
    Ok((header, rows))
}
