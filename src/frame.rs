//! One localization frame: everything the core needs about one camera image, joined by
//! `header.stamp` across topics, and the map it is localized against.

use nalgebra::{Isometry3, Point2, Point3};

use crate::geometry::{DepthImage, Intrinsics};

/// `header.stamp` in nanoseconds since the epoch; the key that joins a frame's topics.
pub type Stamp = i64;

/// One putative match between an image pixel and a 3D map point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Correspondence {
    /// Pixel (u = column, v = row), sub-pixel, in the camera image's pixel grid.
    pub pixel: Point2<f64>,
    /// Map point in the map frame, metres.
    pub point: Point3<f64>,
    /// Confidence in [0, 1]: the matcher's on input, the inlier score on output.
    pub score: f32,
}

/// Ground truth carried by evaluation bags (never used by the localizer itself).
#[derive(Clone, Debug)]
pub struct GroundTruth {
    /// Camera-to-map pose of the camera's optical frame.
    pub pose: Option<Isometry3<f64>>,
    /// Metric depth registered to the camera image, metres; 0 = unknown.
    pub depth: Option<DepthImage>,
}

/// Everything about one camera image that the localizer consumes.
#[derive(Clone, Debug)]
pub struct Frame {
    pub stamp: Stamp,
    /// The camera's optical frame (`header.frame_id` of the correspondences).
    pub camera_frame_id: String,
    /// Frame of the map points.
    pub map_frame_id: String,
    pub intrinsics: Intrinsics,
    pub correspondences: Vec<Correspondence>,
    /// Monocular depth prior, known up to scale and shift; any resolution.
    pub depth_prior: Option<DepthImage>,
    /// Encoded camera image (JPEG/PNG bytes) when the source carries one.
    pub image: Option<EncodedImage>,
    pub ground_truth: Option<GroundTruth>,
}

/// A compressed camera image as it travels (`sensor_msgs/CompressedImage`).
#[derive(Clone, Debug)]
pub struct EncodedImage {
    pub format: String,
    pub data: Vec<u8>,
}

/// The point map the camera is localized against.
#[derive(Clone, Debug, Default)]
pub struct MapCloud {
    pub frame_id: String,
    pub points: Vec<Point3<f32>>,
}
