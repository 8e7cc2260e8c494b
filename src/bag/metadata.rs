//! rosbag2 `metadata.yaml` (written in version 9 layout, read leniently from older ones).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// The whole `metadata.yaml` file.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MetadataFile {
    pub rosbag2_bagfile_information: BagInfo,
}

/// `rosbag2_bagfile_information` (keys sorted as rosbags writes them).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct BagInfo {
    pub compression_format: String,
    pub compression_mode: String,
    pub custom_data: Option<BTreeMap<String, String>>,
    pub duration: Duration,
    pub files: Vec<FileInfo>,
    pub message_count: u64,
    pub relative_file_paths: Vec<String>,
    pub ros_distro: String,
    pub starting_time: StartingTime,
    pub storage_identifier: String,
    pub topics_with_message_count: Vec<TopicWithCount>,
    pub version: u32,
}

#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize)]
pub struct Duration {
    pub nanoseconds: u64,
}

#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize)]
pub struct StartingTime {
    pub nanoseconds_since_epoch: i64,
}

/// One storage file of the bag.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct FileInfo {
    pub duration: Duration,
    pub message_count: u64,
    pub path: String,
    pub starting_time: StartingTime,
}

#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct TopicWithCount {
    pub message_count: u64,
    pub topic_metadata: TopicMetadata,
}

#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct TopicMetadata {
    pub name: String,
    /// A YAML list in version 9, a string holding YAML in older versions.
    pub offered_qos_profiles: serde_yaml::Value,
    pub serialization_format: String,
    #[serde(rename = "type")]
    pub type_name: String,
    pub type_description_hash: String,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_a_rosbags_metadata_file() {
        let text = "rosbag2_bagfile_information:\n  compression_format: ''\n  compression_mode: ''\n  custom_data: null\n  duration:\n    nanoseconds: 20\n  files:\n  - duration:\n      nanoseconds: 20\n    message_count: 2\n    path: a.mcap\n    starting_time:\n      nanoseconds_since_epoch: 5\n  message_count: 2\n  relative_file_paths:\n  - a.mcap\n  ros_distro: rosbags\n  starting_time:\n    nanoseconds_since_epoch: 5\n  storage_identifier: mcap\n  topics_with_message_count:\n  - message_count: 2\n    topic_metadata:\n      name: /x\n      offered_qos_profiles: []\n      serialization_format: cdr\n      type: std_msgs/msg/Header\n      type_description_hash: \n        RIHS01_ab\n  version: 9\n";
        let m: MetadataFile = serde_yaml::from_str(text).unwrap();
        let info = m.rosbag2_bagfile_information;
        assert_eq!(info.relative_file_paths, vec!["a.mcap"]);
        assert_eq!(info.topics_with_message_count[0].topic_metadata.type_name, "std_msgs/msg/Header");
        assert_eq!(info.topics_with_message_count[0].topic_metadata.type_description_hash, "RIHS01_ab");
        assert_eq!(info.version, 9);
    }
}
