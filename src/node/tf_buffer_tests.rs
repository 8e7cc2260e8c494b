use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use super::*;
use crate::node::tf::{map_to_odom, tf_message};

/// A transform from a translation and a rotation about `axis` (shared with the TF tests).
pub(crate) fn iso(t: [f64; 3], axis: [f64; 3], angle: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_scaled_axis(Vector3::from(axis).normalize() * angle),
    )
}

pub(crate) fn close(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
    (a.translation.vector - b.translation.vector).norm() < 1e-9 && a.rotation.angle_to(&b.rotation) < 1e-9
}

const S: i64 = 1_000_000_000;

/// odom → base_link moving along x at 1 m/s (a sample every 100 ms from t = 10 s), and a static
/// base_link → camera_link → camera_color_optical_frame.
fn robot() -> (TfHistory, Isometry3<f64>) {
    let mut tf = TfHistory::default();
    for i in 0..=20 {
        let t = 10 * S + i * S / 10;
        let odom_base = iso([t as f64 / S as f64, 0.0, 0.0], [0.0, 0.0, 1.0], 0.01 * i as f64);
        assert!(tf.update(&tf_message(t, "odom", "base_link", &odom_base), false).is_empty());
    }
    let base_link = iso([0.2, 0.0, 0.4], [0.0, 1.0, 0.0], 0.1);
    let optical = iso([0.0, 0.03, 0.0], [1.0, -1.0, 1.0], 2.09);
    assert!(tf.update(&tf_message(0, "base_link", "camera_link", &base_link), true).is_empty());
    assert!(tf.update(&tf_message(0, "/camera_link", "camera_color_optical_frame", &optical), true).is_empty());
    (tf, base_link * optical)
}

#[test]
fn looks_up_a_chain_at_a_stamp_between_samples() {
    let (tf, base_camera) = robot();
    // 10.25 s lies between the samples at 10.2 and 10.3 s: halfway in x and in yaw.
    let at = 10 * S + S / 4;
    let got = tf.lookup("odom", "camera_color_optical_frame", at).unwrap();
    let odom_base = iso([10.25, 0.0, 0.0], [0.0, 0.0, 1.0], 0.025);
    assert!(close(&got, &(odom_base * base_camera)), "{got} vs {}", odom_base * base_camera);
    // On a sample it is that sample.
    let on = tf.lookup("odom", "base_link", 10 * S + 3 * S / 10).unwrap();
    assert!(close(&on, &iso([10.3, 0.0, 0.0], [0.0, 0.0, 1.0], 0.03)));
}

#[test]
fn looks_up_across_branches_and_inverse_directions() {
    let (mut tf, base_camera) = robot();
    let base_lidar = iso([0.0, 0.0, 1.0], [0.0, 0.0, 1.0], 3.0);
    tf.update(&tf_message(0, "base_link", "lidar", &base_lidar), true);
    let at = 11 * S;
    let camera_lidar = tf.lookup("camera_color_optical_frame", "lidar", at).unwrap();
    assert!(close(&camera_lidar, &(base_camera.inverse() * base_lidar)));
    let base_odom = tf.lookup("base_link", "odom", at).unwrap();
    assert!(close(&base_odom, &tf.lookup("odom", "base_link", at).unwrap().inverse()));
    assert!(close(&tf.lookup("lidar", "lidar", at).unwrap(), &Isometry3::identity()));
}

#[test]
fn refuses_to_extrapolate_and_names_what_is_missing() {
    let (mut tf, _) = robot();
    let late = 12 * S + 1;
    assert_eq!(
        tf.lookup("odom", "camera_color_optical_frame", late),
        Err(TfLookupError::Extrapolation {
            parent: "odom".into(),
            child: "base_link".into(),
            stamp: late,
            oldest: 10 * S,
            newest: 12 * S
        })
    );
    assert_eq!(tf.lookup("map", "base_link", 11 * S), Err(TfLookupError::UnknownFrame { frame: "map".into() }));
    tf.update(&tf_message(0, "world", "other", &Isometry3::identity()), true);
    assert_eq!(
        tf.lookup("odom", "other", 11 * S),
        Err(TfLookupError::NotConnected { parent: "odom".into(), child: "other".into() })
    );
}

#[test]
fn history_is_bounded_by_the_cache_time() {
    let mut tf = TfHistory::default();
    for i in 0..400 {
        tf.update(&tf_message(i * S / 10, "odom", "base_link", &Isometry3::identity()), false);
    }
    // 40 s heard, 10 s kept.
    assert!(tf.lookup("odom", "base_link", 20 * S).is_err());
    assert!(tf.lookup("odom", "base_link", 35 * S).is_ok());
    assert!(tf.links["base_link"].samples.len() <= 101);
}

#[test]
fn bad_transforms_are_reported_and_a_reparented_frame_starts_anew() {
    let mut tf = TfHistory::default();
    let mut nan = tf_message(S, "odom", "base_link", &Isometry3::identity());
    nan.transforms[0].transform.translation.x = f64::NAN;
    assert_eq!(tf.update(&nan, false).len(), 1);
    assert_eq!(tf.update(&tf_message(S, "", "base_link", &Isometry3::identity()), false).len(), 1);
    assert_eq!(tf.update(&tf_message(S, "a", "a", &Isometry3::identity()), false).len(), 1);
    tf.update(&tf_message(S, "odom", "base_link", &Isometry3::identity()), false);
    tf.update(&tf_message(2 * S, "map", "base_link", &Isometry3::identity()), false);
    assert!(matches!(tf.lookup("odom", "base_link", 2 * S), Err(TfLookupError::UnknownFrame { .. })));
    assert!(tf.lookup("map", "base_link", 2 * S).is_ok());
}

#[test]
fn a_loop_in_the_tree_ends_the_walk() {
    let mut tf = TfHistory::default();
    tf.update(&tf_message(0, "a", "b", &Isometry3::identity()), true);
    tf.update(&tf_message(0, "b", "a", &Isometry3::identity()), true);
    tf.update(&tf_message(0, "x", "y", &Isometry3::identity()), true);
    assert!(tf.lookup("a", "y", 0).is_err());
}

#[test]
fn a_slack_takes_the_newest_sample_a_little_after_it() {
    let mut tf = TfHistory::with_slack(S / 10);
    tf.update(&tf_message(S, "odom", "base_link", &iso([1.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.0)), false);
    let got = tf.lookup("odom", "base_link", S + S / 20).unwrap();
    assert!(close(&got, &iso([1.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.0)));
    assert!(matches!(tf.lookup("odom", "base_link", S + S / 5), Err(TfLookupError::Extrapolation { .. })));
}

#[test]
fn map_to_odom_composes_with_odom_to_camera_into_map_to_camera() {
    let map_camera = iso([1.0, -2.0, 0.5], [0.2, 1.0, -0.3], 0.7);
    let odom_camera = iso([0.3, 0.1, 1.2], [1.0, 0.0, 0.4], -1.1);
    let map_odom = map_to_odom(&map_camera, &odom_camera);
    assert!(close(&(map_odom * odom_camera), &map_camera));
    // A point seen by the camera lands at the same map point either way.
    let p = nalgebra::Point3::new(0.4, -0.2, 2.0);
    assert!(((map_odom * (odom_camera * p)) - map_camera * p).norm() < 1e-9);
    // Identity odom → camera: map → odom is the camera pose itself.
    assert!(close(&map_to_odom(&map_camera, &Isometry3::identity()), &map_camera));
}

#[test]
fn tf_message_carries_the_transform() {
    let t = iso([1.0, 2.0, 3.0], [0.0, 0.0, 1.0], 0.3);
    let m = tf_message(42, "map", "odom", &t);
    let ts = &m.transforms[0];
    assert_eq!((ts.header.frame_id.as_str(), ts.child_frame_id.as_str()), ("map", "odom"));
    assert_eq!(ts.header.stamp.to_nanos(), 42);
    let mut buf = TfHistory::default();
    buf.update(&m, false);
    assert!(close(&buf.lookup("map", "odom", 42).unwrap(), &t));
}

/// A transform that would close a loop in the tree is refused and named (#38), and the tree
/// stays as it was: a → b → a once made the node believe in a frame above the map.
#[test]
fn a_transform_that_closes_a_loop_is_refused() {
    let (mut tf, base_camera) = robot();
    let camera = "camera_color_optical_frame";
    let before = tf.lookup("base_link", camera, 0).expect("the chain");
    let bad = tf.update(&tf_message(0, camera, "base_link", &iso([1.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.0)), true);
    assert_eq!(bad.len(), 1, "{bad:?}");
    assert!(bad[0].contains("loop"), "{bad:?}");
    let bad = tf.update(&tf_message(10 * S, "base_link", "odom", &iso([0.0; 3], [0.0, 0.0, 1.0], 0.0)), false);
    assert!(bad.iter().any(|b| b.contains("loop")), "{bad:?}");
    assert!(close(&tf.lookup("base_link", camera, 0).expect("the chain, unchanged"), &before));
    assert!(close(&before, &base_camera));
}
