//! The TF the node broadcasts and its base pose, as REP 105 has them (tested with the buffer,
//! in `src/tf_buffer_tests.rs`).
//!
//! - `map → odom` = (map→camera) · (odom→camera)⁻¹, so the map frame joins the robot's
//!   `odom → base_link → … → camera` tree as AMCL-style localizers do; `odom → camera` comes
//!   from [`TfHistory`], looked up at the image's stamp through any chain of frames. It is
//!   future-dated by `transform_tolerance_s` and the last one is re-sent at
//!   `tf_publish_rate_hz` ([`TfBroadcast::republish`]).
//! - `map → camera` (`tf_mode: map_to_camera`, or `auto` while `odom_frame` has never been
//!   heard: a camera and a bag, no odometry).
//! - the pose of `base_frame` in the map = map→camera · (base→camera)⁻¹, when that chain is known.
//!
//! A frame that is never heard on `/tf` is not an error (the user has no such frame); a chain
//! that is heard but cannot be looked up at a frame's stamp is (counted, logged once until it
//! works again).

use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};

use nalgebra::Isometry3;
use thiserror::Error;

use super::log::lock;
use crate::frame::Stamp;
use crate::msgs::{self, convert, TFMessage};
use crate::params::{NodeParams, TfMode};
use crate::tf_buffer::{TfHistory, TfLookupError};

/// `map → odom` from the camera's pose in the map and in odom: (map→camera) · (odom→camera)⁻¹.
pub fn map_to_odom(map_camera: &Isometry3<f64>, odom_camera: &Isometry3<f64>) -> Isometry3<f64> {
    map_camera * odom_camera.inverse()
}

/// Why a localized frame sends no TF or no base pose.
#[derive(Debug, Error, PartialEq)]
pub enum TfError {
    #[error(
        "frame {stamp}: correspondences in map frame {got:?} but node.map_frame is {expected:?}: no TF nor base pose (set map_frame)"
    )]
    MapFrameMismatch { stamp: Stamp, got: String, expected: String },
    #[error("frame {stamp}: no transform {odom} → {camera} at its stamp ({source}); no TF published")]
    NoOdomTransform { stamp: Stamp, odom: String, camera: String, source: TfLookupError },
    #[error("frame {stamp}: no transform {base} → {camera} at its stamp ({source}); no base pose published")]
    NoBaseTransform { stamp: Stamp, base: String, camera: String, source: TfLookupError },
}

impl TfError {
    /// The diagnostics key it is counted under (`error.<key>`).
    pub fn key(&self) -> &'static str {
        match self {
            TfError::MapFrameMismatch { .. } => "map_frame_mismatch",
            TfError::NoOdomTransform { .. } => "no_odom_transform",
            TfError::NoBaseTransform { .. } => "no_base_transform",
        }
    }
}

/// A problem of one frame, and whether it is news (logged: the first of its kind, or the first
/// since that kind last worked).
#[derive(Debug)]
pub struct TfProblem {
    pub error: TfError,
    pub log: bool,
}

/// Notes worth one log line each: the fallback to `map → camera`, a frame never heard.
#[derive(Debug, PartialEq)]
pub enum TfNote {
    /// `tf_mode: auto` and `odom_frame` never heard: `map → camera` is broadcast.
    FallbackToCamera { odom: String },
    /// `odom_frame` heard at last: from now on `map → odom`.
    OdomHeard { odom: String },
    /// `base_frame` never heard: no base pose.
    NoBaseFrame { base: String },
}

impl std::fmt::Display for TfNote {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TfNote::FallbackToCamera { odom } => write!(
                f,
                "tf_mode auto: no {odom:?} frame heard on /tf or /tf_static, broadcasting map → camera until it is \
                 (tf_mode:=map_to_camera keeps it so, tf_mode:=map_to_odom waits for odometry)"
            ),
            TfNote::OdomHeard { odom } => write!(f, "tf_mode auto: {odom:?} heard on /tf, broadcasting map → {odom}"),
            TfNote::NoBaseFrame { base } => {
                write!(f, "no {base:?} frame heard on /tf or /tf_static: no base pose until it is (base_frame:='' turns it off)")
            }
        }
    }
}

/// What one localized frame sends.
#[derive(Debug, Default)]
pub struct FrameTf {
    pub tf: Option<TFMessage>,
    /// Which transform `tf` is (`map_to_odom`, `map_to_camera`), counted as `tf.<kind>`.
    pub kind: Option<&'static str>,
    pub base_pose: Option<msgs::PoseStamped>,
    pub problems: Vec<TfProblem>,
    pub notes: Vec<TfNote>,
}

/// The frames of REP 105 the node works with (no leading slash; empty: not used).
#[derive(Clone, Debug, PartialEq)]
pub struct TfFrames {
    pub map: String,
    pub odom: String,
    pub base: String,
}

fn frame_id(name: &str) -> String {
    name.trim().trim_start_matches('/').to_string()
}

/// The node's TF and base pose: what to send for a localized frame and what to re-send.
#[derive(Debug)]
pub struct TfBroadcast {
    mode: TfMode,
    frames: TfFrames,
    buffer: Arc<Mutex<TfHistory>>,
    /// `transform_tolerance_s` in ns.
    tolerance_ns: i64,
    /// The last `map → odom`, re-sent between frames.
    last_map_odom: Option<Isometry3<f64>>,
    /// Problems logged and not yet resolved; notes given.
    logged: BTreeSet<&'static str>,
    said_fallback: bool,
    said_no_base: bool,
    /// Whether this camera sends `map → odom` (of a node's several cameras, only the first: one
    /// robot has one `map → odom`, see docs/multi-camera.md).
    sends_map_odom: bool,
}

impl TfBroadcast {
    /// From the node's parameters; `buffer` holds what was heard on `/tf` and `/tf_static`.
    pub fn new(np: &NodeParams, buffer: Arc<Mutex<TfHistory>>) -> Self {
        let frames =
            TfFrames { map: frame_id(&np.map_frame), odom: frame_id(&np.odom_frame), base: frame_id(&np.base_frame) };
        let mode = if frames.odom.is_empty() { TfMode::MapToCamera } else { np.tf_mode };
        Self {
            mode,
            frames,
            buffer,
            tolerance_ns: tolerance_ns(np.transform_tolerance_s),
            last_map_odom: None,
            logged: BTreeSet::new(),
            said_fallback: false,
            said_no_base: false,
            sends_map_odom: true,
        }
    }

    /// A camera of a several-camera node other than the first: it sends no `map → odom` (the
    /// first camera does), still `map → <its camera>` where that is the mode, and its base pose.
    pub fn without_map_to_odom(mut self) -> Self {
        self.sends_map_odom = false;
        self
    }

    /// A new `transform_tolerance_s` (a live parameter change): the future-dating and the
    /// buffer's slack.
    pub fn set_tolerance_ns(&mut self, tolerance_ns: i64) {
        self.tolerance_ns = tolerance_ns;
        lock(&self.buffer).set_slack(tolerance_ns);
    }

    /// Forgets the last `map → odom` (a lifecycle cleanup: a node configured again re-sends
    /// nothing from before, only what its next localized frame gives).
    pub fn forget_map_odom(&mut self) {
        self.last_map_odom = None;
    }

    /// The mode in effect (`map_to_camera` when `odom_frame` is empty).
    pub fn mode(&self) -> TfMode {
        self.mode
    }

    pub fn frames(&self) -> &TfFrames {
        &self.frames
    }

    /// The camera's pose in `odom_frame` at `stamp` (odom-from-camera), as heard on `/tf`: the
    /// frame's odometry, for tracking; `None` without `odom_frame` or where the lookup fails
    /// (the frame is then predicted without it; the TF it sends says why, once localized).
    pub fn odometry_at(&self, camera: &str, stamp: Stamp) -> Option<Isometry3<f64>> {
        if self.frames.odom.is_empty() {
            return None;
        }
        lock(&self.buffer).lookup(&self.frames.odom, &frame_id(camera), stamp).ok()
    }

    /// The TF (when `with_tf`) and base pose of a frame localized at `map_camera`.
    pub fn for_frame(
        &mut self,
        stamp: Stamp,
        camera: &str,
        map_frame_id: &str,
        map_camera: &Isometry3<f64>,
        with_tf: bool,
    ) -> FrameTf {
        let mut out = FrameTf::default();
        let camera = frame_id(camera);
        let got = frame_id(map_frame_id);
        if !got.is_empty() && got != self.frames.map {
            let error = TfError::MapFrameMismatch { stamp, got, expected: self.frames.map.clone() };
            out.problems.push(self.problem(error));
            return out;
        }
        self.resolved("map_frame_mismatch");
        if with_tf {
            self.frame_tf(stamp, &camera, map_camera, &mut out);
        }
        if !self.frames.base.is_empty() {
            self.base_pose(stamp, &camera, map_camera, &mut out);
        }
        out
    }

    /// `map → odom` or `map → camera` for one frame.
    fn frame_tf(&mut self, stamp: Stamp, camera: &str, map_camera: &Isometry3<f64>, out: &mut FrameTf) {
        let odom = self.frames.odom.clone();
        let heard_odom = lock(&self.buffer).knows(&odom);
        let to_camera = match self.mode {
            TfMode::MapToCamera => true,
            TfMode::MapToOdom => false,
            TfMode::Auto => !heard_odom,
        };
        if self.mode == TfMode::Auto && to_camera != self.said_fallback {
            self.said_fallback = to_camera;
            let note = if to_camera { TfNote::FallbackToCamera { odom } } else { TfNote::OdomHeard { odom } };
            out.notes.push(note);
        }
        if to_camera {
            out.tf = Some(convert::transform_message(stamp, &self.frames.map, camera, map_camera));
            out.kind = Some("map_to_camera");
            return;
        }
        if !self.sends_map_odom {
            return;
        }
        let odom_camera = lock(&self.buffer).lookup(&self.frames.odom, camera, stamp);
        match odom_camera {
            Ok(odom_camera) => {
                self.resolved("no_odom_transform");
                let map_odom = map_to_odom(map_camera, &odom_camera);
                self.last_map_odom = Some(map_odom);
                // Future-dated (REP 105, as amcl): valid until the next localization is due.
                let stamp = stamp.saturating_add(self.tolerance_ns);
                out.tf = Some(convert::transform_message(stamp, &self.frames.map, &self.frames.odom, &map_odom));
                out.kind = Some("map_to_odom");
            }
            Err(source) => {
                let error = TfError::NoOdomTransform {
                    stamp,
                    odom: self.frames.odom.clone(),
                    camera: camera.to_string(),
                    source,
                };
                out.problems.push(self.problem(error));
            }
        }
    }

    /// The pose of `base_frame` in the map, when `base → camera` is known at `stamp`.
    fn base_pose(&mut self, stamp: Stamp, camera: &str, map_camera: &Isometry3<f64>, out: &mut FrameTf) {
        let base = self.frames.base.clone();
        let buffer = lock(&self.buffer);
        if !buffer.knows(&base) {
            drop(buffer);
            if !self.said_no_base {
                self.said_no_base = true;
                out.notes.push(TfNote::NoBaseFrame { base });
            }
            return;
        }
        let base_camera = buffer.lookup(&base, camera, stamp);
        drop(buffer);
        match base_camera {
            Ok(base_camera) => {
                self.resolved("no_base_transform");
                let map_base = map_camera * base_camera.inverse();
                out.base_pose = Some(convert::pose_stamped(stamp, &self.frames.map, &map_base));
            }
            Err(source) => {
                let error = TfError::NoBaseTransform { stamp, base, camera: camera.to_string(), source };
                out.problems.push(self.problem(error));
            }
        }
    }

    /// The last `map → odom`, stamped `transform_tolerance_s` after `now` (the node's clock);
    /// `None` before the first one or outside the odom modes.
    pub fn republish(&self, now: Stamp) -> Option<TFMessage> {
        let map_odom = self.last_map_odom.as_ref()?;
        let stamp = now.saturating_add(self.tolerance_ns);
        Some(convert::transform_message(stamp, &self.frames.map, &self.frames.odom, map_odom))
    }

    fn problem(&mut self, error: TfError) -> TfProblem {
        let log = self.logged.insert(error.key());
        TfProblem { error, log }
    }

    fn resolved(&mut self, key: &'static str) {
        self.logged.remove(key);
    }
}

/// Seconds → ns, saturating (the parameter is validated finite and ≥ 0).
pub fn tolerance_ns(seconds: f64) -> i64 {
    (seconds * 1e9).round().clamp(0.0, i64::MAX as f64) as i64
}

#[cfg(test)]
#[path = "tf_tests.rs"]
mod tests;
