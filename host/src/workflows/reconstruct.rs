//! `deltaz reconstruct` as a stream: identified dots are read from the CSV in batches, each batch
//! reconstructed on all cores ([`deltaz_calib::reconstruct::reconstruct_dot`]) while the next is
//! read, and appended to the outputs, so memory does not grow with the number of points, and the
//! work per dot does not grow with the number of images: a row holds its image's frame index,
//! not its name, and an image is looked up (hashed) only where the rows' image changes. Without
//! the whole-system covariance nothing is allocated per dot.
//!
//! The PLY header needs the vertex count, so the vertices go to a temporary file first and the
//! cloud is assembled (header + vertices) into another temporary file that is renamed over the
//! target: a failure at any line leaves no output, old or partial, behind.
//!
//! Rows: with a `kind` column only the `dot` rows (an error when there are none), otherwise
//! every row; `point` is the ray id. A ray seen twice in a run of rows of the same image is an
//! error (the check needs no memory beyond the current image), and so is a dot off the
//! calibration's sensor.
//!
//! σ: with the whole-system adjustment's covariance in system.json every point gets the σ of
//! camera, projector and the dots' image noise (estimated, or `--sigma-px`); otherwise
//! `--sigma-px` gives the image-noise floor. The cloud's `frame` property is the index of the
//! point's image (in the order the images first appear), also for a single image.

use crate::io::atomic::Pending;
use crate::io::observations::off_sensor;
use crate::io::ply::{header, push_point, CloudInfo, Encoding, Layout};
use crate::io::system_file::{SystemFile, SystemFrame};
use crate::io::{csv_reader, header_columns, number_field, optional_column, record_line};
use crate::io::{points_comment, text_field, FileError};
use anyhow::{bail, Context, Result};
use deltaz_calib::projector_calibration::DotObservation;
use deltaz_calib::reconstruct::{reconstruct_dot, ReconstructedPoint};
use deltaz_calib::system_adjustment::Frame;
use deltaz_shared::rig::Method;
use rayon::prelude::*;
use std::collections::{HashMap, HashSet};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Rows read together.
const BATCH: usize = 1 << 16;

/// Rows a thread reconstructs and formats together.
const CHUNK: usize = 1024;

/// One CSV line `image,point,X,Y,Z,miss[,sigma_X,sigma_Y,sigma_Z]`.
fn csv_line(text: &mut String, image: &str, p: &ReconstructedPoint) {
    use std::fmt::Write as _;
    let (x, m) = (p.point, p.miss);
    // Writing into a String cannot fail.
    let _ = write!(text, "{image},{},{},{},{},{m}", p.id, x.x, x.y, x.z);
    if let Some(s) = p.sigma {
        let _ = write!(text, ",{},{},{}", s.x, s.y, s.z);
    }
    text.push('\n');
}

/// One row to reconstruct: its frame (the index of its image, in the order the images first
/// appear), dot and line. No image name: a row costs no allocation.
#[derive(Debug, Clone, Copy)]
struct Row {
    frame: u32,
    dot: DotObservation,
    line: usize,
}

/// Rows read together, and the names of the images first met among them (their frames follow
/// the ones before, in order).
#[derive(Debug, Default)]
struct Batch {
    rows: Vec<Row>,
    new_images: Vec<Box<str>>,
}

/// The CSV's rows in batches of [`BATCH`], checked. The work per row does not depend on the
/// number of images: one record buffer is reused, an image's frame is looked up (hashed) only
/// where the image changes, and the duplicate check holds only the current image's rays.
struct Rows {
    path: PathBuf,
    reader: csv::Reader<crate::io::LfOnly<std::fs::File>>,
    record: csv::StringRecord,
    columns: [usize; 4],
    /// The header's number of fields: a row with more is refused.
    width: usize,
    kind: Option<usize>,
    /// The current run's image and its frame (`None` before the first row).
    image: String,
    current: Option<u32>,
    /// Every image met so far: its frame.
    frames: HashMap<Box<str>, u32>,
    seen: HashSet<u16>,
    /// The calibration's sensor (width, height): dots off it are errors.
    sensor: (u32, u32),
}

impl Rows {
    fn open(path: &Path, sensor: (u32, u32)) -> Result<Self> {
        let mut reader = csv_reader(path)?;
        let head = reader
            .headers()
            .map_err(|e| FileError::at(path, 1, e.to_string()))?
            .clone();
        Ok(Self {
            path: path.to_path_buf(),
            columns: header_columns(path, &head, ["image", "point", "col", "row"])?,
            kind: optional_column(&head, "kind"),
            width: head.len(),
            reader,
            record: csv::StringRecord::new(),
            image: String::new(),
            current: None,
            frames: HashMap::new(),
            seen: HashSet::new(),
            sensor,
        })
    }

    /// The next batch (no rows at the end of the file).
    fn batch(&mut self) -> Result<Batch> {
        let path = &self.path;
        let [ci, cp, cc, cr] = self.columns;
        let mut out = Batch {
            rows: Vec::with_capacity(BATCH),
            new_images: Vec::new(),
        };
        while out.rows.len() < BATCH {
            let more = self.reader.read_record(&mut self.record).map_err(|e| {
                let line = e.position().map_or(0, |p| p.line() as usize);
                FileError::at(path, line, e.to_string())
            })?;
            if !more {
                break;
            }
            let record = &self.record;
            let line = record_line(record);
            if record.iter().skip(self.width).any(|f| !f.trim().is_empty()) {
                bail!(FileError::at(
                    path,
                    line,
                    format!(
                        "{} fields but the header has {}: a decimal comma (write 1.5, not 1,5)?",
                        record.len(),
                        self.width
                    )
                ));
            }
            if let Some(k) = self.kind {
                match record.get(k).map(str::trim) {
                    Some("dot") => {}
                    None | Some("") | Some("control") => continue,
                    Some(other) => bail!(FileError::at(
                        path,
                        line,
                        format!("`kind` must be `control` or `dot`, not {other:?}")
                    )),
                }
            }
            let image = text_field(path, record, ci, "image")?;
            let point = text_field(path, record, cp, "point")?;
            let Ok(id) = point.parse::<u16>() else {
                bail!(FileError::at(
                    path,
                    line,
                    format!("point {point:?} is not a ray id")
                ));
            };
            let dot = DotObservation {
                id,
                col: number_field(path, record, cc, "col")?,
                row: number_field(path, record, cr, "row")?,
            };
            if let Some(e) = off_sensor(path, line, (dot.col, dot.row), self.sensor) {
                bail!(e);
            }
            let frame = match self.current {
                Some(frame) if self.image == image => frame,
                _ => {
                    let frame = match self.frames.get(image) {
                        Some(&frame) => frame,
                        None => {
                            let frame = self.frames.len() as u32;
                            self.frames.insert(image.into(), frame);
                            out.new_images.push(image.into());
                            frame
                        }
                    };
                    self.image.clear();
                    self.image.push_str(image);
                    self.current = Some(frame);
                    self.seen.clear();
                    frame
                }
            };
            if !self.seen.insert(id) {
                bail!(FileError::at(
                    path,
                    line,
                    format!("duplicate observation of ray {id} in image {image:?}")
                ));
            }
            out.rows.push(Row { frame, dot, line });
        }
        Ok(out)
    }
}

/// What `deltaz reconstruct` reads and writes.
#[derive(Debug, Clone)]
pub struct ReconstructArgs {
    /// The calibrated system (system.json).
    pub system: PathBuf,
    /// Dot observations.
    pub obs: PathBuf,
    /// Output PLY file.
    pub out: PathBuf,
    /// Also a CSV `image,point,X,Y,Z,miss[,sigma_X,sigma_Y,sigma_Z]` (mm).
    pub csv: Option<PathBuf>,
    /// ASCII PLY instead of binary.
    pub ascii: bool,
    /// Image noise (px): each point's propagated σ (mm).
    pub sigma_px: Option<f64>,
    /// Intersection method.
    pub method: Method,
    /// The points' frame; `None`: the system's own.
    pub frame: Option<Frame>,
}

/// What a reconstruction wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct StreamSummary {
    /// Points written.
    pub points: usize,
    /// Images they came from.
    pub images: usize,
    /// RMS of the miss distances (mm).
    pub miss_rms: f64,
    /// The calibration's fingerprint.
    pub fingerprint: String,
    /// The points' frame, in words.
    pub frame: String,
}

/// `deltaz reconstruct`: reads, reconstructs and writes in batches; nothing is left on failure.
pub fn reconstruct_stream(args: &ReconstructArgs) -> Result<StreamSummary> {
    let (system, rig) = SystemFile::load(&args.system)?;
    let calibration = system.line_covariances();
    let model = system
        .content
        .model()
        .map_err(|e| anyhow::anyhow!("{}: {e:#}", args.system.display()))?
        .map(|mut model| {
            if let Some(s) = args.sigma_px {
                model.sigma_dots_px = s;
            }
            model
        });
    // The system's own frame, or the plate frame of its datum image.
    let own = &system.content.frame;
    let plate = match (args.frame, own) {
        (Some(Frame::Camera), SystemFrame::Plate { .. }) => bail!(
            "{}: the system is in {own} (a `calibrate projector` calibration): its points \
             cannot be given in the camera system (`calibrate system` calibrates in it)",
            args.system.display()
        ),
        (Some(Frame::Plate), SystemFrame::Camera) => true,
        _ => false,
    };
    let frame = match (&model, plate) {
        (Some(m), true) => match &m.datum {
            Some(d) => format!(
                "the plate frame of image {} (the datum of `calibrate system`)",
                d.image
            ),
            None => bail!(
                "{}: --frame plate needs a datum image, which this file does not name",
                args.system.display()
            ),
        },
        (None, true) => bail!(
            "{}: --frame plate needs the covariance of `calibrate system`",
            args.system.display()
        ),
        (_, false) => own.to_string(),
    };
    let model_frame = if plate { Frame::Plate } else { Frame::Camera };
    let method = args.method;
    let layout = Layout {
        encoding: if args.ascii {
            Encoding::Ascii
        } else {
            Encoding::BinaryLittleEndian
        },
        sigma: args.sigma_px.is_some() || model.is_some(),
        frame: true,
    };
    let mut rows = Rows::open(&args.obs, (rig.grid().width, rig.grid().height))?;
    let (vertices, mut vertex_file) = Pending::new(&args.out, "vertices")?;
    let mut csv = match &args.csv {
        Some(path) => {
            let (pending, mut writer) = Pending::new(path, "csv")?;
            let fingerprint = system.fingerprint_u64()?;
            let mut head = points_comment(&frame, fingerprint) + "image,point,X,Y,Z,miss";
            if layout.sigma {
                head += ",sigma_X,sigma_Y,sigma_Z";
            }
            writeln!(writer, "{head}").with_context(|| format!("{}", path.display()))?;
            Some((pending, writer))
        }
        None => None,
    };
    let (mut count, mut miss2) = (0, 0.0);
    // The images' names by frame, for the CSV: one per image, whatever the number of dots.
    let mut names: Vec<Box<str>> = Vec::new();
    // The next batch is read while this one is reconstructed (on the other core).
    let mut batch = rows.batch()?;
    while !batch.rows.is_empty() {
        names.append(&mut batch.new_images);
        let rows_now = &batch.rows;
        let (next, outputs) = rayon::join(
            || rows.batch(),
            || {
                // Chunks of rows on all cores, each reconstructed and formatted (PLY and CSV).
                let chunks = rows_now.len().div_ceil(CHUNK);
                (0..chunks)
                    .into_par_iter()
                    .map(|k| {
                        let mut ply = Vec::with_capacity(CHUNK * 64);
                        let mut text = String::new();
                        let mut miss2 = 0.0;
                        let end = ((k + 1) * CHUNK).min(rows_now.len());
                        for row in &rows_now[k * CHUNK..end] {
                            let d = row.dot;
                            let at = |why: String| {
                                let why = format!("ray {} at ({}, {}): {why}", d.id, d.col, d.row);
                                FileError::at(&args.obs, row.line, why)
                            };
                            let mut p = reconstruct_dot(
                                &rig,
                                &d,
                                method,
                                args.sigma_px.filter(|_| model.is_none()),
                                Some(&calibration),
                            )
                            .map_err(|e| at(e.root_cause().to_string()))?;
                            if let Some(model) = &model {
                                let q = model
                                    .reconstruct(rig.grid(), &d, method, model_frame)
                                    .map_err(|e| at(e.to_string()))?;
                                if plate {
                                    p.point = q.point;
                                }
                                p.sigma = Some((q.image + q.calibration).diagonal().map(f64::sqrt));
                            }
                            miss2 += p.miss * p.miss;
                            push_point(&mut ply, &p, Some(row.frame), &layout);
                            if csv.is_some() {
                                let image = names.get(row.frame as usize).map_or("", |n| n);
                                csv_line(&mut text, image, &p);
                            }
                        }
                        Ok::<_, anyhow::Error>((ply, text, miss2))
                    })
                    .collect::<Vec<_>>()
            },
        );
        for output in outputs {
            let (ply, text, m) = output?;
            miss2 += m;
            vertex_file
                .write_all(&ply)
                .with_context(|| format!("{}: cannot write", args.out.display()))?;
            if let Some((pending, writer)) = &mut csv {
                writer
                    .write_all(text.as_bytes())
                    .with_context(|| format!("{}: cannot write", pending.target.display()))?;
            }
        }
        count += batch.rows.len();
        batch = next?;
    }
    let images = names.len();
    if count == 0 {
        bail!(FileError::whole(&args.obs, "no dot observations"));
    }
    // The cloud: header, then the vertices copied over.
    vertex_file
        .flush()
        .with_context(|| format!("{}: cannot write", args.out.display()))?;
    drop(vertex_file);
    let info = CloudInfo {
        frame: frame.clone(),
        fingerprint: Some(system.fingerprint.clone()),
        ..CloudInfo::default()
    };
    let (cloud, mut cloud_file) = Pending::new(&args.out, "ply")?;
    let copied = (|| -> std::io::Result<()> {
        cloud_file.write_all(header(count, &layout, &info).as_bytes())?;
        std::io::copy(&mut std::fs::File::open(&vertices.tmp)?, &mut cloud_file)?;
        Ok(())
    })();
    copied.with_context(|| format!("{}: cannot write", args.out.display()))?;
    if let Some((pending, writer)) = csv {
        pending.commit(writer)?;
    }
    cloud.commit(cloud_file)?;
    drop(vertices);
    Ok(StreamSummary {
        points: count,
        images,
        miss_rms: (miss2 / count as f64).sqrt(),
        fingerprint: system.fingerprint,
        frame,
    })
}
