//! The node's resolved topic names.
//!
//! ROS names without a leading `/` are relative to the node's namespace. The `topics.*`
//! defaults are absolute because bags record absolute names; in the live node a topic left at
//! its default is taken as relative (`/camera/camera_info` → `camera/camera_info`), so
//! `-r __ns:=/cam0` (or launch's `push-ros-namespace`) moves every input and output under
//! `/cam0` and two cameras do not collide. A value that differs from the default is used as
//! given. `/diagnostics`, `/tf` and `/tf_static` stay absolute, as `diagnostic_updater` and
//! tf2 have them (remap them, e.g. `-r /tf:=tf`, to keep them per robot).

use crate::bag::TopicMap;
use crate::params::{AppParams, Names};

/// Resolved topic names of the node.
#[derive(Clone, Debug)]
pub struct Topics {
    pub camera_info: String,
    pub image: String,
    pub image_raw: String,
    pub depth_prior: String,
    pub correspondences: String,
    pub map: String,
    pub pose: String,
    pub pose_with_covariance: String,
    pub output_correspondences: String,
    pub diagnostics: String,
    pub tf: String,
    pub tf_static: String,
    pub debug_image: String,
    /// The pose of `node.base_frame` in the map.
    pub base_pose: String,
    /// `initialpose` (relative, as nav2's amcl has it).
    pub initial_pose: String,
}

/// `value`, made relative when it is the (absolute) default `default`.
fn relative_if_default(value: &str, default: &str) -> String {
    if value == default {
        value.trim_start_matches('/').to_string()
    } else {
        value.to_string()
    }
}

impl Topics {
    pub fn new(params: &AppParams, names: &Names) -> Self {
        let (t, n, d) = (&params.topics, &params.node, TopicMap::default());
        let topic = |value: &str, default: &str| names.resolve(&relative_if_default(value, default));
        Self {
            camera_info: topic(&t.camera_info, &d.camera_info),
            image: topic(&t.image, &d.image),
            image_raw: names.resolve(&n.image_raw_topic),
            depth_prior: topic(&t.depth_prior, &d.depth_prior),
            correspondences: topic(&t.correspondences, &d.correspondences),
            map: topic(&t.map, &d.map),
            pose: topic(&t.pose, &d.pose),
            pose_with_covariance: topic(&t.pose_with_covariance, &d.pose_with_covariance),
            output_correspondences: topic(&t.output_correspondences, &d.output_correspondences),
            diagnostics: names.resolve(&n.diagnostics_topic),
            tf: names.resolve(&n.tf_topic),
            tf_static: names.resolve(&n.tf_static_topic),
            debug_image: names.resolve(&n.debug_image_topic),
            base_pose: names.resolve(&n.base_pose_topic),
            initial_pose: names.resolve(&n.initialpose_topic),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::{resolve, Layers, RosArgs};

    fn topics(args: &[&str]) -> Topics {
        let a = RosArgs::parse(args).unwrap();
        let names = Names::new("angle_i2p", &a);
        let r = resolve(&Layers { names: &names, params_file: None, ros_args: &a }).unwrap();
        Topics::new(&r, &names)
    }

    #[test]
    fn defaults_follow_the_namespace_and_set_names_stay() {
        let root = topics(&[]);
        assert_eq!(root.camera_info, "/camera/camera_info");
        assert_eq!(root.pose, "/angle_i2p/pose");
        let ns = topics(&["--ros-args", "-r", "__ns:=/cam0", "-p", "topics.map:=/shared/map"]);
        for t in [
            &ns.camera_info,
            &ns.image,
            &ns.image_raw,
            &ns.depth_prior,
            &ns.correspondences,
            &ns.pose,
            &ns.pose_with_covariance,
            &ns.output_correspondences,
            &ns.debug_image,
            &ns.base_pose,
        ] {
            assert!(t.starts_with("/cam0/"), "{t}");
        }
        assert_eq!(ns.map, "/shared/map");
        assert_eq!((ns.diagnostics.as_str(), ns.tf.as_str()), ("/diagnostics", "/tf"));
        // Remaps apply to the relative names, as rcl does.
        let r = topics(&["--ros-args", "-r", "__ns:=/cam0", "-r", "matcher/correspondences:=/m/c"]);
        assert_eq!(r.correspondences, "/m/c");
    }
}
