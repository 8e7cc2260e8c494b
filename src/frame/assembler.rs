//! [`FrameAssembler`]: joins [`FramePart`]s by `header.stamp` into [`Frame`]s, for a bag reader
//! and the live node alike.
//!
//! Sans-io, as the `mcap` crate's readers are: it never reads a clock. Every call that can
//! start or end a wait is given `now`, a reading of the caller's monotonic clock
//! ([`MonotonicNs`]: the node's time since start, a bag's log time), so stamp tolerance,
//! arrival time-outs and the recognition of late parts and repeated stamps live here, once,
//! and are tested without sleeping.

use std::collections::BTreeMap;

use nalgebra::Isometry3;

use super::pinhole::PinholeRectifier;
use super::recent::RecentStamps;
use super::{Assembled, CameraImage, Correspondence, Frame, FramePart, GroundTruth, IncompleteFrame, PartKind, Stamp};
use crate::camera::{CameraModel, PixelSpace};
use crate::geometry::DepthImage;

/// A reading of the caller's monotonic clock, in nanoseconds (any origin, never decreasing).
pub type MonotonicNs = i64;

/// The correspondences part: camera frame, map frame, matches.
struct CorrespondencesPart {
    camera_frame_id: String,
    map_frame_id: String,
    correspondences: Vec<Correspondence>,
}

/// The parts gathered so far for one stamp.
struct Pending {
    /// When its first part arrived.
    first_arrival: MonotonicNs,
    /// Parts that arrived or failed (bit per [`PartKind`]).
    resolved: u8,
    camera: Option<CameraModel>,
    correspondences: Option<CorrespondencesPart>,
    depth_prior: Option<DepthImage>,
    image: Option<CameraImage>,
    gt_pose: Option<Isometry3<f64>>,
    gt_depth: Option<DepthImage>,
    errors: Vec<String>,
}

impl Pending {
    fn arrived(now: MonotonicNs) -> Self {
        Self {
            first_arrival: now,
            resolved: 0,
            camera: None,
            correspondences: None,
            depth_prior: None,
            image: None,
            gt_pose: None,
            gt_depth: None,
            errors: Vec::new(),
        }
    }

    /// Stores `part`; true when one of its kind was already there (the last is kept).
    fn store(&mut self, part: FramePart) -> bool {
        match part {
            FramePart::CameraInfo { camera, .. } => self.camera.replace(camera).is_some(),
            FramePart::Correspondences { camera_frame_id, map_frame_id, correspondences, .. } => {
                let part = CorrespondencesPart { camera_frame_id, map_frame_id, correspondences };
                self.correspondences.replace(part).is_some()
            }
            FramePart::DepthPrior { depth, .. } => self.depth_prior.replace(depth).is_some(),
            FramePart::Image { image, .. } => self.image.replace(image).is_some(),
            FramePart::GroundTruthPose { pose, .. } => self.gt_pose.replace(pose).is_some(),
            FramePart::GroundTruthDepth { depth, .. } => self.gt_depth.replace(depth).is_some(),
        }
    }

    fn has(&self, kind: PartKind) -> bool {
        match kind {
            PartKind::CameraInfo => self.camera.is_some(),
            PartKind::Correspondences => self.correspondences.is_some(),
            PartKind::DepthPrior => self.depth_prior.is_some(),
            PartKind::Image => self.image.is_some(),
            PartKind::GroundTruthPose => self.gt_pose.is_some(),
            PartKind::GroundTruthDepth => self.gt_depth.is_some(),
        }
    }

    fn resolved(&self, kind: PartKind) -> bool {
        self.resolved & kind.bit() != 0
    }
}

/// Joins [`FramePart`]s by `header.stamp` into [`Frame`]s (see the module doc).
///
/// A frame is handed out as soon as every *expected* part for its stamp has arrived (or
/// failed); [`expire`](Self::expire) hands out the frames waiting longer than the arrival
/// time-out and [`finish`](Self::finish) the rest, each with what is missing.
pub struct FrameAssembler {
    expected: u8,
    /// A part joins the waiting frame whose stamp is within this many ns of its own (0: exact).
    stamp_tolerance_ns: i64,
    /// A frame waits this long after its first part (`None`: until `finish` or `take`).
    arrival_timeout_ns: Option<i64>,
    pending: BTreeMap<Stamp, Pending>,
    /// Parts for stamps already handed out: a late part, or a second frame at one stamp.
    repeats: BTreeMap<Stamp, Pending>,
    /// The stamps handed out lately, to recognise late parts; `None` when off.
    handed_out: Option<RecentStamps>,
    /// Frames opened so far (stamps that started waiting; not late parts).
    opened: u64,
    /// Reduces each frame's camera to the core's pinhole one (see [`crate::camera`]).
    rectifier: PinholeRectifier,
}

impl FrameAssembler {
    /// Waits for `expected` parts per stamp; the required parts are always expected.
    pub fn new(expected: &[PartKind]) -> Self {
        let expected = expected.iter().chain(PartKind::REQUIRED.iter()).fold(0, |m, k| m | k.bit());
        Self {
            expected,
            stamp_tolerance_ns: 0,
            arrival_timeout_ns: None,
            pending: BTreeMap::new(),
            repeats: BTreeMap::new(),
            handed_out: None,
            opened: 0,
            rectifier: PinholeRectifier::new(PixelSpace::default()),
        }
    }

    /// Also recognises parts for a stamp already handed out (the last 4096 are remembered): a
    /// late part, or a second complete frame at one stamp, each reported as such and skipped.
    /// For recorded bags, where a stamp is one frame for the whole bag.
    pub fn with_repeat_detection(mut self) -> Self {
        self.handed_out = Some(RecentStamps::new(None));
        self
    }

    /// Like [`with_repeat_detection`](Self::with_repeat_detection), remembering a handed-out
    /// stamp for `window_ns` only: for a live stream, where a restarted player later sends the
    /// same stamps again as new frames.
    pub fn with_repeat_window(mut self, window_ns: i64) -> Self {
        self.handed_out = Some(RecentStamps::new(Some(window_ns.max(0))));
        self
    }

    /// Which pixel space the correspondences and the prior are in (raw pixels of a distorting
    /// lens are undistorted, rectified ones take P's intrinsics): [`crate::camera`].
    pub fn with_pixel_space(mut self, space: PixelSpace) -> Self {
        self.rectifier = PinholeRectifier::new(space);
        self
    }

    /// Joins a part to the waiting (or just handed-out) frame whose stamp is nearest to its
    /// own within `tolerance_ns`, for sources whose stamps differ by a little.
    pub fn with_stamp_tolerance(mut self, tolerance_ns: i64) -> Self {
        self.stamp_tolerance_ns = tolerance_ns.max(0);
        self
    }

    /// Hands out, in [`expire`](Self::expire), a frame still incomplete `timeout_ns` after its
    /// first part arrived.
    pub fn with_arrival_timeout(mut self, timeout_ns: i64) -> Self {
        self.arrival_timeout_ns = Some(timeout_ns.max(0));
        self
    }

    /// Number of stamps still waiting for parts (late parts included).
    pub fn pending(&self) -> usize {
        self.pending.len() + self.repeats.len()
    }

    /// Frames opened so far: stamps that started waiting (late parts open none).
    pub fn frames_opened(&self) -> u64 {
        self.opened
    }

    /// The oldest stamp waiting for parts.
    pub fn oldest(&self) -> Option<Stamp> {
        let a = self.pending.keys().next().copied();
        let b = self.repeats.keys().next().copied();
        a.into_iter().chain(b).min()
    }

    /// The stamp a part stamped `stamp` belongs to: its own, or the nearest one within the
    /// tolerance that is waiting or was just handed out.
    fn snap(&self, stamp: Stamp) -> Stamp {
        let known = |s: Stamp| {
            self.pending.contains_key(&s)
                || self.repeats.contains_key(&s)
                || self.handed_out.as_ref().is_some_and(|h| h.contains(s))
        };
        if self.stamp_tolerance_ns == 0 || known(stamp) {
            return stamp;
        }
        let (lo, hi) = (stamp.saturating_sub(self.stamp_tolerance_ns), stamp.saturating_add(self.stamp_tolerance_ns));
        let waiting = self.pending.range(lo..=hi).chain(self.repeats.range(lo..=hi)).map(|(s, _)| *s);
        let handed = self.handed_out.iter().flat_map(|h| h.range(lo, hi));
        waiting.chain(handed).min_by_key(|s| ((s - stamp).unsigned_abs(), *s)).unwrap_or(stamp)
    }

    /// The entry a part at `stamp` goes to: the open frame, or — when the frame at `stamp` was
    /// already handed out — a repeat entry that is reported as late parts or a repeated frame.
    fn entry(&mut self, stamp: Stamp, now: MonotonicNs) -> &mut Pending {
        if let Some(h) = self.handed_out.as_mut() {
            h.forget_old(now);
        }
        let seen = self.handed_out.as_ref().is_some_and(|h| h.contains(stamp));
        if seen && !self.pending.contains_key(&stamp) {
            return self.repeats.entry(stamp).or_insert_with(|| Pending::arrived(now));
        }
        if !self.pending.contains_key(&stamp) {
            self.opened += 1;
        }
        self.pending.entry(stamp).or_insert_with(|| Pending::arrived(now))
    }

    /// Adds a part that arrived at `now`; returns the frame (or report) this completes.
    pub fn push(&mut self, part: FramePart, now: MonotonicNs) -> Option<Assembled> {
        let stamp = self.snap(part.stamp());
        let kind = part.kind();
        let p = self.entry(stamp, now);
        if p.store(part.with_stamp(stamp)) {
            p.errors.push(format!("{}: duplicate message, kept the last", kind.name()));
        }
        p.resolved |= kind.bit();
        self.complete_if_ready(stamp, now)
    }

    /// Records that the part `kind` of the frame at `stamp`, arrived at `now`, could not be
    /// decoded; returns the frame (or report) this completes.
    pub fn push_error(
        &mut self,
        stamp: Stamp,
        kind: PartKind,
        reason: impl std::fmt::Display,
        now: MonotonicNs,
    ) -> Option<Assembled> {
        let stamp = self.snap(stamp);
        let p = self.entry(stamp, now);
        p.errors.push(format!("{}: {reason}", kind.name()));
        p.resolved |= kind.bit();
        self.complete_if_ready(stamp, now)
    }

    /// Hands out, by stamp, every frame (and late part) whose first part arrived at least the
    /// arrival time-out before `now`, with a time-out note; nothing without a time-out.
    pub fn expire(&mut self, now: MonotonicNs) -> Vec<Assembled> {
        let Some(timeout) = self.arrival_timeout_ns else { return Vec::new() };
        let due = |p: &Pending| now.saturating_sub(p.first_arrival) >= timeout;
        let old: Vec<Stamp> = self.pending.iter().filter(|(_, p)| due(p)).map(|(s, _)| *s).collect();
        let late: Vec<Stamp> = self.repeats.iter().filter(|(_, p)| due(p)).map(|(s, _)| *s).collect();
        let reason = format!("timed out after {} ms waiting for parts", timeout / 1_000_000);
        let mut out: Vec<Assembled> = old.into_iter().filter_map(|s| self.take(s, reason.clone(), now)).collect();
        out.extend(late.into_iter().filter_map(|s| self.take_repeat(s)));
        out
    }

    /// Hands out the oldest waiting frame as it is (the caller bounds how many wait), noting
    /// `reason`.
    pub fn take_oldest(&mut self, reason: String, now: MonotonicNs) -> Option<Assembled> {
        let stamp = self.oldest()?;
        self.take(stamp, reason, now)
    }

    /// Hands out the frame waiting at `stamp` as it is, noting `reason`; `None` if nothing
    /// waits there.
    pub fn take(&mut self, stamp: Stamp, reason: String, now: MonotonicNs) -> Option<Assembled> {
        let Some(mut p) = self.pending.remove(&stamp) else { return self.take_repeat(stamp) };
        p.errors.push(reason);
        Some(self.hand_out(stamp, p, now))
    }

    /// Hands out every frame still waiting, sorted by stamp (late parts after the frames).
    pub fn finish(&mut self, now: MonotonicNs) -> Vec<Assembled> {
        let mut out: Vec<Assembled> =
            std::mem::take(&mut self.pending).into_iter().map(|(s, p)| self.hand_out(s, p, now)).collect();
        let late: Vec<Stamp> = self.repeats.keys().copied().collect();
        out.extend(late.into_iter().filter_map(|s| self.take_repeat(s)));
        out
    }

    /// Late parts at `stamp` (its frame was handed out before they came): reported, no frame.
    fn take_repeat(&mut self, stamp: Stamp) -> Option<Assembled> {
        let p = self.repeats.remove(&stamp)?;
        let parts: Vec<&str> = PartKind::ALL.iter().filter(|k| p.resolved(**k)).map(|k| k.name()).collect();
        let first = format!(
            "late part ({}) for the frame at stamp {stamp}, which was already handed out; skipped",
            parts.join(", ")
        );
        Some(repeat_report(stamp, first, p, true))
    }

    fn hand_out(&mut self, stamp: Stamp, p: Pending, now: MonotonicNs) -> Assembled {
        if let Some(h) = self.handed_out.as_mut() {
            h.insert(stamp, now);
        }
        self.assemble(stamp, p)
    }

    fn complete_if_ready(&mut self, stamp: Stamp, now: MonotonicNs) -> Option<Assembled> {
        if self.repeats.get(&stamp).is_some_and(|p| p.resolved & self.expected == self.expected) {
            // Every part again at a stamp already handed out: a second frame with that stamp.
            let p = self.repeats.remove(&stamp)?;
            let first =
                format!("repeated stamp: a second complete frame at stamp {stamp} (the first was handed out); skipped");
            return Some(repeat_report(stamp, first, p, false));
        }
        let ready = self.pending.get(&stamp).is_some_and(|p| p.resolved & self.expected == self.expected);
        if !ready {
            return None;
        }
        let p = self.pending.remove(&stamp)?;
        Some(self.hand_out(stamp, p, now))
    }

    fn assemble(&mut self, stamp: Stamp, mut p: Pending) -> Assembled {
        let missing: Vec<&'static str> =
            PartKind::ALL.iter().filter(|k| self.expected & k.bit() != 0 && !p.has(**k)).map(|k| k.name()).collect();
        let mut errors = std::mem::take(&mut p.errors);
        let has_correspondences = p.resolved(PartKind::Correspondences);
        let frame = match frame_of(stamp, p) {
            Some((frame, camera)) => self.to_pinhole(frame, &camera, &mut errors),
            None => None,
        };
        let report = |dropped| IncompleteFrame {
            stamp,
            missing: missing.clone(),
            errors: errors.clone(),
            dropped,
            repeat: false,
            late_parts: false,
            has_correspondences,
        };
        if stamp < 0 {
            let mut r = report(true);
            r.errors.insert(0, format!("negative header.stamp {stamp} ns (before 1970); skipped"));
            return Assembled::Dropped(r);
        }
        let clean = missing.is_empty() && errors.is_empty();
        match frame {
            None => Assembled::Dropped(report(true)),
            Some(frame) if clean => Assembled::Complete(frame),
            Some(frame) => Assembled::Partial(frame, report(false)),
        }
    }
}

impl FrameAssembler {
    /// `frame` in the core's pinhole camera (see [`crate::camera`]); `None` for a camera that
    /// cannot be used, with the reason in `errors`, as are correspondences the lens model could
    /// not undistort.
    fn to_pinhole(&mut self, mut frame: Frame, camera: &CameraModel, errors: &mut Vec<String>) -> Option<Frame> {
        match self.rectifier.apply(camera, &mut frame) {
            Ok(report) => {
                if report.dropped > 0 {
                    errors.push(format!(
                        "{} correspondences outside the lens model's valid region left out",
                        report.dropped
                    ));
                }
                frame.lens = report.remapped.then(|| camera.clone());
                Some(frame)
            }
            Err(e) => {
                errors.push(format!("camera_info: {e}"));
                None
            }
        }
    }
}

/// The frame of the parts at `stamp` (in the raw camera's intrinsics) and its camera; `None`
/// without camera info or correspondences.
fn frame_of(stamp: Stamp, p: Pending) -> Option<(Frame, CameraModel)> {
    let (camera, corr) = (p.camera?, p.correspondences?);
    let ground_truth =
        (p.gt_pose.is_some() || p.gt_depth.is_some()).then_some(GroundTruth { pose: p.gt_pose, depth: p.gt_depth });
    let frame = Frame {
        stamp,
        camera_frame_id: corr.camera_frame_id,
        map_frame_id: corr.map_frame_id,
        intrinsics: camera.raw,
        correspondences: corr.correspondences,
        depth_prior: p.depth_prior,
        image: p.image,
        ground_truth,
        lens: None,
        // Not a part of the frame's messages: the edge looks it up on /tf at the stamp.
        odometry: None,
    };
    Some((frame, camera))
}

/// The report of parts at a stamp already handed out: late parts, or a repeated stamp.
fn repeat_report(stamp: Stamp, first: String, p: Pending, late_parts: bool) -> Assembled {
    let has_correspondences = p.resolved(PartKind::Correspondences);
    let mut errors = vec![first];
    errors.extend(p.errors);
    Assembled::Dropped(IncompleteFrame {
        stamp,
        missing: Vec::new(),
        errors,
        dropped: true,
        repeat: true,
        late_parts,
        has_correspondences,
    })
}

#[cfg(test)]
#[path = "assembler_tests.rs"]
mod tests;
