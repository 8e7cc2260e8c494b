//! Message structs; field order is the `.msg` order (= CDR wire order).

use serde::{Deserialize, Serialize};

use super::schema;
use super::serde_helpers::{bytes, fixed};
use super::RosMessage;

macro_rules! ros_message {
    ($ty:ty, $name:literal, $schema:expr, $hash:literal) => {
        impl RosMessage for $ty {
            const TYPE_NAME: &'static str = $name;
            const SCHEMA: &'static str = $schema;
            const TYPE_HASH: &'static str = $hash;
        }
    };
}

/// `builtin_interfaces/msg/Time`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// From nanoseconds since the epoch (seconds saturate at the `int32` range).
    pub fn from_nanos(ns: i64) -> Self {
        let sec = ns.div_euclid(1_000_000_000);
        let nanosec = ns.rem_euclid(1_000_000_000) as u32;
        match i32::try_from(sec) {
            Ok(sec) => Self { sec, nanosec },
            Err(_) if sec < 0 => Self { sec: i32::MIN, nanosec: 0 },
            Err(_) => Self { sec: i32::MAX, nanosec: 999_999_999 },
        }
    }

    /// Nanoseconds since the epoch.
    pub fn to_nanos(&self) -> i64 {
        self.sec as i64 * 1_000_000_000 + self.nanosec as i64
    }
}

/// `std_msgs/msg/Header`.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

impl Header {
    pub fn new(stamp_ns: i64, frame_id: impl Into<String>) -> Self {
        Self { stamp: Time::from_nanos(stamp_ns), frame_id: frame_id.into() }
    }
}

/// `sensor_msgs/msg/Image`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Image {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub encoding: String,
    pub is_bigendian: u8,
    pub step: u32,
    #[serde(with = "bytes")]
    pub data: Vec<u8>,
}

/// `sensor_msgs/msg/CompressedImage`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CompressedImage {
    pub header: Header,
    pub format: String,
    #[serde(with = "bytes")]
    pub data: Vec<u8>,
}

/// `sensor_msgs/msg/RegionOfInterest`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RegionOfInterest {
    pub x_offset: u32,
    pub y_offset: u32,
    pub height: u32,
    pub width: u32,
    pub do_rectify: bool,
}

/// `sensor_msgs/msg/CameraInfo`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CameraInfo {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub distortion_model: String,
    pub d: Vec<f64>,
    #[serde(with = "fixed")]
    pub k: [f64; 9],
    #[serde(with = "fixed")]
    pub r: [f64; 9],
    #[serde(with = "fixed")]
    pub p: [f64; 12],
    pub binning_x: u32,
    pub binning_y: u32,
    pub roi: RegionOfInterest,
}

/// `sensor_msgs/msg/PointField`.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PointField {
    pub name: String,
    pub offset: u32,
    pub datatype: u8,
    pub count: u32,
}

impl PointField {
    pub const INT8: u8 = 1;
    pub const UINT8: u8 = 2;
    pub const INT16: u8 = 3;
    pub const UINT16: u8 = 4;
    pub const INT32: u8 = 5;
    pub const UINT32: u8 = 6;
    pub const FLOAT32: u8 = 7;
    pub const FLOAT64: u8 = 8;
}

/// `sensor_msgs/msg/PointCloud2`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PointCloud2 {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub fields: Vec<PointField>,
    pub is_bigendian: bool,
    pub point_step: u32,
    pub row_step: u32,
    #[serde(with = "bytes")]
    pub data: Vec<u8>,
    pub is_dense: bool,
}

/// `geometry_msgs/msg/Point`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Point {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// `geometry_msgs/msg/Vector3`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// `geometry_msgs/msg/Quaternion` (x, y, z, w; identity by default as in ROS).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

impl Default for Quaternion {
    fn default() -> Self {
        Self { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }
    }
}

/// `geometry_msgs/msg/Pose`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    pub position: Point,
    pub orientation: Quaternion,
}

/// `geometry_msgs/msg/PoseStamped`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseStamped {
    pub header: Header,
    pub pose: Pose,
}

/// `geometry_msgs/msg/PoseWithCovariance`: covariance is 6×6 row-major over
/// (x, y, z, rotation about x, y, z).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseWithCovariance {
    pub pose: Pose,
    #[serde(with = "fixed")]
    pub covariance: [f64; 36],
}

impl Default for PoseWithCovariance {
    fn default() -> Self {
        Self { pose: Pose::default(), covariance: [0.0; 36] }
    }
}

/// `geometry_msgs/msg/PoseWithCovarianceStamped`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseWithCovarianceStamped {
    pub header: Header,
    pub pose: PoseWithCovariance,
}

/// `geometry_msgs/msg/Transform`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    pub translation: Vector3,
    pub rotation: Quaternion,
}

/// `geometry_msgs/msg/TransformStamped`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TransformStamped {
    pub header: Header,
    pub child_frame_id: String,
    pub transform: Transform,
}

/// `tf2_msgs/msg/TFMessage`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TFMessage {
    pub transforms: Vec<TransformStamped>,
}

/// `diagnostic_msgs/msg/KeyValue`.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct KeyValue {
    pub key: String,
    pub value: String,
}

/// `diagnostic_msgs/msg/DiagnosticStatus`.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    pub level: u8,
    pub name: String,
    pub message: String,
    pub hardware_id: String,
    pub values: Vec<KeyValue>,
}

impl DiagnosticStatus {
    pub const OK: u8 = 0;
    pub const WARN: u8 = 1;
    pub const ERROR: u8 = 2;
    pub const STALE: u8 = 3;
}

/// `diagnostic_msgs/msg/DiagnosticArray`.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct DiagnosticArray {
    pub header: Header,
    pub status: Vec<DiagnosticStatus>,
}

/// `angle_i2p_msgs/msg/Correspondence`: one putative pixel ↔ map point match.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Correspondence {
    pub u: f32,
    pub v: f32,
    pub x: f32,
    pub y: f32,
    pub z: f32,
    pub score: f32,
}

/// `angle_i2p_msgs/msg/Correspondences`: header.stamp = image stamp, header.frame_id = camera
/// optical frame; points in `map_frame_id`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Correspondences {
    pub header: Header,
    pub map_frame_id: String,
    pub correspondences: Vec<Correspondence>,
}

ros_message!(
    Time,
    "builtin_interfaces/msg/Time",
    schema::TIME,
    "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197"
);
ros_message!(
    Header,
    "std_msgs/msg/Header",
    schema::HEADER,
    "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01"
);
ros_message!(
    Image,
    "sensor_msgs/msg/Image",
    schema::IMAGE,
    "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47"
);
ros_message!(
    CompressedImage,
    "sensor_msgs/msg/CompressedImage",
    schema::COMPRESSED_IMAGE,
    "RIHS01_15640771531571185e2efc8a100baf923961a4d15d5569652e6cb6691e8e371a"
);
ros_message!(
    CameraInfo,
    "sensor_msgs/msg/CameraInfo",
    schema::CAMERA_INFO,
    "RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275"
);
ros_message!(
    RegionOfInterest,
    "sensor_msgs/msg/RegionOfInterest",
    schema::REGION_OF_INTEREST,
    "RIHS01_ad16bcba5f9131dcdba6fbded19f726f5440e3c513b4fb586dd3027eeed8abb1"
);
ros_message!(
    PointCloud2,
    "sensor_msgs/msg/PointCloud2",
    schema::POINT_CLOUD2,
    "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5"
);
ros_message!(
    PointField,
    "sensor_msgs/msg/PointField",
    schema::POINT_FIELD,
    "RIHS01_5c6a4750728c2bcfbbf7037225b20b02d4429634732146b742dee1726637ef01"
);
ros_message!(
    Point,
    "geometry_msgs/msg/Point",
    schema::POINT,
    "RIHS01_6963084842a9b04494d6b2941d11444708d892da2f4b09843b9c43f42a7f6881"
);
ros_message!(
    Vector3,
    "geometry_msgs/msg/Vector3",
    schema::VECTOR3,
    "RIHS01_cc12fe83e4c02719f1ce8070bfd14aecd40f75a96696a67a2a1f37f7dbb0765d"
);
ros_message!(
    Quaternion,
    "geometry_msgs/msg/Quaternion",
    schema::QUATERNION,
    "RIHS01_8a765f66778c8ff7c8ab94afcc590a2ed5325a1d9a076ffff38fbce36f458684"
);
ros_message!(
    Pose,
    "geometry_msgs/msg/Pose",
    schema::POSE,
    "RIHS01_d501954e9476cea2996984e812054b68026ae0bfae789d9a10b23daf35cc90fa"
);
ros_message!(
    PoseStamped,
    "geometry_msgs/msg/PoseStamped",
    schema::POSE_STAMPED,
    "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"
);
ros_message!(
    PoseWithCovariance,
    "geometry_msgs/msg/PoseWithCovariance",
    schema::POSE_WITH_COVARIANCE,
    "RIHS01_9a7c0fd234b7f45c6098745ecccd773ca1085670e64107135397aee31c02e1bb"
);
ros_message!(
    PoseWithCovarianceStamped,
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    schema::POSE_WITH_COVARIANCE_STAMPED,
    "RIHS01_26432f9803e43727d3c8f668d1fdb3c630f548af631e2f4e31382371bfea3b6e"
);
ros_message!(
    Transform,
    "geometry_msgs/msg/Transform",
    schema::TRANSFORM,
    "RIHS01_beb83fbe698636351461f6f35d1abb20010c43d55374d81bd041f1ba2581fddc"
);
ros_message!(
    TransformStamped,
    "geometry_msgs/msg/TransformStamped",
    schema::TRANSFORM_STAMPED,
    "RIHS01_0a241f87d04668d94099cbb5ba11691d5ad32c2f29682e4eb5653424bd275206"
);
ros_message!(
    TFMessage,
    "tf2_msgs/msg/TFMessage",
    schema::TF_MESSAGE,
    "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
);
ros_message!(
    KeyValue,
    "diagnostic_msgs/msg/KeyValue",
    schema::KEY_VALUE,
    "RIHS01_d68081eaa540288c5440753baecef0c4e16e81a5f78ad68902ded5100413bb42"
);
ros_message!(
    DiagnosticStatus,
    "diagnostic_msgs/msg/DiagnosticStatus",
    schema::DIAGNOSTIC_STATUS,
    "RIHS01_b0e3e692ea2d54a8af2f4ef1930e81556a2db55216b771f8a7d2724ed47bf0e4"
);
ros_message!(
    DiagnosticArray,
    "diagnostic_msgs/msg/DiagnosticArray",
    schema::DIAGNOSTIC_ARRAY,
    "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e"
);
ros_message!(
    Correspondence,
    "angle_i2p_msgs/msg/Correspondence",
    schema::CORRESPONDENCE,
    "RIHS01_f67e105156c9c3c657ca5ef5f68e45f21c485533afe8591fcdc74c2996ff5152"
);
ros_message!(
    Correspondences,
    "angle_i2p_msgs/msg/Correspondences",
    schema::CORRESPONDENCES,
    "RIHS01_6030ffc9f437bab5e6f86e2ec4aedc90aa2d292f31b87a91e9442fbbfc2ca434"
);
