//! One localization frame: everything the core needs about one camera image, joined by
//! `header.stamp` across topics, and the map it is localized against.

use nalgebra::{Isometry3, Point2, Point3};

use crate::camera::CameraModel;
use crate::geometry::{DepthImage, Intrinsics};

mod assembler;
pub mod pinhole;
mod recent;

pub use assembler::{FrameAssembler, MonotonicNs};

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
    /// The camera image when the source carries one.
    pub image: Option<CameraImage>,
    pub ground_truth: Option<GroundTruth>,
    /// The lens model the pixels were undistorted with, when they were (raw pixels of a
    /// distorting camera): outputs map kept pixels back through it, so a matcher gets its own
    /// pixels back.
    pub lens: Option<CameraModel>,
    /// The camera's pose in the odometry frame at the frame's stamp (`odom → camera` on `/tf`,
    /// REP 105), when the robot has odometry: the motion since the last pose, for tracking.
    pub odometry: Option<Isometry3<f64>>,
}

/// A frame's camera image.
#[derive(Clone, Debug)]
pub enum CameraImage {
    /// As it travels (`sensor_msgs/CompressedImage`: JPEG/PNG bytes), as bags carry it.
    Compressed(EncodedImage),
    /// Decoded RGB (the live node converts a raw `sensor_msgs/Image` in its reader; a
    /// compressed one it keeps compressed until it draws the debug image).
    Raw(image::RgbImage),
}

impl CameraImage {
    /// The compressed bytes, when the image is still compressed.
    pub fn compressed(&self) -> Option<&EncodedImage> {
        match self {
            CameraImage::Compressed(e) => Some(e),
            CameraImage::Raw(_) => None,
        }
    }
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

/// The kinds of message that make up a [`Frame`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum PartKind {
    CameraInfo,
    Correspondences,
    DepthPrior,
    Image,
    GroundTruthPose,
    GroundTruthDepth,
}

impl PartKind {
    pub const ALL: [PartKind; 6] = [
        PartKind::CameraInfo,
        PartKind::Correspondences,
        PartKind::DepthPrior,
        PartKind::Image,
        PartKind::GroundTruthPose,
        PartKind::GroundTruthDepth,
    ];

    /// Parts without which no [`Frame`] can be built.
    pub const REQUIRED: [PartKind; 2] = [PartKind::CameraInfo, PartKind::Correspondences];

    /// The role name (as in the topic map): `camera_info`, `correspondences`, ….
    pub fn name(self) -> &'static str {
        match self {
            PartKind::CameraInfo => "camera_info",
            PartKind::Correspondences => "correspondences",
            PartKind::DepthPrior => "depth_prior",
            PartKind::Image => "image",
            PartKind::GroundTruthPose => "ground_truth_pose",
            PartKind::GroundTruthDepth => "ground_truth_depth",
        }
    }

    pub(crate) fn bit(self) -> u8 {
        1 << self as u8
    }
}

/// One decoded message that belongs to the frame at `stamp`.
#[derive(Clone, Debug)]
pub enum FramePart {
    /// The camera as CameraInfo describes it (K, D, P); the assembler reduces it to the core's
    /// pinhole camera ([`crate::camera`]).
    CameraInfo {
        stamp: Stamp,
        camera: CameraModel,
    },
    /// `camera_frame_id` is the correspondences' `header.frame_id`.
    Correspondences {
        stamp: Stamp,
        camera_frame_id: String,
        map_frame_id: String,
        correspondences: Vec<Correspondence>,
    },
    DepthPrior {
        stamp: Stamp,
        depth: DepthImage,
    },
    Image {
        stamp: Stamp,
        image: CameraImage,
    },
    GroundTruthPose {
        stamp: Stamp,
        pose: Isometry3<f64>,
    },
    GroundTruthDepth {
        stamp: Stamp,
        depth: DepthImage,
    },
}

impl FramePart {
    /// The part with its stamp replaced (stamp-tolerant matching joins it to a nearby frame).
    pub fn with_stamp(self, s: Stamp) -> FramePart {
        match self {
            FramePart::CameraInfo { camera, .. } => FramePart::CameraInfo { stamp: s, camera },
            FramePart::Correspondences { camera_frame_id, map_frame_id, correspondences, .. } => {
                FramePart::Correspondences { stamp: s, camera_frame_id, map_frame_id, correspondences }
            }
            FramePart::DepthPrior { depth, .. } => FramePart::DepthPrior { stamp: s, depth },
            FramePart::Image { image, .. } => FramePart::Image { stamp: s, image },
            FramePart::GroundTruthPose { pose, .. } => FramePart::GroundTruthPose { stamp: s, pose },
            FramePart::GroundTruthDepth { depth, .. } => FramePart::GroundTruthDepth { stamp: s, depth },
        }
    }

    pub fn stamp(&self) -> Stamp {
        match self {
            FramePart::CameraInfo { stamp, .. }
            | FramePart::Correspondences { stamp, .. }
            | FramePart::DepthPrior { stamp, .. }
            | FramePart::Image { stamp, .. }
            | FramePart::GroundTruthPose { stamp, .. }
            | FramePart::GroundTruthDepth { stamp, .. } => *stamp,
        }
    }

    pub fn kind(&self) -> PartKind {
        match self {
            FramePart::CameraInfo { .. } => PartKind::CameraInfo,
            FramePart::Correspondences { .. } => PartKind::Correspondences,
            FramePart::DepthPrior { .. } => PartKind::DepthPrior,
            FramePart::Image { .. } => PartKind::Image,
            FramePart::GroundTruthPose { .. } => PartKind::GroundTruthPose,
            FramePart::GroundTruthDepth { .. } => PartKind::GroundTruthDepth,
        }
    }
}

/// A frame that lacks an expected part or had a part that failed to decode.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct IncompleteFrame {
    pub stamp: Stamp,
    /// Role names of the expected parts that never arrived (or failed to decode).
    pub missing: Vec<&'static str>,
    /// Why parts failed (`"<part>: <reason>"`), duplicates, time-outs.
    pub errors: Vec<String>,
    /// True when a required part is missing, so no [`Frame`] was produced.
    pub dropped: bool,
    /// Late parts or a repeated frame at a stamp already handed out: not a frame of its own.
    pub repeat: bool,
    /// Only late parts (no second complete frame) for a stamp already handed out: not a frame
    /// at all. Implies `repeat`; a `repeat` without it is a repeated stamp (a second frame).
    pub late_parts: bool,
    /// A correspondences message came for this stamp (decoded or not): the input had a frame here.
    pub has_correspondences: bool,
}

/// What the assembler hands out for one stamp.
#[derive(Clone, Debug)]
pub enum Assembled {
    /// Every expected part arrived and decoded.
    Complete(Frame),
    /// Usable (required parts present) but some expected part is missing or broken.
    Partial(Frame, IncompleteFrame),
    /// A required part is missing: no frame.
    Dropped(IncompleteFrame),
}

impl Assembled {
    pub fn stamp(&self) -> Stamp {
        match self {
            Assembled::Complete(f) | Assembled::Partial(f, _) => f.stamp,
            Assembled::Dropped(i) => i.stamp,
        }
    }

    /// Splits outcomes into usable frames and reports (a partial frame appears in both).
    pub fn split(items: impl IntoIterator<Item = Assembled>) -> (Vec<Frame>, Vec<IncompleteFrame>) {
        let (mut frames, mut reports) = (Vec::new(), Vec::new());
        for item in items {
            match item {
                Assembled::Complete(f) => frames.push(f),
                Assembled::Partial(f, r) => {
                    frames.push(f);
                    reports.push(r);
                }
                Assembled::Dropped(r) => reports.push(r),
            }
        }
        (frames, reports)
    }
}
