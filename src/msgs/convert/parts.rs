//! Message → frame part (and the map): one conversion per input message, used by bag replay
//! ([`crate::bag::decode_part_limited`]) and by the live node's readers alike.
//!
//! Each function validates what it converts (finite values, sizes within the
//! [`InputLimits`]) and returns the part stamped with the message's `header.stamp`.

use super::{
    compressed_image, correspondences_from_msg, depth_from_image, encoded_image, intrinsics_from_camera_info,
    isometry_from_pose, map_cloud_from_point_cloud, stamp,
};
use crate::camera::{CameraModel, CameraModelError, Distortion};
use crate::frame::{CameraImage, EncodedImage, FramePart, MapCloud, Stamp};
use crate::limits::{limit_correspondences, CorrespondenceFixes, InputLimits};
use crate::msgs::{CameraInfo, CompressedImage, Correspondences, Image, MsgError, PointCloud2, PoseStamped};

/// Refuses an image side over `limits.max_image_side` before anything is allocated for it.
fn check_side(what: &'static str, width: u32, height: u32, limits: &InputLimits) -> Result<(), MsgError> {
    crate::limits::check_image_side(what, width, height, limits).map_err(|reason| MsgError::Invalid { what, reason })
}

/// Refuses an image that would be decoded into memory over `limits.max_image_side` or
/// `limits.max_image_pixels`, before a pixel is converted.
fn check_size(what: &'static str, width: u32, height: u32, limits: &InputLimits) -> Result<(), MsgError> {
    check_side(what, width, height, limits)?;
    crate::limits::check_image_pixels(what, width, height, limits).map_err(|reason| MsgError::Invalid { what, reason })
}

/// A `sensor_msgs/CameraInfo` → the frame's intrinsics.
pub fn camera_info_part(msg: &CameraInfo, limits: &InputLimits) -> Result<FramePart, MsgError> {
    check_side("CameraInfo", msg.width, msg.height, limits)?;
    let raw = intrinsics_from_camera_info(msg)?;
    // A model this build does not know is refused only where D is used (raw pixels).
    let (distortion, unsupported_model) = match Distortion::from_ros(&msg.distortion_model, &msg.d) {
        Ok(distortion) => (distortion, None),
        Err(CameraModelError::UnknownModel { model }) => (Distortion::None, Some(model)),
        Err(e) => return Err(MsgError::Invalid { what: "CameraInfo", reason: e.to_string() }),
    };
    let camera = CameraModel { raw, distortion, projection: msg.p, unsupported_model };
    Ok(FramePart::CameraInfo { stamp: stamp(&msg.header), camera })
}

/// An `angle_i2p_msgs/Correspondences` → the frame's putative matches (its `header.frame_id`
/// is the camera frame).
pub fn correspondences_part(msg: Correspondences) -> Result<FramePart, MsgError> {
    Ok(FramePart::Correspondences {
        stamp: stamp(&msg.header),
        correspondences: correspondences_from_msg(&msg)?,
        camera_frame_id: msg.header.frame_id,
        map_frame_id: msg.map_frame_id,
    })
}

/// Like [`correspondences_part`], held to the limits at once (scores clamped, duplicates
/// merged over `merge_duplicates_above`, the best `max_correspondences` kept, as a frame's
/// assembly does): the live node's readers hand on at most the limit however many a message
/// carries, so what waits in its queues is bounded. What changed comes back to be counted.
pub fn correspondences_part_within(
    msg: Correspondences,
    limits: &InputLimits,
) -> Result<(FramePart, CorrespondenceFixes), MsgError> {
    let mut part = correspondences_part(msg)?;
    let fixes = match &mut part {
        FramePart::Correspondences { correspondences, .. } => limit_correspondences(correspondences, limits),
        _ => CorrespondenceFixes::default(),
    };
    Ok((part, fixes))
}

/// A `sensor_msgs/Image` (32FC1 or 16UC1) → the frame's monocular depth prior.
pub fn depth_prior_part(msg: &Image, limits: &InputLimits) -> Result<FramePart, MsgError> {
    check_size("depth prior", msg.width, msg.height, limits)?;
    Ok(FramePart::DepthPrior { stamp: stamp(&msg.header), depth: depth_from_image(msg)? })
}

/// A `sensor_msgs/CompressedImage` → the frame's camera image, as it came (not decoded).
pub fn compressed_image_part(msg: &CompressedImage) -> FramePart {
    FramePart::Image { stamp: stamp(&msg.header), image: CameraImage::Compressed(encoded_image(msg)) }
}

/// The `sensor_msgs/CompressedImage` of a frame's camera image (a decoded one as PNG): the
/// inverse of [`compressed_image_part`], for writing input bags.
pub fn compressed_image_msg(stamp: Stamp, frame_id: &str, image: &CameraImage) -> Result<CompressedImage, MsgError> {
    let png;
    let encoded = match image {
        CameraImage::Compressed(e) => e,
        CameraImage::Raw(rgb) => {
            let mut data = Vec::new();
            rgb.write_to(&mut std::io::Cursor::new(&mut data), image::ImageFormat::Png)
                .map_err(|e| MsgError::Invalid { what: "camera image", reason: format!("PNG encoding failed: {e}") })?;
            png = EncodedImage { format: "png".into(), data };
            &png
        }
    };
    Ok(compressed_image(stamp, frame_id, encoded))
}

/// A map as decoded, with what the limits changed in it (said, never silent).
pub struct DecodedMap {
    pub map: MapCloud,
    pub notes: Vec<String>,
}

/// A `sensor_msgs/PointCloud2` → the map: non-finite points dropped, an even subsample within
/// `limits.max_map_points`, each change noted.
pub fn map_part(cloud: &PointCloud2, limits: &InputLimits) -> Result<DecodedMap, MsgError> {
    let total = cloud.width as usize * cloud.height as usize;
    let mut map = map_cloud_from_point_cloud(cloud)?;
    let mut notes = Vec::new();
    let non_finite = total.saturating_sub(map.points.len());
    if non_finite > 0 {
        notes.push(format!("{non_finite} of {total} map points are not finite; dropped"));
    }
    let left_out = crate::limits::limit_map(&mut map, limits);
    if left_out > 0 {
        notes.push(format!(
            "map of {} points: kept an even subsample of {} (limits.max_map_points), left out {left_out}",
            map.points.len() + left_out,
            map.points.len()
        ));
    }
    if map.points.is_empty() {
        notes.push("the map has no usable point: frames are localized without it (no verification)".into());
    }
    Ok(DecodedMap { map, notes })
}

/// A `geometry_msgs/PoseStamped` (camera-to-map) → the frame's ground-truth pose.
pub fn ground_truth_pose_part(msg: &PoseStamped) -> Result<FramePart, MsgError> {
    Ok(FramePart::GroundTruthPose { stamp: stamp(&msg.header), pose: isometry_from_pose(&msg.pose)? })
}

/// A `sensor_msgs/Image` (16UC1 mm or 32FC1 m) → the frame's ground-truth depth.
pub fn ground_truth_depth_part(msg: &Image, limits: &InputLimits) -> Result<FramePart, MsgError> {
    check_size("ground-truth depth", msg.width, msg.height, limits)?;
    Ok(FramePart::GroundTruthDepth { stamp: stamp(&msg.header), depth: depth_from_image(msg)? })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Correspondence;
    use crate::geometry::{DepthImage, Intrinsics};
    use nalgebra::{Point2, Point3};

    #[test]
    fn parts_carry_the_header_stamp_and_refuse_absurd_sizes() {
        let k = Intrinsics { fx: 500.0, fy: 500.0, cx: 320.0, cy: 240.0, width: 640, height: 480 };
        let limits = InputLimits::default();
        let info = super::super::camera_info(42, "cam", &k);
        assert!(matches!(camera_info_part(&info, &limits), Ok(FramePart::CameraInfo { stamp: 42, .. })));
        // A distortion model this build does not know travels as such: refused for raw pixels
        // (where D is used), fine for rectified ones.
        let mut kannala = info.clone();
        kannala.distortion_model = "kannala_brandt".into();
        kannala.d = vec![0.1, 0.01, 0.0, 0.0];
        let Ok(FramePart::CameraInfo { camera, .. }) = camera_info_part(&kannala, &limits) else {
            panic!("an unknown model is not refused at the message");
        };
        assert_eq!(camera.unsupported_model.as_deref(), Some("kannala_brandt"));
        assert!(camera.core_intrinsics(crate::camera::PixelSpace::Raw).unwrap_err().to_string().contains("kannala"));
        assert_eq!(camera.core_intrinsics(crate::camera::PixelSpace::Rectified).unwrap(), k, "P empty: K");
        let mut huge = info.clone();
        huge.width = limits.max_image_side + 1;
        let err = camera_info_part(&huge, &limits).unwrap_err().to_string();
        assert!(err.contains("limits.max_image_side"), "{err}");

        let prior = super::super::image_32fc1(7, "cam", &DepthImage::new(2, 1, vec![1.0, 2.0]));
        assert!(matches!(depth_prior_part(&prior, &limits), Ok(FramePart::DepthPrior { stamp: 7, .. })));
        let mut tall = prior.clone();
        tall.height = u32::MAX;
        assert!(depth_prior_part(&tall, &limits).is_err());
        // Within max_image_side but over the pixel budget: refused before any pixel is read,
        // the prior and the ground-truth depth alike.
        let budget = InputLimits { max_image_pixels: 1, ..InputLimits::default() };
        let err = depth_prior_part(&prior, &budget).unwrap_err().to_string();
        assert!(err.contains("limits.max_image_pixels = 1") && err.contains("2x1"), "{err}");
        assert!(ground_truth_depth_part(&prior, &budget).is_err());

        let c = Correspondence { pixel: Point2::new(1.0, 2.0), point: Point3::new(0.0, 0.0, 1.0), score: 0.5 };
        let msg = super::super::correspondences_msg(9, "cam", "map", &[c]);
        match correspondences_part(msg.clone()) {
            Ok(FramePart::Correspondences { stamp: 9, camera_frame_id, map_frame_id, correspondences }) => {
                assert_eq!((camera_frame_id.as_str(), map_frame_id.as_str()), ("cam", "map"));
                assert_eq!(correspondences, vec![c]);
            }
            other => panic!("{other:?}"),
        }
        let mut nan = msg;
        nan.correspondences[0].u = f32::NAN;
        assert!(correspondences_part(nan).is_err());
    }

    #[test]
    fn a_decoded_camera_image_is_written_as_png_and_reads_back() {
        let mut rgb = image::RgbImage::new(3, 2);
        rgb.put_pixel(2, 1, image::Rgb([200, 100, 50]));
        let msg = compressed_image_msg(5, "cam", &CameraImage::Raw(rgb.clone())).expect("png");
        assert_eq!((msg.format.as_str(), super::super::stamp(&msg.header)), ("png", 5));
        match compressed_image_part(&msg) {
            FramePart::Image { stamp: 5, image: CameraImage::Compressed(e) } => {
                assert_eq!(image::load_from_memory(&e.data).expect("decodes").to_rgb8(), rgb);
            }
            other => panic!("{other:?}"),
        }
    }
}
