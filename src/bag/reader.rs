//! Reading rosbag2 MCAP bags: a bag directory (with `metadata.yaml`) or a bare `.mcap`.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use mcap::records::Record;

use super::metadata::MetadataFile;
use super::BagError;

/// A topic of the bag with its type and schema.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BagChannel {
    pub topic: String,
    /// Full type name, e.g. `sensor_msgs/msg/Image`.
    pub type_name: String,
    /// Schema text (`ros2msg` or `ros2idl`).
    pub schema: String,
    pub schema_encoding: String,
    /// Channel metadata (e.g. `offered_qos_profiles`).
    pub metadata: std::collections::BTreeMap<String, String>,
}

/// One serialized message.
#[derive(Clone, Debug)]
pub struct BagMessage {
    pub channel: Arc<BagChannel>,
    pub log_time: u64,
    pub publish_time: u64,
    /// CDR bytes with encapsulation header.
    pub data: Vec<u8>,
}

impl BagMessage {
    pub fn topic(&self) -> &str {
        &self.channel.topic
    }

    pub fn type_name(&self) -> &str {
        &self.channel.type_name
    }
}

/// A whole bag read into memory, its messages in log-time order.
#[derive(Debug)]
pub struct BagReader {
    files: Vec<PathBuf>,
    channels: Vec<Arc<BagChannel>>,
    messages: Vec<BagMessage>,
}

impl BagReader {
    /// Opens a bag directory (files listed by `metadata.yaml`, or every `.mcap` in it when it
    /// has none) or a single `.mcap` file, checking profile `ros2` and encoding `cdr`.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, BagError> {
        let files = storage_files(path.as_ref())?;
        let mut reader = BagReader { files: files.clone(), channels: Vec::new(), messages: Vec::new() };
        for file in &files {
            reader.read_file(file)?;
        }
        // Stable: messages with equal log time keep file order.
        reader.messages.sort_by_key(|m| m.log_time);
        Ok(reader)
    }

    /// The storage files read, in order.
    pub fn files(&self) -> &[PathBuf] {
        &self.files
    }

    /// Every channel of every file (one entry per distinct topic + type + schema).
    pub fn channels(&self) -> &[Arc<BagChannel>] {
        &self.channels
    }

    /// All messages, in log-time order.
    pub fn messages(&self) -> &[BagMessage] {
        &self.messages
    }

    pub fn into_messages(self) -> Vec<BagMessage> {
        self.messages
    }

    fn read_file(&mut self, file: &Path) -> Result<(), BagError> {
        let bytes = std::fs::read(file).map_err(|source| BagError::Io { path: file.to_path_buf(), source })?;
        check_magic(file, &bytes)?;
        let corrupt = |e: mcap::McapError| BagError::Corrupt { path: file.to_path_buf(), reason: e.to_string() };
        // The first record must be the header with the profile.
        let mut records = mcap::read::LinearReader::new(&bytes).map_err(corrupt)?;
        match records.next() {
            Some(Ok(Record::Header(h))) if h.profile == "ros2" => {}
            Some(Ok(Record::Header(h))) => {
                return Err(BagError::ForeignProfile { path: file.to_path_buf(), profile: h.profile });
            }
            Some(Ok(_)) | None => {
                return Err(BagError::Corrupt { path: file.to_path_buf(), reason: "no header record".into() })
            }
            Some(Err(e)) => return Err(corrupt(e)),
        }
        let mut by_id: std::collections::HashMap<u16, Arc<BagChannel>> = Default::default();
        for message in mcap::MessageStream::new(&bytes).map_err(corrupt)? {
            let message = message.map_err(corrupt)?;
            let channel = match by_id.get(&message.channel.id) {
                Some(c) => c.clone(),
                None => {
                    let c = self.channel(file, &message.channel)?;
                    by_id.insert(message.channel.id, c.clone());
                    c
                }
            };
            self.messages.push(BagMessage {
                channel,
                log_time: message.log_time,
                publish_time: message.publish_time,
                data: message.data.into_owned(),
            });
        }
        Ok(())
    }

    fn channel(&mut self, file: &Path, c: &mcap::Channel) -> Result<Arc<BagChannel>, BagError> {
        if c.message_encoding != "cdr" {
            return Err(BagError::MessageEncoding {
                path: file.to_path_buf(),
                topic: c.topic.clone(),
                encoding: c.message_encoding.clone(),
            });
        }
        let Some(schema) = &c.schema else {
            return Err(BagError::Corrupt {
                path: file.to_path_buf(),
                reason: format!("topic {} has no schema", c.topic),
            });
        };
        if schema.encoding != "ros2msg" && schema.encoding != "ros2idl" {
            return Err(BagError::SchemaEncoding {
                path: file.to_path_buf(),
                topic: c.topic.clone(),
                encoding: schema.encoding.clone(),
            });
        }
        let channel = BagChannel {
            topic: c.topic.clone(),
            type_name: schema.name.clone(),
            schema: String::from_utf8_lossy(&schema.data).into_owned(),
            schema_encoding: schema.encoding.clone(),
            metadata: c.metadata.clone(),
        };
        if let Some(known) = self.channels.iter().find(|k| ***k == channel) {
            return Ok(known.clone());
        }
        let channel = Arc::new(channel);
        self.channels.push(channel.clone());
        Ok(channel)
    }
}

fn check_magic(file: &Path, bytes: &[u8]) -> Result<(), BagError> {
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(BagError::NotMcap { path: file.to_path_buf() });
    }
    if bytes.len() < 2 * mcap::MAGIC.len() || !bytes.ends_with(mcap::MAGIC) {
        return Err(BagError::Truncated { path: file.to_path_buf() });
    }
    Ok(())
}

/// The `.mcap` files of a bag path.
fn storage_files(path: &Path) -> Result<Vec<PathBuf>, BagError> {
    let meta = std::fs::metadata(path).map_err(|source| BagError::Io { path: path.to_path_buf(), source })?;
    if meta.is_file() {
        if path.file_name().is_some_and(|n| n == "metadata.yaml") {
            return storage_files(path.parent().unwrap_or(Path::new(".")));
        }
        return Ok(vec![path.to_path_buf()]);
    }
    let yaml = path.join("metadata.yaml");
    if yaml.exists() {
        let text = std::fs::read_to_string(&yaml).map_err(|source| BagError::Io { path: yaml.clone(), source })?;
        let m: MetadataFile = serde_yaml::from_str(&text)
            .map_err(|e| BagError::Metadata { path: yaml.clone(), reason: e.to_string() })?;
        let info = m.rosbag2_bagfile_information;
        if !info.storage_identifier.is_empty() && info.storage_identifier != "mcap" {
            return Err(BagError::Metadata {
                path: yaml,
                reason: format!("storage {:?} is not supported (only mcap)", info.storage_identifier),
            });
        }
        let mut names = info.relative_file_paths;
        if names.is_empty() {
            names = info.files.into_iter().map(|f| f.path).collect();
        }
        if names.is_empty() {
            return Err(BagError::Metadata { path: yaml, reason: "lists no storage files".into() });
        }
        return Ok(names.into_iter().map(|n| path.join(n)).collect());
    }
    let entries = std::fs::read_dir(path).map_err(|source| BagError::Io { path: path.to_path_buf(), source })?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(BagError::NoStorageFiles { path: path.to_path_buf() });
    }
    Ok(files)
}
