//! ROS 2 messages as serde structs, their `ros2msg` schemas, and CDR (XCDR1) encoding.
//!
//! Field order follows the `.msg` definitions, so serde's struct order is the wire order.
//! Fixed-size arrays (`float64[9] k`) serialize without a length prefix, sequences with one.
//! [`convert`] turns messages into the core's types ([`crate::frame`], [`crate::geometry`]) and
//! builds output messages from them.

pub mod convert;
mod schema;
mod serde_helpers;
mod types;

pub use types::*;

use byteorder::{BigEndian, LittleEndian};
use serde::{de::DeserializeOwned, Serialize};

/// A ROS 2 message type with its full name, `ros2msg` schema (as rosbag2 / rosbags write it
/// into MCAP files) and RIHS01 type description hash.
pub trait RosMessage: Serialize + DeserializeOwned {
    /// Full type name, e.g. `sensor_msgs/msg/Image`.
    const TYPE_NAME: &'static str;
    /// The type's `.msg` text (comment-free) followed by each dependency, separated by
    /// `=` × 80 lines and `MSG: pkg/Type` headers.
    const SCHEMA: &'static str;
    /// RIHS01 type description hash (rosbag2 `metadata.yaml`, `type_description_hash`).
    const TYPE_HASH: &'static str;
}

/// The encapsulation header of little-endian plain CDR (XCDR1).
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Why a message could not be decoded or converted.
#[derive(Debug, thiserror::Error)]
pub enum MsgError {
    #[error("CDR payload too short ({0} bytes) for the 4-byte encapsulation header")]
    TooShort(usize),
    #[error("unsupported CDR encapsulation {0:02x?} (expected plain CDR, 00 01 or 00 00)")]
    Encapsulation([u8; 4]),
    #[error("CDR decode of {type_name} failed: {reason}")]
    Cdr { type_name: &'static str, reason: String },
    #[error("{type_name}: {count} bytes left over after the message")]
    TrailingBytes { type_name: &'static str, count: usize },
    #[error("unsupported image encoding {0:?} for a depth image (expected 32FC1 or 16UC1)")]
    UnsupportedEncoding(String),
    #[error("{what}: data size mismatch: expected {expected} bytes, got {actual}")]
    SizeMismatch { what: String, expected: usize, actual: usize },
    #[error("{what} #{index} is not finite")]
    NonFinite { what: &'static str, index: usize },
    #[error("invalid {what}: {reason}")]
    Invalid { what: &'static str, reason: String },
}

/// Encodes a message as little-endian CDR with its encapsulation header.
pub fn to_cdr<M: Serialize>(msg: &M) -> Vec<u8> {
    let mut out = CDR_LE_HEADER.to_vec();
    // Serializing into a Vec only fails for sequences of unknown length, which our message
    // types never produce.
    cdr_encoding::to_writer::<M, LittleEndian, _>(&mut out, msg)
        .unwrap_or_else(|e| panic!("CDR serialization into memory cannot fail: {e}"));
    out
}

/// Decodes a CDR message (little- or big-endian plain CDR, with encapsulation header).
/// Up to 3 trailing padding bytes are accepted; more is an error.
pub fn from_cdr<M: RosMessage>(data: &[u8]) -> Result<M, MsgError> {
    if data.len() < 4 {
        return Err(MsgError::TooShort(data.len()));
    }
    let header = [data[0], data[1], data[2], data[3]];
    let body = &data[4..];
    let decoded = match (header[0], header[1]) {
        (0x00, 0x01) => cdr_encoding::from_bytes::<M, LittleEndian>(body),
        (0x00, 0x00) => cdr_encoding::from_bytes::<M, BigEndian>(body),
        _ => return Err(MsgError::Encapsulation(header)),
    };
    let (msg, used) = decoded.map_err(|e| MsgError::Cdr { type_name: M::TYPE_NAME, reason: e.to_string() })?;
    let left = body.len().saturating_sub(used);
    if left > 3 {
        return Err(MsgError::TrailingBytes { type_name: M::TYPE_NAME, count: left });
    }
    Ok(msg)
}

/// Decodes only the leading `std_msgs/Header` of a CDR message whose first field is a header
/// (every stamped message), ignoring the rest; used to attribute undecodable messages.
pub fn peek_header(data: &[u8]) -> Result<Header, MsgError> {
    if data.len() < 4 {
        return Err(MsgError::TooShort(data.len()));
    }
    let body = &data[4..];
    let decoded = match (data[0], data[1]) {
        (0x00, 0x01) => cdr_encoding::from_bytes::<Header, LittleEndian>(body),
        (0x00, 0x00) => cdr_encoding::from_bytes::<Header, BigEndian>(body),
        _ => return Err(MsgError::Encapsulation([data[0], data[1], data[2], data[3]])),
    };
    decoded.map(|(h, _)| h).map_err(|e| MsgError::Cdr { type_name: Header::TYPE_NAME, reason: e.to_string() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_nanos_round_trip_including_negative() {
        for ns in [0i64, 1, 1_700_000_000_123_456_789, -1, -1_500_000_000] {
            let t = Time::from_nanos(ns);
            assert!(t.nanosec < 1_000_000_000);
            assert_eq!(t.to_nanos(), ns);
        }
        assert_eq!(Time::from_nanos(-1), Time { sec: -1, nanosec: 999_999_999 });
    }

    #[test]
    fn fixed_arrays_have_no_length_prefix_sequences_do() {
        let info = CameraInfo::default();
        let bytes = to_cdr(&info);
        // header: stamp 8 + frame_id (4 + 1 nul) → 13, pad to 16; height, width → 24;
        // distortion_model "" → 29, pad 32; d: len 4 → 36, pad to 40 for f64;
        // k, r, p: 30 × 8 = 240 → 280; binning 8 → 288; roi 4×4 + bool → 305.
        assert_eq!(bytes.len(), 4 + 305);
        assert_eq!(&bytes[..4], &CDR_LE_HEADER);
        let back: CameraInfo = from_cdr(&bytes).unwrap();
        assert_eq!(back, info);
    }

    #[test]
    fn covariance_of_36_round_trips() {
        let mut m = PoseWithCovarianceStamped::default();
        for (i, c) in m.pose.covariance.iter_mut().enumerate() {
            *c = i as f64;
        }
        let bytes = to_cdr(&m);
        let back: PoseWithCovarianceStamped = from_cdr(&bytes).unwrap();
        assert_eq!(back, m);
    }

    #[test]
    fn byte_sequences_round_trip() {
        let img = Image {
            encoding: "16UC1".into(),
            width: 3,
            height: 1,
            step: 6,
            data: vec![1, 2, 3, 4, 5, 6],
            ..Default::default()
        };
        let back: Image = from_cdr(&to_cdr(&img)).unwrap();
        assert_eq!(back, img);
    }

    #[test]
    fn decode_errors_are_reported() {
        assert!(matches!(from_cdr::<Header>(&[0, 1]), Err(MsgError::TooShort(2))));
        assert!(matches!(from_cdr::<Header>(&[0, 7, 0, 0, 0, 0]), Err(MsgError::Encapsulation(_))));
        let bytes = to_cdr(&PoseStamped::default());
        let err = from_cdr::<PoseStamped>(&bytes[..bytes.len() - 3]).unwrap_err();
        assert!(matches!(err, MsgError::Cdr { .. }), "{err}");
        let mut long = bytes.clone();
        long.extend([0u8; 8]);
        assert!(matches!(from_cdr::<PoseStamped>(&long), Err(MsgError::TrailingBytes { count: 8, .. })));
        long.truncate(bytes.len() + 3);
        assert!(from_cdr::<PoseStamped>(&long).is_ok());
    }

    #[test]
    fn big_endian_cdr_is_read() {
        // Header { stamp: {1, 2}, frame_id: "a" } in big-endian CDR.
        let bytes = [0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 2, b'a', 0];
        let h: Header = from_cdr(&bytes).unwrap();
        assert_eq!(h, Header { stamp: Time { sec: 1, nanosec: 2 }, frame_id: "a".into() });
    }

    #[test]
    fn schemas_match_rosbag2_layout() {
        let expected = "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n================================================================================\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n================================================================================\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n";
        assert_eq!(Image::SCHEMA, expected);
        assert!(PointCloud2::SCHEMA.contains("MSG: sensor_msgs/PointField\nuint8 INT8=1\n"));
        assert_eq!(Correspondences::TYPE_NAME, "angle_i2p_msgs/msg/Correspondences");
        assert!(Correspondences::SCHEMA.ends_with("MSG: angle_i2p_msgs/Correspondence\nfloat32 u\nfloat32 v\nfloat32 x\nfloat32 y\nfloat32 z\nfloat32 score\n"));
    }

    /// The contract `.msg` files, without comments, are the definitions in our schemas.
    #[test]
    fn contract_msg_files_match_schemas() {
        let strip = |text: &str| -> String {
            text.lines()
                .map(|l| l.split('#').next().unwrap_or("").trim_end().replace("  ", " "))
                .map(|l| l.split_whitespace().collect::<Vec<_>>().join(" "))
                .filter(|l| !l.is_empty())
                .map(|l| if l.starts_with("Correspondence[]") { format!("angle_i2p_msgs/{l}") } else { l })
                .map(|l| l + "\n")
                .collect()
        };
        let own = |schema: &str| schema.split("=====").next().unwrap_or("").to_string();
        assert_eq!(strip(include_str!("../../angle_i2p_msgs/msg/Correspondence.msg")), own(Correspondence::SCHEMA));
        assert_eq!(strip(include_str!("../../angle_i2p_msgs/msg/Correspondences.msg")), own(Correspondences::SCHEMA));
    }
}
