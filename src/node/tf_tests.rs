//! What [`TfBroadcast`] sends for a localized frame, in each mode, from transforms heard.

use nalgebra::Isometry3;

use super::*;
use crate::msgs::convert::transform_message;
use crate::tf_buffer::tests::{close, iso};

const S: i64 = 1_000_000_000;
const CAM: &str = "camera_optical";

fn transform_of(m: &TFMessage) -> (Stamp, String, String, Isometry3<f64>) {
    let t = &m.transforms[0];
    let pose = msgs::Pose {
        position: msgs::Point {
            x: t.transform.translation.x,
            y: t.transform.translation.y,
            z: t.transform.translation.z,
        },
        orientation: t.transform.rotation,
    };
    let iso = convert::isometry_from_pose(&pose).expect("a valid transform");
    (convert::stamp(&t.header), t.header.frame_id.clone(), t.child_frame_id.clone(), iso)
}

fn params(mode: TfMode) -> NodeParams {
    NodeParams { tf_mode: mode, ..NodeParams::default() }
}

/// odom → base_link at 10 s and 11 s (moving), static base_link → camera.
fn odometry(buffer: &Mutex<TfHistory>) -> (Isometry3<f64>, Isometry3<f64>) {
    let odom_base = iso([1.0, 2.0, 0.0], [0.0, 0.0, 1.0], 0.4);
    let base_cam = iso([0.1, 0.0, 0.5], [1.0, -1.0, 0.2], -1.2);
    let mut b = lock(buffer);
    for t in [10 * S, 11 * S] {
        assert!(b.update(&transform_message(t, "odom", "base_link", &odom_base), false).is_empty());
    }
    assert!(b.update(&transform_message(0, "base_link", CAM, &base_cam), true).is_empty());
    (odom_base, base_cam)
}

#[test]
fn auto_sends_map_to_camera_until_odom_is_heard_then_map_to_odom() {
    let buffer = Arc::new(Mutex::new(TfHistory::with_slack(S / 10)));
    let mut tf = TfBroadcast::new(&params(TfMode::Auto), buffer.clone());
    let map_cam = iso([3.0, -1.0, 1.5], [0.2, 1.0, -0.3], 0.7);
    let out = tf.for_frame(5 * S, CAM, "map", &map_cam, true);
    let (stamp, parent, child, got) = transform_of(out.tf.as_ref().expect("map → camera"));
    assert_eq!((stamp, parent.as_str(), child.as_str(), out.kind), (5 * S, "map", CAM, Some("map_to_camera")));
    assert!(close(&got, &map_cam));
    let no_base = TfNote::NoBaseFrame { base: "base_link".into() };
    assert_eq!(out.notes, [TfNote::FallbackToCamera { odom: "odom".into() }, no_base]);
    assert!(out.problems.is_empty() && out.base_pose.is_none());
    assert_eq!(tf.republish(6 * S), None, "no map → odom to re-send yet");
    // Said once.
    assert!(tf.for_frame(6 * S, CAM, "map", &map_cam, true).notes.is_empty());

    let (odom_base, base_cam) = odometry(&buffer);
    let at = 10 * S + S / 2;
    let out = tf.for_frame(at, CAM, "map", &map_cam, true);
    assert_eq!(out.notes[0], TfNote::OdomHeard { odom: "odom".into() });
    let (stamp, parent, child, map_odom) = transform_of(out.tf.as_ref().expect("map → odom"));
    // Future-dated by transform_tolerance_s (0.1 s).
    assert_eq!((stamp, parent.as_str(), child.as_str(), out.kind), (at + S / 10, "map", "odom", Some("map_to_odom")));
    assert!(close(&(map_odom * odom_base * base_cam), &map_cam), "map → odom → base → camera is the camera pose");
    // The base pose: map → base = map → camera · (base → camera)⁻¹.
    let base = out.base_pose.expect("base pose");
    assert_eq!((convert::stamp(&base.header), base.header.frame_id.as_str()), (at, "map"));
    let map_base = convert::isometry_from_pose(&base.pose).expect("pose");
    assert!(close(&(map_base * base_cam), &map_cam));
    // Re-sent from the node's clock, future-dated again.
    let (stamp, _, child, again) = transform_of(&tf.republish(20 * S).expect("re-send"));
    assert_eq!((stamp, child.as_str()), (20 * S + S / 10, "odom"));
    assert!(close(&again, &map_odom));
}

#[test]
fn map_to_odom_counts_a_missing_chain_and_logs_it_once_until_it_works() {
    let buffer = Arc::new(Mutex::new(TfHistory::with_slack(S / 10)));
    let mut tf = TfBroadcast::new(&params(TfMode::MapToOdom), buffer.clone());
    let map_cam = iso([1.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.1);
    let out = tf.for_frame(5 * S, CAM, "map", &map_cam, true);
    assert!(out.tf.is_none(), "no fallback outside auto");
    assert!(!out.notes.iter().any(|n| matches!(n, TfNote::FallbackToCamera { .. })));
    assert!(matches!(out.problems[0].error, TfError::NoOdomTransform { stamp, ref source, .. }
        if stamp == 5 * S && *source == TfLookupError::UnknownFrame { frame: "odom".into() }));
    assert!(out.problems[0].log);
    assert_eq!(out.problems[0].error.key(), "no_odom_transform");
    odometry(&buffer);
    // Heard, but not at this stamp (13 s is past the newest sample and its slack): counted, not logged again.
    let out = tf.for_frame(13 * S, CAM, "map", &map_cam, true);
    let p = &out.problems[0];
    assert!(!p.log && matches!(p.error, TfError::NoOdomTransform { source: TfLookupError::Extrapolation { .. }, .. }));
    assert!(p.error.to_string().contains("odom → camera_optical"), "{}", p.error);
    // base → camera is static: the base pose does not need odometry.
    assert!(out.problems.len() == 1 && out.base_pose.is_some());
    assert!(tf.for_frame(11 * S, CAM, "map", &map_cam, true).tf.is_some());
    let out = tf.for_frame(13 * S, CAM, "map", &map_cam, true);
    assert!(out.problems[0].log, "news again after it worked");
}

#[test]
fn map_to_camera_another_map_frame_and_no_tf() {
    let buffer = Arc::new(Mutex::new(TfHistory::default()));
    odometry(&buffer);
    let map_cam = iso([1.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.1);
    // An empty odom_frame means map → camera, whatever odometry is heard.
    let np = NodeParams { odom_frame: String::new(), ..NodeParams::default() };
    let mut tf = TfBroadcast::new(&np, buffer.clone());
    assert_eq!(tf.mode(), TfMode::MapToCamera);
    let out = tf.for_frame(10 * S, CAM, "/map", &map_cam, true);
    assert_eq!(out.kind, Some("map_to_camera"));
    assert!(out.base_pose.is_some() && out.problems.is_empty());
    // Correspondences in another map frame: nothing, counted.
    let out = tf.for_frame(10 * S, CAM, "world", &map_cam, true);
    assert!(out.tf.is_none() && out.base_pose.is_none());
    assert_eq!(out.problems[0].error.key(), "map_frame_mismatch");
    assert!(out.problems[0].error.to_string().contains("\"world\""));
    // publish_tf off: the base pose only; no base_frame: nothing at all, and no complaint.
    let out = tf.for_frame(10 * S, CAM, "map", &map_cam, false);
    assert!(out.tf.is_none() && out.base_pose.is_some());
    let np = NodeParams { base_frame: String::new(), ..params(TfMode::MapToCamera) };
    let out = TfBroadcast::new(&np, buffer).for_frame(10 * S, CAM, "map", &map_cam, false);
    assert!(out.tf.is_none() && out.base_pose.is_none() && out.problems.is_empty() && out.notes.is_empty());
}

#[test]
fn a_base_frame_never_heard_is_a_note_not_an_error() {
    let buffer = Arc::new(Mutex::new(TfHistory::default()));
    let mut tf = TfBroadcast::new(&params(TfMode::MapToCamera), buffer);
    let out = tf.for_frame(S, CAM, "map", &Isometry3::identity(), true);
    assert_eq!(out.notes, [TfNote::NoBaseFrame { base: "base_link".into() }]);
    assert!(out.problems.is_empty() && out.base_pose.is_none());
    assert!(tf.for_frame(2 * S, CAM, "map", &Isometry3::identity(), true).notes.is_empty());
}

#[test]
fn a_base_chain_heard_but_not_at_the_stamp_is_counted() {
    let buffer = Arc::new(Mutex::new(TfHistory::default()));
    odometry(&buffer);
    // "odom" as the base frame: its chain to the camera moves, known from 10 to 11 s only.
    let np = NodeParams { base_frame: "odom".into(), ..params(TfMode::MapToCamera) };
    let mut tf = TfBroadcast::new(&np, buffer);
    let out = tf.for_frame(13 * S, CAM, "map", &Isometry3::identity(), true);
    assert!(out.base_pose.is_none() && out.tf.is_some());
    let p = &out.problems[0];
    assert!(p.log && p.error.key() == "no_base_transform", "{p:?}");
    assert!(p.error.to_string().contains("odom → camera_optical"), "{}", p.error);
    assert!(tf.for_frame(10 * S, CAM, "map", &Isometry3::identity(), true).base_pose.is_some());
}

#[test]
fn of_several_cameras_only_the_first_sends_map_to_odom() {
    let buffer = Arc::new(Mutex::new(TfHistory::with_slack(S / 10)));
    odometry(&buffer);
    let map_cam = iso([3.0, -1.0, 1.5], [0.2, 1.0, -0.3], 0.7);
    let mut first = TfBroadcast::new(&params(TfMode::MapToOdom), buffer.clone());
    let mut other = TfBroadcast::new(&params(TfMode::MapToOdom), buffer.clone()).without_map_to_odom();
    let sent = first.for_frame(10 * S, CAM, "map", &map_cam, true);
    assert_eq!(sent.kind, Some("map_to_odom"));
    let quiet = other.for_frame(10 * S, CAM, "map", &map_cam, true);
    assert!(quiet.tf.is_none() && quiet.kind.is_none() && quiet.problems.is_empty(), "{quiet:?}");
    assert!(quiet.base_pose.is_some(), "its base pose is still published");
    assert_eq!(other.republish(11 * S), None, "nothing to re-send");
    // map → camera names the camera's own frame: every camera sends its own.
    let mut own = TfBroadcast::new(&params(TfMode::MapToCamera), buffer).without_map_to_odom();
    assert_eq!(own.for_frame(10 * S, CAM, "map", &map_cam, true).kind, Some("map_to_camera"));
}
