//! The node's resolved topic names.
//!
//! ROS names without a leading `/` are relative to the node's namespace. The topic names
//! ([`TopicMap`]) are absolute in bags; the live node takes them as relative
//! (`/camera/camera_info` → `camera/camera_info`), so `-r __ns:=/cam0` (or launch's
//! `push-ros-namespace`) moves every input and output under `/cam0` and two cameras do not
//! collide, and `-r FROM:=TO` renames any of them. `/diagnostics`, `/tf` and `/tf_static` stay
//! absolute, as `diagnostic_updater` and tf2 have them (remap them, e.g. `-r /tf:=tf`, to keep
//! them per robot).

use crate::params::{Names, TopicMap};

/// The node's topics: [`TopicMap`]'s names under its namespace and remaps (the ground-truth
/// names are a bag's only).
pub type Topics = TopicMap;

/// The topics of a node with one camera.
pub fn of_node(names: &Names) -> Topics {
    TopicMap::relative().map_names(|name| names.resolve(name))
}

/// The topics of camera `camera` (a namespace relative to the node's, from `node.cameras`;
/// empty: the node's one camera). Its inputs, outputs and `initialpose` move under the
/// camera's namespace; the map, `/diagnostics` and TF stay the node's.
pub fn of_camera(names: &Names, camera: &str) -> Topics {
    let node = of_node(names);
    if camera.is_empty() {
        return node;
    }
    let camera_topics = TopicMap::relative().map_names(|name| match name.starts_with('/') {
        true => names.resolve(name),
        false => names.resolve(&format!("{camera}/{name}")),
    });
    TopicMap { map: node.map, ..camera_topics }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::RosArgs;

    fn topics(args: &[&str]) -> Topics {
        of_node(&Names::new("angle_i2p", &RosArgs::parse(args).unwrap()))
    }

    #[test]
    fn defaults_follow_the_namespace_and_remaps_rename() {
        let root = topics(&[]);
        assert_eq!(root.camera_info, "/camera/camera_info");
        assert_eq!(root.pose, "/angle_i2p/pose");
        assert_eq!(root.initial_pose, "/initialpose");
        let ns = topics(&["--ros-args", "-r", "__ns:=/cam0", "-r", "map/points:=/shared/map"]);
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
            &ns.initial_pose,
        ] {
            assert!(t.starts_with("/cam0/"), "{t}");
        }
        assert_eq!(ns.map, "/shared/map");
        assert_eq!((ns.diagnostics.as_str(), ns.tf.as_str()), ("/diagnostics", "/tf"));
        // Remaps apply to the relative names, as rcl does.
        let r = topics(&["--ros-args", "-r", "__ns:=/cam0", "-r", "matcher/correspondences:=/m/c", "-r", "/tf:=tf"]);
        assert_eq!((r.correspondences.as_str(), r.tf.as_str()), ("/m/c", "/cam0/tf"));
    }

    #[test]
    fn each_camera_of_a_node_gets_its_namespace_and_the_map_stays_one() {
        let a = RosArgs::parse(&["--ros-args", "-r", "__ns:=/robot", "-r", "/robot/cam1/angle_i2p/pose:=/p1"]).unwrap();
        let names = Names::new("angle_i2p", &a);
        let cam0 = of_camera(&names, "cam0");
        let cam1 = of_camera(&names, "cam1");
        assert_eq!(cam0.camera_info, "/robot/cam0/camera/camera_info");
        assert_eq!(cam0.correspondences, "/robot/cam0/matcher/correspondences");
        assert_eq!(cam0.pose, "/robot/cam0/angle_i2p/pose");
        assert_eq!(cam0.initial_pose, "/robot/cam0/initialpose");
        assert_eq!(cam0.base_pose, "/robot/cam0/angle_i2p/base_pose");
        assert_eq!(cam1.pose, "/p1", "remaps apply to a camera's names");
        for t in [&cam0, &cam1] {
            assert_eq!(
                (t.map.as_str(), t.tf.as_str(), t.diagnostics.as_str()),
                ("/robot/map/points", "/tf", "/diagnostics")
            );
        }
        assert_eq!(of_camera(&names, "").camera_info, "/robot/camera/camera_info");
    }
}
