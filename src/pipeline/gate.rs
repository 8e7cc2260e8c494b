//! A pose gate (an `/initialpose` the node's frames follow) as evidence, not a veto (#38).
//!
//! The guided search looks inside the gate only, so a wrong pose with more support elsewhere
//! cannot win there. The plain search over every match looks everywhere: when the camera has
//! left the gate (a jump, a replayed bag, a wrong initial pose), it finds the true pose outside,
//! and the guided search's best inside is a weak, wrong one. Measured on the frame itself, a
//! pose outside the gate that is sure ([`super::CascadeParams::publish_nfa`]) and surer than
//! the pose inside contradicts the gate: the frame publishes no pose (it reports why, and the
//! node lets the gate go) rather than the weakly supported one inside it.

use nalgebra::Isometry3;

use super::localization::{Failure, Localization};
use crate::pnp::PoseGate;

/// Whether `pose` may be a frame's pose: inside `gate`, or there is no gate.
pub(super) fn admits(gate: Option<&PoseGate>, pose: &Isometry3<f64>) -> bool {
    gate.is_none_or(|g| g.check(pose).is_ok())
}

/// Notes in `out` a pose the plain search found outside the gate, `log10_nfa` sure among every
/// match (the surest one is kept).
pub(super) fn note_outside(out: &mut Localization, log10_nfa: f64) {
    let surest = out.outside_gate_log10_nfa.map_or(log10_nfa, |known| known.min(log10_nfa));
    out.outside_gate_log10_nfa = Some(surest);
}

/// Why the frame's pose inside the gate (if any) is not published: a pose outside it is sure at
/// `publish_nfa` (a-contrario's own level of 1 when publishing is not gated on the NFA) and surer.
pub(super) fn contradiction(out: &Localization, publish_nfa: f64) -> Option<Failure> {
    let outside = out.outside_gate_log10_nfa?;
    let level = if publish_nfa > 0.0 { publish_nfa.log10() } else { 0.0 };
    let inside = out.pose.and(out.log10_nfa);
    let outweighed = outside <= level && inside.is_none_or(|inside| outside < inside);
    outweighed.then_some(Failure::GateContradicted { outside_log10_nfa: outside, inside_log10_nfa: inside })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Frame;
    use crate::geometry::Intrinsics;
    use crate::pipeline::Method;
    use nalgebra::{Translation3, UnitQuaternion};

    fn localization() -> Localization {
        let frame = Frame {
            stamp: 7,
            camera_frame_id: "camera".into(),
            map_frame_id: "map".into(),
            intrinsics: Intrinsics { fx: 500.0, fy: 500.0, cx: 320.0, cy: 240.0, width: 640, height: 480 },
            correspondences: Vec::new(),
            depth_prior: None,
            image: None,
            ground_truth: None,
            lens: None,
            odometry: None,
        };
        Localization::nothing_yet(&frame, Method::AngleI2p)
    }

    /// Only a sure pose outside, surer than the pose inside, contradicts the gate.
    #[test]
    fn a_sure_pose_outside_outweighs_a_weaker_one_inside() {
        let mut out = localization();
        assert_eq!(contradiction(&out, 0.01), None, "nothing outside");
        note_outside(&mut out, -1.0);
        assert_eq!(contradiction(&out, 0.01), None, "not sure at 0.01");
        note_outside(&mut out, -8.0);
        note_outside(&mut out, -3.0);
        assert_eq!(out.outside_gate_log10_nfa, Some(-8.0), "the surest is kept");
        let none_inside = Some(Failure::GateContradicted { outside_log10_nfa: -8.0, inside_log10_nfa: None });
        assert_eq!(contradiction(&out, 0.01), none_inside);
        out.pose = Some(Isometry3::identity());
        out.log10_nfa = Some(-9.0);
        assert_eq!(contradiction(&out, 0.01), None, "the pose inside is surer");
        out.log10_nfa = Some(-4.0);
        assert!(matches!(contradiction(&out, 0.01), Some(Failure::GateContradicted { .. })));
        assert!(matches!(contradiction(&out, 0.0), Some(Failure::GateContradicted { .. })), "level 1 when off");
    }

    #[test]
    fn no_gate_admits_every_pose() {
        let far = Isometry3::from_parts(Translation3::new(9.0, 0.0, 0.0), UnitQuaternion::identity());
        assert!(admits(None, &far));
        let gate = PoseGate { centre: Isometry3::identity(), radius_m: 1.0, max_angle_rad: 0.2 };
        assert!(admits(Some(&gate), &Isometry3::identity()) && !admits(Some(&gate), &far));
    }
}
