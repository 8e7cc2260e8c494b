//! The node's resolved topic names.
//!
//! ROS names without a leading `/` are relative to the node's namespace. The topic names
//! ([`TopicMap`]) are absolute in bags; the live node takes them as relative
//! (`/camera/camera_info` → `camera/camera_info`), so `-r __ns:=/cam0` (or launch's
//! `push-ros-namespace`) moves every input and output under `/cam0` and two cameras do not
//! collide, and `-r FROM:=TO` renames any of them. `/diagnostics`, `/tf` and `/tf_static` stay
//! absolute, as `diagnostic_updater` and tf2 have them (remap them, e.g. `-r /tf:=tf`, to keep
//! them per robot).

use std::convert::Infallible;

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

/// A camera of a several-camera node whose topic would not move under its namespace.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error(
    "camera {camera:?}: {key} is the absolute name {topic:?}, which every camera of node.cameras would share; \
     give it as a relative name (it then moves under each camera's namespace) or remap the camera's topic"
)]
pub struct SharedCameraTopic {
    pub camera: String,
    pub key: &'static str,
    pub topic: String,
}

impl Topics {
    /// The topics of a node with one camera.
    pub fn new(params: &AppParams, names: &Names) -> Self {
        let Ok(topics) = Self::resolved_with(params, names, |_, name| Ok::<_, Infallible>(names.resolve(name)));
        topics
    }

    /// The topics of camera `camera` (a namespace relative to the node's, from `node.cameras`;
    /// empty: the node's one camera). Its inputs, outputs and `initialpose` move under the
    /// camera's namespace; the map, `/diagnostics` and TF stay the node's. A camera's topic given
    /// as an absolute name would be every camera's: refused.
    pub fn for_camera(params: &AppParams, names: &Names, camera: &str) -> Result<Self, SharedCameraTopic> {
        if camera.is_empty() {
            return Ok(Self::new(params, names));
        }
        Self::resolved_with(params, names, |key, name| {
            if name.starts_with('/') || name.starts_with('~') {
                return Err(SharedCameraTopic { camera: camera.to_string(), key, topic: name.to_string() });
            }
            Ok(names.resolve(&format!("{camera}/{name}")))
        })
    }

    /// The topics, the camera's resolved with `camera_topic` (its parameter's key, its name).
    fn resolved_with<E>(
        params: &AppParams,
        names: &Names,
        camera_topic: impl Fn(&'static str, &str) -> Result<String, E>,
    ) -> Result<Self, E> {
        let (t, n) = (TopicMap::relative(), &params.node);
        Ok(Self {
            camera_info: camera_topic("camera_info", &t.camera_info)?,
            image: camera_topic("image", &t.image)?,
            image_raw: camera_topic("node.image_raw_topic", &n.image_raw_topic)?,
            depth_prior: camera_topic("depth_prior", &t.depth_prior)?,
            correspondences: camera_topic("correspondences", &t.correspondences)?,
            map: names.resolve(&t.map),
            pose: camera_topic("pose", &t.pose)?,
            pose_with_covariance: camera_topic("pose_with_covariance", &t.pose_with_covariance)?,
            output_correspondences: camera_topic("output_correspondences", &t.output_correspondences)?,
            diagnostics: names.resolve(&n.diagnostics_topic),
            tf: names.resolve(&n.tf_topic),
            tf_static: names.resolve(&n.tf_static_topic),
            debug_image: camera_topic("node.debug_image_topic", &n.debug_image_topic)?,
            base_pose: camera_topic("node.base_pose_topic", &n.base_pose_topic)?,
            initial_pose: camera_topic("node.initialpose_topic", &n.initialpose_topic)?,
        })
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
        ] {
            assert!(t.starts_with("/cam0/"), "{t}");
        }
        assert_eq!(ns.map, "/shared/map");
        assert_eq!((ns.diagnostics.as_str(), ns.tf.as_str()), ("/diagnostics", "/tf"));
        // Remaps apply to the relative names, as rcl does.
        let r = topics(&["--ros-args", "-r", "__ns:=/cam0", "-r", "matcher/correspondences:=/m/c"]);
        assert_eq!(r.correspondences, "/m/c");
    }

    #[test]
    fn each_camera_of_a_node_gets_its_namespace_and_the_map_stays_one() {
        let a = RosArgs::parse(&["--ros-args", "-r", "__ns:=/robot", "-r", "/robot/cam1/angle_i2p/pose:=/p1"]).unwrap();
        let names = Names::new("angle_i2p", &a);
        let r = resolve(&Layers { names: &names, params_file: None, ros_args: &a }).unwrap();
        let cam0 = Topics::for_camera(&r, &names, "cam0").unwrap();
        let cam1 = Topics::for_camera(&r, &names, "cam1").unwrap();
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
        let mut shared = r.clone();
        shared.node.base_pose_topic = "/base_pose".into();
        let err = Topics::for_camera(&shared, &names, "cam0").unwrap_err();
        assert_eq!(err.key, "node.base_pose_topic");
        assert!(Topics::for_camera(&shared, &names, "").is_ok(), "one camera may read any topic");
    }
}
