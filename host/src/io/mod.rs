//! The files other tools and tests exchange: image observations (CSV), control points (CSV),
//! the camera calibration (`camera.json`), the system calibration (`system.json`), resected
//! poses, point clouds (PLY) and OpenCV's camera file.
//!
//! Readers fail with a [`FileError`] naming the file, the line and the problem; writers go through
//! [`atomic::write_atomic`], so a failed run never leaves a partial file behind.

pub mod analysis_file;
pub mod atomic;
pub mod camera_file;
pub mod control;
pub mod observations;
pub mod opencv;
pub mod ply;
pub mod poses;
pub mod system_file;

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

/// The 1-based line of a CSV record.
pub(crate) fn record_line(record: &csv::StringRecord) -> usize {
    record.position().map_or(0, |p| p.line() as usize)
}

/// A field of a record, trimmed: present and non-empty.
pub(crate) fn text_field<'r>(
    path: &Path,
    record: &'r csv::StringRecord,
    column: usize,
    name: &str,
) -> Result<&'r str> {
    match record.get(column).map(str::trim) {
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

/// The largest CSV file read (bytes): larger is not an observations or control file, and is
/// refused before it is read into memory.
pub const MAX_CSV_BYTES: u64 = 1 << 30;

/// Reads every record of a CSV file (headers on, whitespace trimmed, `#` comments), turning csv
/// errors into [`FileError`]s. Each record's line is counted from the file's bytes, so that
/// CRLF files are numbered like LF ones; a row with more fields than the header (a decimal
/// comma, an unquoted label) is refused on its own line.
pub(crate) fn records(path: &Path) -> Result<(csv::StringRecord, Vec<csv::StringRecord>)> {
    let size = std::fs::metadata(path)
        .map_err(|e| FileError::whole(path, e.to_string()))?
        .len();
    if size > MAX_CSV_BYTES {
        return Err(FileError::whole(
            path,
            format!("{size} bytes: larger than the limit of {MAX_CSV_BYTES} bytes"),
        ));
    }
    let bytes = std::fs::read(path).map_err(|e| FileError::whole(path, e.to_string()))?;
    // The csv crate's own line count is one short after CRLF; its byte offset may point at the
    // terminator before a record, so the record starts at the first byte after line ends.
    let line_at = |byte: u64| {
        let mut end = usize::try_from(byte).unwrap_or(usize::MAX).min(bytes.len());
        while end < bytes.len() && matches!(bytes[end], b'\r' | b'\n') {
            end += 1;
        }
        1 + bytes[..end].iter().filter(|&&b| b == b'\n').count()
    };
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .flexible(true)
        .comment(Some(b'#'))
        .from_reader(bytes.as_slice());
    let header = reader
        .headers()
        .map_err(|e| FileError::at(path, 1, e.to_string()))?
        .clone();
    let mut rows = Vec::new();
    for record in reader.records() {
        let mut record = record.map_err(|e| {
            let line = e.position().map_or(0, |p| line_at(p.byte()));
            FileError::at(path, line, e.to_string())
        })?;
        if let Some(position) = record.position() {
            let mut position = position.clone();
            position.set_line(line_at(position.byte()) as u64);
            record.set_position(Some(position));
        }
        if record.iter().skip(header.len()).any(|f| !f.is_empty()) {
            return Err(FileError::at(
                path,
                record_line(&record),
                format!(
                    "{} fields but the header has {}: a decimal comma (write 1.5, not 1,5) \
                     or a label with a comma (quote it)?",
                    record.len(),
                    header.len()
                ),
            ));
        }
        rows.push(record);
    }
    Ok((header, rows))
}

/// A streaming CSV reader configured like [`records`] (headers on, `#` comments) for files too
/// large to hold: carriage returns before a line feed are dropped on the way in, so the csv
/// crate's line numbers are right for CRLF files too. Only the header is trimmed here (the csv
/// crate trims a record by copying it); [`text_field`] and [`number_field`] trim each field, so
/// a record read into the same `StringRecord` again costs no allocation.
pub(crate) fn csv_reader(path: &Path) -> Result<csv::Reader<LfOnly<std::fs::File>>> {
    let file = std::fs::File::open(path).map_err(|e| FileError::whole(path, e.to_string()))?;
    Ok(csv::ReaderBuilder::new()
        .trim(csv::Trim::Headers)
        .flexible(true)
        .comment(Some(b'#'))
        .from_reader(LfOnly {
            inner: std::io::BufReader::new(file),
        }))
}

/// A reader that turns CRLF line ends into LF (a `\r` not followed by `\n` is kept).
pub(crate) struct LfOnly<R> {
    inner: std::io::BufReader<R>,
}

impl<R: std::io::Read> std::io::Read for LfOnly<R> {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        use std::io::BufRead;
        let mut n = 0;
        while n < out.len() {
            let buf = self.inner.fill_buf()?;
            if buf.is_empty() {
                break;
            }
            let room = buf.len().min(out.len() - n);
            let run = buf[..room].iter().position(|&b| b == b'\r').unwrap_or(room);
            if run > 0 {
                out[n..n + run].copy_from_slice(&buf[..run]);
                n += run;
                self.inner.consume(run);
                continue;
            }
            // A carriage return: dropped when a line feed follows.
            self.inner.consume(1);
            if self.inner.fill_buf()?.first() != Some(&b'\n') {
                out[n] = b'\r';
                n += 1;
            }
        }
        Ok(n)
    }
}

/// CSV text of a header and rows, fields quoted where needed (labels with commas or quotes).
pub(crate) fn csv_text<'a>(
    header: &[&str],
    rows: impl Iterator<Item = Vec<std::borrow::Cow<'a, str>>>,
) -> String {
    let mut writer = csv::Writer::from_writer(Vec::new());
    // Writing records into memory cannot fail.
    let _ = writer.write_record(header);
    for row in rows {
        let _ = writer.write_record(row.iter().map(|f| f.as_ref()));
    }
    String::from_utf8(writer.into_inner().unwrap_or_default()).unwrap_or_default()
}

/// Labelled points of a CSV `point,X,Y,Z` or a PLY cloud (by its extension).
pub fn read_points(path: &Path) -> anyhow::Result<Vec<(String, nalgebra::Vector3<f64>)>> {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("ply"))
    {
        return Ok(ply::read_points(path)?);
    }
    Ok(control::read_control(path)?
        .into_iter()
        .map(|c| (c.point, c.xyz))
        .collect())
}

/// The `format` tag of a JSON file (`"deltaz.system/2"`, ...), if it has one: read before the
/// rest, so that a file of another kind is named as such.
pub fn format_tag(text: &str) -> Option<String> {
    #[derive(serde::Deserialize)]
    struct Tagged {
        format: String,
    }
    serde_json::from_str::<Tagged>(text).ok().map(|t| t.format)
}

/// The first line of a points CSV: a `#` comment (the readers skip it) with the unit, the points'
/// frame and the calibration's fingerprint.
pub fn points_comment(frame: &str, fingerprint: u64) -> String {
    format!("# points in mm, {frame}, calibration {fingerprint:016x}\n")
}
