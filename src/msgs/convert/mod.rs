//! Conversions between ROS messages and the core types, and builders for output messages.
//!
//! Decoding direction (`*_from_*` / `to_*`) validates and returns [`MsgError`] on bad data;
//! building direction never fails. [`parts`] turns each input message into its frame part and
//! [`localization`] a result into its output messages: both edges (bag replay and the live
//! node) go through them.

mod localization;
mod parts;

pub use localization::{localization_messages, LocalizationMessages};
pub use parts::{
    camera_info_part, compressed_image_msg, compressed_image_part, correspondences_part, correspondences_part_within,
    depth_prior_part, ground_truth_depth_part, ground_truth_pose_part, map_part, DecodedMap,
};

use nalgebra::{Isometry3, Matrix6, Point2, Point3, Quaternion as NQuaternion, Translation3, UnitQuaternion};

use super::{
    CameraInfo, CompressedImage, Correspondence, Correspondences, Header, Image, MsgError, PointCloud2, PointField,
    Pose, PoseStamped, PoseWithCovariance, PoseWithCovarianceStamped, Quaternion, RegionOfInterest,
};
use crate::frame::{self, EncodedImage, MapCloud, Stamp};
use crate::geometry::{DepthImage, Intrinsics};

/// `header.stamp` in nanoseconds.
pub fn stamp(header: &Header) -> Stamp {
    header.stamp.to_nanos()
}

/// Pinhole intrinsics from `k` (fx = k[0], fy = k[4], cx = k[2], cy = k[5]) and the image size.
pub fn intrinsics_from_camera_info(info: &CameraInfo) -> Result<Intrinsics, MsgError> {
    let k = &info.k;
    let intrinsics = Intrinsics { fx: k[0], fy: k[4], cx: k[2], cy: k[5], width: info.width, height: info.height };
    if !intrinsics.is_valid() {
        return Err(MsgError::Invalid {
            what: "CameraInfo",
            reason: format!(
                "need a non-empty image and finite fx, fy giving a pinhole's field of view (0.01–179°); \
                 got fx={} fy={} cx={} cy={} size {}x{}",
                k[0], k[4], k[2], k[5], info.width, info.height
            ),
        });
    }
    Ok(intrinsics)
}

/// A distortion-free `plumb_bob` CameraInfo: zero `d`, K, identity R, P = [K | 0].
pub fn camera_info(stamp: Stamp, frame_id: &str, k: &Intrinsics) -> CameraInfo {
    let (fx, fy, cx, cy) = (k.fx, k.fy, k.cx, k.cy);
    CameraInfo {
        header: Header::new(stamp, frame_id),
        height: k.height,
        width: k.width,
        distortion_model: "plumb_bob".into(),
        d: vec![0.0; 5],
        k: [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        binning_x: 0,
        binning_y: 0,
        roi: RegionOfInterest::default(),
    }
}

/// Checks an image's size fields against its data; returns the row length in bytes.
fn checked_rows(img: &Image, bytes_per_pixel: usize) -> Result<usize, MsgError> {
    let (w, h, step) = (img.width as usize, img.height as usize, img.step as usize);
    let row = w * bytes_per_pixel;
    if step < row {
        return Err(MsgError::Invalid {
            what: "Image",
            reason: format!("step {step} is shorter than width {w} × {bytes_per_pixel} bytes"),
        });
    }
    let expected = step * h;
    if img.data.len() != expected {
        return Err(MsgError::SizeMismatch {
            what: format!("Image {}x{} {} (step {step})", w, h, img.encoding),
            expected,
            actual: img.data.len(),
        });
    }
    Ok(row)
}

/// A depth image from `32FC1` (metres, or any unit of a prior) or `16UC1` (millimetres →
/// metres, 0 = unknown). Honours `is_bigendian` and row padding in `step`.
pub fn depth_from_image(img: &Image) -> Result<DepthImage, MsgError> {
    let big = img.is_bigendian != 0;
    type Decode = fn(&[u8], bool) -> f32;
    let (bpp, decode): (usize, Decode) = match img.encoding.as_str() {
        "32FC1" => (4, |b, big| {
            let a = [b[0], b[1], b[2], b[3]];
            if big {
                f32::from_be_bytes(a)
            } else {
                f32::from_le_bytes(a)
            }
        }),
        "16UC1" => (2, |b, big| {
            let a = [b[0], b[1]];
            let mm = if big { u16::from_be_bytes(a) } else { u16::from_le_bytes(a) };
            mm as f32 / 1000.0
        }),
        other => return Err(MsgError::UnsupportedEncoding(other.to_string())),
    };
    let row = checked_rows(img, bpp)?;
    let mut data = Vec::with_capacity(img.width as usize * img.height as usize);
    if row > 0 {
        for r in img.data.chunks_exact(img.step as usize) {
            data.extend(r[..row].chunks_exact(bpp).map(|b| decode(b, big)));
        }
    }
    Ok(DepthImage::new(img.width, img.height, data))
}

/// A little-endian `32FC1` image of `depth`, rows unpadded.
pub fn image_32fc1(stamp: Stamp, frame_id: &str, depth: &DepthImage) -> Image {
    Image {
        header: Header::new(stamp, frame_id),
        height: depth.height,
        width: depth.width,
        encoding: "32FC1".into(),
        is_bigendian: 0,
        step: depth.width * 4,
        data: depth.data.iter().flat_map(|d| d.to_le_bytes()).collect(),
    }
}

/// A little-endian `16UC1` image of `depth` in millimetres (rounded; unknown or
/// non-positive → 0, saturating at 65535).
pub fn image_16uc1_mm(stamp: Stamp, frame_id: &str, depth: &DepthImage) -> Image {
    let mm = |d: f32| -> u16 {
        if d.is_finite() && d > 0.0 {
            (d as f64 * 1000.0).round().min(u16::MAX as f64) as u16
        } else {
            0
        }
    };
    Image {
        header: Header::new(stamp, frame_id),
        height: depth.height,
        width: depth.width,
        encoding: "16UC1".into(),
        is_bigendian: 0,
        step: depth.width * 2,
        data: depth.data.iter().flat_map(|&d| mm(d).to_le_bytes()).collect(),
    }
}

/// Pose → isometry; the quaternion (x, y, z, w) is normalized; non-finite or zero → error.
pub fn isometry_from_pose(pose: &Pose) -> Result<Isometry3<f64>, MsgError> {
    let (p, q) = (&pose.position, &pose.orientation);
    let values = [p.x, p.y, p.z, q.x, q.y, q.z, q.w];
    if let Some(index) = values.iter().position(|v| !v.is_finite()) {
        return Err(MsgError::NonFinite { what: "pose value (x, y, z, qx, qy, qz, qw)", index });
    }
    let quat = NQuaternion::new(q.w, q.x, q.y, q.z);
    if quat.norm() < 1e-9 {
        return Err(MsgError::Invalid { what: "Pose", reason: "zero quaternion".into() });
    }
    Ok(Isometry3::from_parts(Translation3::new(p.x, p.y, p.z), UnitQuaternion::from_quaternion(quat)))
}

/// One `parent → child` transform (parent-from-child) as a `/tf` message.
pub fn transform_message(stamp: Stamp, parent: &str, child: &str, parent_child: &Isometry3<f64>) -> super::TFMessage {
    let p = pose_from_isometry(parent_child);
    super::TFMessage {
        transforms: vec![super::TransformStamped {
            header: super::Header::new(stamp, parent),
            child_frame_id: child.to_string(),
            transform: super::Transform {
                translation: super::Vector3 { x: p.position.x, y: p.position.y, z: p.position.z },
                rotation: p.orientation,
            },
        }],
    }
}

/// Isometry → Pose.
pub fn pose_from_isometry(iso: &Isometry3<f64>) -> Pose {
    let t = &iso.translation.vector;
    let q = iso.rotation.quaternion();
    Pose {
        position: super::Point { x: t.x, y: t.y, z: t.z },
        orientation: Quaternion { x: q.i, y: q.j, z: q.k, w: q.w },
    }
}

/// A PoseStamped of `pose` in `frame_id`.
pub fn pose_stamped(stamp: Stamp, frame_id: &str, pose: &Isometry3<f64>) -> PoseStamped {
    PoseStamped { header: Header::new(stamp, frame_id), pose: pose_from_isometry(pose) }
}

/// A PoseWithCovarianceStamped; `covariance` over (x, y, z, rot x, rot y, rot z), written
/// row-major.
pub fn pose_with_covariance_stamped(
    stamp: Stamp,
    frame_id: &str,
    pose: &Isometry3<f64>,
    covariance: &Matrix6<f64>,
) -> PoseWithCovarianceStamped {
    let mut cov = [0.0; 36];
    for r in 0..6 {
        for c in 0..6 {
            cov[r * 6 + c] = covariance[(r, c)];
        }
    }
    PoseWithCovarianceStamped {
        header: Header::new(stamp, frame_id),
        pose: PoseWithCovariance { pose: pose_from_isometry(pose), covariance: cov },
    }
}

/// The 6×6 covariance of a PoseWithCovariance (row-major in the message).
pub fn covariance_matrix(pose: &PoseWithCovariance) -> Matrix6<f64> {
    Matrix6::from_row_slice(&pose.covariance)
}

/// Points of a PointCloud2 with `x`, `y`, `z` fields (FLOAT32 or FLOAT64, any offsets);
/// non-finite points are skipped. The map frame is `header.frame_id`.
pub fn map_cloud_from_point_cloud(cloud: &PointCloud2) -> Result<MapCloud, MsgError> {
    let invalid = |reason: String| MsgError::Invalid { what: "PointCloud2", reason };
    let step = cloud.point_step as usize;
    let mut fields = [(0usize, 0u8); 3];
    for (slot, name) in fields.iter_mut().zip(["x", "y", "z"]) {
        let f = cloud.fields.iter().find(|f| f.name == name).ok_or_else(|| invalid(format!("no field {name:?}")))?;
        let size = match f.datatype {
            PointField::FLOAT32 => 4,
            PointField::FLOAT64 => 8,
            t => return Err(invalid(format!("field {name:?} has datatype {t}, expected FLOAT32 (7) or FLOAT64 (8)"))),
        };
        if f.offset as usize + size > step {
            return Err(invalid(format!("field {name:?} at offset {} does not fit point_step {step}", f.offset)));
        }
        *slot = (f.offset as usize, f.datatype);
    }
    let (w, h, row_step) = (cloud.width as usize, cloud.height as usize, cloud.row_step as usize);
    if row_step < w * step {
        return Err(invalid(format!("row_step {row_step} < width {w} × point_step {step}")));
    }
    if cloud.data.len() != row_step * h {
        return Err(MsgError::SizeMismatch {
            what: format!("PointCloud2 {w}x{h} (row_step {row_step})"),
            expected: row_step * h,
            actual: cloud.data.len(),
        });
    }
    let big = cloud.is_bigendian;
    let read = |b: &[u8], (off, ty): (usize, u8)| -> f64 {
        if ty == PointField::FLOAT32 {
            let a = [b[off], b[off + 1], b[off + 2], b[off + 3]];
            (if big { f32::from_be_bytes(a) } else { f32::from_le_bytes(a) }) as f64
        } else {
            let mut a = [0u8; 8];
            a.copy_from_slice(&b[off..off + 8]);
            if big {
                f64::from_be_bytes(a)
            } else {
                f64::from_le_bytes(a)
            }
        }
    };
    let mut points = Vec::with_capacity(w * h);
    if step > 0 {
        for row in cloud.data.chunks_exact(row_step.max(1)).take(h) {
            for p in row[..w * step].chunks_exact(step) {
                let (x, y, z) = (read(p, fields[0]), read(p, fields[1]), read(p, fields[2]));
                if x.is_finite() && y.is_finite() && z.is_finite() {
                    points.push(Point3::new(x as f32, y as f32, z as f32));
                }
            }
        }
    }
    Ok(MapCloud { frame_id: cloud.header.frame_id.clone(), points })
}

/// An unorganized little-endian PointCloud2 with FLOAT32 x, y, z (point_step 12).
pub fn point_cloud(stamp: Stamp, map: &MapCloud) -> PointCloud2 {
    let n = map.points.len() as u32;
    let field = |name: &str, offset| PointField { name: name.into(), offset, datatype: PointField::FLOAT32, count: 1 };
    PointCloud2 {
        header: Header::new(stamp, map.frame_id.as_str()),
        height: 1,
        width: n,
        fields: vec![field("x", 0), field("y", 4), field("z", 8)],
        is_bigendian: false,
        point_step: 12,
        row_step: 12 * n,
        data: map.points.iter().flat_map(|p| [p.x, p.y, p.z]).flat_map(f32::to_le_bytes).collect(),
        is_dense: map.points.iter().all(|p| p.iter().all(|v| v.is_finite())),
    }
}

/// Core correspondences from a message; a non-finite value is an error naming its index.
pub fn correspondences_from_msg(msg: &Correspondences) -> Result<Vec<frame::Correspondence>, MsgError> {
    msg.correspondences
        .iter()
        .enumerate()
        .map(|(index, c)| {
            if [c.u, c.v, c.x, c.y, c.z, c.score].iter().all(|v| v.is_finite()) {
                Ok(frame::Correspondence {
                    pixel: Point2::new(c.u as f64, c.v as f64),
                    point: Point3::new(c.x as f64, c.y as f64, c.z as f64),
                    score: c.score,
                })
            } else {
                Err(MsgError::NonFinite { what: "correspondence", index })
            }
        })
        .collect()
}

/// A Correspondences message (header frame = camera optical frame).
pub fn correspondences_msg(
    stamp: Stamp,
    camera_frame_id: &str,
    map_frame_id: &str,
    correspondences: &[frame::Correspondence],
) -> Correspondences {
    Correspondences {
        header: Header::new(stamp, camera_frame_id),
        map_frame_id: map_frame_id.into(),
        correspondences: correspondences
            .iter()
            .map(|c| Correspondence {
                u: c.pixel.x as f32,
                v: c.pixel.y as f32,
                x: c.point.x as f32,
                y: c.point.y as f32,
                z: c.point.z as f32,
                score: c.score,
            })
            .collect(),
    }
}

/// The encoded image of a CompressedImage.
pub fn encoded_image(msg: &CompressedImage) -> EncodedImage {
    EncodedImage { format: msg.format.clone(), data: msg.data.clone() }
}

/// A CompressedImage carrying `image`.
pub fn compressed_image(stamp: Stamp, frame_id: &str, image: &EncodedImage) -> CompressedImage {
    CompressedImage { header: Header::new(stamp, frame_id), format: image.format.clone(), data: image.data.clone() }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::Point;
    use nalgebra::Vector3;

    fn image(encoding: &str, w: u32, h: u32, step: u32, big: bool, data: Vec<u8>) -> Image {
        Image {
            header: Header::new(5, "cam"),
            height: h,
            width: w,
            encoding: encoding.into(),
            is_bigendian: big as u8,
            step,
            data,
        }
    }

    #[test]
    fn camera_info_round_trips_and_rejects_bad_k() {
        let k = Intrinsics { fx: 525.0, fy: 526.0, cx: 320.0, cy: 240.0, width: 640, height: 480 };
        let info = camera_info(7, "cam", &k);
        assert_eq!(intrinsics_from_camera_info(&info).unwrap(), k);
        assert_eq!(info.p[2], 320.0);
        assert_eq!(info.p[6], 240.0);
        let mut bad = info.clone();
        bad.k[0] = 0.0;
        assert!(intrinsics_from_camera_info(&bad).is_err());
        bad.k[0] = f64::NAN;
        assert!(intrinsics_from_camera_info(&bad).is_err());
    }

    #[test]
    fn depth_32fc1_with_padding_and_both_endians() {
        let vals = [1.5f32, 2.0, -1.0, 4.25];
        for big in [false, true] {
            let mut data = Vec::new();
            for row in vals.chunks(2) {
                for v in row {
                    data.extend(if big { v.to_be_bytes() } else { v.to_le_bytes() });
                }
                data.extend([0xAA; 4]); // row padding
            }
            let d = depth_from_image(&image("32FC1", 2, 2, 12, big, data)).unwrap();
            assert_eq!(d.data, vals);
        }
    }

    #[test]
    fn depth_16uc1_is_millimetres() {
        let d = DepthImage::new(3, 1, vec![1.234, 0.0, f32::NAN]);
        let img = image_16uc1_mm(1, "cam", &d);
        assert_eq!(img.data, [0xd2, 0x04, 0, 0, 0, 0]);
        let back = depth_from_image(&img).unwrap();
        assert_eq!(back.data, [1.234, 0.0, 0.0]);
        let be = image("16UC1", 1, 1, 2, true, vec![0x04, 0xd2]);
        assert_eq!(depth_from_image(&be).unwrap().data, [1.234]);
    }

    #[test]
    fn depth_errors() {
        assert!(matches!(
            depth_from_image(&image("rgb8", 1, 1, 3, false, vec![0; 3])),
            Err(MsgError::UnsupportedEncoding(_))
        ));
        assert!(matches!(
            depth_from_image(&image("32FC1", 2, 2, 8, false, vec![0; 12])),
            Err(MsgError::SizeMismatch { .. })
        ));
        assert!(depth_from_image(&image("32FC1", 2, 1, 4, false, vec![0; 4])).is_err());
        let d = DepthImage::new(2, 1, vec![0.5, 3.0]);
        assert_eq!(depth_from_image(&image_32fc1(0, "c", &d)).unwrap(), d);
    }

    #[test]
    fn pose_round_trip() {
        let iso = Isometry3::new(Vector3::new(1.0, -2.0, 3.0), Vector3::new(0.1, 0.2, -0.3));
        let back = isometry_from_pose(&pose_stamped(3, "map", &iso).pose).unwrap();
        assert!((back.to_homogeneous() - iso.to_homogeneous()).norm() < 1e-12);
        let bad = Pose { position: Point { x: f64::INFINITY, y: 0.0, z: 0.0 }, ..Default::default() };
        assert!(matches!(isometry_from_pose(&bad), Err(MsgError::NonFinite { index: 0, .. })));
        let zero = Pose { orientation: Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 0.0 }, ..Default::default() };
        assert!(isometry_from_pose(&zero).is_err());
    }

    #[test]
    fn covariance_is_row_major() {
        let mut m = Matrix6::zeros();
        m[(0, 1)] = 7.0;
        let msg = pose_with_covariance_stamped(0, "map", &Isometry3::identity(), &m);
        assert_eq!(msg.pose.covariance[1], 7.0);
        assert_eq!(msg.pose.covariance[6], 0.0);
        assert_eq!(covariance_matrix(&msg.pose), m);
    }

    #[test]
    fn point_cloud_with_odd_layout() {
        // point_step 20: intensity at 0, z at 4, x at 8, y at 12, padding; one padded row.
        let mut data = Vec::new();
        let pts = [[1.0f32, 2.0, 3.0], [f32::NAN, 0.0, 0.0], [4.0, 5.0, 6.0]];
        for p in &pts {
            data.extend(9.0f32.to_be_bytes());
            data.extend(p[2].to_be_bytes());
            data.extend(p[0].to_be_bytes());
            data.extend(p[1].to_be_bytes());
            data.extend([0u8; 4]);
        }
        data.extend([0u8; 4]);
        let f = |n: &str, o| PointField { name: n.into(), offset: o, datatype: PointField::FLOAT32, count: 1 };
        let mut cloud = PointCloud2 {
            header: Header::new(0, "map"),
            height: 1,
            width: 3,
            fields: vec![f("intensity", 0), f("z", 4), f("x", 8), f("y", 12)],
            is_bigendian: true,
            point_step: 20,
            row_step: 64,
            data,
            is_dense: false,
        };
        let map = map_cloud_from_point_cloud(&cloud).unwrap();
        assert_eq!(map.frame_id, "map");
        assert_eq!(map.points, vec![Point3::new(1.0, 2.0, 3.0), Point3::new(4.0, 5.0, 6.0)]);
        cloud.data.pop();
        assert!(matches!(map_cloud_from_point_cloud(&cloud), Err(MsgError::SizeMismatch { .. })));
        cloud.fields.retain(|f| f.name != "y");
        assert!(map_cloud_from_point_cloud(&cloud).is_err());
        let back = map_cloud_from_point_cloud(&point_cloud(0, &map)).unwrap();
        assert_eq!(back.points, map.points);
    }

    #[test]
    fn correspondences_round_trip_and_reject_nan() {
        let c =
            vec![frame::Correspondence { pixel: Point2::new(1.5, 2.5), point: Point3::new(1.0, 2.0, 3.0), score: 0.5 }];
        let msg = correspondences_msg(9, "cam", "map", &c);
        assert_eq!(correspondences_from_msg(&msg).unwrap(), c);
        let mut bad = msg.clone();
        bad.correspondences.push(Correspondence { u: f32::NAN, ..Default::default() });
        let err = correspondences_from_msg(&bad).unwrap_err();
        assert!(err.to_string().contains("#1"), "{err}");
    }
}
