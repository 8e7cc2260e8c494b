//! `Localization` → output messages: what `replay` writes to its output bag and the live node
//! publishes, built in one place so the two edges cannot drift apart.

use super::{correspondences_msg, pose_stamped, pose_with_covariance_stamped};
use crate::camera::CameraModel;
use crate::frame::Correspondence;
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
///
/// `lens`: the frame's pixels were undistorted with it ([`Frame::lens`](crate::frame::Frame::lens));
/// the kept correspondences are then published back in the input's raw pixels.
pub fn localization_messages(loc: &Localization, lens: Option<&CameraModel>) -> LocalizationMessages {
    let (t, map) = (loc.stamp, loc.map_frame_id.as_str());
    let pose = loc.pose.as_ref().map(|pose| pose_stamped(t, map, pose));
    let pose_with_covariance = match (&loc.pose, &loc.covariance) {
        (Some(pose), Some(cov)) => Some(pose_with_covariance_stamped(t, map, pose, cov)),
        _ => None,
    };
    LocalizationMessages {
        pose,
        pose_with_covariance,
        kept: match lens {
            None => correspondences_msg(t, &loc.camera_frame_id, map, &loc.kept),
            Some(lens) => {
                let raw: Vec<Correspondence> =
                    loc.kept.iter().map(|c| Correspondence { pixel: lens.distort_pixel(&c.pixel), ..*c }).collect();
                correspondences_msg(t, &loc.camera_frame_id, map, &raw)
            }
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{Correspondence, Frame};
    use crate::geometry::Intrinsics;
    use crate::pipeline::{Localizer, Method};
    use nalgebra::{Isometry3, Matrix6, Point2, Point3, Vector3};

    /// A localization as the core hands it out (a frame it cannot solve), its pose set by hand.
    fn localization() -> Localization {
        let params = crate::pipeline::LocalizerParams { method: Method::Ransac, ..Default::default() };
        let frame = Frame {
            stamp: 42,
            camera_frame_id: "cam".into(),
            map_frame_id: "map".into(),
            intrinsics: Intrinsics { fx: 500.0, fy: 500.0, cx: 320.0, cy: 240.0, width: 640, height: 480 },
            correspondences: Vec::new(),
            depth_prior: None,
            image: None,
            ground_truth: None,
            lens: None,
            odometry: None,
        };
        Localizer::new(params).expect("a ransac localizer").process(&frame)
    }

    #[test]
    fn a_frame_without_pose_still_reports_its_kept_set() {
        let loc = localization();
        assert!(loc.pose.is_none());
        let out = localization_messages(&loc, None);
        assert!(out.pose.is_none() && out.pose_with_covariance.is_none());
        assert_eq!((super::super::stamp(&out.kept.header), out.kept.map_frame_id.as_str()), (42, "map"));
    }

    #[test]
    fn a_pose_and_its_covariance_become_both_pose_messages() {
        let mut loc = localization();
        let pose = Isometry3::new(Vector3::new(1.0, 2.0, 3.0), Vector3::new(0.0, 0.3, 0.0));
        loc.pose = Some(pose);
        loc.kept = vec![Correspondence { pixel: Point2::new(1.0, 2.0), point: Point3::new(0.0, 0.0, 1.0), score: 0.5 }];
        let out = localization_messages(&loc, None);
        let msg = out.pose.expect("pose");
        assert_eq!((msg.header.frame_id.as_str(), super::super::stamp(&msg.header)), ("map", 42));
        let back = super::super::isometry_from_pose(&msg.pose).expect("pose");
        assert!((back.to_homogeneous() - pose.to_homogeneous()).norm() < 1e-12);
        assert!(out.pose_with_covariance.is_none(), "no covariance, no PoseWithCovarianceStamped");
        assert_eq!(out.kept.correspondences.len(), 1);
        loc.covariance = Some(Matrix6::identity() * 0.25);
        let with_cov = localization_messages(&loc, None).pose_with_covariance.expect("pose with covariance");
        assert_eq!(with_cov.pose.covariance[0], 0.25);
        assert_eq!(with_cov.pose.covariance[7], 0.25);
    }
}
