//! Where the station's frames come from: a folder of images played at a frame rate
//! ([`Replay`], what the tests and a user without hardware use) or a Linux video device
//! ([`Camera`], V4L2: UVC webcams). A source that fails mid-run (a folder removed, a camera
//! unplugged) says why and is tried again by [`Source::next_frame`] until it comes back.

use crate::workflows::scan::frame_files;
use anyhow::{Context, Result};
use deltaz_measure::{load_image, LoadedImage};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime};

/// Which source the command line names.
#[derive(Debug, Clone)]
pub enum SourceArgs {
    /// A folder of images (PNG, TIFF, JPEG) in name order, played in a loop at `fps`.
    Replay {
        /// The folder.
        dir: PathBuf,
        /// Frames per second.
        fps: f64,
    },
    /// A V4L2 video device (e.g. /dev/video0).
    Camera {
        /// Its path.
        device: PathBuf,
    },
}

/// A frame as read: its label, image and when it was read.
pub type RawFrame = (String, LoadedImage, SystemTime);

/// A source of camera frames.
pub trait Source: Send {
    /// The next frame, waiting for it (a replay keeps its frame rate). An error says why no
    /// frame came (the folder or camera gone); the next call tries again.
    fn next_frame(&mut self) -> Result<RawFrame>;
}

/// Opens the source `args` name, for frames of `sensor` (width, height) pixels: a folder with
/// no images or a camera that cannot be opened is an error here, before the station starts.
pub fn open(args: &SourceArgs, sensor: (u32, u32)) -> Result<Box<dyn Source>> {
    match args {
        SourceArgs::Replay { dir, fps } => Ok(Box::new(Replay::new(dir, *fps)?)),
        SourceArgs::Camera { device } => Ok(Box::new(Camera::open(device, sensor)?)),
    }
}

/// A folder of images played in a loop.
pub struct Replay {
    dir: PathBuf,
    files: Vec<PathBuf>,
    next: usize,
    period: Duration,
    due: Instant,
}

impl Replay {
    /// The images of `dir` at `fps` frames per second.
    pub fn new(dir: &Path, fps: f64) -> Result<Self> {
        if !(fps.is_finite() && fps > 0.0) {
            anyhow::bail!("--fps {fps}: not a positive frame rate");
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            files: frame_files(dir)?,
            next: 0,
            period: Duration::from_secs_f64(1.0 / fps),
            due: Instant::now(),
        })
    }
}

impl Source for Replay {
    fn next_frame(&mut self) -> Result<RawFrame> {
        let now = Instant::now();
        if self.due > now {
            std::thread::sleep(self.due - now);
        }
        self.due = self.due.max(now) + self.period;
        if self.files.is_empty() {
            // Gone before: list the folder again.
            self.files = frame_files(&self.dir)?;
            self.next = 0;
        }
        let path = self.files[self.next % self.files.len()].clone();
        self.next = (self.next + 1) % self.files.len();
        let read_at = SystemTime::now();
        match load_image(&path) {
            Ok(image) => {
                let label = path
                    .file_stem()
                    .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
                Ok((label, image, read_at))
            }
            Err(e) => {
                self.files.clear();
                Err(e)
            }
        }
    }
}

/// A V4L2 video device, read as 8-bit grey (its GREY format, or the Y of YUYV).
pub struct Camera {
    path: PathBuf,
    sensor: (u32, u32),
    /// The open stream and its frames' layout: width, height, bytes per line, bytes per pixel
    /// (1: GREY, 2: YUYV, whose first byte is the grey value Y).
    #[cfg(target_os = "linux")]
    stream: Option<(linuxvideo::stream::ReadStream, [usize; 4])>,
    frames: u64,
}

impl Camera {
    /// Opens `path` for frames of `sensor` pixels; an error names the device and the problem.
    pub fn open(path: &Path, sensor: (u32, u32)) -> Result<Self> {
        let mut camera = Self {
            path: path.to_path_buf(),
            sensor,
            #[cfg(target_os = "linux")]
            stream: None,
            frames: 0,
        };
        camera.connect()?;
        Ok(camera)
    }

    #[cfg(target_os = "linux")]
    fn connect(&mut self) -> Result<()> {
        use linuxvideo::format::{PixFormat, PixelFormat};
        let at = || format!("{}: the camera", self.path.display());
        let device = linuxvideo::Device::open(&self.path)
            .with_context(|| format!("{}: cannot open the camera", self.path.display()))?;
        let grey = PixelFormat::from_fourcc(*b"GREY");
        let has_grey = device
            .formats(linuxvideo::BufType::VIDEO_CAPTURE)
            .any(|f| f.is_ok_and(|f| f.pixel_format() == grey));
        let wanted = if has_grey { grey } else { PixelFormat::YUYV };
        let (width, height) = self.sensor;
        let capture = device
            .video_capture(PixFormat::new(width, height, wanted))
            .with_context(at)?;
        let format = capture.format();
        let (w, h, pixel) = (format.width(), format.height(), format.pixel_format());
        if (w, h) != self.sensor {
            anyhow::bail!(
                "{}: the camera gives {w} × {h} pixels, the calibration's sensor is {width} × \
                 {height}",
                self.path.display()
            );
        }
        let step = match pixel {
            p if p == grey => 1,
            p if p == PixelFormat::YUYV => 2,
            _ => anyhow::bail!(
                "{}: the camera offers neither GREY nor YUYV frames",
                self.path.display()
            ),
        };
        let layout = [
            w as usize,
            h as usize,
            format.bytes_per_line() as usize,
            step,
        ];
        self.stream = Some((capture.into_stream().with_context(at)?, layout));
        Ok(())
    }

    #[cfg(not(target_os = "linux"))]
    fn connect(&mut self) -> Result<()> {
        anyhow::bail!(
            "{}: --camera needs Linux (V4L2); use --replay DIR",
            self.path.display()
        )
    }
}

impl Source for Camera {
    #[cfg(target_os = "linux")]
    fn next_frame(&mut self) -> Result<RawFrame> {
        if self.stream.is_none() {
            std::thread::sleep(Duration::from_secs(1));
            self.connect()?;
        }
        let Some((stream, [width, height, line, step])) = self.stream.as_mut() else {
            anyhow::bail!("{}: the camera is not open", self.path.display());
        };
        let (width, height, line, step) = (*width, *height, *line, *step);
        let read = stream.dequeue(|buffer| {
            let mut pixels = Vec::with_capacity(width * height);
            for row in 0..height {
                let start = row * line;
                let bytes = buffer.get(start..start + width * step).ok_or_else(|| {
                    std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "a short frame")
                })?;
                pixels.extend(bytes.iter().step_by(step));
            }
            Ok(pixels)
        });
        match read {
            Ok(pixels) => {
                self.frames += 1;
                let image = image::GrayImage::from_raw(width as u32, height as u32, pixels)
                    .context("a frame of the wrong size")?;
                let label = format!("c{:06}", self.frames);
                Ok((label, LoadedImage::Eight(image), SystemTime::now()))
            }
            Err(e) => {
                self.stream = None;
                Err(e).with_context(|| format!("{}: the camera is gone", self.path.display()))
            }
        }
    }

    #[cfg(not(target_os = "linux"))]
    fn next_frame(&mut self) -> Result<RawFrame> {
        self.connect()?;
        anyhow::bail!("{}: no camera support here", self.path.display())
    }
}
