//! The live node under heavy and hostile traffic (#38): storms and floods over DDS, inside a
//! private network namespace, each into a fresh node (the good map loaded first, then the attack)
//! so that no case leans on what an earlier one left. After each: a good frame gets its pose
//! promptly; the node still localizes a real bag's 20 frames (the shipped synthetic bag's without
//! the shared data), at least 18 and none more than 10 cm off, so no map that is not a map
//! replaced the good one; the flood is counted; and the node's peak memory stays under a stated
//! bound (a clean node holds ~60–110 MB).

use std::process::Command;
use std::time::{Duration, Instant};

use angle_i2p::bag::{read_frames, TopicMap};
use angle_i2p::frame::{Frame, MapCloud};
use angle_i2p::msgs::{self, convert};
use angle_i2p::node::dds;
use angle_i2p::params::LocalizerParams;
use angle_i2p::pipeline::Localizer;
use nalgebra::{Isometry3, Matrix6};

use super::live_node::{map_and_good_frame, png, png_declaring, read, start_node, Parts, Wire, DOMAIN};
use crate::common::manifest;
use crate::netns::{self, mark_done, run_in_netns, wait_bounded};

/// Peak resident memory the node may reach through every flood below (#38's bound).
const MAX_PEAK_RSS_MB: u64 = 512;
/// How long after a storm a good frame may wait for its pose. The node answers in well under a
/// second when idle; the bound leaves room for a loaded test machine and is printed as measured.
const RESPONSIVE_WITHIN: Duration = Duration::from_secs(5);
/// Of the shipped bag's 20 frames sent after a case, at least this many get a pose (#38).
const MIN_LOCALIZED_AFTER: usize = 18;
/// No pose after a case is further than this from the ground truth (#38), metres.
const MAX_POSE_ERROR_M: f64 = 0.10;

#[test]
fn live_node_stays_bounded_and_responsive_under_floods() {
    run_in_netns("live_floods::inner_live_node_floods");
}

/// The node's peak resident set (VmHWM), MB; 0 when /proc cannot tell.
fn peak_rss_mb(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let line = status.lines().find(|l| l.starts_with("VmHWM:")).unwrap_or("");
    line.split_whitespace().nth(1).and_then(|kb| kb.parse::<u64>().ok()).map_or(0, |kb| kb / 1024)
}

/// Sends the good frame at `stamp` and returns how long its pose took to come back.
fn good_frame_answers(wire: &Wire, good: &Frame, stamp: i64, log: &std::path::Path) -> Duration {
    let start = Instant::now();
    Parts::of(good, stamp).publish(wire);
    wire.wait_pose(stamp, log);
    start.elapsed()
}

/// A map cloud of `points` (a cloud of no point, or of every point NaN, is not a map).
fn cloud(points: Vec<nalgebra::Point3<f32>>) -> msgs::PointCloud2 {
    convert::point_cloud(0, &MapCloud { points, frame_id: "map".into() })
}

/// One `/tf` message of `n` transforms, child frames `flood_{first}…`, stamped `stamp`.
fn tf_message(first: usize, n: usize, stamp: i64) -> msgs::TFMessage {
    let transforms = (first..first + n)
        .map(|k| msgs::TransformStamped {
            header: msgs::Header::new(stamp, "map"),
            child_frame_id: format!("flood_{}", k % 5000),
            transform: msgs::Transform {
                translation: msgs::Vector3 { x: k as f64 * 1e-3, y: 0.0, z: 0.0 },
                rotation: msgs::Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 },
            },
        })
        .collect();
    msgs::TFMessage { transforms }
}

/// One hostile case: what it sends to a node holding the good map, then waits to be counted.
type Attack = fn(&mut Wire, &Scene, &std::path::Path);

/// What every case sends with: the good map, a frame that localizes, the bag's frames.
struct Scene {
    map: MapCloud,
    good: Frame,
    frames: Vec<Frame>,
}

impl Scene {
    /// Stamp `k` seconds after the good frame's.
    fn at(&self, k: i64) -> i64 {
        self.good.stamp + k * 1_000_000_000
    }
}

/// The scene of a real bag, redkitchen-hard-val (a 203 k-point map, 20 frames) where the shared
/// data is; else the shipped synthetic hard bag (the real-bag check recorded as skipped).
fn scene() -> Scene {
    let (map, good, bag) = match crate::common::shared_bag("redkitchen-hard-val") {
        Some(bag) => {
            let input = read_frames(&bag, &TopicMap::default()).expect("read bag");
            let map = input.map.clone().expect("the bag's map");
            let mut localizer = Localizer::new(LocalizerParams::default()).expect("a localizer");
            localizer.set_map(&map);
            let good =
                input.frames.iter().find(|f| localizer.process(f).pose.is_some()).cloned().expect("a posed frame");
            (map, good, bag)
        }
        None => {
            let (map, good) = map_and_good_frame();
            (map, good, manifest().join("bags/synth-hard"))
        }
    };
    let frames = read_frames(&bag, &TopicMap::default()).expect("read bag").frames;
    assert_eq!(frames.len(), 20, "{}: its frames", bag.display());
    Scene { map, good, frames }
}

/// A map storm: 40 valid maps at 20 Hz, each different (the map less its last k points; the node
/// skips a map equal to the one it holds). One is indexed at a time, the newest supersedes.
fn map_storm(wire: &mut Wire, scene: &Scene, log: &std::path::Path) {
    for k in 1..=40 {
        let points = scene.map.points[..scene.map.points.len() - k].to_vec();
        wire.map_stream.publish(cloud(points)).expect("publish map");
        std::thread::sleep(Duration::from_millis(50));
    }
    wire.wait_diag("maps_received", |v| v >= 30, log);
}

/// Maps that are not maps (no point; every point NaN): counted, none replaces the good one.
fn maps_that_are_not_maps(wire: &mut Wire, _: &Scene, log: &std::path::Path) {
    wire.map_stream.publish(cloud(Vec::new())).expect("publish empty map");
    wire.wait_diag("error.invalid_map", |v| v >= 1, log);
    let nan = nalgebra::Point3::new(f32::NAN, f32::NAN, f32::NAN);
    wire.map_stream.publish(cloud(vec![nan; 1000])).expect("publish NaN map");
    wire.wait_diag("error.invalid_map", |v| v >= 2, log);
}

/// A /tf flood: 300 000 transforms over 5000 frame names in 60 messages, past the buffer's frame
/// and sample budgets: counted, and the memory they may hold is bounded.
fn tf_flood(wire: &mut Wire, scene: &Scene, log: &std::path::Path) {
    for m in 0..60 {
        wire.tf.publish(tf_message(m * 5000, 5000, scene.at(4) + m as i64 * 1_000_000)).expect("publish tf");
    }
    wire.wait_diag("error.invalid_transform", |v| v >= 1, log);
}

/// Camera images: one declaring 8192² (over limits.max_image_pixels) is refused from its header;
/// twenty real 4096² ones (within it) travel compressed and are decoded one at a time.
fn image_flood(wire: &mut Wire, scene: &Scene, log: &std::path::Path) {
    let mut p = Parts::of(&scene.good, scene.at(6));
    p.image.data = png_declaring(8192);
    p.publish(wire);
    wire.wait_diag("error.invalid_image", |v| v >= 1, log);
    let big = png(4096, 4096);
    for k in 0..20 {
        let mut p = Parts::of(&scene.good, scene.at(7 + k));
        p.image.data = big.clone();
        p.publish(wire);
        std::thread::sleep(Duration::from_millis(30));
    }
}

/// A correspondence flood: 30 messages of 50 000 matches each (1.2 MB on the wire, 10× the node's
/// limit): each is held to the limit by its reader, counted, and what waits is bounded.
fn correspondence_flood(wire: &mut Wire, scene: &Scene, log: &std::path::Path) {
    let good = &scene.good;
    let flood: Vec<_> = (0..50_000)
        .map(|k| {
            let mut c = good.correspondences[k % good.correspondences.len()];
            c.pixel.x += (k / good.correspondences.len()) as f64 * 1e-3;
            c
        })
        .collect();
    for k in 0..30 {
        let msg = convert::correspondences_msg(scene.at(40 + k), &good.camera_frame_id, &good.map_frame_id, &flood);
        wire.corr.publish(msg).expect("publish correspondences");
        std::thread::sleep(Duration::from_millis(20));
    }
    wire.wait_diag("error.correspondences_over_limit", |v| v >= 1, log);
}

/// An initial pose in a frame that is not the map's, 100 m off: counted, gates nothing.
fn initial_pose_elsewhere(wire: &mut Wire, scene: &Scene, log: &std::path::Path) {
    let truth = scene.good.ground_truth.as_ref().and_then(|g| g.pose).unwrap_or_else(Isometry3::identity);
    let far = Isometry3::translation(100.0, 0.0, 0.0) * truth;
    let covariance = Matrix6::identity() * 0.01;
    let elsewhere = convert::pose_with_covariance_stamped(scene.at(31), "nowhere", &far, &covariance);
    wire.initialpose.publish(elsewhere).expect("publish initial pose");
    std::thread::sleep(Duration::from_millis(300));
    // Counted when a frame meets it.
    Parts::of(&scene.good, scene.at(32)).publish(wire);
    wire.wait_diag("error.invalid_initialpose", |v| v >= 1, log);
}

/// What a case left: how long the good frame waited, the bag's frames localized and the worst
/// pose error among them, the node's peak memory.
#[derive(Debug)]
struct After {
    answered_in: Duration,
    localized: usize,
    worst_error_m: f64,
    peak_rss_mb: u64,
}

/// The bag's frames after the case, stamped from `first` on at their own spacing: how many get a
/// pose, and the largest distance of one from the ground truth.
fn bag_after(wire: &Wire, scene: &Scene, first: i64) -> (usize, f64) {
    let (mut localized, mut worst) = (0, 0.0f64);
    let origin = scene.frames.first().map_or(0, |f| f.stamp);
    for frame in &scene.frames {
        let stamp = first + (frame.stamp - origin);
        Parts::of(frame, stamp).publish(wire);
        let Some(pose) = wire.pose_of(stamp, Duration::from_secs(3)) else { continue };
        localized += 1;
        if let Some(truth) = frame.ground_truth.as_ref().and_then(|g| g.pose) {
            worst = worst.max((pose.translation.vector - truth.translation.vector).norm());
        }
    }
    (localized, worst)
}

/// A fresh node with the good map, `attack`, then the good frame and the bag: what it left.
fn run_case(name: &str, attack: Attack, scene: &Scene) -> After {
    let tmp = tempfile::tempdir().expect("tmp");
    let log = tmp.path().join("node.log");
    let mut node = start_node(&log, scene.good.correspondences.len() + 50);
    let pid = node.0.id();
    let context = dds::context().expect("context");
    let mut wire = Wire::new(&context);
    wire.wait_matched(&log);
    wire.map.publish(convert::point_cloud(0, &scene.map)).expect("publish map");
    wire.wait_diag("maps_received", |v| v == 1, &log);
    let before = good_frame_answers(&wire, &scene.good, scene.at(1), &log);
    eprintln!("{name}: a good frame answered in {before:?} before the attack");
    attack(&mut wire, scene, &log);
    let answered_in = good_frame_answers(&wire, &scene.good, scene.at(100), &log);
    let (localized, worst_error_m) = bag_after(&wire, scene, scene.at(101));
    let after = After { answered_in, localized, worst_error_m, peak_rss_mb: peak_rss_mb(pid) };
    eprintln!("{name}: {after:?}");
    assert!(matches!(node.0.try_wait(), Ok(None)), "{name}: the node exited\n{}", read(&log));
    let _ = Command::new("kill").args(["-INT", &pid.to_string()]).status();
    let status = wait_bounded(&mut node.0, Duration::from_secs(40)).expect("node did not stop on SIGINT");
    assert!(status.success(), "{name}: node exit {status}\n{}", read(&log));
    let log_text = read(&log);
    assert!(after.answered_in <= RESPONSIVE_WITHIN, "{name}: a good frame waited {:?}\n{log_text}", after.answered_in);
    assert!(after.localized >= MIN_LOCALIZED_AFTER, "{name}: {after:?}\n{log_text}");
    assert!(after.worst_error_m <= MAX_POSE_ERROR_M, "{name}: {after:?}\n{log_text}");
    assert!(after.peak_rss_mb <= MAX_PEAK_RSS_MB, "{name}: peak RSS {} MB\n{log_text}", after.peak_rss_mb);
    after
}

#[test]
#[ignore = "runs inside a network namespace, via live_node_stays_bounded_and_responsive_under_floods"]
fn inner_live_node_floods() {
    netns::enter_netns("live_node_stays_bounded_and_responsive_under_floods", DOMAIN);
    let scene = scene();
    let cases: [(&str, Attack); 6] = [
        ("map storm", map_storm),
        ("maps that are not maps", maps_that_are_not_maps),
        ("tf flood", tf_flood),
        ("image flood", image_flood),
        ("correspondence flood", correspondence_flood),
        ("initial pose elsewhere", initial_pose_elsewhere),
    ];
    for (name, attack) in cases {
        run_case(name, attack, &scene);
    }
    mark_done();
}
