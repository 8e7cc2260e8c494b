//! `/initialpose` (geometry_msgs/PoseWithCovarianceStamped, the camera's pose in the map, as
//! RViz's "2D Pose Estimate" or a GNSS fix gives it) as a gate on the node's poses: a pose PnP
//! finds farther from the prior than its covariance allows (`gate_sigmas` standard deviations,
//! at least `min_radius_m` / `min_angle_deg`) is not published and is counted
//! (`error.outside_initialpose_gate`). Each accepted pose becomes the gate's centre, so the gate
//! follows the camera; `~/relocalize` drops it (global localization again).
//!
//! The gate acts inside PnP ([`crate::pnp::PoseGate`]: the guided search scores no hypothesis
//! outside it, so a wrong pose with more support elsewhere cannot win) and again on the result.
//! It is evidence, not a veto: when a frame's plain search over every match finds a sure pose
//! outside it, surer than the best inside (the camera jumped, a bag was replayed, the initial
//! pose was wrong), the frame publishes nothing and the gate is let go, so that the next frames
//! localize globally instead of staying blind or taking a weak wrong pose inside it (#38).

use crate::msgs::{convert, PoseWithCovarianceStamped};
use crate::pipeline::{Failure, Localization};
pub use crate::pnp::{GateMiss, PoseGate};

/// An accepted `/initialpose`: its gate, and the frame it was given in (empty: none named),
/// which the frames' map must be in for the gate to apply.
#[derive(Clone, Debug, PartialEq)]
pub struct InitialPose {
    pub frame_id: String,
    pub gate: PoseGate,
}

impl InitialPose {
    /// Whether this initial pose can gate a frame whose map is `map_frame_id`: a pose given in
    /// another frame (`odom`, a typo, another map) is not a place in this map (#38: one 100 m
    /// off in an unknown frame made every later frame fail until `~/relocalize`).
    pub fn applies_to(&self, map_frame_id: &str) -> bool {
        self.frame_id.is_empty() || map_frame_id.is_empty() || self.frame_id == map_frame_id
    }
}

/// What the gate did with one frame's localization.
#[derive(Clone, Debug, PartialEq)]
pub enum GateOutcome {
    /// No gate, or no pose to check.
    Ungated,
    /// The pose is inside; the gate moved to it.
    Followed,
    /// The pose is outside and was withdrawn.
    Withdrawn(GateMiss),
    /// The frame's evidence contradicts the gate (a sure pose outside it): the gate is gone.
    Released,
}

/// Applies the gate in `initial` to `loc`: a pose outside it is withdrawn, one inside moves it,
/// and a frame that contradicts it ([`Failure::GateContradicted`]) lets it go.
pub fn apply_gate(initial: &mut Option<InitialPose>, loc: &mut Localization) -> GateOutcome {
    let Some(InitialPose { gate, .. }) = initial.as_mut() else { return GateOutcome::Ungated };
    if matches!(loc.failure, Some(Failure::GateContradicted { .. })) {
        *initial = None;
        return GateOutcome::Released;
    }
    let Some(pose) = loc.pose else { return GateOutcome::Ungated };
    match gate.check(&pose) {
        Ok(()) => {
            gate.follow(&pose);
            GateOutcome::Followed
        }
        Err(miss) => {
            loc.pose = None;
            loc.covariance = None;
            GateOutcome::Withdrawn(miss)
        }
    }
}

/// How wide the gate is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GateWidth {
    pub sigmas: f64,
    pub min_radius_m: f64,
    pub min_angle_deg: f64,
}

/// An unusable `/initialpose`.
#[derive(Debug, thiserror::Error)]
pub enum InitialPoseError {
    #[error("initial pose: {0}")]
    Pose(String),
    #[error("initial pose in frame {got:?}, the map is in {want:?}")]
    Frame { got: String, want: String },
    #[error("initial pose covariance: entry {index} is {value} (must be finite, diagonal >= 0)")]
    Covariance { index: usize, value: f64 },
}

/// The gate of an `/initialpose` message; `map_frame` (when known and the message names a
/// frame) must match its frame.
pub fn gate_from_msg(
    msg: &PoseWithCovarianceStamped,
    map_frame: Option<&str>,
    width: GateWidth,
) -> Result<PoseGate, InitialPoseError> {
    let got = msg.header.frame_id.trim_start_matches('/');
    if let Some(want) = map_frame.filter(|w| !w.is_empty() && !got.is_empty() && *w != got) {
        return Err(InitialPoseError::Frame { got: got.into(), want: want.into() });
    }
    let centre = convert::isometry_from_pose(&msg.pose.pose).map_err(|e| InitialPoseError::Pose(e.to_string()))?;
    let cov = &msg.pose.covariance;
    for (index, value) in cov.iter().enumerate() {
        let diagonal = index % 7 == 0;
        if !value.is_finite() || (diagonal && *value < 0.0) {
            return Err(InitialPoseError::Covariance { index, value: *value });
        }
    }
    // Position: the largest of the x, y, z deviations; rotation: of roll, pitch, yaw.
    let sigma_pos = [0, 7, 14].iter().map(|&i| cov[i].sqrt()).fold(0.0, f64::max);
    let sigma_rot = [21, 28, 35].iter().map(|&i| cov[i].sqrt()).fold(0.0, f64::max);
    Ok(PoseGate {
        centre,
        radius_m: (width.sigmas * sigma_pos).max(width.min_radius_m),
        max_angle_rad: (width.sigmas * sigma_rot).max(width.min_angle_deg.to_radians()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{Header, PoseWithCovariance};
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

    fn msg(frame: &str, at: [f64; 3], var_pos: f64, var_rot: f64) -> PoseWithCovarianceStamped {
        let iso = Isometry3::from_parts(Translation3::new(at[0], at[1], at[2]), UnitQuaternion::identity());
        let mut covariance = [0.0; 36];
        for i in 0..3 {
            covariance[i * 7] = var_pos;
            covariance[(i + 3) * 7] = var_rot;
        }
        PoseWithCovarianceStamped {
            header: Header::new(0, frame),
            pose: PoseWithCovariance { pose: convert::pose_from_isometry(&iso), covariance },
        }
    }

    const WIDTH: GateWidth = GateWidth { sigmas: 3.0, min_radius_m: 0.5, min_angle_deg: 10.0 };

    #[test]
    fn gate_from_covariance_follows_accepted_poses() {
        let mut gate = gate_from_msg(&msg("map", [1.0, 2.0, 0.0], 0.25, 0.01), Some("map"), WIDTH).unwrap();
        assert!((gate.radius_m - 1.5).abs() < 1e-12);
        assert!((gate.max_angle_rad - 0.3).abs() < 1e-12);
        let near = Isometry3::from_parts(Translation3::new(2.0, 2.5, 0.5), UnitQuaternion::identity());
        assert!(gate.check(&near).is_ok());
        let far = Isometry3::from_parts(Translation3::new(4.0, 2.0, 0.0), UnitQuaternion::identity());
        let miss = gate.check(&far).unwrap_err();
        assert!((miss.distance_m - 3.0).abs() < 1e-12, "{miss}");
        let turned = Isometry3::from_parts(
            Translation3::new(1.0, 2.0, 0.0),
            UnitQuaternion::from_scaled_axis(Vector3::z() * 0.5),
        );
        assert!(gate.check(&turned).is_err());
        gate.follow(&near);
        assert!(gate
            .check(&Isometry3::from_parts(Translation3::new(3.4, 2.5, 0.5), UnitQuaternion::identity()))
            .is_ok());
        // A zero covariance still leaves the minimum gate.
        let tight = gate_from_msg(&msg("", [0.0; 3], 0.0, 0.0), Some("map"), WIDTH).unwrap();
        assert_eq!(tight.radius_m, 0.5);
    }

    /// An initial pose gates only frames whose map is the frame it was given in (#38); one that
    /// names no frame, or a frame whose map names none, is taken as the map's.
    #[test]
    fn an_initial_pose_applies_only_in_its_own_frame() {
        let gate = gate_from_msg(&msg("map", [0.0; 3], 0.1, 0.1), None, WIDTH).unwrap();
        let in_map = InitialPose { frame_id: "map".into(), gate: gate.clone() };
        assert!(in_map.applies_to("map") && in_map.applies_to(""));
        assert!(!in_map.applies_to("world"));
        let unknown = InitialPose { frame_id: "nowhere".into(), gate: gate.clone() };
        assert!(!unknown.applies_to("map"));
        let unnamed = InitialPose { frame_id: String::new(), gate };
        assert!(unnamed.applies_to("map"));
    }

    #[test]
    fn bad_initial_poses_are_named() {
        let e = gate_from_msg(&msg("odom", [0.0; 3], 0.1, 0.1), Some("map"), WIDTH).unwrap_err();
        assert!(matches!(e, InitialPoseError::Frame { .. }), "{e}");
        let e = gate_from_msg(&msg("map", [0.0; 3], -1.0, 0.1), Some("map"), WIDTH).unwrap_err();
        assert!(matches!(e, InitialPoseError::Covariance { index: 0, .. }), "{e}");
        let mut m = msg("map", [0.0; 3], 0.1, 0.1);
        m.pose.pose.orientation.w = f64::NAN;
        assert!(gate_from_msg(&m, None, WIDTH).is_err());
    }
}
