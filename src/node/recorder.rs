//! The node's `--record` bag: what it publishes, written as it goes (shared by the worker's
//! outputs and the debug image's drawer).

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use anyhow::{anyhow, Result};

use super::diagnostics::Stats;
use super::log::{lock, now_ns, warn};
use crate::bag::BagWriter;
use crate::msgs::RosMessage;

/// Writes what the node publishes to a bag (`--record`); write errors are logged and counted,
/// never fatal.
#[derive(Clone, Default)]
pub struct Recorder {
    writer: Arc<Mutex<Option<BagWriter>>>,
}

impl Recorder {
    /// Records to a new bag at `path`.
    pub fn create(path: &std::path::Path) -> Result<Self> {
        let w = BagWriter::create(path).map_err(|e| anyhow!("--record {}: {e}", path.display()))?;
        Ok(Self { writer: Arc::new(Mutex::new(Some(w))) })
    }

    pub fn write<M: RosMessage>(&self, topic: &str, msg: &M, stats: &Mutex<Stats>) {
        let mut guard = lock(&self.writer);
        if let Some(w) = guard.as_mut() {
            if let Err(e) = w.write(topic, now_ns(), msg) {
                warn(format!("recording {topic} failed: {e}"));
                lock(stats).error("record_failed", format!("recording {topic}: {e}"));
            }
        }
    }

    /// Closes the bag; `None` when not recording.
    pub fn finish(&self) -> Option<Result<PathBuf>> {
        let w = lock(&self.writer).take()?;
        Some(w.finish().map_err(Into::into))
    }
}
