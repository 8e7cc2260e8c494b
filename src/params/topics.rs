//! Topic names of the inputs and outputs, shared by both edges (bag replay and the live node).
//! They are no parameters: as for every ROS node, remapping renames them — `--ros-args -r
//! FROM:=TO` for the node, `-r FROM:=TO` for the bag commands — and namespaces move them. What
//! each topic carries is the edges' business ([`crate::bag`]).

use super::ros_args::Names;

/// Topic names, inputs and outputs; the defaults are those of the shared bags.
#[derive(Clone, Debug, PartialEq, Eq)]
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
    /// `sensor_msgs/msg/Image` (rgb8, bgr8, mono8, rgba8, bgra8) beside the compressed image,
    /// for the debug image.
    pub image_raw: String,
    /// Output `sensor_msgs/msg/Image` rgb8: kept matches green, rejected red (`node.debug_image`).
    pub debug_image: String,
    /// Output `geometry_msgs/msg/PoseStamped` of `node.base_frame` in the map.
    pub base_pose: String,
    /// `geometry_msgs/msg/PoseWithCovarianceStamped` of the camera: a gate on the poses.
    pub initial_pose: String,
    /// `diagnostic_msgs/msg/DiagnosticArray`, out.
    pub diagnostics: String,
    /// `tf2_msgs/msg/TFMessage`: odometry read, the localization broadcast.
    pub tf: String,
    /// `tf2_msgs/msg/TFMessage`, latched.
    pub tf_static: String,
}

/// Names that stay absolute in the live node, as tf2 and diagnostic_updater have them.
const GLOBAL: [&str; 3] = ["/diagnostics", "/tf", "/tf_static"];

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
            image_raw: "/camera/image_raw".into(),
            debug_image: "/angle_i2p/debug_image".into(),
            base_pose: "/angle_i2p/base_pose".into(),
            initial_pose: "/initialpose".into(),
            diagnostics: "/diagnostics".into(),
            tf: "/tf".into(),
            tf_static: "/tf_static".into(),
        }
    }
}

impl TopicMap {
    /// Each name mapped by `rename` (resolution under a namespace and remaps).
    pub fn map_names(&self, rename: impl Fn(&str) -> String) -> Self {
        Self {
            map: rename(&self.map),
            camera_info: rename(&self.camera_info),
            image: rename(&self.image),
            depth_prior: rename(&self.depth_prior),
            correspondences: rename(&self.correspondences),
            ground_truth_pose: rename(&self.ground_truth_pose),
            ground_truth_depth: rename(&self.ground_truth_depth),
            pose: rename(&self.pose),
            pose_with_covariance: rename(&self.pose_with_covariance),
            output_correspondences: rename(&self.output_correspondences),
            image_raw: rename(&self.image_raw),
            debug_image: rename(&self.debug_image),
            base_pose: rename(&self.base_pose),
            initial_pose: rename(&self.initial_pose),
            diagnostics: rename(&self.diagnostics),
            tf: rename(&self.tf),
            tf_static: rename(&self.tf_static),
        }
    }

    /// The default names as a bag command has them: absolute, each under the command's remaps
    /// (`-r /matcher/correspondences:=/my/matches` reads and writes `/my/matches`).
    pub fn remapped(names: &Names) -> Self {
        Self::default().map_names(|name| names.resolve(name))
    }

    /// The default names made relative (`camera/camera_info`), as the live node has them: they
    /// move with its namespace (`-r __ns:=/cam0`) before its remaps apply. `/diagnostics`,
    /// `/tf` and `/tf_static` stay absolute, as tf2 and diagnostic_updater have them.
    pub fn relative() -> Self {
        Self::default().map_names(|name| {
            if GLOBAL.contains(&name) {
                name.to_string()
            } else {
                name.trim_start_matches('/').to_string()
            }
        })
    }

    /// The remap rule that gives the topic of `key` (a field's name) the name `to`; `None` for
    /// a key that names no topic.
    pub fn remap_rule(&self, key: &str, to: &str) -> Option<String> {
        let from = match key {
            "image_raw" => &self.image_raw,
            "debug_image" => &self.debug_image,
            "base_pose" => &self.base_pose,
            "initial_pose" => &self.initial_pose,
            "diagnostics" => &self.diagnostics,
            "tf" => &self.tf,
            "tf_static" => &self.tf_static,
            "map" => &self.map,
            "camera_info" => &self.camera_info,
            "image" => &self.image,
            "depth_prior" => &self.depth_prior,
            "correspondences" => &self.correspondences,
            "ground_truth_pose" => &self.ground_truth_pose,
            "ground_truth_depth" => &self.ground_truth_depth,
            "pose" => &self.pose,
            "pose_with_covariance" => &self.pose_with_covariance,
            "output_correspondences" => &self.output_correspondences,
            _ => return None,
        };
        Some(format!("{from}:={to}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::RosArgs;

    #[test]
    fn remaps_rename_a_bag_commands_topics_and_only_those() {
        let args =
            RosArgs::parse(&["--ros-args", "-r", "/matcher/correspondences:=/m", "-r", "angle_i2p/pose:=/p"]).unwrap();
        let t = TopicMap::remapped(&Names::new("angle_i2p", &args));
        assert_eq!((t.correspondences.as_str(), t.pose.as_str()), ("/m", "/p"), "absolute and relative rules");
        assert_eq!(t.map, "/map/points");
        assert_eq!(TopicMap::remapped(&Names::new("angle_i2p", &RosArgs::default())), TopicMap::default());
        let relative = TopicMap::relative();
        assert_eq!(
            (relative.camera_info.as_str(), relative.initial_pose.as_str()),
            ("camera/camera_info", "initialpose")
        );
        assert_eq!((relative.tf.as_str(), relative.diagnostics.as_str()), ("/tf", "/diagnostics"));
        assert_eq!(t.remap_rule("pose", "/x").as_deref(), Some("/p:=/x"));
        assert_eq!(TopicMap::default().remap_rule("image", "/i").as_deref(), Some("/camera/image_raw/compressed:=/i"));
        assert_eq!(t.remap_rule("nope", "/x"), None);
    }
}
