//! The TF the node broadcasts: `map → <camera frame>`, or with `node.odom_frame` set,
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

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn iso(t: [f64; 3], axis: [f64; 3], angle: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_scaled_axis(Vector3::from(axis).normalize() * angle),
        )
    }

    fn close(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
        (a.translation.vector - b.translation.vector).norm() < 1e-9 && a.rotation.angle_to(&b.rotation) < 1e-9
    }

    #[test]
    fn map_to_odom_composes_with_odom_to_camera_into_map_to_camera() {
        let map_camera = iso([1.0, -2.0, 0.5], [0.2, 1.0, -0.3], 0.7);
        let odom_camera = iso([0.3, 0.1, 1.2], [1.0, 0.0, 0.4], -1.1);
        let map_odom = map_to_odom(&map_camera, &odom_camera);
        assert!(close(&(map_odom * odom_camera), &map_camera));
        // A point seen by the camera lands at the same map point either way.
        let p = nalgebra::Point3::new(0.4, -0.2, 2.0);
        assert!(((map_odom * (odom_camera * p)) - map_camera * p).norm() < 1e-9);
        // Identity odom → camera: map → odom is the camera pose itself.
        assert!(close(&map_to_odom(&map_camera, &Isometry3::identity()), &map_camera));
    }

    #[test]
    fn tf_message_carries_the_transform() {
        let t = iso([1.0, 2.0, 3.0], [0.0, 0.0, 1.0], 0.3);
        let m = tf_message(42, "map", "odom", &t);
        let ts = &m.transforms[0];
        assert_eq!((ts.header.frame_id.as_str(), ts.child_frame_id.as_str()), ("map", "odom"));
        assert_eq!(ts.header.stamp.to_nanos(), 42);
        let mut buf = super::super::tf_buffer::TfHistory::default();
        buf.update(&m, false);
        assert!(close(&buf.lookup("map", "odom", 42).unwrap(), &t));
    }
}
