//! Topic names of the inputs and outputs (`topics.*`): a parameter of both edges, bag replay
//! and the live node. What each topic carries is the edges' business ([`crate::bag`]).

use serde::{Deserialize, Serialize};

/// Topic names, inputs and outputs; defaults are those of the shared bags.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TopicMap {
    /// `sensor_msgs/msg/PointCloud2`, once.
    pub map: String,
    /// `sensor_msgs/msg/CameraInfo`.
    pub camera_info: String,
    /// `sensor_msgs/msg/CompressedImage`.
    pub image: String,
    /// `sensor_msgs/msg/Image` (32FC1 or 16UC1).
    pub depth_prior: String,
    /// `angle_i2p_msgs/msg/Correspondences`.
    pub correspondences: String,
    /// `geometry_msgs/msg/PoseStamped`, camera-to-map.
    pub ground_truth_pose: String,
    /// `sensor_msgs/msg/Image`, 16UC1 millimetres.
    pub ground_truth_depth: String,
    /// Output `geometry_msgs/msg/PoseStamped`.
    pub pose: String,
    /// Output `geometry_msgs/msg/PoseWithCovarianceStamped`.
    pub pose_with_covariance: String,
    /// Output `angle_i2p_msgs/msg/Correspondences` (inliers, with inlier scores).
    pub output_correspondences: String,
}

impl Default for TopicMap {
    fn default() -> Self {
        Self {
            map: "/map/points".into(),
            camera_info: "/camera/camera_info".into(),
            image: "/camera/image_raw/compressed".into(),
            depth_prior: "/depth_prior/image".into(),
            correspondences: "/matcher/correspondences".into(),
            ground_truth_pose: "/ground_truth/pose".into(),
            ground_truth_depth: "/ground_truth/depth".into(),
            pose: "/angle_i2p/pose".into(),
            pose_with_covariance: "/angle_i2p/pose_with_covariance".into(),
            output_correspondences: "/angle_i2p/correspondences".into(),
        }
    }
}
