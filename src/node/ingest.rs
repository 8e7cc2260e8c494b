//! The ingest state machine: inputs from the readers → frames (the shared, sans-io
//! [`FrameAssembler`] joins them, with the node's stamp tolerance, arrival time-out and
//! late-part window) → the worker's queue; holds the map. Every frame it hears of is
//! eventually queued or dropped with a reason, each counted in `/diagnostics`.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::diagnostics::Stats;
use super::log::{lock, warn};
use super::queue::DropOldestQueue;
use crate::frame::Stamp;
use crate::frame::{Assembled, Frame, FrameAssembler, FramePart, IncompleteFrame, MapCloud, MonotonicNs, PartKind};
use crate::limits::{CorrespondenceFixes, InputLimits, LimitCounts};
use crate::msgs::convert::DecodedMap;

/// What a reader task hands to the ingest task.
pub enum Input {
    Part(FramePart),
    /// Correspondences already held to the input limits by their reader, and what that changed.
    LimitedCorrespondences(FramePart, CorrespondenceFixes),
    /// A message that decoded but did not convert; `stamp` from its header.
    PartError {
        kind: PartKind,
        stamp: Stamp,
        reason: String,
    },
    /// A map, with what the limits changed in it, and who sent it.
    Map(Result<DecodedMap, String>, MapSender),
    /// The DDS sample could not be deserialized (no header to attribute it to).
    ReadError {
        topic: String,
        reason: String,
    },
    /// A message outside frames (e.g. a transform) was unusable, or is worth counting (an
    /// initial pose from another publisher): counted under `reason`.
    Invalid {
        reason: &'static str,
        detail: String,
    },
}

/// Where a map came from: the node's file (`map_path`, `~/load_map`) or a publisher on the map
/// topic (its DDS GUID, as `ros2 topic info -v` shows it).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum MapSender {
    File,
    Publisher(String),
}

/// An input and the camera it is for: the index into the node's cameras, `None` for the
/// node's own inputs (the map, TF), which concern every camera.
pub struct Routed {
    pub camera: Option<usize>,
    pub input: Input,
}

/// One frame waiting for the worker (which takes a new map from the node's shared
/// [`crate::map_index::swap::MapSwap`] between two frames).
pub struct Job {
    pub frame: Frame,
    /// When the assembler handed it out (complete, or timed out).
    pub handed_out: Instant,
}

/// How frames are joined: the node's `frame_timeout_ms`, `stamp_tolerance_ns`, `require_map`.
#[derive(Clone)]
pub struct IngestRules {
    /// The parts a frame waits for (the required ones are always waited for).
    pub expected: Vec<PartKind>,
    pub stamp_tolerance_ns: i64,
    /// How long a frame waits after its first part; also how long a handed-out stamp is
    /// remembered, so a part for it is named a late part (later, the same stamp is a new
    /// frame: a restarted player).
    pub frame_timeout: Duration,
    /// Frames before any map are dropped (`no_map`).
    pub require_map: bool,
    /// The input limits applied to each assembled frame (`limits.*`).
    pub limits: InputLimits,
    /// The camera's pixel space (`camera.pixels`).
    pub pixels: crate::camera::PixelSpace,
}

/// Joins parts into frames, times out incomplete ones, knows whether a map arrived, feeds the
/// queue (one per camera).
pub struct Ingest {
    assembler: FrameAssembler,
    /// `frames_opened` of the assembler already counted as received.
    opened_counted: u64,
    require_map: bool,
    map: Option<Arc<MapCloud>>,
    queue: Arc<DropOldestQueue<Job>>,
    stats: Arc<Mutex<Stats>>,
    limits: InputLimits,
    limit_counts: LimitCounts,
}

impl Ingest {
    pub fn new(rules: IngestRules, queue: Arc<DropOldestQueue<Job>>, stats: Arc<Mutex<Stats>>) -> Self {
        let timeout_ns = rules.frame_timeout.as_nanos().min(i64::MAX as u128) as i64;
        let assembler = FrameAssembler::new(&rules.expected)
            .with_stamp_tolerance(rules.stamp_tolerance_ns)
            .with_arrival_timeout(timeout_ns)
            .with_repeat_window(timeout_ns)
            .with_pixel_space(rules.pixels);
        Self {
            assembler,
            opened_counted: 0,
            require_map: rules.require_map,
            map: None,
            queue,
            stats,
            limits: rules.limits,
            limit_counts: LimitCounts::default(),
        }
    }

    /// Handles one input that arrived at `now` (the node's monotonic clock).
    pub fn on_input(&mut self, input: Input, now: MonotonicNs) {
        match input {
            Input::Part(part) => {
                let mut s = lock(&self.stats);
                s.health.heard(part.kind().name(), Instant::now());
                if let FramePart::DepthPrior { stamp, depth } = &part {
                    if !depth.data.iter().any(|v| v.is_finite()) {
                        // Counted, and the frame goes on without a usable prior (as it would
                        // with none): #38.
                        s.error("unusable_prior", format!("frame {stamp}: depth prior: no finite value"));
                    }
                }
                drop(s);
                let done = self.assembler.push(part, now);
                self.handle(done);
            }
            Input::LimitedCorrespondences(part, fixes) => {
                let before = self.limit_counts.clone();
                self.limit_counts.add(&fixes);
                self.count_limited(&before, part.stamp());
                self.on_input(Input::Part(part), now);
            }
            Input::PartError { kind, stamp, reason } => {
                let name = kind.name();
                warn(format!("frame {stamp}: bad {name}: {reason}"));
                let mut s = lock(&self.stats);
                s.health.heard(name, Instant::now());
                s.error(&format!("invalid_{name}"), format!("frame {stamp}: {name}: {reason}"));
                drop(s);
                let done = self.assembler.push_error(stamp, kind, format!("{reason} (counted)"), now);
                self.handle(done);
            }
            Input::Map(Ok(DecodedMap { map, notes }), _) => self.set_map(Arc::new(map), &notes),
            Input::Map(Err(reason), _) => {
                warn(format!("bad map (kept the previous one): {reason}"));
                self.count_error("invalid_map", format!("map: {reason}"));
            }
            Input::ReadError { topic, reason } => {
                warn(format!("{topic}: undecodable message: {reason}"));
                lock(&self.stats).error("undecodable_message", format!("{topic}: {reason}"));
            }
            Input::Invalid { reason, detail } => {
                warn(&detail);
                lock(&self.stats).error(reason, detail);
            }
        }
    }

    /// The map frames are localized against from now on (shared by every camera: the node
    /// indexes it once), with what the input limits changed in it (`notes`, counted).
    pub fn set_map(&mut self, map: Arc<MapCloud>, notes: &[String]) {
        let mut s = lock(&self.stats);
        for note in notes {
            s.error("map_cleaned", format!("map: {note}"));
        }
        s.maps_received += 1;
        s.map_points = map.points.len();
        self.map = Some(map);
    }

    /// Counts an input of the node's own (e.g. a bad map or transform) in this camera's status.
    pub fn count_error(&self, reason: &str, detail: String) {
        lock(&self.stats).error(reason, detail);
    }

    /// Hands out the frames (and late parts) that waited past the time-out at `now`.
    pub fn expire(&mut self, now: MonotonicNs) {
        for done in self.assembler.expire(now) {
            self.handle(Some(done));
        }
    }

    fn handle(&mut self, done: Option<Assembled>) {
        // Every stamp that started waiting is a frame heard of, whatever becomes of it.
        let opened = self.assembler.frames_opened();
        lock(&self.stats).frames_received += opened - self.opened_counted;
        self.opened_counted = opened;
        let Some(done) = done else { return };
        let before = self.limit_counts.clone();
        let limited = crate::bag::limit_frame(done, &self.limits, &mut self.limit_counts);
        self.count_limited(&before, limited.stamp());
        match limited {
            Assembled::Complete(frame) => self.enqueue(frame),
            Assembled::Partial(frame, report) => {
                self.count_incomplete(&report);
                self.enqueue(frame);
            }
            Assembled::Dropped(report) => self.count_incomplete(&report),
        }
    }

    /// Names what the input limits changed in the frame at `stamp` (its report says how much).
    fn count_limited(&self, before: &LimitCounts, stamp: Stamp) {
        let after = &self.limit_counts;
        let changes = [
            (
                after.frames_over_correspondence_limit,
                before.frames_over_correspondence_limit,
                "correspondences_over_limit",
            ),
            (after.frames_with_duplicates_merged, before.frames_with_duplicates_merged, "duplicates_merged"),
            (after.frames_with_scores_clamped, before.frames_with_scores_clamped, "scores_clamped"),
        ];
        let mut s = lock(&self.stats);
        for (now, was, reason) in changes {
            if now > was {
                s.error(reason, format!("frame {stamp}: {reason} (see the frame's report)"));
            }
        }
    }

    fn count_incomplete(&self, r: &IncompleteFrame) {
        let detail = crate::app::describe(r);
        warn(&detail);
        let mut s = lock(&self.stats);
        if r.late_parts {
            // Not a frame: parts for one already handed out.
            s.error("late_part", detail);
        } else if r.repeat {
            // A second frame at one stamp: a frame heard of, skipped.
            s.frames_received += 1;
            s.drop_frame("repeated_stamp", detail);
        } else if r.dropped {
            s.drop_frame(&dropped_reason(r), detail);
        } else {
            for m in &r.missing {
                s.error(&format!("partial_missing_{m}"), detail.clone());
            }
            if r.missing.is_empty() && !r.errors.is_empty() {
                s.error("partial_frame", detail);
            }
        }
    }

    fn enqueue(&mut self, frame: Frame) {
        let stamp = frame.stamp;
        let mut s = lock(&self.stats);
        s.frames_in += 1;
        if self.require_map && self.map.is_none() {
            s.drop_frame("no_map", format!("frame {stamp}: no map received yet"));
            warn(format!("frame {stamp}: dropped, no map received yet"));
            return;
        }
        if let Some(map) = &self.map {
            if !map.frame_id.is_empty() && !frame.map_frame_id.is_empty() && map.frame_id != frame.map_frame_id {
                s.error(
                    "map_frame_mismatch",
                    format!("frame {stamp}: correspondences in {:?}, map in {:?}", frame.map_frame_id, map.frame_id),
                );
            }
        }
        drop(s);
        let dropped = self.queue.push(Job { frame, handed_out: Instant::now() });
        let mut stats = lock(&self.stats);
        stats.queued_max = stats.queued_max.max(self.queue.len());
        if let Some(old) = dropped {
            let msg = format!("frame {}: dropped, queue full (newer frame {stamp} arrived)", old.frame.stamp);
            warn(&msg);
            stats.drop_frame("queue_full", msg);
        }
    }
}

/// Why a frame without a usable set of parts was dropped: the first required part missing,
/// or a stamp before 1970.
fn dropped_reason(r: &IncompleteFrame) -> String {
    if let Some(required) = PartKind::REQUIRED.iter().map(|k| k.name()).find(|n| r.missing.contains(n)) {
        return format!("missing_{required}");
    }
    if r.stamp < 0 {
        return "negative_stamp".into();
    }
    "missing_parts".into()
}

#[cfg(test)]
#[path = "ingest_tests.rs"]
mod tests;
