//! `deltaz reconstruct` as a stream: identified dots are read from the CSV in batches, each batch
//! reconstructed on all cores ([`deltaz_calib::reconstruct::reconstruct`], one dot at a time) and
//! appended to the outputs, so memory does not grow with the number of points.
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
use crate::io::ply::{header, push_point, CloudInfo, Encoding, Layout};
use crate::io::system_file::{SystemFile, SystemFrame};
use crate::io::{csv_reader, header_columns, number_field, optional_column, record_line};
use crate::io::{points_comment, text_field, FileError};
use anyhow::{bail, Context, Result};
use deltaz_calib::projector_calibration::DotObservation;
use deltaz_calib::reconstruct::{reconstruct, ReconstructedPoint};
use deltaz_calib::system_adjustment::Frame;
use deltaz_shared::rig::Method;
use rayon::prelude::*;
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

/// One row to reconstruct: its image (and that image's index), dot and line.
struct Row {
    image: String,
    frame: u32,
    dot: DotObservation,
    line: usize,
}

/// The CSV's rows in batches of [`BATCH`], checked.
struct Rows {
    path: PathBuf,
    records: csv::StringRecordsIntoIter<crate::io::LfOnly<std::fs::File>>,
    columns: [usize; 4],
    /// The header's number of fields: a row with more is refused.
    width: usize,
    kind: Option<usize>,
    image: String,
    /// The images met so far, in order: a row's frame index.
    images: Vec<String>,
    seen: std::collections::HashSet<u16>,
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
            records: reader.into_records(),
            image: String::new(),
            images: Vec::new(),
            seen: Default::default(),
            sensor,
        })
    }

    /// The next batch (empty at the end of the file).
    fn batch(&mut self) -> Result<Vec<Row>> {
        let path = &self.path;
        let [ci, cp, cc, cr] = self.columns;
        let mut out = Vec::new();
        while out.len() < BATCH {
            let Some(record) = self.records.next() else {
                break;
            };
            let record = record.map_err(|e| {
                let line = e.position().map_or(0, |p| p.line() as usize);
                FileError::at(path, line, e.to_string())
            })?;
            let line = record_line(&record);
            if record.iter().skip(self.width).any(|f| !f.is_empty()) {
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
                match record.get(k) {
                    Some("dot") => {}
                    None | Some("") | Some("control") => continue,
                    Some(other) => bail!(FileError::at(
                        path,
                        line,
                        format!("`kind` must be `control` or `dot`, not {other:?}")
                    )),
                }
            }
            let image = text_field(path, &record, ci, "image")?;
            let point = text_field(path, &record, cp, "point")?;
            let Ok(id) = point.parse::<u16>() else {
                bail!(FileError::at(
                    path,
                    line,
                    format!("point {point:?} is not a ray id")
                ));
            };
            let dot = DotObservation {
                id,
                col: number_field(path, &record, cc, "col")?,
                row: number_field(path, &record, cr, "row")?,
            };
            let (w, h) = self.sensor;
            if !(-0.5..=w as f64 - 0.5).contains(&dot.col)
                || !(-0.5..=h as f64 - 0.5).contains(&dot.row)
            {
                bail!(FileError::at(
                    path,
                    line,
                    format!("({}, {}) is off the {w} × {h} sensor", dot.col, dot.row)
                ));
            }
            if image != self.image {
                self.image = image.to_owned();
                self.seen.clear();
                if !self.images.iter().any(|i| i == image) {
                    self.images.push(image.to_owned());
                }
            }
            if !self.seen.insert(id) {
                bail!(FileError::at(
                    path,
                    line,
                    format!("duplicate observation of ray {id} in image {image:?}")
                ));
            }
            out.push(Row {
                image: self.image.clone(),
                frame: self
                    .images
                    .iter()
                    .position(|i| *i == self.image)
                    .unwrap_or(0) as u32,
                dot,
                line,
            });
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
    // The file is read on its own thread while the previous batch is reconstructed.
    let (send, receive) = std::sync::mpsc::sync_channel::<Result<Vec<Row>>>(1);
    let images = std::thread::scope(|scope| -> Result<usize> {
        let reader = scope.spawn(move || loop {
            let batch = rows.batch();
            let end = batch.as_ref().map_or(true, |b| b.is_empty());
            if send.send(batch).is_err() || end {
                return rows.images.len();
            }
        });
        for batch in receive {
            let batch = batch?;
            if batch.is_empty() {
                break;
            }
            // Chunks of rows on all cores, each reconstructed and formatted (PLY and CSV).
            let chunks = batch.len().div_ceil(CHUNK);
            let outputs: Vec<_> = (0..chunks)
                .into_par_iter()
                .map(|k| {
                    let mut ply = Vec::new();
                    let mut text = String::new();
                    let mut miss2 = 0.0;
                    for row in &batch[k * CHUNK..((k + 1) * CHUNK).min(batch.len())] {
                        let d = row.dot;
                        let at = |why: String| {
                            let why = format!("ray {} at ({}, {}): {why}", d.id, d.col, d.row);
                            FileError::at(&args.obs, row.line, why)
                        };
                        let mut p = reconstruct(
                            &rig,
                            std::slice::from_ref(&d),
                            method,
                            args.sigma_px.filter(|_| model.is_none()),
                            Some(&calibration),
                        )
                        .map_err(|e| at(e.root_cause().to_string()))?[0];
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
                            csv_line(&mut text, &row.image, &p);
                        }
                    }
                    Ok::<_, anyhow::Error>((ply, text, miss2))
                })
                .collect();
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
            count += batch.len();
        }
        reader
            .join()
            .map_err(|_| anyhow::anyhow!("{}: the reader failed", args.obs.display()))
    })?;
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
