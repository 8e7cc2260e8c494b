//! The TF the node broadcasts (tested with the buffer, in `tf_buffer_tests.rs`): `map → <camera frame>`, or with `node.odom_frame` set,
//! `map → odom` = (map→camera) · (odom→camera)⁻¹ so the map frame joins an existing
//! `odom → … → camera` tree (as AMCL-style localizers do).
//!
//! `odom → camera` comes from [`super::tf_buffer::TfHistory`]: looked up at the image's stamp
//! through any chain of frames (`odom → base_link → camera_link → … → optical`).

use nalgebra::Isometry3;

use crate::frame::Stamp;
use crate::msgs::{self, convert, TFMessage};

/// `map → odom` from the camera's pose in the map and in odom: (map→camera) · (odom→camera)⁻¹.
pub fn map_to_odom(map_camera: &Isometry3<f64>, odom_camera: &Isometry3<f64>) -> Isometry3<f64> {
    map_camera * odom_camera.inverse()
}

/// One `parent → child` transform as a TF message.
pub fn tf_message(stamp: Stamp, parent: &str, child: &str, parent_child: &Isometry3<f64>) -> TFMessage {
    let p = convert::pose_from_isometry(parent_child);
    TFMessage {
        transforms: vec![msgs::TransformStamped {
            header: msgs::Header::new(stamp, parent),
            child_frame_id: child.to_string(),
            transform: msgs::Transform {
                translation: msgs::Vector3 { x: p.position.x, y: p.position.y, z: p.position.z },
                rotation: p.orientation,
            },
        }],
    }
}
