//! `Localization` → output messages: what `replay` writes to its output bag and the live node
//! publishes, built in one place so the two edges cannot drift apart.

use super::{correspondences_msg, pose_stamped, pose_with_covariance_stamped};
use crate::msgs::{Correspondences, PoseStamped, PoseWithCovarianceStamped};
use crate::pipeline::Localization;

/// One frame's results as messages, all stamped with the frame's stamp.
#[derive(Clone, Debug)]
pub struct LocalizationMessages {
    /// Camera-to-map pose in the map frame; `None` when the frame has no pose.
    pub pose: Option<PoseStamped>,
    /// The pose with its 6×6 covariance; `None` without a pose or a covariance.
    pub pose_with_covariance: Option<PoseWithCovarianceStamped>,
    /// The kept correspondences (`score` = inlier score), also sent for a frame without a pose.
    pub kept: Correspondences,
}

/// The messages that report `loc`.
pub fn localization_messages(loc: &Localization) -> LocalizationMessages {
    let (t, map) = (loc.stamp, loc.map_frame_id.as_str());
    let pose = loc.pose.as_ref().map(|pose| pose_stamped(t, map, pose));
    let pose_with_covariance = match (&loc.pose, &loc.covariance) {
        (Some(pose), Some(cov)) => Some(pose_with_covariance_stamped(t, map, pose, cov)),
        _ => None,
    };
    LocalizationMessages {
        pose,
        pose_with_covariance,
        kept: correspondences_msg(t, &loc.camera_frame_id, map, &loc.kept),
    }
}
