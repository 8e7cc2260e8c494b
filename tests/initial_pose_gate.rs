//! The `/initialpose` gate as the live node applies it (#38): set at the first frame's pose,
//! following the camera through a bag, then the bag played again from its start — the camera
//! jumps back, far outside the gate. No published pose may be wrong because of the gate: a frame
//! whose evidence strongly supports a pose outside it publishes nothing and the gate is let go,
//! so that the rest of the replay localizes as without a gate.

use angle_i2p::bag::read_frames;
use angle_i2p::eval::pose_errors;
use angle_i2p::frame::Frame;
use angle_i2p::node::initial_pose::{apply_gate, GateOutcome, InitialPose, PoseGate};
use angle_i2p::params::{LocalizerParams, TopicMap};
use angle_i2p::pipeline::{Failure, Localizer};

mod common;
use common::{manifest, onnx_runtime, shared_bag};

/// The node's default gate around a pose (`node.initialpose_min_radius_m`, `_min_angle_deg`).
fn gate_at(frame: &Frame) -> PoseGate {
    let centre = *frame.ground_truth.as_ref().and_then(|g| g.pose.as_ref()).expect("a ground-truth pose");
    PoseGate { centre, radius_m: 0.5, max_angle_rad: 15f64.to_radians() }
}

/// What one replay with a gate published: per frame, the gate's outcome and, for a published
/// pose, its RMSE-at-depth error (m).
struct Replay {
    outcomes: Vec<GateOutcome>,
    published_errors_m: Vec<f64>,
    frames: usize,
}

/// Plays `frames` twice through one localizer, the gate set at the first frame and applied as
/// the node's worker does.
fn replay_twice(frames: &[Frame], map: &angle_i2p::frame::MapCloud) -> Replay {
    let mut localizer = Localizer::new(LocalizerParams::default()).expect("a localizer");
    localizer.set_map(map);
    let mut initial = Some(InitialPose { frame_id: String::new(), gate: gate_at(&frames[0]) });
    let (mut outcomes, mut published_errors_m) = (Vec::new(), Vec::new());
    for frame in frames.iter().chain(frames) {
        localizer.set_pose_gate(initial.as_ref().map(|i| i.gate.clone()));
        let mut loc = localizer.process(frame);
        outcomes.push(apply_gate(&mut initial, &mut loc));
        let Some(pose) = loc.pose else { continue };
        let gt = frame.ground_truth.as_ref().expect("ground truth");
        let (gt_pose, depth) = (gt.pose.expect("gt pose"), gt.depth.as_ref().expect("gt depth"));
        published_errors_m.push(pose_errors(&pose, &gt_pose, &frame.intrinsics, depth).rmse_m);
        if matches!(loc.failure, Some(Failure::GateContradicted { .. })) {
            unreachable!("a contradicted frame has no pose");
        }
    }
    Replay { outcomes, published_errors_m, frames: 2 * frames.len() }
}

fn check(name: &str, replay: &Replay) {
    let wrong: Vec<_> = replay.published_errors_m.iter().filter(|&&e| !(e < 0.1)).collect();
    let released = replay.outcomes.iter().filter(|o| **o == GateOutcome::Released).count();
    eprintln!(
        "{name}: {} of {} frames published, wrong {wrong:?}, gate released {released}×",
        replay.published_errors_m.len(),
        replay.frames
    );
    assert!(wrong.is_empty(), "{name}: published poses 10 cm or more off: {wrong:?}");
    assert!(released >= 1, "{name}: the jump back to the start never contradicted the gate");
    // Once let go, the replay localizes as without a gate: at most a frame per jump is lost.
    assert!(replay.published_errors_m.len() + 2 >= replay.frames, "{name}: {:?}", replay.outcomes);
}

/// On the shipped bag (always there) and a shared real one (skipped, and said, when absent).
#[test]
fn a_jump_out_of_the_gate_publishes_no_wrong_pose_and_lets_the_gate_go() {
    if onnx_runtime().is_none() {
        return;
    }
    let shipped = manifest().join("bags/synth-hard");
    let bags = std::iter::once(Some(shipped)).chain(std::iter::once(shared_bag("redkitchen-hard-val")));
    for bag in bags.flatten() {
        let input = read_frames(&bag, &TopicMap::default()).expect("the bag reads");
        let map = input.map.as_ref().expect("the bag has a map");
        let name = bag.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        check(&name, &replay_twice(&input.frames, map));
    }
}
