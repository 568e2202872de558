//! The station's end-to-end figures: frames per second and latency from a frame's read to its
//! event at the page (the event read off the server's event stream by an HTTP client in this
//! process, the same clock as the read's time stamp), on a replay through the device, first as
//! fast as the chain goes, then paced at a set rate.

use super::live::unix_ms;
use super::{start, StationArgs};
use anyhow::{bail, Context, Result};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::{Duration, Instant, SystemTime};

/// A client of the station's event stream (`GET /events`, chunked server-sent events).
pub struct EventClient {
    reader: BufReader<TcpStream>,
    pending: Vec<u8>,
}

impl EventClient {
    /// Connects to the station at `addr`.
    pub fn connect(addr: SocketAddr) -> Result<Self> {
        let mut stream = TcpStream::connect(addr)?;
        stream.set_read_timeout(Some(Duration::from_secs(30)))?;
        write!(
            stream,
            "GET /events HTTP/1.1\r\nHost: {addr}\r\nAccept: text/event-stream\r\n\r\n"
        )?;
        let mut reader = BufReader::new(stream);
        let mut line = String::new();
        reader.read_line(&mut line)?;
        if !line.starts_with("HTTP/1.1 200") {
            bail!("GET /events: {}", line.trim());
        }
        loop {
            line.clear();
            reader.read_line(&mut line)?;
            if line == "\r\n" || line.is_empty() {
                break;
            }
        }
        Ok(Self {
            reader,
            pending: Vec::new(),
        })
    }

    /// The next event: its name, its data and when it arrived.
    pub fn next_event(&mut self) -> Result<(String, String, SystemTime)> {
        loop {
            if let Some(end) = find(&self.pending, b"\n\n") {
                let block: Vec<u8> = self.pending.drain(..end + 2).collect();
                let text = String::from_utf8_lossy(&block);
                let mut name = String::from("message");
                let mut data = String::new();
                for line in text.lines() {
                    if let Some(v) = line.strip_prefix("event:") {
                        name = v.trim().to_owned();
                    } else if let Some(v) = line.strip_prefix("data:") {
                        data.push_str(v.strip_prefix(' ').unwrap_or(v));
                    }
                }
                if data.is_empty() {
                    continue; // a keep-alive comment
                }
                return Ok((name, data, SystemTime::now()));
            }
            self.read_chunk()?;
        }
    }

    /// One chunk of the chunked body into `pending`.
    fn read_chunk(&mut self) -> Result<()> {
        let mut size = String::new();
        self.reader.read_line(&mut size)?;
        let size = usize::from_str_radix(size.trim(), 16)
            .with_context(|| format!("a chunk size {size:?}"))?;
        if size == 0 {
            bail!("the event stream ended");
        }
        let mut chunk = vec![0; size + 2];
        self.reader.read_exact(&mut chunk)?;
        chunk.truncate(size);
        self.pending.extend(chunk);
        Ok(())
    }
}

fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    haystack.windows(needle.len()).position(|w| w == needle)
}

/// Figures of one run.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Run {
    /// The replay's frame rate asked for.
    pub fps_asked: f64,
    /// Live events received.
    pub frames: usize,
    /// Live events per second at the page.
    pub fps: f64,
    /// Latency from a frame's read to its event at the page (ms): mean, median, 95th
    /// percentile, largest.
    pub latency_ms: [f64; 4],
    /// Surface events per second, and their mean latency from the newest frame's read (ms).
    pub surface: [f64; 2],
    /// The mean size of a live event (bytes).
    pub live_event_bytes: f64,
    /// Points per frame (mean).
    pub points: f64,
}

/// Runs the station on `args` (its replay's frame rate replaced by `fps`) for `seconds`, its
/// events read as a page would.
pub fn run(args: &StationArgs, fps: f64, seconds: f64) -> Result<Run> {
    let mut args = args.clone();
    if let super::source::SourceArgs::Replay { fps: f, .. } = &mut args.source {
        *f = fps;
    }
    let station = start(args)?;
    let result = measure(station.addr, fps, seconds);
    station.stop();
    result
}

fn measure(addr: SocketAddr, fps: f64, seconds: f64) -> Result<Run> {
    let mut client = EventClient::connect(addr)?;
    // The first live event is the latest before connecting: skip the warm-up.
    let warm = Instant::now();
    while warm.elapsed() < Duration::from_secs(2) {
        client.next_event()?;
    }
    let began = Instant::now();
    let (mut latency, mut bytes, mut points) = (Vec::new(), 0usize, 0.0);
    let (mut surfaces, mut surface_latency) = (0usize, 0.0);
    while began.elapsed().as_secs_f64() < seconds {
        let (name, data, at) = client.next_event()?;
        let json: serde_json::Value = serde_json::from_str(&data)?;
        let read = json["read_ms"].as_f64().unwrap_or(f64::NAN);
        match name.as_str() {
            "live" => {
                latency.push(unix_ms(at) - read);
                bytes += data.len();
                points += json["counts"]["points"].as_f64().unwrap_or(0.0);
            }
            "surface" if read.is_finite() => {
                surfaces += 1;
                surface_latency += unix_ms(at) - read;
            }
            _ => {}
        }
    }
    let elapsed = began.elapsed().as_secs_f64();
    let n = latency.len();
    if n == 0 {
        bail!("no frame reached the page in {seconds} s");
    }
    let mean = latency.iter().sum::<f64>() / n as f64;
    latency.sort_by(f64::total_cmp);
    let at = |q: f64| latency[((n - 1) as f64 * q).round() as usize];
    Ok(Run {
        fps_asked: fps,
        frames: n,
        fps: n as f64 / elapsed,
        latency_ms: [mean, at(0.5), at(0.95), latency[n - 1]],
        surface: [
            surfaces as f64 / elapsed,
            surface_latency / surfaces.max(1) as f64,
        ],
        live_event_bytes: bytes as f64 / n as f64,
        points: points / n as f64,
    })
}
