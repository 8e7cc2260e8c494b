//! The node's log lines on stderr and `/rosout` (rcl_interfaces/Log, unless
//! `--disable-rosout-logs`), filtered by `--log-level`.

use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::OnceLock;

use ros2_client::builtin_interfaces::Time;
use ros2_client::log::LogLevel as RosLogLevel;
use ros2_client::rosout::{NodeLoggingHandle, RosoutRaw};

use crate::params::LogLevel;

/// The node's `--log-level` (`LogLevel as u8`; info by default).
static LOG_LEVEL: AtomicU8 = AtomicU8::new(LogLevel::Info as u8);

/// Where log lines also go: the node's `/rosout` writer and the logger name (the node's
/// fully qualified name without the leading slash, dots between its parts, as rcl names it).
static ROSOUT: OnceLock<(NodeLoggingHandle, String)> = OnceLock::new();

/// Sends every later log line also to `/rosout` through `handle` (once per process).
pub fn enable_rosout(handle: NodeLoggingHandle, logger_name: String) {
    let _ = ROSOUT.set((handle, logger_name));
}

/// rcl's logger name of a node: `/cam0/angle_i2p` → `cam0.angle_i2p`.
pub fn logger_name(fully_qualified: &str) -> String {
    fully_qualified.trim_start_matches('/').replace('/', ".")
}

/// Sets the level below which the node's messages are not printed.
pub fn set_log_level(level: LogLevel) {
    LOG_LEVEL.store(level as u8, Ordering::Relaxed);
}

fn log_at(level: LogLevel, msg: impl std::fmt::Display) {
    if level as u8 >= LOG_LEVEL.load(Ordering::Relaxed) {
        let tag = if level >= LogLevel::Warn { "WARN " } else { "" };
        eprintln!("[angle_i2p] {tag}{msg}");
        if let Some((handle, name)) = ROSOUT.get() {
            let ros_level = if level >= LogLevel::Warn { RosLogLevel::Warn } else { RosLogLevel::Info };
            handle.rosout_raw(Time::now(), ros_level, name, &msg.to_string(), file!(), "", 0);
        }
    }
}

/// Progress (info).
pub fn info(msg: impl std::fmt::Display) {
    log_at(LogLevel::Info, msg);
}

/// Something dropped, refused or failed (warn).
pub fn warn(msg: impl std::fmt::Display) {
    log_at(LogLevel::Warn, msg);
}

/// Wall-clock time in ns since the epoch (0 if the clock is before it).
pub fn now_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos().min(i64::MAX as u128) as i64)
        .unwrap_or(0)
}

/// The node's statistics, usable after a panic elsewhere (its counters stay consistent).
pub fn lock<T>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}
