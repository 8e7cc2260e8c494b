//! Frames streamed from a bag: [`FrameStream`] reads a bag twice, message by message, and never
//! holds more than one chunk, one map and the frames still waiting for parts.
//!
//! The first pass checks the whole bag (record limits, chunk and data CRCs, each input topic's
//! type) before anything is processed, and takes the map wherever it is in the bag (the first
//! map message; later ones are reported and ignored), so a map that comes late is still used
//! for every frame. The second pass joins the frame topics by `header.stamp` and hands frames
//! out as they complete, with the input limits applied ([`crate::limits`]).

use std::collections::{HashMap, VecDeque};
use std::path::Path;

use super::odometry::{BagOdometry, OdometryTopics};
use super::{decode_part_limited, BagError, BagMessages, MessageIssue, ReadOptions, TopicMap};
use crate::frame::{Assembled, FrameAssembler, IncompleteFrame, MapCloud, MonotonicNs, PartKind, Stamp};
use crate::limits::{limit_correspondences, InputLimits, LimitCounts};
use crate::msgs::{self, convert, from_cdr, RosMessage};

/// The type each input topic must carry.
pub fn expected_types(topics: &TopicMap) -> HashMap<String, &'static str> {
    let mut out = HashMap::new();
    out.insert(topics.map.clone(), msgs::PointCloud2::TYPE_NAME);
    for kind in PartKind::ALL {
        let type_name = match kind {
            PartKind::CameraInfo => msgs::CameraInfo::TYPE_NAME,
            PartKind::Correspondences => msgs::Correspondences::TYPE_NAME,
            PartKind::DepthPrior | PartKind::GroundTruthDepth => msgs::Image::TYPE_NAME,
            PartKind::Image => msgs::CompressedImage::TYPE_NAME,
            PartKind::GroundTruthPose => msgs::PoseStamped::TYPE_NAME,
        };
        out.insert(topics.topic_of(kind).to_string(), type_name);
    }
    out
}

pub use crate::msgs::convert::DecodedMap;

/// The map of a PointCloud2 message with the limits applied, and what was changed (the
/// conversion the node's map reader uses too).
pub fn decode_map(data: &[u8], limits: &InputLimits) -> Result<DecodedMap, msgs::MsgError> {
    convert::map_part(&from_cdr(data)?, limits)
}

/// Applies the per-frame limits to an assembled frame; anomalies join its issues, every change
/// is counted in `counts`.
pub fn limit_frame(item: Assembled, limits: &InputLimits, counts: &mut LimitCounts) -> Assembled {
    let (mut frame, report) = match item {
        Assembled::Complete(f) => (f, None),
        Assembled::Partial(f, r) => (f, Some(r)),
        dropped @ Assembled::Dropped(_) => return dropped,
    };
    let fixes = limit_correspondences(&mut frame.correspondences, limits);
    counts.add(&fixes);
    let notes = fixes.notes(limits);
    if notes.is_empty() {
        return match report {
            None => Assembled::Complete(frame),
            Some(r) => Assembled::Partial(frame, r),
        };
    }
    let mut report = report.unwrap_or(IncompleteFrame {
        stamp: frame.stamp,
        missing: Vec::new(),
        errors: Vec::new(),
        dropped: false,
        repeat: false,
        late_parts: false,
        has_correspondences: true,
    });
    report.errors.extend(notes);
    Assembled::Partial(frame, report)
}

/// Frames of a bag, handed out as they complete (see the module doc).
pub struct FrameStream {
    messages: BagMessages,
    topics: TopicMap,
    limits: InputLimits,
    assembler: FrameAssembler,
    ready: VecDeque<Assembled>,
    finished: bool,
    /// The latest log time read.
    now: MonotonicNs,
    /// The bag's map (first map message), if one decoded.
    pub map: Option<MapCloud>,
    /// Map messages that failed or were left out, and what the limits changed in the map.
    pub issues: Vec<MessageIssue>,
    /// Messages on the correspondences topic (an estimate of the frame count).
    pub correspondence_messages: usize,
    /// What the per-frame limits changed so far.
    pub limit_counts: LimitCounts,
    /// The TF read so far, for the frames' odometry (none unless [`Self::with_odometry`]).
    pub odometry: Option<BagOdometry>,
}

impl FrameStream {
    /// Checks the bag and reads its map (first pass); frames come from [`Self::next_frame`].
    /// Reads the correspondences' pixels (and the prior) as `space` ([`crate::camera`]).
    pub fn with_pixel_space(mut self, space: crate::camera::PixelSpace) -> Self {
        self.assembler = std::mem::replace(&mut self.assembler, FrameAssembler::new(&[])).with_pixel_space(space);
        self
    }

    /// Reads the bag's TF as well and gives every frame its odometry where it has one
    /// ([`BagOdometry`]).
    pub fn with_odometry(mut self, topics: OdometryTopics) -> Self {
        self.odometry = Some(BagOdometry::new(topics));
        self
    }

    pub fn open(path: impl AsRef<Path>, topics: &TopicMap, limits: &InputLimits) -> Result<Self, BagError> {
        let path = path.as_ref();
        let options = ReadOptions { max_record_bytes: limits.max_record_bytes, expected_types: expected_types(topics) };
        let mut check = BagMessages::open(path, options.clone())?;
        let (mut map, mut issues, mut correspondence_messages) = (None, Vec::new(), 0usize);
        for m in check.by_ref() {
            let m = m?;
            if m.topic() == topics.correspondences {
                correspondence_messages += 1;
            }
            if m.topic() != topics.map {
                continue;
            }
            let issue = |reason: String| MessageIssue { topic: topics.map.clone(), log_time: m.log_time, reason };
            if map.is_some() {
                issues.push(issue("another map message; kept the first".into()));
                continue;
            }
            match decode_map(&m.data, limits) {
                Ok(decoded) => {
                    issues.extend(decoded.notes.into_iter().map(issue));
                    map = Some(decoded.map);
                }
                Err(e) => issues.push(issue(e.to_string())),
            }
        }
        let expected: Vec<PartKind> = PartKind::ALL
            .into_iter()
            .filter(|k| check.channels().iter().any(|c| c.topic == topics.topic_of(*k)))
            .collect();
        Ok(Self {
            messages: BagMessages::open(path, options)?,
            topics: topics.clone(),
            limits: limits.clone(),
            assembler: FrameAssembler::new(&expected).with_repeat_detection(),
            ready: VecDeque::new(),
            finished: false,
            now: 0,
            map,
            issues,
            correspondence_messages,
            limit_counts: LimitCounts::default(),
            odometry: None,
        })
    }

    /// The next frame (complete, partial or dropped), in completion order; `None` at the end.
    pub fn next_frame(&mut self) -> Result<Option<Assembled>, BagError> {
        while self.ready.is_empty() && !self.finished {
            let Some(m) = self.messages.next().transpose()? else {
                self.finished = true;
                self.ready.extend(self.assembler.finish(self.now));
                break;
            };
            // The bag's clock: log times (only repeat detection reads it here, which has no window).
            self.now = self.now.max(m.log_time.min(i64::MAX as u64) as MonotonicNs);
            if self.odometry.as_mut().is_some_and(|o| o.take(m.topic(), &m.data)) {
                continue;
            }
            let Some(kind) = self.topics.part_of(m.topic()) else { continue };
            let done = match decode_part_limited(kind, &m.data, &self.limits) {
                Ok(part) => self.assembler.push(part, self.now),
                Err(e) => {
                    // Attribute the failure to the message's stamp when its header is readable.
                    let stamp: Stamp = msgs::peek_header(&m.data)
                        .map(|h| convert::stamp(&h))
                        .unwrap_or(m.log_time.min(i64::MAX as u64) as Stamp);
                    let reason = format!("{} at stamp {stamp}: {e}", m.topic());
                    self.assembler.push_error(stamp, kind, reason, self.now)
                }
            };
            self.ready.extend(done);
            while self.assembler.pending() > self.limits.max_pending_frames {
                let reason = format!(
                    "still incomplete when more than {} frames were waiting (limits.max_pending_frames)",
                    self.limits.max_pending_frames
                );
                self.ready.extend(self.assembler.take_oldest(reason, self.now));
            }
        }
        let mut next = self.ready.pop_front().map(|a| limit_frame(a, &self.limits, &mut self.limit_counts));
        if let (Some(odometry), Some(Assembled::Complete(frame) | Assembled::Partial(frame, _))) =
            (&self.odometry, next.as_mut())
        {
            frame.odometry = odometry.at(&frame.camera_frame_id, frame.stamp);
        }
        Ok(next)
    }
}
