//! What the station's threads share: the latest live frame, surface and status as the events
//! the page receives (each a `watch` channel: a slow page skips to the latest, nothing waits for
//! it), and the last frames with their points, from which a capture is taken.

use crate::workflows::scan::Identified;
use serde::Serialize;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::SystemTime;
use tokio::sync::watch;

/// One event for the page: its SSE name and JSON text.
pub type Event = Arc<(String, String)>;

/// A frame kept for capture: its dots and what the device made of them.
#[derive(Debug, Clone)]
pub struct KeptFrame {
    /// The frame's label (file stem, or the camera's frame number).
    pub label: String,
    /// When it was read.
    pub read_at: SystemTime,
    /// Its measured dots (col, row), px.
    pub dots: Vec<(f64, f64)>,
    /// The identified dots and their points.
    pub found: Identified,
}

/// Whether a part of the station works, in words for the page.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Health {
    /// It works.
    pub ok: bool,
    /// What it is doing, or what went wrong.
    pub text: String,
}

impl Health {
    /// Working: `text`.
    pub fn ok(text: impl Into<String>) -> Self {
        Self {
            ok: true,
            text: text.into(),
        }
    }

    /// Failing: `text`.
    pub fn failing(text: impl Into<String>) -> Self {
        Self {
            ok: false,
            text: text.into(),
        }
    }
}

/// The device's status on the page.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DeviceStatus {
    /// Answering, or not.
    pub health: Health,
    /// The calibration it holds (16 hex digits), once known.
    pub fingerprint: Option<String>,
    /// Frames damaged on the line, answers to unreadable frames and stale answers, so far.
    pub link_errors: u64,
    /// Requests sent again.
    pub resent: u64,
}

/// The station's status event.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Status {
    /// The frame source.
    pub source: Health,
    /// The device.
    pub device: DeviceStatus,
}

/// The state the threads and the server share.
pub struct Shared {
    live: watch::Sender<Event>,
    surface: watch::Sender<Event>,
    status_events: watch::Sender<Event>,
    status: Mutex<Status>,
    kept: Mutex<VecDeque<KeptFrame>>,
    keep: usize,
}

impl Shared {
    /// Keeping the last `keep` frames for capture.
    pub fn new(keep: usize) -> Self {
        let empty = |name: &str| watch::channel(Arc::new((name.to_owned(), "null".to_owned()))).0;
        let status = Status {
            source: Health::ok("starting"),
            device: DeviceStatus {
                health: Health::ok("connecting"),
                fingerprint: None,
                link_errors: 0,
                resent: 0,
            },
        };
        let shared = Self {
            live: empty("live"),
            surface: empty("surface"),
            status_events: empty("status"),
            status: Mutex::new(status),
            kept: Mutex::new(VecDeque::with_capacity(keep)),
            keep: keep.max(1),
        };
        shared.update_status(|_| {});
        shared
    }

    /// Publish a live frame (its JSON) and keep the frame for capture.
    pub fn publish_live(&self, json: String, frame: KeptFrame) {
        {
            let mut kept = self.kept.lock().unwrap_or_else(|e| e.into_inner());
            if kept.len() == self.keep {
                kept.pop_front();
            }
            kept.push_back(frame);
        }
        self.live.send_replace(Arc::new(("live".to_owned(), json)));
    }

    /// Publish the surface of the latest frames (its JSON).
    pub fn publish_surface(&self, json: String) {
        self.surface
            .send_replace(Arc::new(("surface".to_owned(), json)));
    }

    /// Change the status and publish it, if it changed.
    pub fn update_status(&self, change: impl FnOnce(&mut Status)) {
        // Published under the lock: two threads' changes reach the page in their order.
        let mut status = self.status.lock().unwrap_or_else(|e| e.into_inner());
        change(&mut status);
        let json = serde_json::to_string(&*status).unwrap_or_else(|_| "null".to_owned());
        self.status_events.send_if_modified(|event| {
            let changed = event.1 != json;
            if changed {
                *event = Arc::new(("status".to_owned(), json));
            }
            changed
        });
    }

    /// The status now.
    pub fn status(&self) -> Status {
        self.status
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// The frames kept (oldest first).
    pub fn kept(&self) -> Vec<KeptFrame> {
        self.kept
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
            .cloned()
            .collect()
    }

    /// Receivers of the three event streams (live, surface, status), each starting with its
    /// latest event.
    pub fn subscribe(&self) -> [watch::Receiver<Event>; 3] {
        [
            self.live.subscribe(),
            self.surface.subscribe(),
            self.status_events.subscribe(),
        ]
    }

    /// The latest event of each stream.
    pub fn latest(&self) -> [Event; 3] {
        [
            self.live.borrow().clone(),
            self.surface.borrow().clone(),
            self.status_events.borrow().clone(),
        ]
    }
}
