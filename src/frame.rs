//! One localization frame: everything the core needs about one camera image, joined by
//! `header.stamp` across topics, and the map it is localized against.

use nalgebra::{Isometry3, Point2, Point3};

use crate::geometry::{DepthImage, Intrinsics};

/// `header.stamp` in nanoseconds since the epoch; the key that joins a frame's topics.
pub type Stamp = i64;

/// One putative match between an image pixel and a 3D map point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Correspondence {
    /// Pixel (u = column, v = row), sub-pixel, in the camera image's pixel grid.
    pub pixel: Point2<f64>,
    /// Map point in the map frame, metres.
    pub point: Point3<f64>,
    /// Confidence in [0, 1]: the matcher's on input, the inlier score on output.
    pub score: f32,
}

/// Ground truth carried by evaluation bags (never used by the localizer itself).
#[derive(Clone, Debug)]
pub struct GroundTruth {
    /// Camera-to-map pose of the camera's optical frame.
    pub pose: Option<Isometry3<f64>>,
    /// Metric depth registered to the camera image, metres; 0 = unknown.
    pub depth: Option<DepthImage>,
}

/// Everything about one camera image that the localizer consumes.
#[derive(Clone, Debug)]
pub struct Frame {
    pub stamp: Stamp,
    /// The camera's optical frame (`header.frame_id` of the correspondences).
    pub camera_frame_id: String,
    /// Frame of the map points.
    pub map_frame_id: String,
    pub intrinsics: Intrinsics,
    pub correspondences: Vec<Correspondence>,
    /// Monocular depth prior, known up to scale and shift; any resolution.
    pub depth_prior: Option<DepthImage>,
    /// Encoded camera image (JPEG/PNG bytes) when the source carries one.
    pub image: Option<EncodedImage>,
    pub ground_truth: Option<GroundTruth>,
}

/// A compressed camera image as it travels (`sensor_msgs/CompressedImage`).
#[derive(Clone, Debug)]
pub struct EncodedImage {
    pub format: String,
    pub data: Vec<u8>,
}

/// The point map the camera is localized against.
#[derive(Clone, Debug, Default)]
pub struct MapCloud {
    pub frame_id: String,
    pub points: Vec<Point3<f32>>,
}

/// The kinds of message that make up a [`Frame`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum PartKind {
    CameraInfo,
    Correspondences,
    DepthPrior,
    Image,
    GroundTruthPose,
    GroundTruthDepth,
}

impl PartKind {
    pub const ALL: [PartKind; 6] = [
        PartKind::CameraInfo,
        PartKind::Correspondences,
        PartKind::DepthPrior,
        PartKind::Image,
        PartKind::GroundTruthPose,
        PartKind::GroundTruthDepth,
    ];

    /// Parts without which no [`Frame`] can be built.
    pub const REQUIRED: [PartKind; 2] = [PartKind::CameraInfo, PartKind::Correspondences];

    /// The role name (as in the topic map): `camera_info`, `correspondences`, ….
    pub fn name(self) -> &'static str {
        match self {
            PartKind::CameraInfo => "camera_info",
            PartKind::Correspondences => "correspondences",
            PartKind::DepthPrior => "depth_prior",
            PartKind::Image => "image",
            PartKind::GroundTruthPose => "ground_truth_pose",
            PartKind::GroundTruthDepth => "ground_truth_depth",
        }
    }

    fn bit(self) -> u8 {
        1 << self as u8
    }
}

/// One decoded message that belongs to the frame at `stamp`.
#[derive(Clone, Debug)]
pub enum FramePart {
    CameraInfo {
        stamp: Stamp,
        intrinsics: Intrinsics,
    },
    /// `camera_frame_id` is the correspondences' `header.frame_id`.
    Correspondences {
        stamp: Stamp,
        camera_frame_id: String,
        map_frame_id: String,
        correspondences: Vec<Correspondence>,
    },
    DepthPrior {
        stamp: Stamp,
        depth: DepthImage,
    },
    Image {
        stamp: Stamp,
        image: EncodedImage,
    },
    GroundTruthPose {
        stamp: Stamp,
        pose: Isometry3<f64>,
    },
    GroundTruthDepth {
        stamp: Stamp,
        depth: DepthImage,
    },
}

impl FramePart {
    pub fn stamp(&self) -> Stamp {
        match self {
            FramePart::CameraInfo { stamp, .. }
            | FramePart::Correspondences { stamp, .. }
            | FramePart::DepthPrior { stamp, .. }
            | FramePart::Image { stamp, .. }
            | FramePart::GroundTruthPose { stamp, .. }
            | FramePart::GroundTruthDepth { stamp, .. } => *stamp,
        }
    }

    pub fn kind(&self) -> PartKind {
        match self {
            FramePart::CameraInfo { .. } => PartKind::CameraInfo,
            FramePart::Correspondences { .. } => PartKind::Correspondences,
            FramePart::DepthPrior { .. } => PartKind::DepthPrior,
            FramePart::Image { .. } => PartKind::Image,
            FramePart::GroundTruthPose { .. } => PartKind::GroundTruthPose,
            FramePart::GroundTruthDepth { .. } => PartKind::GroundTruthDepth,
        }
    }
}

/// A frame that lacks an expected part or had a part that failed to decode.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct IncompleteFrame {
    pub stamp: Stamp,
    /// Role names of the expected parts that never arrived (or failed to decode).
    pub missing: Vec<&'static str>,
    /// Why parts failed (`"<part>: <reason>"`), duplicates, time-outs.
    pub errors: Vec<String>,
    /// True when a required part is missing, so no [`Frame`] was produced.
    pub dropped: bool,
    /// Late parts or a repeated frame at a stamp already handed out: not a frame of its own.
    pub repeat: bool,
    /// A correspondences message came for this stamp (decoded or not): the input had a frame here.
    pub has_correspondences: bool,
}

/// What the assembler hands out for one stamp.
#[derive(Clone, Debug)]
pub enum Assembled {
    /// Every expected part arrived and decoded.
    Complete(Frame),
    /// Usable (required parts present) but some expected part is missing or broken.
    Partial(Frame, IncompleteFrame),
    /// A required part is missing: no frame.
    Dropped(IncompleteFrame),
}

impl Assembled {
    pub fn stamp(&self) -> Stamp {
        match self {
            Assembled::Complete(f) | Assembled::Partial(f, _) => f.stamp,
            Assembled::Dropped(i) => i.stamp,
        }
    }

    /// Splits outcomes into usable frames and reports (a partial frame appears in both).
    pub fn split(items: impl IntoIterator<Item = Assembled>) -> (Vec<Frame>, Vec<IncompleteFrame>) {
        let (mut frames, mut reports) = (Vec::new(), Vec::new());
        for item in items {
            match item {
                Assembled::Complete(f) => frames.push(f),
                Assembled::Partial(f, r) => {
                    frames.push(f);
                    reports.push(r);
                }
                Assembled::Dropped(r) => reports.push(r),
            }
        }
        (frames, reports)
    }
}

#[derive(Default)]
struct Pending {
    /// Parts that arrived or failed (bit per [`PartKind`]).
    resolved: u8,
    intrinsics: Option<Intrinsics>,
    correspondences: Option<(String, String, Vec<Correspondence>)>,
    depth_prior: Option<DepthImage>,
    image: Option<EncodedImage>,
    gt_pose: Option<Isometry3<f64>>,
    gt_depth: Option<DepthImage>,
    errors: Vec<String>,
}

/// Joins [`FramePart`]s by `header.stamp` into [`Frame`]s.
///
/// A frame is handed out as soon as every *expected* part for its stamp has arrived (or
/// failed); [`finish`](Self::finish) and [`expire`](Self::expire) hand out the rest with what
/// is missing. Usable by a bag reader (expected = topics present in the bag) and a live node.
pub struct FrameAssembler {
    expected: u8,
    pending: std::collections::BTreeMap<Stamp, Pending>,
    /// Parts for stamps already handed out: a late part, or a second frame at one stamp.
    repeats: std::collections::BTreeMap<Stamp, Pending>,
    /// The most recent stamps handed out (bounded), to recognise late parts; `None` when off.
    handed_out: Option<RecentStamps>,
}

/// How many handed-out stamps are remembered to recognise late parts and repeated stamps.
const REMEMBERED_STAMPS: usize = 4096;

/// A bounded set of recent stamps (oldest forgotten first).
#[derive(Default)]
struct RecentStamps {
    order: std::collections::VecDeque<Stamp>,
    set: std::collections::HashSet<Stamp>,
}

impl RecentStamps {
    fn insert(&mut self, stamp: Stamp) {
        if self.set.insert(stamp) {
            self.order.push_back(stamp);
            if self.order.len() > REMEMBERED_STAMPS {
                if let Some(old) = self.order.pop_front() {
                    self.set.remove(&old);
                }
            }
        }
    }

    fn contains(&self, stamp: Stamp) -> bool {
        self.set.contains(&stamp)
    }
}

impl FrameAssembler {
    /// Waits for `expected` parts per stamp; the required parts are always expected.
    pub fn new(expected: &[PartKind]) -> Self {
        let expected = expected.iter().chain(PartKind::REQUIRED.iter()).fold(0, |m, k| m | k.bit());
        Self { expected, pending: Default::default(), repeats: Default::default(), handed_out: None }
    }

    /// Also recognises parts for a stamp already handed out (the last 4096 are remembered): a
    /// late part, or a second complete frame at one stamp, each reported as such and skipped.
    /// For recorded bags; a live node leaves it off, since a restarted player sends the same
    /// stamps again as new frames.
    pub fn with_repeat_detection(mut self) -> Self {
        self.handed_out = Some(RecentStamps::default());
        self
    }

    /// Number of stamps still waiting for parts (late parts included).
    pub fn pending(&self) -> usize {
        self.pending.len() + self.repeats.len()
    }

    /// The oldest stamp waiting for parts.
    pub fn oldest(&self) -> Option<Stamp> {
        let a = self.pending.keys().next().copied();
        let b = self.repeats.keys().next().copied();
        a.into_iter().chain(b).min()
    }

    /// The entry a part at `stamp` goes to: the open frame, or — when the frame at `stamp` was
    /// already handed out — a repeat entry that is reported as late parts or a repeated frame.
    fn entry(&mut self, stamp: Stamp) -> &mut Pending {
        let seen = self.handed_out.as_ref().is_some_and(|h| h.contains(stamp));
        if seen && !self.pending.contains_key(&stamp) {
            self.repeats.entry(stamp).or_default()
        } else {
            self.pending.entry(stamp).or_default()
        }
    }

    /// Adds a part; returns the frame when this completes it.
    pub fn push(&mut self, part: FramePart) -> Option<Assembled> {
        let stamp = part.stamp();
        let kind = part.kind();
        let p = self.entry(stamp);
        let already = match part {
            FramePart::CameraInfo { intrinsics, .. } => p.intrinsics.replace(intrinsics).is_some(),
            FramePart::Correspondences { camera_frame_id, map_frame_id, correspondences, .. } => {
                p.correspondences.replace((camera_frame_id, map_frame_id, correspondences)).is_some()
            }
            FramePart::DepthPrior { depth, .. } => p.depth_prior.replace(depth).is_some(),
            FramePart::Image { image, .. } => p.image.replace(image).is_some(),
            FramePart::GroundTruthPose { pose, .. } => p.gt_pose.replace(pose).is_some(),
            FramePart::GroundTruthDepth { depth, .. } => p.gt_depth.replace(depth).is_some(),
        };
        if already {
            p.errors.push(format!("{}: duplicate message, kept the last", kind.name()));
        }
        p.resolved |= kind.bit();
        self.complete_if_ready(stamp)
    }

    /// Records that the part `kind` of the frame at `stamp` could not be decoded.
    pub fn push_error(&mut self, stamp: Stamp, kind: PartKind, reason: impl std::fmt::Display) -> Option<Assembled> {
        let p = self.entry(stamp);
        p.errors.push(format!("{}: {reason}", kind.name()));
        p.resolved |= kind.bit();
        self.complete_if_ready(stamp)
    }

    /// Hands out every frame whose stamp is older than `now - timeout_ns`, with a time-out
    /// note for what is missing.
    pub fn expire(&mut self, now: Stamp, timeout_ns: i64) -> Vec<Assembled> {
        let cutoff = now.saturating_sub(timeout_ns);
        let old: Vec<Stamp> = self.pending.range(..cutoff).map(|(s, _)| *s).collect();
        let late: Vec<Stamp> = self.repeats.range(..cutoff).map(|(s, _)| *s).collect();
        let mut out: Vec<Assembled> = old
            .into_iter()
            .filter_map(|s| {
                let mut p = self.pending.remove(&s)?;
                p.errors.push(format!("timed out after {} ms waiting for parts", timeout_ns / 1_000_000));
                Some(self.assemble(s, p))
            })
            .collect();
        out.extend(late.into_iter().filter_map(|s| self.take_repeat(s)));
        out
    }

    /// Hands out the oldest waiting frame as it is (the caller bounds how many wait), noting
    /// `reason`.
    pub fn take_oldest(&mut self, reason: String) -> Option<Assembled> {
        let stamp = self.oldest()?;
        self.take(stamp, reason)
    }

    /// Late parts at `stamp` (its frame was handed out before they came): reported, no frame.
    fn take_repeat(&mut self, stamp: Stamp) -> Option<Assembled> {
        let p = self.repeats.remove(&stamp)?;
        let parts: Vec<&str> = PartKind::ALL.iter().filter(|k| p.resolved & k.bit() != 0).map(|k| k.name()).collect();
        let mut errors = vec![format!(
            "late part ({}) for the frame at stamp {stamp}, which was already handed out; skipped",
            parts.join(", ")
        )];
        errors.extend(p.errors);
        Some(Assembled::Dropped(IncompleteFrame {
            stamp,
            missing: Vec::new(),
            errors,
            dropped: true,
            repeat: true,
            has_correspondences: p.resolved & PartKind::Correspondences.bit() != 0,
        }))
    }

    fn hand_out(&mut self, stamp: Stamp, p: Pending) -> Assembled {
        if let Some(h) = self.handed_out.as_mut() {
            h.insert(stamp);
        }
        self.assemble(stamp, p)
    }

    /// Hands out the frame waiting at `stamp` as it is, noting `reason` (e.g. a wall-clock
    /// time-out decided by the caller); `None` if nothing waits there.
    pub fn take(&mut self, stamp: Stamp, reason: String) -> Option<Assembled> {
        let Some(mut p) = self.pending.remove(&stamp) else { return self.take_repeat(stamp) };
        p.errors.push(reason);
        Some(self.hand_out(stamp, p))
    }

    /// Hands out every frame still waiting, sorted by stamp (late parts after the frames).
    pub fn finish(&mut self) -> Vec<Assembled> {
        let mut out: Vec<Assembled> =
            std::mem::take(&mut self.pending).into_iter().map(|(s, p)| self.hand_out(s, p)).collect();
        let late: Vec<Stamp> = self.repeats.keys().copied().collect();
        out.extend(late.into_iter().filter_map(|s| self.take_repeat(s)));
        out
    }

    fn complete_if_ready(&mut self, stamp: Stamp) -> Option<Assembled> {
        if self.repeats.get(&stamp).is_some_and(|p| p.resolved & self.expected == self.expected) {
            // Every part again at a stamp already handed out: a second frame with that stamp.
            let p = self.repeats.remove(&stamp)?;
            let mut errors = vec![format!(
                "repeated stamp: a second complete frame at stamp {stamp} (the first was handed out); skipped"
            )];
            errors.extend(p.errors);
            return Some(Assembled::Dropped(IncompleteFrame {
                stamp,
                missing: Vec::new(),
                errors,
                dropped: true,
                repeat: true,
                has_correspondences: p.resolved & PartKind::Correspondences.bit() != 0,
            }));
        }
        let ready = self.pending.get(&stamp).is_some_and(|p| p.resolved & self.expected == self.expected);
        if !ready {
            return None;
        }
        let p = self.pending.remove(&stamp)?;
        Some(self.hand_out(stamp, p))
    }

    fn assemble(&self, stamp: Stamp, p: Pending) -> Assembled {
        let present = |k: PartKind| match k {
            PartKind::CameraInfo => p.intrinsics.is_some(),
            PartKind::Correspondences => p.correspondences.is_some(),
            PartKind::DepthPrior => p.depth_prior.is_some(),
            PartKind::Image => p.image.is_some(),
            PartKind::GroundTruthPose => p.gt_pose.is_some(),
            PartKind::GroundTruthDepth => p.gt_depth.is_some(),
        };
        let missing: Vec<&'static str> =
            PartKind::ALL.iter().filter(|k| self.expected & k.bit() != 0 && !present(**k)).map(|k| k.name()).collect();
        let has_correspondences = p.resolved & PartKind::Correspondences.bit() != 0;
        let report = |dropped| IncompleteFrame {
            stamp,
            missing: missing.clone(),
            errors: p.errors.clone(),
            dropped,
            repeat: false,
            has_correspondences,
        };
        if stamp < 0 {
            let mut r = report(true);
            r.errors.insert(0, format!("negative header.stamp {stamp} ns (before 1970); skipped"));
            return Assembled::Dropped(r);
        }
        let (Some(intrinsics), Some((camera_frame_id, map_frame_id, correspondences))) =
            (p.intrinsics, p.correspondences.clone())
        else {
            return Assembled::Dropped(report(true));
        };
        let clean = missing.is_empty() && p.errors.is_empty();
        let incomplete = (!clean).then(|| report(false));
        let ground_truth =
            (p.gt_pose.is_some() || p.gt_depth.is_some()).then_some(GroundTruth { pose: p.gt_pose, depth: p.gt_depth });
        let frame = Frame {
            stamp,
            camera_frame_id,
            map_frame_id,
            intrinsics,
            correspondences,
            depth_prior: p.depth_prior,
            image: p.image,
            ground_truth,
        };
        match incomplete {
            None => Assembled::Complete(frame),
            Some(r) => Assembled::Partial(frame, r),
        }
    }
}

#[cfg(test)]
#[path = "frame_tests.rs"]
mod assembler_tests;
