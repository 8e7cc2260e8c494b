//! The TF the node broadcasts: `map → <camera frame>`, or with `node.odom_frame` set,
//! `map → odom` = (map→camera) · (odom→camera)⁻¹ so the map frame joins an existing
//! `odom → … → camera` tree (as AMCL-style localizers do).
//!
//! [`TfBuffer`] keeps the latest transform of every child frame heard on `/tf` (and
//! `/tf_static`); `odom → camera` is found through any chain of frames
//! (`odom → base_link → camera_link → … → optical`). No time interpolation: the latest
//! transforms are used, not those at the image's stamp.

use std::collections::HashMap;

use nalgebra::Isometry3;

use crate::frame::Stamp;
use crate::msgs::{self, convert, TFMessage};

/// tf2 frame ids carry no leading slash; accept one anyway.
fn frame(id: &str) -> &str {
    id.strip_prefix('/').unwrap_or(id)
}

/// Latest transform of each child frame: child → (parent, parent-from-child).
#[derive(Debug, Default)]
pub struct TfBuffer {
    by_child: HashMap<String, (String, Isometry3<f64>)>,
}

impl TfBuffer {
    /// Takes every valid transform of `msg`; returns why the others were skipped.
    pub fn update(&mut self, msg: &TFMessage) -> Vec<String> {
        let mut bad = Vec::new();
        for t in &msg.transforms {
            let (parent, child) = (frame(&t.header.frame_id), frame(&t.child_frame_id));
            if parent.is_empty() || child.is_empty() || parent == child {
                bad.push(format!("transform {parent:?} → {child:?}: bad frame ids"));
                continue;
            }
            let tr = &t.transform;
            let pose = msgs::Pose {
                position: msgs::Point { x: tr.translation.x, y: tr.translation.y, z: tr.translation.z },
                orientation: tr.rotation,
            };
            match convert::isometry_from_pose(&pose) {
                Ok(iso) => {
                    self.by_child.insert(child.to_string(), (parent.to_string(), iso));
                }
                Err(e) => bad.push(format!("transform {parent} → {child}: {e}")),
            }
        }
        bad
    }

    /// `parent → child` (parent-from-child), directly or through any chain of frames
    /// (`odom → base_link → camera_link → camera_color_frame → optical`), walking up from
    /// `child`; a loop or a chain longer than [`MAX_CHAIN`] finds nothing.
    pub fn lookup(&self, parent: &str, child: &str) -> Option<Isometry3<f64>> {
        let (parent, mut current) = (frame(parent), frame(child));
        let mut parent_from_child = Isometry3::identity();
        for _ in 0..MAX_CHAIN {
            let (up, up_from_current) = self.by_child.get(current)?;
            parent_from_child = up_from_current * parent_from_child;
            if up == parent {
                return Some(parent_from_child);
            }
            current = up.as_str();
        }
        None
    }
}

/// The longest chain of frames [`TfBuffer::lookup`] follows.
pub const MAX_CHAIN: usize = 64;

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
    fn buffer_finds_direct_and_one_level_chains() {
        let odom_base = iso([2.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.5);
        let base_cam = iso([0.1, 0.0, 0.3], [1.0, 0.0, 0.0], -1.5);
        let mut buf = TfBuffer::default();
        assert!(buf.lookup("odom", "camera").is_none());
        let msg = |parent: &str, child: &str, t: &Isometry3<f64>| tf_message(1, parent, child, t);
        assert!(buf.update(&msg("odom", "base_link", &odom_base)).is_empty());
        assert!(buf.lookup("odom", "camera").is_none());
        assert!(buf.update(&msg("/base_link", "camera", &base_cam)).is_empty());
        let chained = buf.lookup("odom", "camera").unwrap();
        assert!(close(&chained, &(odom_base * base_cam)));
        assert!(buf.lookup("map", "camera").is_none());
        // A direct transform replaces the chain (latest per child).
        let direct = iso([0.0, 1.0, 0.0], [0.0, 1.0, 0.0], 0.2);
        buf.update(&msg("odom", "camera", &direct));
        assert!(close(&buf.lookup("/odom", "camera").unwrap(), &direct));
        // Bad transforms are reported and skipped.
        let mut nan = msg("odom", "camera", &direct);
        nan.transforms[0].transform.translation.x = f64::NAN;
        assert_eq!(buf.update(&nan).len(), 1);
        assert!(close(&buf.lookup("odom", "camera").unwrap(), &direct));
        assert_eq!(buf.update(&msg("", "camera", &direct)).len(), 1);
    }

    #[test]
    fn buffer_follows_long_chains_and_stops_at_loops() {
        let links = [
            ("odom", "base_link", iso([1.0, 2.0, 0.0], [0.0, 0.0, 1.0], 0.4)),
            ("base_link", "camera_link", iso([0.2, 0.0, 0.4], [0.0, 1.0, 0.0], 0.1)),
            ("camera_link", "camera_color_frame", iso([0.0, 0.03, 0.0], [1.0, 0.0, 0.0], 0.0)),
            ("camera_color_frame", "camera_color_optical_frame", iso([0.0; 3], [1.0, -1.0, 1.0], 2.09)),
        ];
        let mut buf = TfBuffer::default();
        let mut want = Isometry3::identity();
        for (parent, child, t) in &links {
            assert!(buf.update(&tf_message(1, parent, child, t)).is_empty());
            want *= t;
        }
        assert!(close(&buf.lookup("odom", "camera_color_optical_frame").unwrap(), &want));
        assert!(close(&buf.lookup("base_link", "camera_color_frame").unwrap(), &(links[1].2 * links[2].2)));
        assert!(buf.lookup("map", "camera_color_optical_frame").is_none());
        // A loop ends the walk.
        buf.update(&tf_message(1, "camera_color_optical_frame", "odom", &Isometry3::identity()));
        assert!(buf.lookup("map", "base_link").is_none());
    }

    #[test]
    fn tf_message_carries_the_transform() {
        let t = iso([1.0, 2.0, 3.0], [0.0, 0.0, 1.0], 0.3);
        let m = tf_message(42, "map", "odom", &t);
        let ts = &m.transforms[0];
        assert_eq!((ts.header.frame_id.as_str(), ts.child_frame_id.as_str()), ("map", "odom"));
        assert_eq!(ts.header.stamp.to_nanos(), 42);
        let mut buf = TfBuffer::default();
        buf.update(&m);
        assert!(close(&buf.lookup("map", "odom").unwrap(), &t));
    }
}
