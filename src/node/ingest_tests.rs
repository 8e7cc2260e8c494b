//! Tests of the node's ingest (`src/node/ingest.rs`), on an explicit clock.

use super::*;
use crate::geometry::{DepthImage, Intrinsics};

const MS: MonotonicNs = 1_000_000;

fn ingest(tolerance_ns: i64, timeout_ms: u64, require_map: bool) -> Ingest {
    let rules = IngestRules {
        expected: vec![PartKind::DepthPrior],
        stamp_tolerance_ns: tolerance_ns,
        frame_timeout: Duration::from_millis(timeout_ms),
        require_map,
        limits: InputLimits::default(),
        pixels: Default::default(),
    };
    Ingest::new(rules, Arc::new(DropOldestQueue::new(2)), Arc::new(Mutex::new(Stats::default())))
}

fn info(stamp: Stamp) -> Input {
    let intrinsics = Intrinsics { fx: 500.0, fy: 500.0, cx: 320.0, cy: 240.0, width: 640, height: 480 };
    Input::Part(FramePart::CameraInfo { stamp, camera: crate::camera::CameraModel::pinhole(intrinsics) })
}

fn corr(stamp: Stamp) -> Input {
    Input::Part(FramePart::Correspondences {
        stamp,
        camera_frame_id: "cam".into(),
        map_frame_id: "map".into(),
        correspondences: vec![],
    })
}

fn prior(stamp: Stamp) -> Input {
    Input::Part(FramePart::DepthPrior { stamp, depth: DepthImage::new(1, 1, vec![1.0]) })
}

fn frame(i: &mut Ingest, stamp: Stamp, now: MonotonicNs) {
    for part in [info(stamp), corr(stamp), prior(stamp)] {
        i.on_input(part, now);
    }
}

#[test]
fn tolerant_matching_joins_nearby_stamps() {
    let mut i = ingest(1000, 10_000, false);
    i.on_input(info(5_000), 0);
    i.on_input(corr(5_400), 0);
    i.on_input(prior(4_200), 0);
    assert_eq!(i.queue.len(), 1);
    assert_eq!(i.assembler.pending(), 0);
    let mut exact = ingest(0, 10_000, false);
    exact.on_input(info(5_000), 0);
    exact.on_input(corr(5_400), 0);
    assert_eq!(exact.assembler.pending(), 2);
    assert_eq!(lock(&exact.stats).frames_received, 2);
}

#[test]
fn no_map_timeouts_queue_drops_and_bad_parts_are_counted() {
    let mut i = ingest(0, 100, true);
    for s in [1, 2] {
        frame(&mut i, s, 0);
    }
    assert_eq!(lock(&i.stats).drop_count("no_map"), 2);
    let map = MapCloud { frame_id: "map".into(), points: vec![] };
    i.on_input(Input::Map(Ok(DecodedMap { map, notes: vec!["no usable point".into()] }), MapSender::File), 0);
    for s in [3, 4, 5] {
        frame(&mut i, s, 0);
    }
    assert_eq!(lock(&i.stats).drop_count("queue_full"), 1);
    assert_eq!(i.queue.len(), 2);
    // Only camera info: times out, dropped for missing correspondences.
    i.on_input(info(6), 10 * MS);
    // Bad correspondences: counted, frame dropped when it times out.
    let bad = Input::PartError { kind: PartKind::Correspondences, stamp: 7, reason: "#0 is not finite".into() };
    i.on_input(bad, 50 * MS);
    i.expire(110 * MS);
    assert_eq!(i.assembler.pending(), 1, "frame 7 waits 100 ms from its first part");
    i.expire(150 * MS);
    assert_eq!(i.assembler.pending(), 0);
    let s = lock(&i.stats);
    assert_eq!(s.drop_count("missing_correspondences"), 1);
    assert_eq!(s.drop_count("missing_camera_info"), 1);
    assert_eq!(s.error_count("invalid_correspondences"), 1);
    assert_eq!(s.error_count("map_cleaned"), 1);
    assert_eq!(s.frames_in, 5);
    // Every frame heard of: dropped (with a reason) or waiting in the queue.
    assert_eq!(s.frames_received, 7);
    assert_eq!(s.frames_received, s.drops.values().sum::<u64>() + i.queue.len() as u64);
}

#[test]
fn late_parts_and_repeated_stamps_are_named_and_a_restart_is_not() {
    let mut i = ingest(0, 100, false);
    frame(&mut i, 1, 0);
    // A late part for frame 1: an error, not a frame.
    i.on_input(corr(1), 20 * MS);
    i.expire(200 * MS);
    // Frame 2 twice in a row: the second is a repeated stamp, skipped.
    frame(&mut i, 2, 200 * MS);
    frame(&mut i, 2, 210 * MS);
    // A player restarted later sends stamp 1 again: a new frame.
    frame(&mut i, 1, 900 * MS);
    let s = lock(&i.stats);
    assert_eq!(s.error_count("late_part"), 1);
    assert_eq!(s.drop_count("repeated_stamp"), 1);
    assert_eq!(s.frames_received, 4);
    assert_eq!((s.frames_in, s.drop_count("queue_full")), (3, 1));
    assert_eq!(s.frames_received, s.drops.values().sum::<u64>() + i.queue.len() as u64);
}

#[test]
fn what_the_limits_change_is_counted_by_name() {
    let limits = InputLimits { max_correspondences: 1, ..InputLimits::default() };
    let rules = IngestRules {
        expected: vec![],
        stamp_tolerance_ns: 0,
        frame_timeout: Duration::from_millis(100),
        require_map: false,
        limits,
        pixels: Default::default(),
    };
    let mut i = Ingest::new(rules, Arc::new(DropOldestQueue::new(2)), Arc::new(Mutex::new(Stats::default())));
    let c = |score: f32| crate::frame::Correspondence {
        pixel: nalgebra::Point2::new(1.0, 2.0 + f64::from(score)),
        point: nalgebra::Point3::new(0.0, 0.0, 1.0),
        score,
    };
    i.on_input(info(1), 0);
    let corr = FramePart::Correspondences {
        stamp: 1,
        camera_frame_id: "cam".into(),
        map_frame_id: "map".into(),
        correspondences: vec![c(0.2), c(0.9)],
    };
    i.on_input(Input::Part(corr), 0);
    assert_eq!(i.queue.len(), 1, "the frame goes on, trimmed");
    assert_eq!(lock(&i.stats).error_count("correspondences_over_limit"), 1);

    // The live node's reader holds a message to the limits itself (a flood of huge messages
    // leaves only the limit waiting): counted once, as at assembly.
    let msg = crate::msgs::convert::correspondences_msg(2, "cam", "map", &[c(0.2), c(0.9), c(0.5)]);
    let (part, fixes) = crate::msgs::convert::correspondences_part_within(msg, &i.limits).expect("converts");
    assert!(matches!(&part, FramePart::Correspondences { correspondences, .. } if correspondences.len() == 1));
    assert_eq!(fixes.over_limit, 2);
    i.on_input(info(2), 0);
    i.on_input(Input::LimitedCorrespondences(part, fixes), 0);
    assert_eq!(i.queue.len(), 2);
    assert_eq!(lock(&i.stats).error_count("correspondences_over_limit"), 2);
}

/// A depth prior without one finite value is counted (#38) and its frame still goes on, as a
/// frame without a usable prior.
#[test]
fn a_prior_without_a_finite_value_is_counted_and_the_frame_goes_on() {
    let mut i = ingest(0, 100, false);
    i.on_input(info(1), 0);
    i.on_input(corr(1), 0);
    i.on_input(
        Input::Part(FramePart::DepthPrior { stamp: 1, depth: DepthImage::new(2, 1, vec![f32::NAN, f32::INFINITY]) }),
        0,
    );
    frame(&mut i, 2, MS);
    let s = lock(&i.stats);
    assert_eq!(s.error_count("unusable_prior"), 1);
    assert_eq!(i.queue.len(), 2, "both frames queued");
}
