//! rosbag2 MCAP bags: [`BagReader`] / [`BagWriter`], the [`TopicMap`], and frames from and to
//! bags ([`read_frames`], [`write_input_bag`]).
//!
//! Bags are directories with `metadata.yaml` and `.mcap` files (profile `ros2`, CDR
//! messages, `ros2msg` schemas), as written by `ros2 bag record -s mcap` and rosbags.

mod frames;
pub mod metadata;
mod odometry;
pub mod qos;
mod reader;
mod writer;

pub use frames::{decode_map, expected_types, limit_frame, DecodedMap, FrameStream};
pub use odometry::{BagOdometry, OdometryTopics};
pub use reader::{
    storage_files, BagChannel, BagMessage, BagMessages, BagReader, ReadOptions, DEFAULT_MAX_RECORD_BYTES,
};
pub use writer::{BagWriter, ChunkCompression, LIBRARY};

pub use crate::params::TopicMap;

use std::path::{Path, PathBuf};

use crate::frame::Frame;
use crate::frame::{Assembled, FramePart, IncompleteFrame, MapCloud, PartKind};
use crate::limits::InputLimits;
use crate::msgs::{convert, from_cdr, MsgError};

/// Why a bag could not be read or written; every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum BagError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not an MCAP file (bad magic bytes at the start)")]
    NotMcap { path: PathBuf },
    #[error("{path}: truncated MCAP file (no end magic; was the recording interrupted?)")]
    Truncated { path: PathBuf },
    #[error("{path}: corrupt MCAP file: {reason}")]
    Corrupt { path: PathBuf, reason: String },
    #[error("{path}: MCAP profile is {profile:?}, not a rosbag2 bag (expected \"ros2\")")]
    ForeignProfile { path: PathBuf, profile: String },
    #[error("{path}: topic {topic} has message encoding {encoding:?}, expected \"cdr\"")]
    MessageEncoding { path: PathBuf, topic: String, encoding: String },
    #[error("{path}: topic {topic} has schema encoding {encoding:?}, expected \"ros2msg\" or \"ros2idl\"")]
    SchemaEncoding { path: PathBuf, topic: String, encoding: String },
    #[error("{path}: bad rosbag2 metadata: {reason}")]
    Metadata { path: PathBuf, reason: String },
    #[error("{path}: no .mcap files and no metadata.yaml")]
    NoStorageFiles { path: PathBuf },
    #[error("{path}: cannot write bag: {reason}")]
    Write { path: PathBuf, reason: String },
    #[error("{path}: {topic}: {source}")]
    Message { path: PathBuf, topic: String, source: MsgError },
    #[error("{path}: topic {topic} carries {found}, expected {expected}")]
    WrongType { path: PathBuf, topic: String, expected: String, found: String },
}

/// What each topic of the map carries, for the bag and node edges (the names are remappable).
impl TopicMap {
    /// The frame part carried by `topic`, if it is a frame input.
    pub fn part_of(&self, topic: &str) -> Option<PartKind> {
        PartKind::ALL.into_iter().find(|k| self.topic_of(*k) == topic)
    }

    /// The input topic of a frame part.
    pub fn topic_of(&self, kind: PartKind) -> &str {
        match kind {
            PartKind::CameraInfo => &self.camera_info,
            PartKind::Correspondences => &self.correspondences,
            PartKind::DepthPrior => &self.depth_prior,
            PartKind::Image => &self.image,
            PartKind::GroundTruthPose => &self.ground_truth_pose,
            PartKind::GroundTruthDepth => &self.ground_truth_depth,
        }
    }
}

/// A message that could not be used and belongs to no frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MessageIssue {
    pub topic: String,
    pub log_time: u64,
    pub reason: String,
}

/// Frames read from a bag.
#[derive(Clone, Debug, Default)]
pub struct BagFrames {
    /// The first map message, if any decoded.
    pub map: Option<MapCloud>,
    /// Usable frames (camera info and correspondences present), sorted by stamp.
    pub frames: Vec<Frame>,
    /// Frames with a missing or broken part, sorted by stamp; `dropped` ones are not in `frames`.
    pub incomplete: Vec<IncompleteFrame>,
    /// Map messages that failed to decode, extra maps.
    pub issues: Vec<MessageIssue>,
}

/// Decodes one frame input message into its part, with the default [`InputLimits`].
pub fn decode_part(kind: PartKind, data: &[u8]) -> Result<FramePart, MsgError> {
    decode_part_limited(kind, data, &InputLimits::default())
}

/// Decodes one frame input message into its part; a CameraInfo or depth image larger than
/// `limits.max_image_side` is refused (the conversions are [`convert`]'s, shared with the node).
pub fn decode_part_limited(kind: PartKind, data: &[u8], limits: &InputLimits) -> Result<FramePart, MsgError> {
    match kind {
        PartKind::CameraInfo => convert::camera_info_part(&from_cdr(data)?, limits),
        PartKind::Correspondences => convert::correspondences_part(from_cdr(data)?),
        PartKind::DepthPrior => convert::depth_prior_part(&from_cdr(data)?, limits),
        PartKind::Image => Ok(convert::compressed_image_part(&from_cdr(data)?)),
        PartKind::GroundTruthPose => convert::ground_truth_pose_part(&from_cdr(data)?),
        PartKind::GroundTruthDepth => convert::ground_truth_depth_part(&from_cdr(data)?, limits),
    }
}

/// Reads the map and all frames of a bag, joining topics by `header.stamp`, with the default
/// [`InputLimits`] (in memory: for small bags and tests; `replay` and `eval` stream).
///
/// A frame waits for every part whose topic exists in the bag; a missing part, or a message
/// that fails to decode (reported with topic, stamp and reason), never aborts the bag.
pub fn read_frames(path: impl AsRef<Path>, topics: &TopicMap) -> Result<BagFrames, BagError> {
    read_frames_limited(path, topics, &InputLimits::default())
}

pub fn read_frames_limited(
    path: impl AsRef<Path>,
    topics: &TopicMap,
    limits: &InputLimits,
) -> Result<BagFrames, BagError> {
    let mut stream = FrameStream::open(path, topics, limits)?;
    let mut assembled = Vec::new();
    while let Some(a) = stream.next_frame()? {
        assembled.push(a);
    }
    assembled.sort_by_key(Assembled::stamp);
    let (frames, incomplete) = Assembled::split(assembled);
    let mut issues = std::mem::take(&mut stream.issues);
    issues.extend(stream.limit_counts.summary().into_iter().map(|reason| MessageIssue {
        topic: topics.correspondences.clone(),
        log_time: 0,
        reason,
    }));
    Ok(BagFrames { map: stream.map.take(), frames, incomplete, issues })
}

/// Writes an input bag in the layout of the shared bags: the map once first (stamp 100 ms
/// before the first frame), then per frame camera_info, compressed image (if any), depth
/// prior (32FC1, if any), correspondences, ground-truth pose (in the map frame) and depth
/// (16UC1 mm), all with `header.stamp` = frame stamp, log time = stamp, and
/// `frame_id` = the camera frame.
pub fn write_input_bag(
    dir: impl AsRef<Path>,
    topics: &TopicMap,
    map: &MapCloud,
    frames: &[Frame],
) -> Result<(), BagError> {
    let dir = dir.as_ref();
    let mut w = BagWriter::create(dir)?;
    let first = frames.iter().map(|f| f.stamp).min().unwrap_or(100_000_000);
    let map_stamp = first.saturating_sub(100_000_000).max(0);
    w.latch(&topics.map);
    w.write(&topics.map, map_stamp, &convert::point_cloud(map_stamp, map))?;
    let mut order: Vec<&Frame> = frames.iter().collect();
    order.sort_by_key(|f| f.stamp);
    for f in order {
        write_frame(&mut w, topics, f)?;
    }
    w.finish()?;
    Ok(())
}

/// The odometry frame a written frame's odometry names on `/tf` (REP 105's `odom`).
pub const ODOM_FRAME_ID: &str = "odom";

/// Writes the messages of one input frame (camera info, image, prior, correspondences, its
/// odometry on `/tf`, ground truth), all at the frame's stamp.
pub fn write_frame(w: &mut BagWriter, topics: &TopicMap, f: &Frame) -> Result<(), BagError> {
    let (t, cam) = (f.stamp, f.camera_frame_id.as_str());
    // First, as TF flows ahead of a frame's parts: its odometry is known when the frame is whole.
    if let Some(odometry) = &f.odometry {
        let tf = convert::transform_message(t, ODOM_FRAME_ID, cam, odometry);
        w.write(&OdometryTopics::default().tf, t, &tf)?;
    }
    w.write(&topics.camera_info, t, &convert::camera_info(t, cam, &f.intrinsics))?;
    if let Some(image) = &f.image {
        let msg = convert::compressed_image_msg(t, cam, image)
            .map_err(|e| BagError::Write { path: w.dir().to_path_buf(), reason: e.to_string() })?;
        w.write(&topics.image, t, &msg)?;
    }
    if let Some(prior) = &f.depth_prior {
        w.write(&topics.depth_prior, t, &convert::image_32fc1(t, cam, prior))?;
    }
    let corr = convert::correspondences_msg(t, cam, &f.map_frame_id, &f.correspondences);
    w.write(&topics.correspondences, t, &corr)?;
    if let Some(gt) = &f.ground_truth {
        if let Some(pose) = &gt.pose {
            w.write(&topics.ground_truth_pose, t, &convert::pose_stamped(t, &f.map_frame_id, pose))?;
        }
        if let Some(depth) = &gt.depth {
            w.write(&topics.ground_truth_depth, t, &convert::image_16uc1_mm(t, cam, depth))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{CameraImage, Correspondence, EncodedImage, GroundTruth, Stamp};
    use crate::geometry::{DepthImage, Intrinsics};
    use crate::msgs;
    use nalgebra::{Isometry3, Point2, Point3, Vector3};

    fn frame(stamp: Stamp, with_prior: bool) -> Frame {
        Frame {
            stamp,
            camera_frame_id: "camera_color_optical_frame".into(),
            map_frame_id: "map".into(),
            intrinsics: Intrinsics { fx: 525.0, fy: 525.0, cx: 320.0, cy: 240.0, width: 4, height: 2 },
            correspondences: vec![Correspondence {
                pixel: Point2::new(1.5, 0.5),
                point: Point3::new(0.25, -1.0, 2.0),
                score: 0.75,
            }],
            depth_prior: with_prior.then(|| DepthImage::new(2, 1, vec![1.5, 2.5])),
            image: Some(CameraImage::Compressed(EncodedImage {
                format: "jpeg".into(),
                data: vec![0xff, 0xd8, 0xff, 0xd9],
            })),
            ground_truth: Some(GroundTruth {
                pose: Some(Isometry3::new(Vector3::new(1.0, 2.0, 3.0), Vector3::new(0.0, 0.5, 0.0))),
                depth: Some(DepthImage::new(4, 2, vec![1.0, 0.0, 2.5, 0.5, 0.0, 0.0, 0.0, 1.234])),
            }),
            lens: None,
            odometry: None,
        }
    }

    #[test]
    fn input_bag_round_trips_through_read_frames() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("bag");
        let map =
            MapCloud { frame_id: "map".into(), points: vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-1.0, 0.5, 9.0)] };
        let frames = vec![frame(1_700_000_000_200_000_000, true), frame(1_700_000_000_100_000_000, true)];
        write_input_bag(&dir, &TopicMap::default(), &map, &frames).unwrap();
        assert!(dir.join("metadata.yaml").exists());
        let read = read_frames(&dir, &TopicMap::default()).unwrap();
        assert_eq!(read.map.unwrap().points, map.points);
        assert!(read.incomplete.is_empty(), "{:?}", read.incomplete);
        assert_eq!(read.frames.len(), 2);
        assert!(read.frames[0].stamp < read.frames[1].stamp);
        let (a, b) = (&read.frames[0], &frames[1]);
        assert_eq!(a.camera_frame_id, b.camera_frame_id);
        assert_eq!(a.intrinsics, b.intrinsics);
        assert_eq!(a.correspondences, b.correspondences);
        assert_eq!(a.depth_prior, b.depth_prior);
        let compressed = |f: &Frame| f.image.as_ref().and_then(CameraImage::compressed).map(|i| i.data.clone());
        assert_eq!(compressed(a), compressed(b));
        assert!(compressed(a).is_some());
        let (ga, gb) = (a.ground_truth.as_ref().unwrap(), b.ground_truth.as_ref().unwrap());
        assert!((ga.pose.unwrap().to_homogeneous() - gb.pose.unwrap().to_homogeneous()).norm() < 1e-12);
        assert_eq!(ga.depth, gb.depth);
    }

    #[test]
    fn input_bag_offers_the_map_latched_and_the_rest_volatile() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("bag");
        let map = MapCloud { frame_id: "map".into(), points: vec![Point3::new(1.0, 2.0, 3.0)] };
        let topics = TopicMap::default();
        write_input_bag(&dir, &topics, &map, &[frame(1_700_000_000_100_000_000, true)]).unwrap();
        let text = std::fs::read_to_string(dir.join("metadata.yaml")).unwrap();
        let meta: metadata::MetadataFile = serde_yaml::from_str(&text).unwrap();
        let durability = |topic: &str| {
            let t = meta.rosbag2_bagfile_information.topics_with_message_count.iter();
            let t = t.map(|t| &t.topic_metadata).find(|m| m.name == topic).unwrap();
            t.offered_qos_profiles[0]["durability"].as_str().unwrap().to_string()
        };
        assert_eq!(durability(&topics.map), "transient_local");
        assert_eq!(durability(&topics.correspondences), "volatile");
        // rosbag2's MCAP storage reads the same list from the channel's metadata.
        let bytes = std::fs::read(dir.join("bag.mcap")).unwrap();
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        let channel = summary.channels.values().find(|c| c.topic == topics.map).unwrap();
        let profiles: serde_yaml::Value = serde_yaml::from_str(&channel.metadata["offered_qos_profiles"]).unwrap();
        assert_eq!(profiles[0]["durability"].as_str(), Some("transient_local"));
    }

    #[test]
    fn missing_parts_and_bad_messages_are_reported() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("bag");
        let topics = TopicMap::default();
        let mut w = BagWriter::create(&dir).unwrap();
        // Frame 10: complete but no depth prior while another frame has one.
        let f = frame(10, false);
        w.write(&topics.camera_info, 10, &convert::camera_info(10, "cam", &f.intrinsics)).unwrap();
        w.write(&topics.correspondences, 10, &convert::correspondences_msg(10, "cam", "map", &f.correspondences))
            .unwrap();
        // Frame 20: a NaN correspondence and a depth prior with a bad encoding.
        let mut bad = convert::correspondences_msg(20, "cam", "map", &f.correspondences);
        bad.correspondences[0].x = f32::NAN;
        w.write(&topics.camera_info, 20, &convert::camera_info(20, "cam", &f.intrinsics)).unwrap();
        w.write(&topics.correspondences, 20, &bad).unwrap();
        let mut prior = convert::image_32fc1(20, "cam", &DepthImage::new(1, 1, vec![1.0]));
        prior.encoding = "rgb8".into();
        w.write(&topics.depth_prior, 20, &prior).unwrap();
        // Frame 30: only correspondences; plus garbage on the map topic.
        w.write(&topics.correspondences, 30, &convert::correspondences_msg(30, "cam", "map", &f.correspondences))
            .unwrap();
        w.write_raw(
            &topics.map,
            "sensor_msgs/msg/PointCloud2",
            <msgs::PointCloud2 as msgs::RosMessage>::SCHEMA,
            1,
            &[0, 1, 0, 0, 9],
        )
        .unwrap();
        w.finish().unwrap();

        let read = read_frames(&dir, &topics).unwrap();
        assert!(read.map.is_none());
        assert_eq!(read.issues.len(), 1);
        assert_eq!(read.frames.iter().map(|f| f.stamp).collect::<Vec<_>>(), vec![10]);
        let stamps: Vec<_> = read.incomplete.iter().map(|i| (i.stamp, i.dropped)).collect();
        assert_eq!(stamps, vec![(10, false), (20, true), (30, true)]);
        assert_eq!(read.incomplete[0].missing, vec!["depth_prior"]);
        let r20 = &read.incomplete[1];
        assert_eq!(r20.missing, vec!["correspondences", "depth_prior"]);
        assert!(
            r20.errors.iter().any(|e| e.contains("/matcher/correspondences") && e.contains("#0")),
            "{:?}",
            r20.errors
        );
        assert!(r20.errors.iter().any(|e| e.contains("rgb8")), "{:?}", r20.errors);
        assert_eq!(read.incomplete[2].missing, vec!["camera_info", "depth_prior"]);
    }

    #[test]
    fn writer_refuses_existing_bag_and_type_conflicts() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("b");
        let mut w = BagWriter::create(&dir).unwrap();
        w.write("/x", 5, &msgs::Header::new(5, "f")).unwrap();
        let err = w.write("/x", 6, &msgs::Time::from_nanos(6)).unwrap_err();
        assert!(err.to_string().contains("/x"), "{err}");
        assert!(w.write("/y", -1, &msgs::Time::default()).is_err());
        w.finish().unwrap();
        let err = BagWriter::create(&dir).err().unwrap();
        assert!(err.to_string().contains("already exists"), "{err}");
    }

    #[test]
    fn a_frame_part_is_found_by_its_remapped_topic() {
        let t = TopicMap { image: "/cam/jpeg".into(), ..TopicMap::default() };
        assert_eq!(t.part_of("/cam/jpeg"), Some(PartKind::Image));
        assert_eq!(t.part_of("/camera/image_raw/compressed"), None);
        assert_eq!(t.part_of("/depth_prior/image"), Some(PartKind::DepthPrior));
    }
}
