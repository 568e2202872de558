//! The live chain: a reader thread takes frames from the source and measures their dots; the
//! device thread has them identified and intersected by the device and publishes each frame for
//! the page (a downscaled image, every dot with its state, the counts and the frame rate) and
//! for capture. The reader keeps only the newest measured frame for the device thread: a slow
//! device drops frames, it never delays the source. A source, device or frame that fails is
//! reported in the status and tried again with the next frame; nothing stops the station.

use super::source::Source;
use super::state::{DeviceStatus, Health, KeptFrame, Shared};
use crate::io::system_file::SystemRig;
use crate::workflows::device::{connect, ensure_calibration, AnyDevice, LinkArgs};
use crate::workflows::scan::{identify_params, measure_dots, on_device, Identified};
use anyhow::Result;
use deltaz_measure::{LoadedImage, MeasureParams};
use deltaz_shared::identify::DepthRange;
use deltaz_shared::rig::Method;
use std::collections::{HashMap, VecDeque};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant, SystemTime};

/// The newest value of a producer for one consumer: `put` replaces what was not taken yet.
pub struct Latest<T> {
    value: Mutex<Option<T>>,
    ready: Condvar,
}

impl<T> Default for Latest<T> {
    fn default() -> Self {
        Self {
            value: Mutex::new(None),
            ready: Condvar::new(),
        }
    }
}

impl<T> Latest<T> {
    /// Offer `value`, replacing one not taken yet.
    pub fn put(&self, value: T) {
        *self.value.lock().unwrap_or_else(|e| e.into_inner()) = Some(value);
        self.ready.notify_one();
    }

    /// The newest value, waiting up to `timeout` for one.
    pub fn take(&self, timeout: Duration) -> Option<T> {
        let guard = self.value.lock().unwrap_or_else(|e| e.into_inner());
        let (mut guard, _) = self
            .ready
            .wait_timeout_while(guard, timeout, |v| v.is_none())
            .unwrap_or_else(|e| e.into_inner());
        guard.take()
    }
}

/// A frame read and measured, waiting for the device.
pub struct Measured {
    label: String,
    read_at: SystemTime,
    dots: Vec<(f64, f64)>,
    thumbnail: Thumbnail,
}

/// A frame downscaled for the page: a JPEG and the factor it was shrunk by.
struct Thumbnail {
    jpeg: Vec<u8>,
    size: (u32, u32),
    factor: u32,
}

/// The widest thumbnail the page gets (px).
const THUMBNAIL_WIDTH: u32 = 400;

/// `image` shrunk by an integer factor (the mean of each block) to at most
/// [`THUMBNAIL_WIDTH`] pixels wide, as a JPEG.
fn thumbnail(image: &LoadedImage) -> Thumbnail {
    let (width, height) = image.dimensions();
    let grey = |x: u32, y: u32| -> u32 {
        match image {
            LoadedImage::Eight(b) => u32::from(b.get_pixel(x, y)[0]),
            LoadedImage::Sixteen(b) => u32::from(b.get_pixel(x, y)[0] >> 8),
        }
    };
    let factor = width.div_ceil(THUMBNAIL_WIDTH).max(1);
    let (w, h) = ((width / factor).max(1), (height / factor).max(1));
    let small = image::GrayImage::from_fn(w, h, |x, y| {
        let mut sum = 0;
        for dy in 0..factor {
            for dx in 0..factor {
                sum += grey(x * factor + dx, y * factor + dy);
            }
        }
        image::Luma([(sum / (factor * factor)) as u8])
    });
    let mut jpeg = Vec::new();
    let encoded = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 80).encode(
        small.as_raw(),
        w,
        h,
        image::ExtendedColorType::L8,
    );
    if encoded.is_err() {
        jpeg.clear();
    }
    Thumbnail {
        jpeg,
        size: (w, h),
        factor,
    }
}

/// Base64 (RFC 4648, with padding) for a `data:` URL.
pub fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = u32::from(b[0]) << 16 | u32::from(b[1]) << 8 | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(char::from(ALPHABET[(n >> (18 - 6 * k) & 63) as usize]));
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// Milliseconds since the Unix epoch (the page compares it with its own clock).
pub fn unix_ms(t: SystemTime) -> f64 {
    t.duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64() * 1e3)
}

/// The reader thread: frames from `source`, measured, offered to the device thread, until
/// `stop`. A source that fails is reported and tried again after a second.
pub fn read_frames(
    mut source: Box<dyn Source>,
    sensor: (u32, u32),
    shared: &Shared,
    measured: &Latest<Measured>,
    stop: &AtomicBool,
) {
    let params = MeasureParams::default();
    let mut healthy = false;
    while !stop.load(Ordering::Relaxed) {
        let frame = source.next_frame().and_then(|(label, image, read_at)| {
            let dots = measure_dots(sensor, &params, &label, &image)?;
            Ok(Measured {
                thumbnail: thumbnail(&image),
                label,
                read_at,
                dots,
            })
        });
        match frame {
            Ok(frame) => {
                if !healthy {
                    healthy = true;
                    shared.update_status(|s| s.source = Health::ok("reading frames"));
                }
                measured.put(frame);
            }
            Err(e) => {
                healthy = false;
                shared.update_status(|s| {
                    s.source = Health::failing(format!("{e:#} (trying again)"));
                });
                std::thread::sleep(Duration::from_secs(1));
            }
        }
    }
}

/// What the device thread needs.
pub struct DeviceSetup {
    /// system.json.
    pub system: PathBuf,
    /// Its rig.
    pub rig: Arc<SystemRig>,
    /// Its fingerprint.
    pub fingerprint: u64,
    /// The link.
    pub link: LinkArgs,
    /// The depth range of the subject (mm).
    pub depth: DepthRange<f64>,
    /// The identification tolerance (px).
    pub tolerance: f64,
}

impl DeviceSetup {
    /// Connect and make sure the device holds the calibration: the station uploads its own to
    /// a device that holds another or none (the frames it shows are measured with it).
    fn connect(&self) -> Result<AnyDevice> {
        let mut device = connect(&self.link)?;
        let cell = if self.rig.grid().width > 2000 {
            32.0
        } else {
            16.0
        };
        let identification = identify_params(self.depth, self.tolerance, cell);
        ensure_calibration(
            &mut device,
            &self.link,
            (&self.system, &self.rig, self.fingerprint),
            Method::ClosestApproach,
            Some(identification),
            true,
        )?;
        Ok(device)
    }
}

/// A dot's state on the page.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum DotState {
    /// Identified, with a point.
    Identified = 0,
    /// Not identified (or without a point).
    NotIdentified = 1,
}

/// Each measured dot's state.
pub fn dot_states(dots: &[(f64, f64)], found: &Identified) -> Vec<DotState> {
    let key = |c: f64, r: f64| (c.to_bits(), r.to_bits());
    let ray_of: HashMap<_, u16> = found
        .identified
        .iter()
        .map(|d| (key(d.col, d.row), d.id))
        .collect();
    let point_of: HashMap<u16, usize> = found
        .points
        .iter()
        .enumerate()
        .map(|(i, p)| (p.id, i))
        .collect();
    dots.iter()
        .map(
            |&(c, r)| match ray_of.get(&key(c, r)).and_then(|id| point_of.get(id)) {
                Some(_) => DotState::Identified,
                None => DotState::NotIdentified,
            },
        )
        .collect()
}

/// The device thread: each measured frame identified and intersected, published with its
/// states and counts; `surface` is poked after each frame. A device that fails is reported,
/// its frames published without points, and tried again with the next frame.
pub fn identify_frames(
    setup: &DeviceSetup,
    shared: &Shared,
    measured: &Latest<Measured>,
    surface: &Latest<()>,
    stop: &AtomicBool,
) {
    let mut device: Option<AnyDevice> = None;
    let mut times: VecDeque<Instant> = VecDeque::new();
    let mut seq = 0u64;
    while !stop.load(Ordering::Relaxed) {
        let Some(frame) = measured.take(Duration::from_millis(300)) else {
            continue;
        };
        let mut found = Identified::default();
        if !frame.dots.is_empty() {
            if device.is_none() {
                match setup.connect() {
                    Ok(d) => device = Some(d),
                    Err(e) => report_device(shared, Err(&e), None),
                }
            }
            if let Some(d) = device.as_mut() {
                let result = on_device(&setup.rig, d)(&frame.dots);
                match result {
                    Ok(f) => {
                        found = f;
                        report_device(shared, Ok(setup.fingerprint), Some(d));
                    }
                    Err(e) => {
                        report_device(shared, Err(&e), Some(d));
                        let lost = e.chain().any(|c| {
                            matches!(
                                c.downcast_ref::<crate::link::DeviceError>(),
                                Some(crate::link::DeviceError::Io(_))
                            )
                        });
                        if lost {
                            device = None;
                        }
                    }
                }
            }
        }
        let now = Instant::now();
        times.push_back(now);
        while times.len() > 30
            || times
                .front()
                .is_some_and(|t| now - *t > Duration::from_secs(3))
        {
            times.pop_front();
        }
        let fps = match (times.front(), times.len()) {
            (Some(first), n) if n > 1 && now > *first => {
                (n - 1) as f64 / (now - *first).as_secs_f64()
            }
            _ => 0.0,
        };
        seq += 1;
        let json = live_json(seq, &frame, &found, fps);
        shared.publish_live(
            json,
            KeptFrame {
                label: frame.label,
                read_at: frame.read_at,
                dots: frame.dots,
                found,
            },
        );
        surface.put(());
    }
}

/// The device's status after a request: answering (with the calibration's fingerprint) or the
/// error; the link's counters.
fn report_device(shared: &Shared, result: Result<u64, &anyhow::Error>, device: Option<&AnyDevice>) {
    let counts = device.map(AnyDevice::line_counts).unwrap_or_default();
    shared.update_status(|s| {
        let health = match result {
            Ok(_) => Health::ok("answering"),
            Err(e) => Health::failing(format!("{e:#} (trying again with the next frame)")),
        };
        let fingerprint = match result {
            Ok(f) => Some(format!("{f:016x}")),
            Err(_) => s.device.fingerprint.clone(),
        };
        s.device = DeviceStatus {
            health,
            fingerprint,
            link_errors: counts.damaged + counts.unreadable + counts.stale,
            resent: counts.resent,
        };
    });
}

/// The live event of a frame.
fn live_json(seq: u64, frame: &Measured, found: &Identified, fps: f64) -> String {
    let states = dot_states(&frame.dots, found);
    let f = f64::from(frame.thumbnail.factor);
    let dots: Vec<[f64; 3]> = frame
        .dots
        .iter()
        .zip(&states)
        .map(|(&(c, r), &s)| {
            // Pixel centres: (0, 0) is the centre of the top-left pixel in both images.
            let at = |v: f64| (((v + 0.5) / f - 0.5) * 10.0).round() / 10.0;
            [at(c), at(r), f64::from(s as u8)]
        })
        .collect();
    let count = |s: DotState| states.iter().filter(|&&x| x == s).count();
    let notice = frame.dots.is_empty().then_some(
        "no dots in this frame: is the projector on and the subject in front of the camera?",
    );
    serde_json::json!({
        "seq": seq,
        "label": frame.label,
        "read_ms": unix_ms(frame.read_at),
        "sent_ms": unix_ms(SystemTime::now()),
        "image": format!("data:image/jpeg;base64,{}", base64(&frame.thumbnail.jpeg)),
        "image_size": [frame.thumbnail.size.0, frame.thumbnail.size.1],
        "factor": frame.thumbnail.factor,
        "dots": dots,
        "counts": {
            "dots": frame.dots.len(),
            "identified": count(DotState::Identified),
            "not_identified": count(DotState::NotIdentified),
            "points": found.points.len(),
        },
        "fps": (fps * 10.0).round() / 10.0,
        "notice": notice,
    })
    .to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc4648() {
        // RFC 4648, section 10.
        let cases = [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ];
        for (plain, encoded) in cases {
            assert_eq!(base64(plain.as_bytes()), encoded);
        }
        assert_eq!(base64(&[0xff, 0xfe, 0x3f]), "//4/");
    }

    #[test]
    fn latest_keeps_only_the_newest() {
        let slot = Latest::default();
        slot.put(1);
        slot.put(2);
        assert_eq!(slot.take(Duration::ZERO), Some(2));
        assert_eq!(slot.take(Duration::from_millis(1)), None);
    }
}
