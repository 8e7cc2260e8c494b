//! A TF buffer as tf2 keeps one: a short history of every `parent → child` transform heard on
//! `/tf` and the static ones of `/tf_static`, looked up at a stamp (interpolated between the
//! samples around it) through any tree path between two frames, e.g.
//! `odom → base_link → camera_link → camera_color_frame → camera_color_optical_frame`.
//!
//! Bounded: [`TfHistory::CACHE_NS`] of history per frame (tf2's default 10 s), at most
//! [`MAX_SAMPLES`] samples per frame and [`MAX_FRAMES`] frames; transforms beyond are dropped
//! and reported.

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
    }
}

/// tf2 frame ids carry no leading slash; accept one anyway.
fn frame_name(id: &str) -> &str {
    id.strip_prefix('/').unwrap_or(id)
}

/// The transforms heard, by child frame.
#[derive(Debug, Default)]
pub struct TfHistory {
    links: HashMap<String, Link>,
    /// A lookup this far beyond a frame's newest (or before its oldest) sample takes that sample.
    slack_ns: i64,
}

impl TfHistory {
    /// History kept per dynamic frame, as tf2's default cache time.
    pub const CACHE_NS: i64 = 10_000_000_000;

    /// A buffer whose lookups take a frame's newest (oldest) sample for a stamp at most `slack_ns`
    /// after (before) it, as a transform tolerance allows.
    pub fn with_slack(slack_ns: i64) -> Self {
        Self { links: HashMap::new(), slack_ns: slack_ns.max(0) }
    }

    /// A new slack (a live change of `transform_tolerance_s`).
    pub fn set_slack(&mut self, slack_ns: i64) {
        self.slack_ns = slack_ns.max(0);
    }

    /// Takes every valid transform of `msg` (`is_static` for `/tf_static`); returns why the
    /// others were skipped.
    pub fn update(&mut self, msg: &TFMessage, is_static: bool) -> Vec<String> {
        let mut bad = Vec::new();
        for t in &msg.transforms {
            let (parent, child) = (frame_name(&t.header.frame_id), frame_name(&t.child_frame_id));
            if parent.is_empty() || child.is_empty() || parent == child {
                bad.push(format!("transform {parent:?} → {child:?}: bad frame ids"));
                continue;
            }
            let tr = &t.transform;
            let pose = msgs::Pose {
                position: msgs::Point { x: tr.translation.x, y: tr.translation.y, z: tr.translation.z },
                orientation: tr.rotation,
            };
            let transform = match convert::isometry_from_pose(&pose) {
                Ok(iso) => iso,
                Err(e) => {
                    bad.push(format!("transform {parent} → {child}: {e}"));
                    continue;
                }
            };
            if self.path_to_root(parent).contains(&child) {
                // tf2 refuses it too: a tree has no loop, and one would make `child` its own
                // ancestor (#38: a → b → a switched the node to publishing map → odom).
                bad.push(format!("transform {parent} → {child}: {child} is already an ancestor of {parent}, a loop"));
                continue;
            }
            if !self.links.contains_key(child) && self.links.len() >= MAX_FRAMES {
                bad.push(format!("transform {parent} → {child}: over {MAX_FRAMES} frames, left out"));
                continue;
            }
            let link = self.links.entry(child.to_string()).or_insert_with(|| Link {
                parent: parent.to_string(),
                is_static,
                samples: VecDeque::new(),
            });
            if link.parent != parent || link.is_static != is_static {
                // A frame re-parented (or moved between /tf and /tf_static): start its history anew.
                *link = Link { parent: parent.to_string(), is_static, samples: VecDeque::new() };
            }
            link.insert(msgs::convert::stamp(&t.header), transform, Self::CACHE_NS);
        }
        bad
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
#[path = "tf_buffer_tests.rs"]
pub(crate) mod tests;
