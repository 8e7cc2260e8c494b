//! A TF buffer as tf2 keeps one: a short history of every `parent → child` transform heard on
//! `/tf` and the static ones of `/tf_static`, looked up at a stamp (interpolated between the
//! samples around it) through any tree path between two frames, e.g.
//! `odom → base_link → camera_link → camera_color_frame → camera_color_optical_frame`.
//! An edge module: the node keeps one live, bag replay one of a bag's `/tf` (a frame's
//! odometry, [`crate::bag::BagOdometry`]).
//!
//! Bounded (#38): [`TfHistory::CACHE_NS`] of history per frame (tf2's default 10 s), at most
//! [`MAX_SAMPLES`] samples per frame, [`MAX_FRAMES`] frames and [`MAX_TOTAL_SAMPLES`] samples
//! in all. A transform of a new frame beyond the frames is left out; beyond the total, the
//! oldest samples of the longest histories are evicted. Both are reported, one summary line per
//! message however many transforms it carried. A history that aged out or was evicted gives its
//! memory back.

use std::collections::{HashMap, VecDeque};

use nalgebra::{Isometry3, Translation3};
use thiserror::Error;

use crate::frame::Stamp;
use crate::msgs::{self, convert, TFMessage};

/// The longest path between two frames a lookup follows.
pub const MAX_CHAIN: usize = 64;
/// Frames the buffer holds at most (a tree of robots is far smaller).
pub const MAX_FRAMES: usize = 4096;
/// Samples per frame at most (10 s of a 1 kHz publisher).
pub const MAX_SAMPLES: usize = 10_000;
/// Longest frame id taken (bytes): real ones are a few dozen, and without a bound the names of
/// [`MAX_FRAMES`] frames (each stored with its parent's) would hold as much as a flood sends.
pub const MAX_FRAME_ID_BYTES: usize = 256;
/// Samples all frames hold together at most. Without it a /tf flood over [`MAX_FRAMES`] names
/// could hold 4096 × [`MAX_SAMPLES`] samples (2.6 GB; ~1.2 GB RSS was measured, never freed).
///
/// A sample is 64 bytes (an 8-byte stamp and a 56-byte `Isometry3<f64>`). A history's deque
/// holds at most 4× its samples (it doubles when it grows, and is shrunk once under a quarter
/// full: `Link::release_spare`), so the samples take at most 250 000 × 64 B × 4 = 64 MB
/// (61 MiB), about half that in steady state, plus ~3 MB of links and names at [`MAX_FRAMES`]
/// (two ids of at most [`MAX_FRAME_ID_BYTES`] each).
/// A real robot — 200 moving frames at 100 Hz over the 10 s cache, 200 × 1001 = 200 200
/// samples — fits with 25 % to spare.
pub const MAX_TOTAL_SAMPLES: usize = 250_000;

/// The arithmetic of [`MAX_TOTAL_SAMPLES`] holds only for 64-byte samples.
const _: () = assert!(std::mem::size_of::<(Stamp, Isometry3<f64>)>() == 64);
/// Every frame keeps its newest sample when the buffer evicts down to its low-water mark.
const _: () = assert!(low_water(MAX_TOTAL_SAMPLES) >= MAX_FRAMES);

/// What an eviction brings the buffer down to: 1/16 below the budget, so a flood pays one pass
/// over the frames per ~15 600 samples (250 000 / 16), not one per sample.
const fn low_water(budget: usize) -> usize {
    budget - budget / 16
}

/// Why a transform could not be found.
#[derive(Debug, Error, PartialEq)]
pub enum TfLookupError {
    #[error("frame {frame:?} has not been heard on /tf or /tf_static")]
    UnknownFrame { frame: String },
    #[error("frames {parent:?} and {child:?} are not connected in the TF tree")]
    NotConnected { parent: String, child: String },
    #[error("transform {parent} → {child} not known at {stamp} ns (heard from {oldest} to {newest} ns)")]
    Extrapolation { parent: String, child: String, stamp: Stamp, oldest: Stamp, newest: Stamp },
}

/// One frame's link to its parent: static (one transform for all time) or a time series.
#[derive(Debug)]
struct Link {
    parent: String,
    is_static: bool,
    /// Ascending by stamp.
    samples: VecDeque<(Stamp, Isometry3<f64>)>,
}

impl Link {
    /// parent-from-child at `stamp`: the static transform, the sample at it, or the two samples
    /// around it interpolated (translation linearly, rotation by slerp).
    /// Within `slack_ns` before the first or after the last sample, that sample.
    fn at(&self, child: &str, stamp: Stamp, slack_ns: i64) -> Result<Isometry3<f64>, TfLookupError> {
        let (Some(first), Some(last)) = (self.samples.front(), self.samples.back()) else {
            return Err(TfLookupError::UnknownFrame { frame: child.to_string() });
        };
        if self.is_static {
            return Ok(last.1);
        }
        if stamp > last.0 && stamp - last.0 <= slack_ns {
            return Ok(last.1);
        }
        if stamp < first.0 && first.0 - stamp <= slack_ns {
            return Ok(first.1);
        }
        if stamp < first.0 || stamp > last.0 {
            return Err(TfLookupError::Extrapolation {
                parent: self.parent.clone(),
                child: child.to_string(),
                stamp,
                oldest: first.0,
                newest: last.0,
            });
        }
        let after = self.samples.partition_point(|(t, _)| *t < stamp);
        let (t1, b) = self.samples[after];
        if t1 == stamp || after == 0 {
            return Ok(b);
        }
        let (t0, a) = self.samples[after - 1];
        let w = (stamp - t0) as f64 / (t1 - t0) as f64;
        let translation = a.translation.vector.lerp(&b.translation.vector, w);
        let rotation = a.rotation.slerp(&b.rotation, w);
        Ok(Isometry3::from_parts(Translation3::from(translation), rotation))
    }

    fn insert(&mut self, stamp: Stamp, transform: Isometry3<f64>, cache_ns: i64) {
        if self.is_static {
            self.samples.clear();
            self.samples.push_back((stamp, transform));
            return;
        }
        let at = self.samples.partition_point(|(t, _)| *t < stamp);
        match self.samples.get_mut(at) {
            Some(sample) if sample.0 == stamp => sample.1 = transform,
            _ => self.samples.insert(at, (stamp, transform)),
        }
        let newest = self.samples.back().map_or(stamp, |s| s.0);
        while self.samples.len() > MAX_SAMPLES
            || self.samples.front().is_some_and(|s| s.0 < newest.saturating_sub(cache_ns))
        {
            self.samples.pop_front();
        }
        self.release_spare();
    }

    /// Evicts the `n` oldest samples (the caller keeps at least the newest).
    fn evict_oldest(&mut self, n: usize) {
        self.samples.drain(..n.min(self.samples.len()));
        self.release_spare();
    }

    /// Gives memory back once the history is under a quarter of its capacity: a deque never
    /// shrinks by itself, so a burst that aged out or was evicted would stay held. A quarter,
    /// not a half, so a steady history around one length is not reallocated sample after sample.
    fn release_spare(&mut self) {
        if self.samples.len() < self.samples.capacity() / 4 {
            self.samples.shrink_to_fit();
        }
    }
}

/// The level to cut the histories of `lens` down to so that at least `need` samples go: the
/// highest `h ≥ 1` with Σ max(0, len − h) ≥ need. Cutting every history longer than `h` to `h`
/// is evicting, `need` times over, the oldest sample of the longest history (ties aside) in one
/// pass. 1 (every history keeps its newest sample) when even that frees less than `need`.
fn water_level(lens: &[usize], need: usize) -> usize {
    let freed = |h: usize| lens.iter().map(|&l| l.saturating_sub(h)).sum::<usize>();
    let (mut lo, mut hi) = (1, lens.iter().copied().max().unwrap_or(1));
    if need == 0 {
        return hi;
    }
    if freed(lo) < need {
        return lo;
    }
    // freed(lo) ≥ need > freed(hi) = 0: the highest such level lies in [lo, hi).
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if freed(mid) >= need {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// One eviction over the budget: how many samples went, and the longest history they came from.
#[derive(Debug, Default, PartialEq)]
struct Eviction {
    samples: usize,
    longest: String,
    longest_len: usize,
}

/// Why one transform of a message was not taken.
#[derive(Debug, PartialEq)]
enum Skipped {
    /// Bad ids, a transform that is no isometry, a loop: named one by one.
    Bad(String),
    /// A new frame beyond [`MAX_FRAMES`] (`parent → child`): counted, one line per message.
    OverFrames(String),
}

/// What one message cost beyond what it brought: said in at most one line per kind, however
/// many transforms it carried (a flood must show in diagnostics, not flood the log).
#[derive(Debug, Default)]
struct MessageSummary {
    over_frames: usize,
    first_over_frames: Option<String>,
    evicted: usize,
    /// The longest history evicted from, and its length before.
    longest: Option<(String, usize)>,
}

impl MessageSummary {
    fn add_eviction(&mut self, e: Eviction) {
        self.evicted += e.samples;
        if self.longest.as_ref().is_none_or(|(_, len)| e.longest_len > *len) {
            self.longest = Some((e.longest, e.longest_len));
        }
    }

    fn add_over_frames(&mut self, transform: String) {
        self.over_frames += 1;
        self.first_over_frames.get_or_insert(transform);
    }

    /// The summary lines; `budget` and `evicted_total` (since the start) for the eviction's.
    fn lines(self, budget: usize, evicted_total: u64) -> Vec<String> {
        let mut out = Vec::new();
        if let Some(first) = self.first_over_frames {
            out.push(format!(
                "{} transforms of new frames over the {MAX_FRAMES} frames held were left out (first: {first})",
                self.over_frames
            ));
        }
        if let Some((frame, len)) = self.longest {
            out.push(format!(
                "TF buffer over its budget of {budget} samples: evicted the {} oldest samples of the longest \
                 histories (the longest: {frame:?}, {len} samples); {evicted_total} evicted since the start",
                self.evicted
            ));
        }
        out
    }
}

/// tf2 frame ids carry no leading slash; accept one anyway.
fn frame_name(id: &str) -> &str {
    id.strip_prefix('/').unwrap_or(id)
}

/// The transforms heard, by child frame.
#[derive(Debug)]
pub struct TfHistory {
    links: HashMap<String, Link>,
    /// A lookup this far beyond a frame's newest (or before its oldest) sample takes that sample.
    slack_ns: i64,
    /// Samples all links hold, kept as they change so the budget check costs nothing.
    total: usize,
    /// Samples all links may hold: [`MAX_TOTAL_SAMPLES`] (smaller in tests).
    budget: usize,
    /// Samples evicted over the budget since the start.
    evicted: u64,
}

impl Default for TfHistory {
    fn default() -> Self {
        Self::with_slack(0)
    }
}

impl TfHistory {
    /// History kept per dynamic frame, as tf2's default cache time.
    pub const CACHE_NS: i64 = 10_000_000_000;

    /// A buffer whose lookups take a frame's newest (oldest) sample for a stamp at most `slack_ns`
    /// after (before) it, as a transform tolerance allows.
    pub fn with_slack(slack_ns: i64) -> Self {
        Self { links: HashMap::new(), slack_ns: slack_ns.max(0), total: 0, budget: MAX_TOTAL_SAMPLES, evicted: 0 }
    }

    /// A new slack (a live change of `transform_tolerance_s`).
    pub fn set_slack(&mut self, slack_ns: i64) {
        self.slack_ns = slack_ns.max(0);
    }

    /// Samples held, all frames together (at most [`MAX_TOTAL_SAMPLES`]).
    pub fn samples(&self) -> usize {
        self.total
    }

    /// Samples evicted over [`MAX_TOTAL_SAMPLES`] since the start.
    pub fn evicted(&self) -> u64 {
        self.evicted
    }

    /// Takes every valid transform of `msg` (`is_static` for `/tf_static`); returns why the
    /// others were skipped, and what the message cost over the limits (frames left out,
    /// samples evicted), in one line each.
    pub fn update(&mut self, msg: &TFMessage, is_static: bool) -> Vec<String> {
        let mut bad = Vec::new();
        let mut summary = MessageSummary::default();
        for t in &msg.transforms {
            match self.take(t, is_static) {
                Ok(Some(eviction)) => summary.add_eviction(eviction),
                Ok(None) => {}
                Err(Skipped::Bad(reason)) => bad.push(reason),
                Err(Skipped::OverFrames(transform)) => summary.add_over_frames(transform),
            }
        }
        bad.extend(summary.lines(self.budget, self.evicted));
        bad
    }

    /// Takes one transform (checked, inserted, the budget kept); `Some` when samples were evicted.
    fn take(&mut self, t: &msgs::TransformStamped, is_static: bool) -> Result<Option<Eviction>, Skipped> {
        let (parent, child) = (frame_name(&t.header.frame_id), frame_name(&t.child_frame_id));
        let transform = self.checked(parent, child, &t.transform).map_err(Skipped::Bad)?;
        if !self.links.contains_key(child) && self.links.len() >= MAX_FRAMES {
            return Err(Skipped::OverFrames(format!("{parent} → {child}")));
        }
        self.insert(parent, child, is_static, msgs::convert::stamp(&t.header), transform);
        Ok(self.keep_budget())
    }

    /// `parent → child` as an isometry, or why it cannot be taken: bad or overlong frame ids,
    /// not a rigid transform, or a loop in the tree.
    fn checked(&self, parent: &str, child: &str, tr: &msgs::Transform) -> Result<Isometry3<f64>, String> {
        if parent.is_empty() || child.is_empty() || parent == child {
            return Err(format!("transform {parent:?} → {child:?}: bad frame ids"));
        }
        if parent.len().max(child.len()) > MAX_FRAME_ID_BYTES {
            return Err(format!(
                "transform with frame ids of {} and {} bytes: longer than {MAX_FRAME_ID_BYTES}, left out",
                parent.len(),
                child.len()
            ));
        }
        let pose = msgs::Pose {
            position: msgs::Point { x: tr.translation.x, y: tr.translation.y, z: tr.translation.z },
            orientation: tr.rotation,
        };
        let transform = convert::isometry_from_pose(&pose).map_err(|e| format!("transform {parent} → {child}: {e}"))?;
        if self.path_to_root(parent).contains(&child) {
            // tf2 refuses it too: a tree has no loop, and one would make `child` its own
            // ancestor (#38: a → b → a switched the node to publishing map → odom).
            return Err(format!("transform {parent} → {child}: {child} is already an ancestor of {parent}, a loop"));
        }
        Ok(transform)
    }

    /// Adds a sample to `child`'s history (started anew when its parent or kind changed),
    /// keeping the count of samples held.
    fn insert(&mut self, parent: &str, child: &str, is_static: bool, stamp: Stamp, transform: Isometry3<f64>) {
        let link = self.links.entry(child.to_string()).or_insert_with(|| Link {
            parent: parent.to_string(),
            is_static,
            samples: VecDeque::new(),
        });
        let before = link.samples.len();
        if link.parent != parent || link.is_static != is_static {
            // A frame re-parented (or moved between /tf and /tf_static): start its history anew.
            *link = Link { parent: parent.to_string(), is_static, samples: VecDeque::new() };
        }
        link.insert(stamp, transform, Self::CACHE_NS);
        self.total = self.total - before + link.samples.len();
    }

    /// Over the budget, evicts the oldest samples of the longest dynamic histories down to the
    /// low-water mark (static ones hold one sample and are never evicted; every history keeps
    /// its newest sample, so lookups at recent stamps still work).
    fn keep_budget(&mut self) -> Option<Eviction> {
        if self.total <= self.budget {
            return None;
        }
        let need = self.total - low_water(self.budget);
        let dynamic = |l: &Link| !l.is_static && l.samples.len() > 1;
        let lens: Vec<usize> = self.links.values().filter(|l| dynamic(l)).map(|l| l.samples.len()).collect();
        let level = water_level(&lens, need);
        let mut eviction = Eviction::default();
        for (frame, link) in self.links.iter_mut().filter(|(_, l)| dynamic(l) && l.samples.len() > level) {
            let len = link.samples.len();
            if len > eviction.longest_len {
                (eviction.longest, eviction.longest_len) = (frame.clone(), len);
            }
            link.evict_oldest(len - level);
            eviction.samples += len - level;
        }
        self.total -= eviction.samples;
        self.evicted += eviction.samples as u64;
        (eviction.samples > 0).then_some(eviction)
    }

    /// Whether `frame` has been heard, as a child or a parent of a transform.
    pub fn knows(&self, frame: &str) -> bool {
        let frame = frame_name(frame);
        self.links.contains_key(frame) || self.links.values().any(|l| l.parent == frame)
    }

    /// `parent → child` (parent-from-child) at `stamp`, through the tree path between them (up
    /// from each to their nearest common ancestor).
    pub fn lookup(&self, parent: &str, child: &str, stamp: Stamp) -> Result<Isometry3<f64>, TfLookupError> {
        let (parent, child) = (frame_name(parent), frame_name(child));
        if parent == child {
            return Ok(Isometry3::identity());
        }
        for frame in [parent, child] {
            if !self.knows(frame) {
                return Err(TfLookupError::UnknownFrame { frame: frame.to_string() });
            }
        }
        let up_from_child = self.path_to_root(child);
        let up_from_parent = self.path_to_root(parent);
        let ancestor = up_from_child
            .iter()
            .find(|f| up_from_parent.contains(f))
            .ok_or_else(|| TfLookupError::NotConnected { parent: parent.to_string(), child: child.to_string() })?;
        let ancestor_from_child = self.compose_up(child, ancestor, stamp)?;
        let ancestor_from_parent = self.compose_up(parent, ancestor, stamp)?;
        Ok(ancestor_from_parent.inverse() * ancestor_from_child)
    }

    /// `frame`, its parent, its parent's parent, … (at most [`MAX_CHAIN`] links; a loop ends it).
    fn path_to_root<'a>(&'a self, frame: &'a str) -> Vec<&'a str> {
        let mut path = vec![frame];
        let mut current = frame;
        while let Some(link) = self.links.get(current) {
            if path.len() > MAX_CHAIN || path.contains(&link.parent.as_str()) {
                break;
            }
            current = link.parent.as_str();
            path.push(current);
        }
        path
    }

    /// ancestor-from-frame at `stamp`, walking up the links from `frame`.
    fn compose_up(&self, frame: &str, ancestor: &str, stamp: Stamp) -> Result<Isometry3<f64>, TfLookupError> {
        let mut ancestor_from_frame = Isometry3::identity();
        let mut current = frame;
        while current != ancestor {
            let link =
                self.links.get(current).ok_or_else(|| TfLookupError::UnknownFrame { frame: current.to_string() })?;
            ancestor_from_frame = link.at(current, stamp, self.slack_ns)? * ancestor_from_frame;
            current = link.parent.as_str();
        }
        Ok(ancestor_from_frame)
    }
}

#[cfg(test)]
impl TfHistory {
    /// A buffer with a budget small enough for a test to fill.
    fn with_budget(budget: usize) -> Self {
        Self { budget, ..Self::default() }
    }
}

#[cfg(test)]
#[path = "tf_buffer_tests.rs"]
pub(crate) mod tests;
