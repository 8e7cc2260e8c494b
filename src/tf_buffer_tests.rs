use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use super::*;
use crate::msgs::convert::transform_message;
use crate::node::tf::map_to_odom;

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
        assert!(tf.update(&transform_message(t, "odom", "base_link", &odom_base), false).is_empty());
    }
    let base_link = iso([0.2, 0.0, 0.4], [0.0, 1.0, 0.0], 0.1);
    let optical = iso([0.0, 0.03, 0.0], [1.0, -1.0, 1.0], 2.09);
    assert!(tf.update(&transform_message(0, "base_link", "camera_link", &base_link), true).is_empty());
    assert!(tf.update(&transform_message(0, "/camera_link", "camera_color_optical_frame", &optical), true).is_empty());
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
    tf.update(&transform_message(0, "base_link", "lidar", &base_lidar), true);
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
    tf.update(&transform_message(0, "world", "other", &Isometry3::identity()), true);
    assert_eq!(
        tf.lookup("odom", "other", 11 * S),
        Err(TfLookupError::NotConnected { parent: "odom".into(), child: "other".into() })
    );
}

#[test]
fn history_is_bounded_by_the_cache_time() {
    let mut tf = TfHistory::default();
    for i in 0..400 {
        tf.update(&transform_message(i * S / 10, "odom", "base_link", &Isometry3::identity()), false);
    }
    // 40 s heard, 10 s kept.
    assert!(tf.lookup("odom", "base_link", 20 * S).is_err());
    assert!(tf.lookup("odom", "base_link", 35 * S).is_ok());
    assert!(tf.links["base_link"].samples.len() <= 101);
}

#[test]
fn bad_transforms_are_reported_and_a_reparented_frame_starts_anew() {
    let mut tf = TfHistory::default();
    let mut nan = transform_message(S, "odom", "base_link", &Isometry3::identity());
    nan.transforms[0].transform.translation.x = f64::NAN;
    assert_eq!(tf.update(&nan, false).len(), 1);
    assert_eq!(tf.update(&transform_message(S, "", "base_link", &Isometry3::identity()), false).len(), 1);
    assert_eq!(tf.update(&transform_message(S, "a", "a", &Isometry3::identity()), false).len(), 1);
    let long = "x".repeat(MAX_FRAME_ID_BYTES + 1);
    let bad = tf.update(&transform_message(S, "odom", &long, &Isometry3::identity()), false);
    assert!(bad.len() == 1 && bad[0].contains("4 and 257 bytes"), "{bad:?}");
    assert!(!tf.knows(&long));
    tf.update(&transform_message(S, "odom", "base_link", &Isometry3::identity()), false);
    tf.update(&transform_message(2 * S, "map", "base_link", &Isometry3::identity()), false);
    assert!(matches!(tf.lookup("odom", "base_link", 2 * S), Err(TfLookupError::UnknownFrame { .. })));
    assert!(tf.lookup("map", "base_link", 2 * S).is_ok());
}

#[test]
fn a_loop_in_the_tree_ends_the_walk() {
    let mut tf = TfHistory::default();
    tf.update(&transform_message(0, "a", "b", &Isometry3::identity()), true);
    tf.update(&transform_message(0, "b", "a", &Isometry3::identity()), true);
    tf.update(&transform_message(0, "x", "y", &Isometry3::identity()), true);
    assert!(tf.lookup("a", "y", 0).is_err());
}

#[test]
fn a_slack_takes_the_newest_sample_a_little_after_it() {
    let mut tf = TfHistory::with_slack(S / 10);
    tf.update(&transform_message(S, "odom", "base_link", &iso([1.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.0)), false);
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
fn transform_message_carries_the_transform() {
    let t = iso([1.0, 2.0, 3.0], [0.0, 0.0, 1.0], 0.3);
    let m = transform_message(42, "map", "odom", &t);
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
    let bad = tf.update(&transform_message(0, camera, "base_link", &iso([1.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.0)), true);
    assert_eq!(bad.len(), 1, "{bad:?}");
    assert!(bad[0].contains("loop"), "{bad:?}");
    let bad = tf.update(&transform_message(10 * S, "base_link", "odom", &iso([0.0; 3], [0.0, 0.0, 1.0], 0.0)), false);
    assert!(bad.iter().any(|b| b.contains("loop")), "{bad:?}");
    assert!(close(&tf.lookup("base_link", camera, 0).expect("the chain, unchanged"), &before));
    assert!(close(&before, &base_camera));
}

/// One message with a transform for each `(parent, child)` at `stamp`.
fn tf_batch(stamp: Stamp, links: impl IntoIterator<Item = (String, String)>) -> TFMessage {
    let transforms = links
        .into_iter()
        .flat_map(|(parent, child)| transform_message(stamp, &parent, &child, &Isometry3::identity()).transforms)
        .collect();
    TFMessage { transforms }
}

/// Samples and deque capacity over every history, counted (the buffer keeps its own count).
fn held(tf: &TfHistory) -> (usize, usize) {
    tf.links.values().fold((0, 0), |(n, cap), l| (n + l.samples.len(), cap + l.samples.capacity()))
}

/// A /tf flood over more than MAX_FRAMES names, 100 samples each (the #38 storm held ~1.2 GB):
/// the buffer stays within MAX_TOTAL_SAMPLES, its deques within 4× that (64 MB), every frame
/// keeps its newest sample, and each message says so in at most one line per kind.
#[test]
fn a_flood_over_max_frames_names_stays_within_the_total_budget() {
    let mut tf = TfHistory::default();
    let names = || (0..MAX_FRAMES + 100).map(|i| ("odom".to_string(), format!("flood_{i}")));
    let mut eviction_lines = 0;
    for k in 0..100 {
        let report = tf.update(&tf_batch(k * S / 100, names()), false);
        assert!(report.len() <= 2, "one summary line per kind, not per sample: {} lines", report.len());
        assert!(report.iter().any(|l| l.contains("100 transforms of new frames")), "{report:?}");
        eviction_lines += report.iter().filter(|l| l.contains("evicted")).count();
    }
    let (samples, capacity) = held(&tf);
    assert_eq!(samples, tf.samples());
    assert!(samples <= MAX_TOTAL_SAMPLES, "{samples} samples held");
    assert!(capacity <= 4 * MAX_TOTAL_SAMPLES + 4 * MAX_FRAMES, "deque capacity {capacity}");
    assert_eq!(tf.links.len(), MAX_FRAMES);
    assert_eq!(tf.evicted() as usize, MAX_FRAMES * 100 - samples);
    assert!((1..=100).contains(&eviction_lines), "{eviction_lines}");
    // Evicted evenly across the equal histories; the newest sample of each is still there.
    let lens: Vec<usize> = tf.links.values().map(|l| l.samples.len()).collect();
    let (min, max) = (lens.iter().min().copied().unwrap_or(0), lens.iter().max().copied().unwrap_or(0));
    assert!(min >= 1 && max - min <= 1, "{min}..{max}");
    assert!(tf.lookup("odom", "flood_7", 99 * S / 100).is_ok());
}

/// Over the budget the longest history loses its oldest samples; the shorter and the static
/// ones keep theirs, and the eviction is counted and said.
#[test]
fn eviction_takes_from_the_longest_history_and_is_reported() {
    let mut tf = TfHistory::with_budget(100);
    let ms = S / 1000;
    for i in 0..60 {
        assert!(tf.update(&transform_message(i * ms, "odom", "long", &Isometry3::identity()), false).is_empty());
    }
    for i in 0..30 {
        assert!(tf.update(&transform_message(i * ms, "odom", "short", &Isometry3::identity()), false).is_empty());
    }
    assert!(tf.update(&transform_message(0, "long", "cam", &Isometry3::identity()), true).is_empty());
    for i in 30..39 {
        assert!(tf.update(&transform_message(i * ms, "odom", "short", &Isometry3::identity()), false).is_empty());
    }
    assert_eq!((tf.samples(), tf.evicted()), (100, 0), "at the budget, nothing evicted yet");
    // One more: 101 > 100, down to the low-water mark 94: the 7 oldest of `long` go.
    let report = tf.update(&transform_message(39 * ms, "odom", "short", &Isometry3::identity()), false);
    assert_eq!(report.len(), 1, "{report:?}");
    assert!(report[0].contains("evicted the 7 oldest") && report[0].contains("\"long\""), "{report:?}");
    assert!(report[0].contains("budget of 100") && report[0].contains("7 evicted since the start"), "{report:?}");
    assert_eq!((tf.samples(), tf.evicted()), (94, 7));
    let len = |f: &str| tf.links[f].samples.len();
    assert_eq!((len("long"), len("short"), len("cam")), (53, 40, 1));
    assert!(
        matches!(tf.lookup("odom", "long", 6 * ms), Err(TfLookupError::Extrapolation { oldest, .. }) if oldest == 7 * ms)
    );
    assert!(tf.lookup("odom", "cam", 7 * ms).is_ok());
    assert!(tf.lookup("odom", "short", 0).is_ok());
}

/// A real robot — 200 moving frames at 100 Hz for 12 s (10 s cached) — fits the budget whole:
/// nothing evicted, and lookups still interpolate.
#[test]
fn a_real_robot_fits_the_budget_and_still_interpolates() {
    let mut tf = TfHistory::default();
    let frames = || (0..200).map(|i| ("odom".to_string(), format!("link_{i}")));
    for k in 0..1200 {
        let t = k * S / 100;
        let mut msg = tf_batch(t, frames());
        // link_0 moves along x at 1 m/s.
        msg.transforms[0] =
            transform_message(t, "odom", "link_0", &iso([t as f64 / S as f64, 0.0, 0.0], [0.0, 0.0, 1.0], 0.0))
                .transforms
                .remove(0);
        assert!(tf.update(&msg, false).is_empty());
    }
    assert_eq!(tf.evicted(), 0);
    assert_eq!(tf.samples(), 200 * 1001, "10 s at 100 Hz, both ends");
    let got = tf.lookup("odom", "link_0", 11 * S + S / 200).expect("between two samples");
    assert!(close(&got, &iso([11.005, 0.0, 0.0], [0.0, 0.0, 1.0], 0.0)), "{got}");
    let (robot, _) = robot();
    assert_eq!((robot.samples(), robot.evicted()), (21 + 2, 0));
}

/// A 1 kHz burst that then ages out gives its deque's memory back.
#[test]
fn a_history_that_ages_out_gives_its_memory_back() {
    let mut tf = TfHistory::default();
    for i in 0..MAX_SAMPLES as i64 {
        tf.update(&transform_message(i * S / 1000, "odom", "base_link", &Isometry3::identity()), false);
    }
    assert!(tf.links["base_link"].samples.capacity() >= MAX_SAMPLES);
    tf.update(&transform_message(30 * S, "odom", "base_link", &Isometry3::identity()), false);
    let link = &tf.links["base_link"];
    assert_eq!((link.samples.len(), tf.samples()), (1, 1));
    assert!(link.samples.capacity() < 16, "capacity {} kept after aging out", link.samples.capacity());
}

#[test]
fn the_water_level_cuts_the_longest_first() {
    assert_eq!(water_level(&[60, 40], 7), 53);
    assert_eq!(water_level(&[60, 40], 25), 37, "at 40 only 20 go; at 37, 23 + 3");
    assert_eq!(water_level(&[10, 10, 10], 3), 9);
    assert_eq!(water_level(&[10, 10, 10], 100), 1, "every history keeps its newest");
    assert_eq!(water_level(&[], 5), 1);
}
