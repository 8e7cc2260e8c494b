//! Tests of the frame assembler (`src/frame/assembler.rs`): every call given its `now`, so
//! time-outs and windows are tested without sleeping.

use super::*;

fn info(stamp: Stamp) -> FramePart {
    let intrinsics =
        crate::geometry::Intrinsics { fx: 500.0, fy: 500.0, cx: 320.0, cy: 240.0, width: 640, height: 480 };
    FramePart::CameraInfo { stamp, camera: crate::camera::CameraModel::pinhole(intrinsics) }
}

fn corr(stamp: Stamp) -> FramePart {
    FramePart::Correspondences {
        stamp,
        camera_frame_id: "cam".into(),
        map_frame_id: "map".into(),
        correspondences: vec![],
    }
}

#[test]
fn completes_when_expected_parts_arrive_in_any_order() {
    let mut a = FrameAssembler::new(&[PartKind::DepthPrior]);
    assert!(a.push(corr(2), 0).is_none());
    assert!(a.push(info(1), 0).is_none());
    assert!(a.push(info(2), 0).is_none());
    let done = a.push(FramePart::DepthPrior { stamp: 2, depth: DepthImage::new(1, 1, vec![1.0]) }, 0);
    match done {
        Some(Assembled::Complete(f)) => {
            assert_eq!(f.stamp, 2);
            assert_eq!(f.camera_frame_id, "cam");
            assert!(f.depth_prior.is_some());
        }
        other => panic!("{other:?}"),
    }
    let rest = a.finish(0);
    assert_eq!(rest.len(), 1);
    match &rest[0] {
        Assembled::Dropped(r) => {
            assert_eq!(r.stamp, 1);
            assert_eq!(r.missing, vec!["correspondences", "depth_prior"]);
            assert!(r.dropped);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn decode_errors_resolve_the_part_and_are_reported() {
    let mut a = FrameAssembler::new(&[PartKind::GroundTruthPose]);
    a.push(info(5), 0);
    a.push(corr(5), 0);
    match a.push_error(5, PartKind::GroundTruthPose, "bad quaternion", 0) {
        Some(Assembled::Partial(f, r)) => {
            assert_eq!(f.stamp, 5);
            assert_eq!(r.missing, vec!["ground_truth_pose"]);
            assert_eq!(r.errors, vec!["ground_truth_pose: bad quaternion".to_string()]);
            assert!(!r.dropped);
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(a.pending(), 0);
}

#[test]
fn late_parts_and_repeated_stamps_are_named_only_when_asked() {
    let mut a = FrameAssembler::new(&[]).with_repeat_detection();
    assert!(matches!(a.push(info(7), 0), None));
    assert!(matches!(a.push(corr(7), 0), Some(Assembled::Complete(_))));
    assert!(a.push(corr(7), 0).is_none(), "a late part waits: a repeat may follow");
    match a.push(info(7), 0) {
        Some(Assembled::Dropped(r)) => {
            assert!(r.repeat && r.errors[0].contains("repeated stamp"), "{r:?}")
        }
        other => panic!("{other:?}"),
    }
    a.push(corr(7), 0);
    match a.finish(0).as_slice() {
        [Assembled::Dropped(r)] => assert!(r.repeat && r.errors[0].contains("late part (correspondences)")),
        other => panic!("{other:?}"),
    }
    // Without detection (the live node) the same stamp later is a new frame.
    let mut live = FrameAssembler::new(&[]);
    live.push(info(7), 0);
    live.push(corr(7), 0);
    live.push(info(7), 0);
    assert!(matches!(live.push(corr(7), 0), Some(Assembled::Complete(_))));
}

#[test]
fn negative_stamps_are_skipped_with_their_reason() {
    let mut a = FrameAssembler::new(&[]);
    a.push(info(-3), 0);
    match a.push(corr(-3), 0) {
        Some(Assembled::Dropped(r)) => assert!(r.errors[0].contains("negative header.stamp -3")),
        other => panic!("{other:?}"),
    }
}

#[test]
fn expire_hands_out_frames_waiting_past_the_arrival_timeout() {
    let mut a = FrameAssembler::new(&[PartKind::Image]).with_arrival_timeout(500);
    a.push(info(100), 0);
    a.push(corr(100), 10);
    a.push(info(1), 400);
    assert!(a.expire(499).is_empty(), "nothing waited 500 ns yet");
    let out = a.expire(500);
    assert_eq!(out.len(), 1);
    let (frames, reports) = Assembled::split(out);
    assert_eq!(frames[0].stamp, 100, "arrival decides, not the stamp");
    assert_eq!(reports[0].missing, vec!["image"]);
    assert!(reports[0].errors[0].contains("timed out"));
    assert_eq!(a.pending(), 1);
    assert!(FrameAssembler::new(&[]).expire(i64::MAX).is_empty(), "no time-out: frames wait for finish");
}

#[test]
fn stamp_tolerance_joins_the_nearest_waiting_frame() {
    let mut a = FrameAssembler::new(&[PartKind::DepthPrior]).with_stamp_tolerance(1000);
    a.push(info(5_000), 0);
    a.push(corr(5_400), 0);
    let prior = FramePart::DepthPrior { stamp: 4_200, depth: DepthImage::new(1, 1, vec![1.0]) };
    match a.push(prior, 0) {
        Some(Assembled::Complete(f)) => assert_eq!(f.stamp, 5_000),
        other => panic!("{other:?}"),
    }
    assert_eq!((a.pending(), a.frames_opened()), (0, 1));
    let mut exact = FrameAssembler::new(&[]);
    exact.push(info(5_000), 0);
    exact.push(corr(5_400), 0);
    assert_eq!((exact.pending(), exact.frames_opened()), (2, 2));
}

#[test]
fn a_live_window_names_late_parts_then_forgets_the_stamp() {
    let mut a = FrameAssembler::new(&[]).with_repeat_window(1_000).with_arrival_timeout(300);
    a.push(info(7), 0);
    assert!(matches!(a.push(corr(7), 0), Some(Assembled::Complete(_))));
    assert!(a.push(corr(7), 100).is_none(), "a late part waits: a repeat may follow");
    assert_eq!(a.frames_opened(), 1, "a late part opens no frame");
    match a.expire(400).as_slice() {
        [Assembled::Dropped(r)] => assert!(r.repeat && r.late_parts && r.errors[0].contains("late part")),
        other => panic!("{other:?}"),
    }
    a.push(info(7), 500);
    match a.push(corr(7), 500) {
        Some(Assembled::Dropped(r)) => assert!(r.repeat && !r.late_parts && r.errors[0].contains("repeated stamp")),
        other => panic!("{other:?}"),
    }
    // Past the window (a restarted player) the same stamp is a new frame.
    a.push(info(7), 2_000);
    assert!(matches!(a.push(corr(7), 2_000), Some(Assembled::Complete(_))));
    assert_eq!(a.frames_opened(), 2);
}
