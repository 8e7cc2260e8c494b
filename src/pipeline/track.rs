//! Tracking: frames in stamp order are a stream, and the poses published before predict the
//! next one. The prediction is evidence, never a veto and never a pose: a pose that rests only
//! on weak support (not meaningful among every match, confirmed by the prior alone) is withheld
//! when it disagrees with a prediction that has proved itself; a pose with meaningful support
//! is published wherever it is (a kidnapped camera re-localizes at once).
//!
//! The prediction carries the last published pose to the frame's stamp: with the robot's
//! odometry when the frame and that pose both have it (the odometry's motion between their
//! stamps, `odom → camera` from `/tf`, REP 105), otherwise by extrapolating the motion over the
//! last few published poses (constant velocity measured over up to three intervals, which
//! divides the poses' own errors; the last pose alone after a re-localization). How far it may
//! be off is learnt from the stream itself, for each of the two sources apart: the recent errors
//! of its predictions against poses that were sure on their own evidence, each scaled to the
//! interval it predicted over. Errors are
//! measured as a *view angle* — the rotation between two poses plus their distance over the
//! depth of the scene in view — so that one measure holds at any range and on any sensor; the
//! floor under it is the inlier threshold's angle at the frame's focal length.

use std::collections::VecDeque;

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};

use crate::frame::{Correspondence, Stamp};
use crate::geometry::Intrinsics;

/// How the localizer uses the stream.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackingParams {
    /// Whether frames are a stream that tracks (replay in stamp order, the node); false: every
    /// frame alone, as the paper's protocol and the benchmarks take them.
    pub enabled: bool,
    /// How many times the typical (median) recent prediction error a pose may be off the
    /// prediction and still agree with it.
    pub gate: f64,
    /// How many times the typical recent prediction error a pose of the cascade's fast path may
    /// be off the prediction for the track to settle the frame (the pose also sure among every
    /// match and the search confident of it, [`super::CascadeParams::settle`]): the network and
    /// the guided search are skipped only where the prediction puts the camera about as closely
    /// as it typically does. Measured: at 1× half of the right poses settle (redkitchen hard:
    /// 5 of 20 frames), at 2× most (12 of 20; the frames' median 6.7 → 2.6 ms), with the same
    /// RR and false poses on 45 bags; the one wrong pose seen settling (building frame 122,
    /// 2.2° off its truth) lay 2.8 typical errors from the prediction and settled at `gate`'s
    /// 3×. 0: the track settles no frame.
    pub settle_gate: f64,
}

impl Default for TrackingParams {
    fn default() -> Self {
        Self { enabled: true, gate: 3.0, settle_gate: 2.0 }
    }
}

/// How a frame's outcome stands to the track.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrackState {
    /// A pose was published that agrees with the prediction.
    Tracking,
    /// A pose was published on the frame's own evidence, with no prediction that had proved
    /// itself, or far from it.
    Relocalized,
    /// No pose was published.
    Lost,
}

impl TrackState {
    pub fn name(self) -> &'static str {
        match self {
            TrackState::Tracking => "tracking",
            TrackState::Relocalized => "relocalized",
            TrackState::Lost => "lost",
        }
    }
}

/// What a prediction carries the last published pose with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PredictionSource {
    /// The robot's odometry between the two stamps.
    Odometry,
    /// The motion of the last published poses, extrapolated (or the last pose alone).
    Motion,
}

impl PredictionSource {
    pub fn name(self) -> &'static str {
        match self {
            PredictionSource::Odometry => "odometry",
            PredictionSource::Motion => "motion",
        }
    }
}

/// The predicted camera-to-map pose of a frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Prediction {
    pub pose: Isometry3<f64>,
    pub source: PredictionSource,
    /// The typical error of predictions over this interval (view angle, radians); `None` until
    /// the stream has measured enough of them (the prediction is then not evidence).
    pub typical_error: Option<f64>,
}

/// How far a pose is from the prediction, against how far it may be.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Disagreement {
    /// View angle between the pose and the prediction (radians).
    pub angle: f64,
    /// The largest that agrees (radians).
    pub gate: f64,
}

impl Disagreement {
    pub fn agrees(&self) -> bool {
        self.angle <= self.gate
    }
}

/// A published pose.
#[derive(Clone, Copy, Debug)]
struct Fix {
    stamp: Stamp,
    pose: Isometry3<f64>,
    /// The frame's odometry (camera in the odometry frame), when it had one.
    odometry: Option<Isometry3<f64>>,
}

/// Published poses the motion is measured over (three intervals).
const FIXES_KEPT: usize = 4;
/// Recent prediction errors kept.
const ERRORS_KEPT: usize = 15;
/// Errors measured before a prediction is evidence.
const MIN_ERRORS: usize = 3;
/// Recent frame intervals kept.
const INTERVALS_KEPT: usize = 15;
/// A frame this many typical frame intervals after the last published pose is not predicted.
const MAX_GAP_INTERVALS: f64 = 10.0;

/// The stream's memory: the last published poses and how well they were predicted.
#[derive(Clone, Debug, Default)]
pub struct Tracker {
    /// The last published poses, oldest first, since the track last started or re-localized.
    fixes: VecDeque<Fix>,
    /// Stamp of the last frame seen (published or not).
    last_frame: Option<Stamp>,
    /// Recent errors of motion predictions against sure poses, per second of extrapolation.
    errors_per_s: VecDeque<f64>,
    /// The same for odometry's predictions.
    odometry_errors_per_s: VecDeque<f64>,
    /// Recent intervals between frames (s).
    intervals: VecDeque<f64>,
}

impl Tracker {
    /// Forgets the stream (a new map, a stamp that goes back).
    pub fn reset(&mut self) {
        *self = Self::default();
    }

    /// The prediction for a frame at `stamp` whose camera is at `odometry` in the odometry
    /// frame (if known); `None` without a recent published pose. A stamp that is not after the
    /// last frame's starts the stream again.
    pub fn predict(&mut self, stamp: Stamp, odometry: Option<&Isometry3<f64>>) -> Option<Prediction> {
        if self.last_frame.is_some_and(|last| stamp <= last) {
            self.reset();
        }
        let last = *self.fixes.back()?;
        let dt = seconds(stamp - last.stamp);
        if let (Some(now), Some(then)) = (odometry, last.odometry.as_ref()) {
            // The map pose of the odometry frame, as the last pose puts it, carries the camera.
            let pose = last.pose * then.inverse() * now;
            let typical = typical_error(&self.odometry_errors_per_s);
            return Some(Prediction {
                pose,
                source: PredictionSource::Odometry,
                typical_error: typical.map(|e| e * dt),
            });
        }
        let typical_interval = median(self.intervals.iter().copied())?;
        if dt > MAX_GAP_INTERVALS * typical_interval {
            return None;
        }
        // The motion over the recent fixes, not the last step alone: each pose carries its own
        // error, and a longer span divides it.
        let reach = MAX_GAP_INTERVALS * typical_interval;
        let pose = match self.fixes.iter().find(|f| seconds(last.stamp - f.stamp) <= reach) {
            Some(first) if first.stamp < last.stamp => extrapolate(first, &last, stamp),
            _ => last.pose,
        };
        let typical = typical_error(&self.errors_per_s);
        Some(Prediction { pose, source: PredictionSource::Motion, typical_error: typical.map(|e| e * dt) })
    }

    /// The frame at `stamp` is done: `published`, the pose it published (if any) and how it
    /// stands, `prediction` what was predicted for it and `odometry` the frame's odometry.
    /// Returns the frame's state.
    pub fn update(
        &mut self,
        stamp: Stamp,
        published: Option<Published>,
        prediction: Option<&Prediction>,
        odometry: Option<&Isometry3<f64>>,
    ) -> TrackState {
        if let Some(last) = self.last_frame {
            push_bounded(&mut self.intervals, seconds(stamp - last), INTERVALS_KEPT);
        }
        self.last_frame = Some(stamp);
        let Some(published) = published else { return TrackState::Lost };
        let mut state = TrackState::Relocalized;
        if let (Some(prediction), Some(last), Some(depth)) = (prediction, self.fixes.back(), published.depth) {
            let angle = view_angle(&prediction.pose, &published.pose, depth);
            if published.sure {
                let dt = seconds(stamp - last.stamp);
                let errors = match prediction.source {
                    PredictionSource::Odometry => &mut self.odometry_errors_per_s,
                    PredictionSource::Motion => &mut self.errors_per_s,
                };
                if dt > 0.0 {
                    push_bounded(errors, angle / dt, ERRORS_KEPT);
                }
            }
            if published.agreement.is_some_and(|d| d.agrees()) {
                state = TrackState::Tracking;
            }
        }
        // Far from a prediction that had proved itself: the motion before does not carry over.
        if published.agreement.is_some_and(|d| !d.agrees()) {
            self.fixes.clear();
        }
        self.fixes.push_back(Fix { stamp, pose: published.pose, odometry: odometry.copied() });
        while self.fixes.len() > FIXES_KEPT {
            self.fixes.pop_front();
        }
        state
    }
}

/// A pose a frame published, as the tracker learns from it.
#[derive(Clone, Copy, Debug)]
pub struct Published {
    pub pose: Isometry3<f64>,
    /// Whether it was sure on the frame's own evidence (meaningful among every match).
    pub sure: bool,
    /// The scene's depth in view (for view angles; measured where there was a prediction).
    pub depth: Option<f64>,
    /// How it stood to a prediction that was evidence.
    pub agreement: Option<Disagreement>,
}

/// How a pose stands to a prediction on a frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Weighed {
    /// The scene's depth in view at the pose ([`scene_depth`]).
    pub depth: Option<f64>,
    /// How far the pose is from the prediction, once the prediction is evidence.
    pub agreement: Option<Disagreement>,
}

/// A prediction as a frame's poses are weighed against it: a pose agrees when it is off by at
/// most `gate` times the prediction's typical error.
#[derive(Clone, Copy, Debug)]
pub struct OnTrack<'a> {
    pub prediction: &'a Prediction,
    pub gate: f64,
}

impl OnTrack<'_> {
    /// `pose` against the prediction on a frame of camera `k` and `correspondences`, whose
    /// inliers (within `threshold_px`) give the depth in view; the floor of the gate is the
    /// inlier threshold's angle at the camera's focal length.
    pub fn weigh(
        &self,
        k: &Intrinsics,
        correspondences: &[Correspondence],
        pose: &Isometry3<f64>,
        threshold_px: f64,
    ) -> Weighed {
        let depth = scene_depth(k, correspondences, pose, threshold_px);
        let floor = threshold_px / k.fx;
        let agreement = depth.and_then(|d| self.prediction.disagreement(pose, d, self.gate, floor));
        Weighed { depth, agreement }
    }

    /// Whether `pose` agrees with a prediction that is evidence ([`OnTrack::weigh`]).
    pub fn agrees(
        &self,
        k: &Intrinsics,
        correspondences: &[Correspondence],
        pose: &Isometry3<f64>,
        threshold_px: f64,
    ) -> bool {
        self.weigh(k, correspondences, pose, threshold_px).agreement.is_some_and(|a| a.agrees())
    }
}

impl Prediction {
    /// How far `pose` (at scene depth `depth`) is from the prediction, against its gate:
    /// `gate` times the typical error, at least the `floor` angle; `None` when the prediction
    /// is not evidence yet.
    pub fn disagreement(&self, pose: &Isometry3<f64>, depth: f64, gate: f64, floor: f64) -> Option<Disagreement> {
        Some(Disagreement { angle: view_angle(&self.pose, pose, depth), gate: self.gate_angle(gate, floor)? })
    }

    /// The largest view angle that agrees with the prediction: `gate` times its typical error,
    /// at least `floor`; `None` when it is not evidence yet.
    fn gate_angle(&self, gate: f64, floor: f64) -> Option<f64> {
        Some(gate * self.typical_error?.max(floor))
    }
}

/// The view angle between two camera-to-map poses seen at scene depth `depth`: the angle of
/// their relative rotation plus the distance between them over the depth (radians).
pub fn view_angle(a: &Isometry3<f64>, b: &Isometry3<f64>, depth: f64) -> f64 {
    let rotation = a.rotation.angle_to(&b.rotation);
    let distance = (a.translation.vector - b.translation.vector).norm();
    rotation + distance / depth.max(f64::EPSILON)
}

/// The median depth, in the camera at `pose`, of the map points of the correspondences that
/// reproject within `threshold_px` (the pose's inliers); `None` with none.
pub fn scene_depth(
    k: &Intrinsics,
    correspondences: &[Correspondence],
    pose: &Isometry3<f64>,
    threshold_px: f64,
) -> Option<f64> {
    let to_camera = pose.inverse();
    let depths = correspondences.iter().filter_map(|c| {
        let p = to_camera.transform_point(&c.point);
        (p.z > 0.0 && k.reprojection_error(&p, &c.pixel) < threshold_px).then_some(p.z)
    });
    median(depths)
}

/// The pose at `stamp` if the camera moves on from `last` as it moved from `before` to it
/// (constant velocity: the motion in the camera's frame scaled by the ratio of the intervals,
/// its rotation on the geodesic, its translation on the straight line — for the few degrees
/// between frames, a chord error far below any pose's own).
fn extrapolate(before: &Fix, last: &Fix, stamp: Stamp) -> Isometry3<f64> {
    let span = (last.stamp - before.stamp) as f64;
    if span <= 0.0 {
        return last.pose;
    }
    let ratio = (stamp - last.stamp) as f64 / span;
    let motion = before.pose.inverse() * last.pose;
    let rotation: UnitQuaternion<f64> = motion.rotation.powf(ratio);
    let scaled = Isometry3::from_parts(Translation3::from(motion.translation.vector * ratio), rotation);
    last.pose * scaled
}

fn seconds(ns: Stamp) -> f64 {
    ns as f64 * 1e-9
}

fn push_bounded(values: &mut VecDeque<f64>, value: f64, kept: usize) {
    if value.is_finite() {
        values.push_back(value);
        while values.len() > kept {
            values.pop_front();
        }
    }
}

/// The typical error per second of recent predictions (their median); `None` until
/// [`MIN_ERRORS`] were measured (the prediction is then not evidence).
fn typical_error(errors_per_s: &VecDeque<f64>) -> Option<f64> {
    (errors_per_s.len() >= MIN_ERRORS).then(|| median(errors_per_s.iter().copied())).flatten()
}

fn median(values: impl Iterator<Item = f64>) -> Option<f64> {
    crate::geometry::align::median(values.filter(|x| x.is_finite()).collect())
}

#[cfg(test)]
#[path = "track_tests.rs"]
mod tests;
