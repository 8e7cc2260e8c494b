//! The live ROS 2 node over DDS (ros2-client on RustDDS; no ROS installation needed).
//!
//! ```text
//!  readers ──(one thread per topic: decode + convert::*_part)──► ingest ──► DropOldestQueue ──► worker
//!                                                                FrameAssembler  (queue_depth)   Localizer::process
//!                                                                (sans-io: time-                 (blocking pool)
//!                                                                outs, late parts), map          └► outputs: pose,
//!  diagnostics (every diagnostics_period_ms) ◄── Stats ◄──────────────────────────────────────────┘  pose+cov, kept, /tf
//! ```
//!
//! `run` does the node's life in named steps (parameters, the ROS node, the lifecycle, loop,
//! shutdown). The node is a managed node (`lifecycle`, `managed`: unconfigured → inactive →
//! active, `node.autostart` configuring and activating it at start); `configured` holds what
//! configure makes — publishers, subscriptions, each camera's localizer and worker, the map —
//! and `readers`, `ingest`, `worker` and `outputs` are the rooms it wires, once per
//! camera (`cameras`: one, or one per `node.cameras` namespace), all on the node's one map
//! (`map_inbox`) and its one index (`map_index::swap::MapSwap`). Nothing heavy
//! runs in the DDS receive path: readers only decode and convert (with the conversions bag
//! replay uses), the localizer runs on tokio's blocking pool, one frame at a time. Bad input
//! (undecodable messages, non-finite correspondences, unsupported depth encodings, frames with
//! missing parts, late parts, repeated stamps, frames before any map) is counted by reason in
//! `/diagnostics` and logged; the node keeps going. Topics are the [`crate::bag::TopicMap`]'s,
//! resolved with `--ros-args` remaps.

mod cameras;
pub mod clock;
mod configured;
pub mod dds;
mod debug_image;
pub mod diagnostics;
pub mod health;
pub mod image;
mod ingest;
pub mod initial_pose;
pub mod install;
pub mod lifecycle;
pub mod lifecycle_msgs;
mod lifecycle_services;
mod log;
mod managed;
pub mod map_file;
mod map_inbox;
mod outputs;
pub mod qos_watch;
pub mod queue;
mod readers;
mod recorder;
pub mod ros_params;
mod run;
pub mod security;
pub mod services;
mod setup;
pub mod tf;
mod topics;
mod worker;

pub use crate::params::{ArgsError, LogLevel, MapQos, Names, NodeParams, RosArgs};
pub use diagnostics::{status_name, status_value, Stats, LOCALIZATION_TASK};
pub use queue::DropOldestQueue;
pub use run::run_node;

use std::path::PathBuf;

use crate::params;

/// Default node name.
pub const NODE_NAME: &str = "angle_i2p";

/// What `angle-i2p node` was given.
#[derive(Clone, Debug, Default)]
pub struct NodeConfig {
    /// Params file applied before the `--ros-args` ones.
    pub params_file: Option<PathBuf>,
    /// The `--ros-args …` tokens (starting with `--ros-args`), or empty.
    pub ros_args: Vec<String>,
    /// Also write everything published to this new bag, plus `replay`'s per-frame status on
    /// `/diagnostics` ([`crate::app::localization_diagnostics`]), so `eval` reports ms/frame.
    pub record: Option<PathBuf>,
}

/// Runs the node until SIGINT/SIGTERM.
pub fn run(config: NodeConfig) -> anyhow::Result<()> {
    let args = RosArgs::parse(&config.ros_args)?;
    let names = Names::new(NODE_NAME, &args);
    let layers = params::Layers { names: &names, params_file: config.params_file.as_deref(), ros_args: &args };
    let mut resolved = params::resolve(&layers)?;
    if let Some(dirs) = std::env::current_exe().ok().as_deref().and_then(install::InstallDirs::of_binary) {
        for change in dirs.resolve(&mut resolved.localizer) {
            eprintln!("[angle_i2p] installed package: {change}");
        }
    }
    if let Some(level) = args.log_level {
        log::set_log_level(level);
    }
    let security = security::SecurityPlan::for_process(args.enclave.as_deref(), "angle_i2p")?;
    if let Some(note) = resolved.node.map_source.takes_topic().then(dds::receive_buffer_note).flatten() {
        eprintln!("[angle_i2p] note: {note}");
    }
    let rosout = args.rosout.unwrap_or(true);
    for flag in &args.ignored {
        eprintln!("[angle_i2p] {flag}: accepted, no effect (the node logs to stderr only)");
    }
    let runtime =
        tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().thread_name("angle_i2p").build()?;
    runtime.block_on(run_node(names, resolved, config.record, rosout, &security))
}
