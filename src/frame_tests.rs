//! Tests of the frame assembler (`src/frame.rs`).

use super::*;

fn info(stamp: Stamp) -> FramePart {
    let intrinsics = Intrinsics { fx: 500.0, fy: 500.0, cx: 320.0, cy: 240.0, width: 640, height: 480 };
    FramePart::CameraInfo { stamp, intrinsics }
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
    assert!(a.push(corr(2)).is_none());
    assert!(a.push(info(1)).is_none());
    assert!(a.push(info(2)).is_none());
    let done = a.push(FramePart::DepthPrior { stamp: 2, depth: DepthImage::new(1, 1, vec![1.0]) });
    match done {
        Some(Assembled::Complete(f)) => {
            assert_eq!(f.stamp, 2);
            assert_eq!(f.camera_frame_id, "cam");
            assert!(f.depth_prior.is_some());
        }
        other => panic!("{other:?}"),
    }
    let rest = a.finish();
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
    a.push(info(5));
    a.push(corr(5));
    match a.push_error(5, PartKind::GroundTruthPose, "bad quaternion") {
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
    assert!(matches!(a.push(info(7)), None));
    assert!(matches!(a.push(corr(7)), Some(Assembled::Complete(_))));
    assert!(a.push(corr(7)).is_none(), "a late part waits: a repeat may follow");
    match a.push(info(7)) {
        Some(Assembled::Dropped(r)) => {
            assert!(r.repeat && r.errors[0].contains("repeated stamp"), "{r:?}")
        }
        other => panic!("{other:?}"),
    }
    a.push(corr(7));
    match a.finish().as_slice() {
        [Assembled::Dropped(r)] => assert!(r.repeat && r.errors[0].contains("late part (correspondences)")),
        other => panic!("{other:?}"),
    }
    // Without detection (the live node) the same stamp later is a new frame.
    let mut live = FrameAssembler::new(&[]);
    live.push(info(7));
    live.push(corr(7));
    live.push(info(7));
    assert!(matches!(live.push(corr(7)), Some(Assembled::Complete(_))));
}

#[test]
fn negative_stamps_are_skipped_with_their_reason() {
    let mut a = FrameAssembler::new(&[]);
    a.push(info(-3));
    match a.push(corr(-3)) {
        Some(Assembled::Dropped(r)) => assert!(r.errors[0].contains("negative header.stamp -3")),
        other => panic!("{other:?}"),
    }
}

#[test]
fn expire_hands_out_old_frames_only() {
    let mut a = FrameAssembler::new(&[PartKind::Image]);
    a.push(info(100));
    a.push(corr(100));
    a.push(info(1_000_000_000));
    let out = a.expire(1_000_000_000, 500_000_000);
    assert_eq!(out.len(), 1);
    let (frames, reports) = Assembled::split(out);
    assert_eq!(frames.len(), 1);
    assert_eq!(reports[0].missing, vec!["image"]);
    assert!(reports[0].errors[0].contains("timed out"));
    assert_eq!(a.pending(), 1);
}
