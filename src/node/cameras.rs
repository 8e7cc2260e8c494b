//! The node's cameras (`node.cameras`; none: the node's one camera). Each has its topics under
//! its namespace, its own frame assembly ([`Ingest`]), [`DropOldestQueue`], worker and
//! [`crate::pipeline::Localizer`], TF state, `/initialpose` gate, `relocalize` service and
//! diagnostics status; they share the node's one map ([`MapInbox`]) and its one index
//! ([`MapSwap`]). See docs/multi-camera.md.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, Result};
use ros2_client::{Node, Publisher};

use super::diagnostics::Stats;
use super::health::Health;
use super::ingest::{Ingest, IngestRules, Input, Job, Routed};
use super::initial_pose::{GateWidth, InitialPose};
use super::lifecycle::Activity;
use super::log::{lock, warn};
use super::map_inbox::MapInbox;
use super::outputs::Outputs;
use super::queue::DropOldestQueue;
use super::readers::{self, Readers};
use super::recorder::Recorder;
use super::tf::TfBroadcast;
use super::topics::{self, Topics};
use crate::frame::{MonotonicNs, PartKind};
use crate::limits::InputLimits;
use crate::map_index::swap::MapSwap;
use crate::msgs;
use crate::params::{AppParams, Names, NodeParams};
use crate::pipeline::{Localizer, LocalizerParams};
use crate::tf_buffer::TfHistory;

/// One camera as configured: its names, statistics, TF state and initial-pose gate.
pub struct CameraSetup {
    /// Its namespace from `node.cameras` (empty: the node's one camera).
    pub name: String,
    /// What its diagnostics statuses are named after: the node (`angle_i2p`), or the node and
    /// the camera (`angle_i2p/cam0`).
    pub status_name: String,
    pub topics: Topics,
    pub stats: Arc<Mutex<Stats>>,
    pub broadcast: Arc<Mutex<TfBroadcast>>,
    /// The gate set on its `initialpose`, shared by that reader, its `relocalize` and its worker.
    pub gate: Arc<Mutex<Option<InitialPose>>>,
}

impl CameraSetup {
    /// The node's cameras: one per entry of `node.cameras`, or the node's one camera. Only the
    /// first sends `map → odom` (one robot, one `map → odom`).
    pub fn all(
        resolved: &AppParams,
        names: &Names,
        tf_buffer: &Arc<Mutex<TfHistory>>,
        wants_prior: bool,
    ) -> Result<Vec<Self>> {
        let list = &resolved.node.cameras;
        let namespaces: Vec<&str> = if list.is_empty() { vec![""] } else { list.iter().map(String::as_str).collect() };
        namespaces
            .into_iter()
            .enumerate()
            .map(|(i, name)| {
                let topics = topics::of_camera(names, name);
                let mut broadcast = TfBroadcast::new(&resolved.node, tf_buffer.clone());
                if i > 0 {
                    broadcast = broadcast.without_map_to_odom();
                }
                let status_name =
                    if name.is_empty() { names.node_name.clone() } else { format!("{}/{name}", names.node_name) };
                let stats = Arc::new(Mutex::new(camera_stats(&resolved.node, &topics, wants_prior)));
                Ok(Self {
                    name: name.to_string(),
                    status_name,
                    topics,
                    stats,
                    broadcast: Arc::new(Mutex::new(broadcast)),
                    gate: Arc::new(Mutex::new(None)),
                })
            })
            .collect()
    }

    /// Its `relocalize` service: the node's `~/relocalize` for the node's one camera, else the
    /// name a node of its own in the camera's namespace would serve (`cam0/angle_i2p/relocalize`).
    pub fn relocalize_service(&self, names: &Names) -> String {
        if self.name.is_empty() {
            names.resolve("~/relocalize")
        } else {
            names.resolve(&format!("{}/{}/relocalize", self.name, names.node_name))
        }
    }
}

/// A camera's statistics, watching its frame inputs.
fn camera_stats(np: &NodeParams, topics: &Topics, wants_prior: bool) -> Stats {
    let mut health = Health::new(Duration::from_secs_f64(np.diagnostics_window_s), np.min_rate_hz, Instant::now());
    health.watch_input(PartKind::CameraInfo.name(), &topics.camera_info);
    health.watch_input(PartKind::Correspondences.name(), &topics.correspondences);
    if wants_prior {
        health.watch_input(PartKind::DepthPrior.name(), &topics.depth_prior);
    }
    let mut stats = Stats::default();
    stats.health = health;
    stats
}

/// What every camera's inputs are read with.
pub struct InputRules<'a> {
    pub limits: &'a InputLimits,
    pub wants_prior: bool,
    pub debug_image: bool,
    pub gate_width: &'a Arc<Mutex<GateWidth>>,
}

/// Camera `index`'s subscriptions and its `relocalize` service.
pub fn subscribe(r: &mut Readers, index: usize, camera: &CameraSetup, names: &Names, rules: &InputRules) -> Result<()> {
    r.camera = Some(index);
    let topics = &camera.topics;
    readers::subscribe_frame_parts(r, topics, rules.limits, rules.wants_prior)?;
    if rules.debug_image {
        readers::subscribe_images(r, topics, rules.limits)?;
    }
    readers::subscribe_initial_pose(r, topics, rules.gate_width, &camera.gate)?;
    readers::spawn_relocalize(r, &camera.relocalize_service(names), &camera.gate)?;
    r.camera = None;
    Ok(())
}

/// What a camera's worker and ingest are started with (the node's, the same for every camera).
pub struct WorkerContext {
    pub np: NodeParams,
    pub params: LocalizerParams,
    pub rules: IngestRules,
    pub tf: Option<Arc<Publisher<msgs::TFMessage>>>,
    pub recorder: Recorder,
    pub swap: Arc<MapSwap>,
    /// Whether the node is active (lifecycle): the workers localize and publish only then.
    pub active: Activity,
}

/// A running camera: its ingest (fed by [`Cameras::on_input`]), queue and worker.
struct CameraRun {
    ingest: Ingest,
    queue: Arc<DropOldestQueue<Job>>,
    worker: tokio::task::JoinHandle<()>,
}

/// The running cameras and the node's map.
pub struct Cameras {
    runs: Vec<CameraRun>,
    map: MapInbox,
    /// The parameters the localizers run with: the params', the model's constants
    /// (`network.*`, from its metadata) in place of the params' own.
    localizer_params: Option<crate::params::LocalizerParams>,
}

impl Cameras {
    /// Starts each camera's publishers, localizer and worker. Every camera's localizer (the
    /// model) and publishers are made before any worker starts, so a failure (a lifecycle
    /// configure that fails) leaves no worker behind.
    pub fn start(node: &mut Node, setups: &[CameraSetup], cx: &WorkerContext) -> Result<Self> {
        let mut made = Vec::with_capacity(setups.len());
        for c in setups {
            let localizer =
                Localizer::new(cx.params.clone()).map_err(|e| anyhow!("method {}: {e}", cx.params.method.name()))?;
            let (broadcast, recorder, stats) = (c.broadcast.clone(), cx.recorder.clone(), c.stats.clone());
            let outputs = Outputs::create(node, &c.topics, &cx.np, cx.tf.clone(), broadcast, recorder, stats)?
                .with_image_limits(&cx.rules.limits);
            made.push((c, localizer, outputs));
        }
        // Every camera loads the same model: its constants (`network.*`) are the first one's.
        let localizer_params = made.first().map(|(_, localizer, _)| localizer.params().clone());
        let runs = made
            .into_iter()
            .map(|(c, localizer, outputs)| {
                let queue = Arc::new(DropOldestQueue::<Job>::new(cx.np.queue_depth));
                let (swap, gate, active) = (cx.swap.clone(), c.gate.clone(), cx.active.clone());
                let run = super::worker::run(queue.clone(), localizer, swap, outputs, gate, active);
                let worker = tokio::spawn(run);
                let ingest = Ingest::new(cx.rules.clone(), queue.clone(), c.stats.clone());
                CameraRun { ingest, queue, worker }
            })
            .collect();
        let map = MapInbox::new(cx.swap.clone(), cx.params.verify.index_settings());
        Ok(Self { runs, map, localizer_params })
    }

    /// Handles one input that arrived at `now`: a camera's goes to its ingest; the node's map
    /// is taken once for every camera; a bad input of the node's is logged once and counted in
    /// every camera's status.
    pub fn on_input(&mut self, routed: Routed, now: MonotonicNs) {
        match (routed.camera, routed.input) {
            (_, Input::Map(map, sender)) => self.map.on_map(map, sender, self.runs.iter_mut().map(|r| &mut r.ingest)),
            (Some(camera), input) => match self.runs.get_mut(camera) {
                Some(run) => run.ingest.on_input(input, now),
                None => warn(format!("an input for camera #{camera}, which this node does not have")),
            },
            (None, Input::ReadError { topic, reason }) => {
                warn(format!("{topic}: undecodable message: {reason}"));
                self.count_error("undecodable_message", &format!("{topic}: {reason}"));
            }
            (None, Input::Invalid { reason, detail }) => {
                warn(&detail);
                self.count_error(reason, &detail);
            }
            (None, Input::Part(_) | Input::LimitedCorrespondences(..) | Input::PartError { .. }) => {
                warn("a frame part without its camera (ignored)");
            }
        }
    }

    /// The parameters the localizers run with (`None` without a camera).
    pub fn localizer_params(&self) -> Option<&crate::params::LocalizerParams> {
        self.localizer_params.as_ref()
    }

    /// Counts a problem of the node's own inputs in every camera's status.
    pub fn count_error(&self, reason: &str, detail: &str) {
        for run in &self.runs {
            run.ingest.count_error(reason, detail.to_string());
        }
    }

    /// Hands out the frames (and late parts) that waited past the time-out at `now`.
    pub fn expire(&mut self, now: MonotonicNs) {
        for run in &mut self.runs {
            run.ingest.expire(now);
        }
    }

    /// Closes the queues and waits (bounded) for the workers to finish their frames.
    pub async fn shutdown(self) {
        for run in &self.runs {
            run.queue.close();
        }
        for (i, run) in self.runs.into_iter().enumerate() {
            if tokio::time::timeout(Duration::from_secs(30), run.worker).await.is_err() {
                warn(format!("the worker of camera #{i} did not finish within 30 s"));
            }
        }
    }
}

/// One `/diagnostics` message with every camera's statuses; `maps_indexed` from the node's index.
pub fn report(
    setups: &[CameraSetup],
    stamp: crate::frame::Stamp,
    hardware_id: &str,
    maps_indexed: u64,
) -> msgs::DiagnosticArray {
    let mut status = Vec::new();
    for c in setups {
        let mut stats = lock(&c.stats);
        stats.maps_indexed = maps_indexed;
        status.extend(stats.report(stamp, &c.status_name, hardware_id).status);
    }
    msgs::DiagnosticArray { header: msgs::Header::new(stamp, ""), status }
}
