//! Reading rosbag2 MCAP bags: a bag directory (with `metadata.yaml`) or a bare `.mcap`.
//!
//! [`BagMessages`] streams the messages of every storage file in file order, holding one record
//! (or one chunk) at a time, so memory does not grow with the bag's length. Every file is
//! checked as it is read: magic bytes, profile `ros2`, encoding `cdr`, a record-length limit
//! (no record or decompressed chunk over [`ReadOptions::max_record_bytes`] is ever buffered),
//! every chunk's CRC before any of its messages is handed out, the data and summary sections'
//! CRCs, and — when asked — each topic's message type. A failed check is an error naming the
//! file and the byte offset where reading stopped (for a chunk: the offset just after it).
//! [`BagReader`] collects the stream in memory, for the small bags of `play` and `diagnostics`.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::io::{Read, Seek, SeekFrom};
use std::path::{Component, Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use mcap::sans_io::LinearReaderOptions;

use super::metadata::MetadataFile;
use super::BagError;

pub use crate::limits::DEFAULT_MAX_RECORD_BYTES;
/// The longest header record read for the profile check.
const MAX_HEADER_RECORD: u64 = 1 << 20;

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
    pub metadata: BTreeMap<String, String>,
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

/// Limits and checks applied while reading.
#[derive(Clone, Debug)]
pub struct ReadOptions {
    /// No record, and no chunk's decompressed content, longer than this is read (bytes).
    pub max_record_bytes: u64,
    /// Topic → the message type it must carry (`pkg/msg/Type`; `pkg/Type` is accepted too).
    pub expected_types: HashMap<String, &'static str>,
}

impl Default for ReadOptions {
    fn default() -> Self {
        Self { max_record_bytes: DEFAULT_MAX_RECORD_BYTES, expected_types: HashMap::new() }
    }
}

/// `pkg/msg/Type` and `pkg/Type` name the same type.
fn same_type(a: &str, b: &str) -> bool {
    a.replace("/msg/", "/") == b.replace("/msg/", "/")
}

/// The messages of a bag's storage files, streamed in file order.
pub struct BagMessages {
    files: std::vec::IntoIter<PathBuf>,
    current: Option<FileMessages>,
    options: ReadOptions,
    channels: Vec<Arc<BagChannel>>,
    failed: bool,
}

/// Byte counter shared with the reader that owns the file (for error offsets).
#[derive(Clone, Default)]
struct Offset(Arc<AtomicU64>);

struct CountingRead<R> {
    inner: R,
    offset: Offset,
}

impl<R: Read> Read for CountingRead<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.offset.0.fetch_add(n as u64, Ordering::Relaxed);
        Ok(n)
    }
}

struct FileMessages {
    path: PathBuf,
    reader: mcap::io::MessageReader<CountingRead<std::io::BufReader<std::fs::File>>>,
    offset: Offset,
    by_id: HashMap<u16, Arc<BagChannel>>,
}

impl BagMessages {
    /// Opens a bag directory (files listed by `metadata.yaml`, or every `.mcap` in it when it
    /// has none) or a single `.mcap` file. Files are opened and checked as they are reached.
    pub fn open(path: impl AsRef<Path>, options: ReadOptions) -> Result<Self, BagError> {
        let files = storage_files(path.as_ref())?;
        Ok(Self { files: files.into_iter(), current: None, options, channels: Vec::new(), failed: false })
    }

    /// The distinct channels seen so far.
    pub fn channels(&self) -> &[Arc<BagChannel>] {
        &self.channels
    }

    fn next_message(&mut self) -> Result<Option<BagMessage>, BagError> {
        loop {
            if self.current.is_none() {
                let Some(path) = self.files.next() else { return Ok(None) };
                self.current = Some(open_file(&path, &self.options)?);
            }
            let Some(file) = self.current.as_mut() else { continue };
            let Some(next) = file.reader.next() else {
                self.current = None;
                continue;
            };
            let message = next.map_err(|e| corrupt_at(&file.path, &file.offset, e))?;
            let channel = match file.by_id.get(&message.channel.id) {
                Some(c) => c.clone(),
                None => {
                    let c = channel(&file.path, &message.channel, &self.options, &mut self.channels)?;
                    file.by_id.insert(message.channel.id, c.clone());
                    c
                }
            };
            return Ok(Some(BagMessage {
                channel,
                log_time: message.log_time,
                publish_time: message.publish_time,
                data: message.data.into_owned(),
            }));
        }
    }
}

impl Iterator for BagMessages {
    type Item = Result<BagMessage, BagError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        let out = self.next_message().transpose();
        if matches!(out, Some(Err(_))) {
            self.failed = true;
        }
        out
    }
}

fn corrupt_at(path: &Path, offset: &Offset, e: mcap::McapError) -> BagError {
    let at = offset.0.load(Ordering::Relaxed);
    let reason = match e {
        mcap::McapError::BadChunkCrc { saved, calculated } => {
            format!("chunk ending before byte {at}: CRC mismatch (stored {saved:#010x}, computed {calculated:#010x})")
        }
        mcap::McapError::BadDataCrc { saved, calculated } => {
            format!("data section CRC mismatch (stored {saved:#010x}, computed {calculated:#010x})")
        }
        e @ (mcap::McapError::RecordTooLarge { .. } | mcap::McapError::ChunkTooLarge(_)) => {
            format!("{e} before byte {at} (the limit is limits.max_record_bytes)")
        }
        e => format!("{e} (before byte {at})"),
    };
    BagError::Corrupt { path: path.to_path_buf(), reason }
}

/// Opens one storage file: a regular file with both magics and a `ros2` header.
fn open_file(path: &Path, options: &ReadOptions) -> Result<FileMessages, BagError> {
    let io = |source| BagError::Io { path: path.to_path_buf(), source };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let meta = file.metadata().map_err(io)?;
    if !meta.is_file() {
        return Err(BagError::Metadata { path: path.to_path_buf(), reason: "not a regular file".into() });
    }
    check_magic_and_profile(path, &mut file, meta.len())?;
    file.seek(SeekFrom::Start(0)).map_err(io)?;
    let limit = usize::try_from(options.max_record_bytes).unwrap_or(usize::MAX);
    let reader_options = LinearReaderOptions::default()
        .with_record_length_limit(limit)
        .with_prevalidate_chunk_crcs(true)
        .with_validate_data_section_crc(true)
        .with_validate_summary_section_crc(true);
    let offset = Offset::default();
    let source = CountingRead { inner: std::io::BufReader::new(file), offset: offset.clone() };
    let reader = mcap::io::MessageReader::new_with_options(source, reader_options);
    Ok(FileMessages { path: path.to_path_buf(), reader, offset, by_id: HashMap::new() })
}

fn check_magic_and_profile(path: &Path, file: &mut std::fs::File, len: u64) -> Result<(), BagError> {
    let io = |source| BagError::Io { path: path.to_path_buf(), source };
    let magic = mcap::MAGIC;
    let mut start = vec![0u8; magic.len()];
    let got = read_up_to(file, &mut start).map_err(io)?;
    if got < magic.len() || start != magic {
        return Err(BagError::NotMcap { path: path.to_path_buf() });
    }
    if len < 2 * magic.len() as u64 {
        return Err(BagError::Truncated { path: path.to_path_buf() });
    }
    file.seek(SeekFrom::End(-(magic.len() as i64))).map_err(io)?;
    let mut end = vec![0u8; magic.len()];
    if read_up_to(file, &mut end).map_err(io)? < magic.len() || end != magic {
        return Err(BagError::Truncated { path: path.to_path_buf() });
    }
    // The header record: opcode 0x01, u64 length, then the profile string (u32 length + bytes).
    let corrupt = |reason: String| BagError::Corrupt { path: path.to_path_buf(), reason };
    file.seek(SeekFrom::Start(magic.len() as u64)).map_err(io)?;
    let mut head = [0u8; 9];
    if read_up_to(file, &mut head).map_err(io)? < head.len() || head[0] != 0x01 {
        return Err(corrupt("no header record".into()));
    }
    let record_len = u64::from_le_bytes(head[1..9].try_into().unwrap_or([0; 8]));
    if !(4..=MAX_HEADER_RECORD).contains(&record_len) {
        return Err(corrupt(format!("header record of {record_len} bytes")));
    }
    let mut body = vec![0u8; record_len as usize];
    if read_up_to(file, &mut body).map_err(io)? < body.len() {
        return Err(corrupt("header record runs past the end of the file".into()));
    }
    let profile_len = u32::from_le_bytes(body[..4].try_into().unwrap_or([0; 4])) as usize;
    let profile = body.get(4..4 + profile_len).ok_or_else(|| corrupt("header profile runs past its record".into()))?;
    let profile = String::from_utf8_lossy(profile).into_owned();
    if profile != "ros2" {
        return Err(BagError::ForeignProfile { path: path.to_path_buf(), profile });
    }
    Ok(())
}

fn read_up_to(file: &mut std::fs::File, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut filled = 0;
    while filled < buf.len() {
        match file.read(&mut buf[filled..]) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        }
    }
    Ok(filled)
}

/// Checks a channel (encoding, schema, expected type) and returns the shared entry for it.
fn channel(
    file: &Path,
    c: &mcap::Channel,
    options: &ReadOptions,
    known: &mut Vec<Arc<BagChannel>>,
) -> Result<Arc<BagChannel>, BagError> {
    if c.message_encoding != "cdr" {
        return Err(BagError::MessageEncoding {
            path: file.to_path_buf(),
            topic: c.topic.clone(),
            encoding: c.message_encoding.clone(),
        });
    }
    let Some(schema) = &c.schema else {
        return Err(BagError::Corrupt { path: file.to_path_buf(), reason: format!("topic {} has no schema", c.topic) });
    };
    if schema.encoding != "ros2msg" && schema.encoding != "ros2idl" {
        return Err(BagError::SchemaEncoding {
            path: file.to_path_buf(),
            topic: c.topic.clone(),
            encoding: schema.encoding.clone(),
        });
    }
    if let Some(expected) = options.expected_types.get(&c.topic) {
        if !same_type(expected, &schema.name) {
            return Err(BagError::WrongType {
                path: file.to_path_buf(),
                topic: c.topic.clone(),
                expected: (*expected).to_string(),
                found: schema.name.clone(),
            });
        }
    }
    let channel = BagChannel {
        topic: c.topic.clone(),
        type_name: schema.name.clone(),
        schema: String::from_utf8_lossy(&schema.data).into_owned(),
        schema_encoding: schema.encoding.clone(),
        metadata: c.metadata.clone(),
    };
    if let Some(k) = known.iter().find(|k| ***k == channel) {
        return Ok(k.clone());
    }
    let channel = Arc::new(channel);
    known.push(channel.clone());
    Ok(channel)
}

/// A whole bag read into memory, its messages in log-time order (for small bags: `play`,
/// `diagnostics`, tests; replay and eval stream with [`BagMessages`]).
#[derive(Debug)]
pub struct BagReader {
    files: Vec<PathBuf>,
    channels: Vec<Arc<BagChannel>>,
    messages: Vec<BagMessage>,
}

impl BagReader {
    /// Reads every message of a bag with the default [`ReadOptions`].
    pub fn open(path: impl AsRef<Path>) -> Result<Self, BagError> {
        Self::open_with(path, ReadOptions::default())
    }

    pub fn open_with(path: impl AsRef<Path>, options: ReadOptions) -> Result<Self, BagError> {
        let files = storage_files(path.as_ref())?;
        let mut stream = BagMessages::open(path, options)?;
        let mut messages = Vec::new();
        for m in stream.by_ref() {
            messages.push(m?);
        }
        // Stable: messages with equal log time keep file order.
        messages.sort_by_key(|m| m.log_time);
        Ok(BagReader { files, channels: stream.channels, messages })
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
}

/// The `.mcap` files of a bag path.
pub fn storage_files(path: &Path) -> Result<Vec<PathBuf>, BagError> {
    let meta = std::fs::metadata(path).map_err(|source| BagError::Io { path: path.to_path_buf(), source })?;
    if meta.is_file() {
        if path.file_name().is_some_and(|n| n == "metadata.yaml") {
            return storage_files(path.parent().unwrap_or(Path::new(".")));
        }
        return Ok(vec![path.to_path_buf()]);
    }
    if !meta.is_dir() {
        return Err(BagError::Metadata {
            path: path.to_path_buf(),
            reason: "neither a bag directory nor an .mcap file".into(),
        });
    }
    let yaml = path.join("metadata.yaml");
    if yaml.exists() {
        return files_from_metadata(path, &yaml);
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

/// The files `metadata.yaml` lists: relative paths inside the bag directory, each once.
fn files_from_metadata(dir: &Path, yaml: &Path) -> Result<Vec<PathBuf>, BagError> {
    let bad = |reason: String| BagError::Metadata { path: yaml.to_path_buf(), reason };
    let meta = std::fs::metadata(yaml).map_err(|source| BagError::Io { path: yaml.to_path_buf(), source })?;
    if !meta.is_file() || meta.len() > 16 << 20 {
        return Err(bad(format!("not a regular file under 16 MiB ({} bytes)", meta.len())));
    }
    let text = std::fs::read_to_string(yaml).map_err(|source| BagError::Io { path: yaml.to_path_buf(), source })?;
    let m: MetadataFile = serde_yaml::from_str(&text).map_err(|e| bad(e.to_string()))?;
    let info = m.rosbag2_bagfile_information;
    if !info.storage_identifier.is_empty() && info.storage_identifier != "mcap" {
        return Err(bad(format!("storage {:?} is not supported (only mcap)", info.storage_identifier)));
    }
    let mut names = info.relative_file_paths;
    if names.is_empty() {
        names = info.files.into_iter().map(|f| f.path).collect();
    }
    if names.is_empty() {
        return Err(bad("lists no storage files".into()));
    }
    let root = dir.canonicalize().map_err(|source| BagError::Io { path: dir.to_path_buf(), source })?;
    let mut seen = HashSet::new();
    let mut files = Vec::with_capacity(names.len());
    for name in names {
        let relative = Path::new(&name);
        if !relative.components().all(|c| matches!(c, Component::Normal(_))) {
            return Err(bad(format!("storage file {name:?} is not a relative path inside the bag directory")));
        }
        let file = dir.join(relative);
        // A missing file is reported by name when it is opened; an existing one must resolve
        // (through any links) to a regular file inside the bag directory.
        if let Ok(real) = file.canonicalize() {
            if !real.starts_with(&root) {
                return Err(bad(format!("storage file {name:?} resolves outside the bag directory")));
            }
            if !seen.insert(real) {
                return Err(bad(format!("storage file {name:?} is listed twice")));
            }
        } else if !seen.insert(file.clone()) {
            return Err(bad(format!("storage file {name:?} is listed twice")));
        }
        files.push(file);
    }
    Ok(files)
}
