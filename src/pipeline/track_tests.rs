use nalgebra::{Isometry3, Vector3};

use super::*;

const MS: Stamp = 1_000_000;

fn pose(x: f64, yaw: f64) -> Isometry3<f64> {
    Isometry3::new(Vector3::new(x, 0.0, 0.0), Vector3::new(0.0, yaw, 0.0))
}

fn sure(pose: Isometry3<f64>, prediction: Option<&Prediction>) -> Published {
    let agreement = prediction.and_then(|p| p.disagreement(&pose, 2.0, 3.0, 0.001));
    Published { pose, sure: true, depth: Some(2.0), agreement }
}

/// The camera's pose at frame `k` when it moves 1 cm forward and turns 0.5° every 100 ms, its
/// measured yaw off by `jitter` degrees on every other frame.
fn truth(k: usize, jitter: f64) -> Isometry3<f64> {
    let step = Isometry3::new(Vector3::new(0.0, 0.0, 0.01), Vector3::new(0.0, 0.5f64.to_radians(), 0.0));
    let moved = (0..k).fold(Isometry3::identity(), |p, _| p * step);
    moved * pose(0.0, if k % 2 == 1 { jitter.to_radians() } else { 0.0 })
}

/// `frames` frames of [`truth`], each published sure.
fn walk(tracker: &mut Tracker, frames: usize, jitter: f64) -> Vec<TrackState> {
    (0..frames)
        .map(|k| {
            let stamp = k as Stamp * 100 * MS;
            let prediction = tracker.predict(stamp, None);
            tracker.update(stamp, Some(sure(truth(k, jitter), prediction.as_ref())), prediction.as_ref(), None)
        })
        .collect()
}

#[test]
fn constant_motion_is_predicted_and_tracked() {
    let mut tracker = Tracker::default();
    let states = walk(&mut tracker, 8, 0.0);
    assert_eq!(states[0], TrackState::Relocalized);
    assert_eq!(*states.last().unwrap(), TrackState::Tracking, "{states:?}");
    let prediction = tracker.predict(8 * 100 * MS, None).expect("a prediction");
    // The motion over three intervals, a third of it per interval: its translation scaled on
    // the chord, not along the arc (the step is 0.5° off the chord: 1 cm · 0.009 / 2 m here).
    let off = view_angle(&prediction.pose, &truth(8, 0.0), 2.0);
    assert!(off < 6e-5, "{off}");
}

#[test]
fn a_prediction_is_evidence_only_once_the_stream_measured_its_errors() {
    let mut tracker = Tracker::default();
    walk(&mut tracker, 2, 0.0);
    let early = tracker.predict(200 * MS, None).expect("a prediction");
    assert_eq!(early.typical_error, None);
    assert_eq!(early.disagreement(&pose(5.0, 1.0), 2.0, 3.0, 0.001), None);
}

#[test]
fn a_jump_is_off_track_and_the_gate_grows_with_the_gap() {
    let mut tracker = Tracker::default();
    let states = walk(&mut tracker, 8, 0.3);
    assert_eq!(*states.last().unwrap(), TrackState::Tracking, "{states:?}");
    let next = tracker.predict(800 * MS, None).expect("a prediction");
    let near = next.disagreement(&truth(8, 0.3), 2.0, 3.0, 0.001).expect("evidence");
    let far = next.disagreement(&(truth(8, 0.0) * pose(0.5, 0.3)), 2.0, 3.0, 0.001).expect("evidence");
    assert!(near.agrees(), "{near:?}");
    assert!(!far.agrees(), "{far:?}");
    let later = tracker.predict(1200 * MS, None).expect("a prediction");
    let later_gate = later.disagreement(&later.pose, 2.0, 3.0, 0.001).expect("evidence").gate;
    assert!(later_gate > near.gate, "{later_gate} vs {}", near.gate);
}

#[test]
fn a_relocalization_drops_the_old_motion_and_a_long_gap_or_a_stamp_back_drops_the_track() {
    let mut tracker = Tracker::default();
    walk(&mut tracker, 6, 0.3);
    let stamp = 600 * MS;
    let prediction = tracker.predict(stamp, None).expect("a prediction");
    let kidnapped = pose(3.0, 1.0);
    let state = tracker.update(stamp, Some(sure(kidnapped, Some(&prediction))), Some(&prediction), None);
    assert_eq!(state, TrackState::Relocalized);
    let held = tracker.predict(700 * MS, None).expect("a prediction");
    assert!(view_angle(&held.pose, &kidnapped, 2.0) < 1e-12, "holds the new pose");
    assert!(tracker.predict(700 * MS + 2_000 * MS, None).is_none(), "ten intervals later");
    assert!(tracker.predict(100 * MS, None).is_none(), "a stamp that goes back");
}

/// The camera in an odometry frame that is not the map's (turned and moved), its odometry off
/// by `drift` metres forward per frame.
fn odometry(k: usize, drift: f64) -> Isometry3<f64> {
    let odom_from_map = Isometry3::new(Vector3::new(4.0, -1.0, 0.5), Vector3::new(0.0, 0.0, 0.7));
    odom_from_map * truth(k, 0.0) * Isometry3::translation(0.0, 0.0, drift * k as f64)
}

/// Frames at irregular stamps (the motion model cannot extrapolate them) with odometry.
#[test]
fn odometry_carries_the_last_pose_across_any_interval() {
    let mut tracker = Tracker::default();
    let stamps = [0, 100, 150, 400, 450, 900, 1000, 1700];
    let mut states = Vec::new();
    for (k, &ms) in stamps.iter().enumerate() {
        let stamp = ms * MS;
        let odom = odometry(k, 0.0005);
        let prediction = tracker.predict(stamp, Some(&odom));
        if k > 0 {
            let p = prediction.expect("a prediction");
            assert_eq!(p.source, PredictionSource::Odometry);
            // Off by the odometry's drift of one frame alone (0.5 mm at 2 m: 2.5e-4).
            assert!(view_angle(&p.pose, &truth(k, 0.0), 2.0) < 3e-4, "frame {k}");
        }
        states.push(tracker.update(
            stamp,
            Some(sure(truth(k, 0.0), prediction.as_ref())),
            prediction.as_ref(),
            Some(&odom),
        ));
    }
    assert_eq!(*states.last().unwrap(), TrackState::Tracking, "{states:?}");
    // Without the frame's odometry, the motion model.
    assert_eq!(tracker.predict(1800 * MS, None).map(|p| p.source), Some(PredictionSource::Motion));
}

/// Odometry's errors are learnt apart from the motion model's: a stream that switches source
/// starts the other's evidence from nothing.
#[test]
fn each_source_learns_its_own_errors() {
    let mut tracker = Tracker::default();
    walk(&mut tracker, 8, 0.3);
    let motion = tracker.predict(800 * MS, None).expect("a prediction");
    assert!(motion.typical_error.is_some());
    let with_odometry = tracker.predict(800 * MS, Some(&odometry(8, 0.0)));
    // The last fix had no odometry: nothing to carry it with.
    assert_eq!(with_odometry.map(|p| p.source), Some(PredictionSource::Motion));
    let stamp = 800 * MS;
    tracker.update(stamp, Some(sure(truth(8, 0.0), Some(&motion))), Some(&motion), Some(&odometry(8, 0.0)));
    let next = tracker.predict(900 * MS, Some(&odometry(9, 0.0))).expect("a prediction");
    assert_eq!(next.source, PredictionSource::Odometry);
    assert_eq!(next.typical_error, None, "no odometry error measured yet");
}

#[test]
fn scene_depth_is_the_median_depth_of_the_inliers() {
    let k = Intrinsics { fx: 500.0, fy: 500.0, cx: 320.0, cy: 240.0, width: 640, height: 480 };
    let at = |x: f64, y: f64, z: f64, off: f64| Correspondence {
        pixel: nalgebra::Point2::new(320.0 + 500.0 * x / z + off, 240.0 + 500.0 * y / z),
        point: nalgebra::Point3::new(x, y, z),
        score: 1.0,
    };
    let matches = [at(0.1, 0.0, 2.0, 0.0), at(-0.2, 0.1, 3.0, 0.0), at(0.0, 0.2, 4.0, 0.0), at(0.3, 0.0, 9.0, 50.0)];
    assert_eq!(scene_depth(&k, &matches, &Isometry3::identity(), 4.0), Some(3.0));
}
