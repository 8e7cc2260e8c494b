//! Writing rosbag2 MCAP bags: `<dir>/<name>.mcap` + `metadata.yaml` (version 9).

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use super::metadata::{self, BagInfo, FileInfo, MetadataFile, StartingTime, TopicMetadata, TopicWithCount};
use super::qos::OfferedQos;
use super::BagError;
use crate::msgs::{to_cdr, RosMessage};

/// Chunk compression of a written bag.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ChunkCompression {
    #[default]
    Zstd,
    Lz4,
    None,
}

/// The library string written into the MCAP header.
pub const LIBRARY: &str = concat!("angle-i2p-", env!("CARGO_PKG_VERSION"));

struct Topic {
    channel_id: u16,
    type_name: String,
    type_hash: String,
    count: u64,
    sequence: u32,
    qos: OfferedQos,
}

/// Writes a rosbag2 bag; schemas and channels are registered on first use of a topic.
pub struct BagWriter {
    dir: PathBuf,
    file: PathBuf,
    mcap: Option<mcap::Writer<BufWriter<File>>>,
    topics: Vec<(String, Topic)>,
    index: HashMap<String, usize>,
    schemas: HashMap<(String, String), u16>,
    start: Option<u64>,
    end: u64,
    /// Topics to be offered latched once registered (see [`BagWriter::latch`]).
    latched: Vec<String>,
}

impl BagWriter {
    /// Creates `dir` (parents too) and `<dir>/<dir name>.mcap` with zstd chunks. Fails if the
    /// bag file or `metadata.yaml` already exist.
    pub fn create(dir: impl AsRef<Path>) -> Result<Self, BagError> {
        Self::create_with(dir, ChunkCompression::Zstd)
    }

    pub fn create_with(dir: impl AsRef<Path>, compression: ChunkCompression) -> Result<Self, BagError> {
        let dir = dir.as_ref().to_path_buf();
        let name = dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .ok_or_else(|| BagError::Write { path: dir.clone(), reason: "bag directory has no name".into() })?;
        std::fs::create_dir_all(&dir).map_err(|source| BagError::Io { path: dir.clone(), source })?;
        let file = dir.join(format!("{name}.mcap"));
        for existing in [&file, &dir.join("metadata.yaml")] {
            if existing.exists() {
                return Err(BagError::Write { path: existing.clone(), reason: "already exists".into() });
            }
        }
        let out = File::create_new(&file).map_err(|source| BagError::Io { path: file.clone(), source })?;
        let compression = match compression {
            ChunkCompression::Zstd => Some(mcap::Compression::Zstd),
            ChunkCompression::Lz4 => Some(mcap::Compression::Lz4),
            ChunkCompression::None => None,
        };
        let mcap = mcap::WriteOptions::new()
            .profile("ros2")
            .library(LIBRARY)
            .compression(compression)
            .create(BufWriter::new(out))
            .map_err(|e| BagError::Write { path: file.clone(), reason: e.to_string() })?;
        Ok(Self {
            dir,
            file,
            mcap: Some(mcap),
            topics: Vec::new(),
            index: HashMap::new(),
            schemas: HashMap::new(),
            start: None,
            end: 0,
            latched: Vec::new(),
        })
    }

    /// The bag directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Records `topic` as offered latched (reliable, transient local, depth 1), as a map server
    /// publishes a map, so `ros2 bag play` offers it to late subscribers. Call before the
    /// topic's first message.
    pub fn latch(&mut self, topic: &str) {
        self.latched.push(topic.to_string());
    }

    /// Serializes `msg` as CDR and writes it on `topic` at `log_time_ns` (also publish time).
    pub fn write<M: RosMessage>(&mut self, topic: &str, log_time_ns: i64, msg: &M) -> Result<(), BagError> {
        self.write_raw_with_hash(topic, M::TYPE_NAME, M::SCHEMA, M::TYPE_HASH, log_time_ns, &to_cdr(msg))
    }

    /// Writes already-serialized CDR bytes (e.g. copied from another bag).
    pub fn write_raw(
        &mut self,
        topic: &str,
        type_name: &str,
        schema: &str,
        log_time_ns: i64,
        data: &[u8],
    ) -> Result<(), BagError> {
        self.write_raw_with_hash(topic, type_name, schema, "", log_time_ns, data)
    }

    fn write_raw_with_hash(
        &mut self,
        topic: &str,
        type_name: &str,
        schema: &str,
        type_hash: &str,
        log_time_ns: i64,
        data: &[u8],
    ) -> Result<(), BagError> {
        let err = |reason: String| BagError::Write { path: self.file.clone(), reason };
        let log_time =
            u64::try_from(log_time_ns).map_err(|_| err(format!("negative log time {log_time_ns} on {topic}")))?;
        let i = match self.index.get(topic) {
            Some(&i) => i,
            None => self.add_topic(topic, type_name, schema, type_hash)?,
        };
        let (_, t) = &mut self.topics[i];
        if t.type_name != type_name {
            let reason = format!("topic {topic} has type {}, cannot write {type_name}", t.type_name);
            return Err(BagError::Write { path: self.file.clone(), reason });
        }
        t.count += 1;
        t.sequence = t.sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id: t.channel_id,
            sequence: t.sequence,
            log_time,
            publish_time: log_time,
        };
        let mcap = self
            .mcap
            .as_mut()
            .ok_or_else(|| BagError::Write { path: self.file.clone(), reason: "already finished".into() })?;
        mcap.write_to_known_channel(&header, data)
            .map_err(|e| BagError::Write { path: self.file.clone(), reason: e.to_string() })?;
        self.start = Some(self.start.map_or(log_time, |s| s.min(log_time)));
        self.end = self.end.max(log_time);
        Ok(())
    }

    fn add_topic(&mut self, topic: &str, type_name: &str, schema: &str, type_hash: &str) -> Result<usize, BagError> {
        let file = self.file.clone();
        let werr = move |e: mcap::McapError| BagError::Write { path: file.clone(), reason: e.to_string() };
        let mcap = self
            .mcap
            .as_mut()
            .ok_or_else(|| BagError::Write { path: self.file.clone(), reason: "already finished".into() })?;
        let key = (type_name.to_string(), schema.to_string());
        let schema_id = match self.schemas.get(&key) {
            Some(&id) => id,
            None => {
                let id = mcap.add_schema(type_name, "ros2msg", schema.as_bytes()).map_err(&werr)?;
                self.schemas.insert(key, id);
                id
            }
        };
        let qos = if self.latched.iter().any(|t| t == topic) { OfferedQos::LATCHED } else { OfferedQos::default() };
        let metadata = BTreeMap::from([("offered_qos_profiles".to_string(), qos.profiles_yaml())]);
        let channel_id = mcap.add_channel(schema_id, topic, "cdr", &metadata).map_err(&werr)?;
        let (type_name, type_hash) = (type_name.into(), type_hash.into());
        let t = Topic { channel_id, type_name, type_hash, count: 0, sequence: 0, qos };
        self.topics.push((topic.to_string(), t));
        self.index.insert(topic.to_string(), self.topics.len() - 1);
        Ok(self.topics.len() - 1)
    }

    /// Completes the MCAP file (summary, rosbag2 metadata record) and writes `metadata.yaml`.
    pub fn finish(mut self) -> Result<PathBuf, BagError> {
        self.finish_inner()?;
        Ok(self.dir.clone())
    }

    fn finish_inner(&mut self) -> Result<(), BagError> {
        let Some(mut mcap) = self.mcap.take() else { return Ok(()) };
        let werr = |e: String| BagError::Write { path: self.file.clone(), reason: e };
        let yaml = serde_yaml::to_string(&self.metadata()).map_err(|e| werr(e.to_string()))?;
        let record = mcap::records::Metadata {
            name: "rosbag2".into(),
            metadata: BTreeMap::from([("serialized_metadata".to_string(), yaml.trim_end().to_string())]),
        };
        mcap.write_metadata(&record).map_err(|e| werr(e.to_string()))?;
        mcap.finish().map_err(|e| werr(e.to_string()))?;
        let mut out = mcap.into_inner();
        std::io::Write::flush(&mut out).map_err(|e| werr(e.to_string()))?;
        let path = self.dir.join("metadata.yaml");
        std::fs::write(&path, yaml).map_err(|source| BagError::Io { path, source })?;
        Ok(())
    }

    fn metadata(&self) -> MetadataFile {
        let start = self.start.unwrap_or(0);
        let duration = metadata::Duration { nanoseconds: self.end.saturating_sub(start) };
        let starting_time = StartingTime { nanoseconds_since_epoch: start as i64 };
        let count: u64 = self.topics.iter().map(|(_, t)| t.count).sum();
        let name = self.file.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        MetadataFile {
            rosbag2_bagfile_information: BagInfo {
                compression_format: String::new(),
                compression_mode: String::new(),
                custom_data: None,
                duration,
                files: vec![FileInfo { duration, message_count: count, path: name.clone(), starting_time }],
                message_count: count,
                relative_file_paths: vec![name],
                ros_distro: "angle-i2p".into(),
                starting_time,
                storage_identifier: "mcap".into(),
                topics_with_message_count: self
                    .topics
                    .iter()
                    .map(|(topic, t)| TopicWithCount {
                        message_count: t.count,
                        topic_metadata: TopicMetadata {
                            name: topic.clone(),
                            offered_qos_profiles: t.qos.profiles(),
                            serialization_format: "cdr".into(),
                            type_name: t.type_name.clone(),
                            type_description_hash: t.type_hash.clone(),
                        },
                    })
                    .collect(),
                version: 9,
            },
        }
    }
}

impl Drop for BagWriter {
    /// Finishes an unfinished bag so it stays readable; errors are lost (call
    /// [`finish`](Self::finish) to see them).
    fn drop(&mut self) {
        let _ = self.finish_inner();
    }
}
