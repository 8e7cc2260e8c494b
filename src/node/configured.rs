//! What a configured node holds — in the lifecycle's inactive and active states — and gives back
//! on cleanup or shutdown: its publishers, its subscriptions and the services that go with them
//! (`~/load_map`, each camera's `relocalize`), each camera's localizer (the model), ingest and
//! worker, and the map (`node.map_path`, indexed once for every camera). Made in the steps
//! nav2_amcl's `on_configure` has them: map file → publishers → subscriptions → cameras. The
//! rooms it wires: [`super::readers`] → [`super::ingest`] → queue → [`super::worker`] →
//! [`super::outputs`].

use std::path::Path;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::Result;
use ros2_client::parameters::ParameterValue;
use ros2_client::{Context, Node, Publisher};
use tokio::sync::mpsc;

use super::cameras::{self, Cameras, InputRules, WorkerContext};
use super::dds;
use super::ingest::{IngestRules, Input, MapSender, Routed};
use super::lifecycle::Activity;
use super::log::{info, lock, now_ns, warn};
use super::map_file;
use super::qos_watch::{InputRequirement, OfferedQos, QosWatch};
use super::readers::{self, Readers};
use super::setup::Setup;
use super::topics::Topics;
use crate::frame::{MonotonicNs, Stamp};
use crate::map_index::swap::MapSwap;
use crate::msgs::{self, convert::DecodedMap};
use crate::params::{MapQos, NodeParams};

/// The configured node's resources.
pub struct Configured {
    /// The readers' inputs; dropping it ends every reader and the services of the configured node.
    rx: mpsc::Receiver<Routed>,
    readers: Vec<JoinHandle<()>>,
    cameras: Cameras,
    diagnostics: DiagnosticsOut,
    resend: TfResend,
    /// The origin of the ingest's monotonic clock.
    origin: Instant,
}

impl Configured {
    /// Configures the node on `node`: the map file read, publishers created (silent until the
    /// node is `active`), subscriptions and services, each camera's localizer and worker. An
    /// error leaves nothing running (what was made is dropped with it).
    pub fn configure(context: &Context, node: &mut Node, s: &Setup, active: &Activity) -> Result<Self> {
        // 1. The map file, the step most likely to fail, before anything runs.
        let map = map_from_file(&s.np)?;
        // 2. Publishers (the node's; each camera's come with its worker).
        let tf = if s.np.publish_tf {
            Some(Arc::new(dds::publisher(node, &s.topics.tf, &dds::reliable(100))?))
        } else {
            None
        };
        let resend = TfResend { publisher: tf.clone(), active: active.clone() };
        let swap = Arc::new(MapSwap::default());
        let diagnostics = DiagnosticsOut {
            publisher: dds::publisher(node, &s.topics.diagnostics, &dds::reliable(10))?,
            qos_watch: QosWatch::new(input_requirements(&s.topics, s.np.map_qos, s.reads_tf)),
            fq_name: s.names.fully_qualified(),
            swap: swap.clone(),
            context: context.clone(),
        };
        // 3. Subscriptions, each camera's localizer and worker, the ingest behind them.
        let (rx, readers) = subscribe(node, s)?;
        let rules = IngestRules {
            expected: s.expected_parts(),
            stamp_tolerance_ns: s.np.stamp_tolerance_ns,
            frame_timeout: Duration::from_millis(s.np.frame_timeout_ms),
            require_map: s.np.require_map,
            limits: s.limits.clone(),
            pixels: s.pixels,
        };
        let (np, params, recorder, active) = (s.np.clone(), s.params.clone(), s.recorder.clone(), active.clone());
        let cx = WorkerContext { np, params, rules, tf, recorder, swap, active };
        let mut cameras = Cameras::start(node, &s.cameras, &cx)?;
        // 4. The map, indexed for every camera.
        if let Some(map) = map {
            cameras.on_input(Routed { camera: None, input: Input::Map(Ok(map), MapSender::File) }, 0);
        }
        Ok(Self { rx, readers, cameras, diagnostics, resend, origin: Instant::now() })
    }

    /// The parameters the localizers run with (the model's constants in `network.*`).
    pub fn localizer_params(&self) -> Option<&crate::params::LocalizerParams> {
        self.cameras.localizer_params()
    }

    /// The next input of the readers (`None`: every reader is gone).
    pub async fn next_input(&mut self) -> Option<Routed> {
        self.rx.recv().await
    }

    /// Hands one input to its camera (or the map to all).
    pub fn on_input(&mut self, routed: Routed) {
        let now = self.now();
        self.cameras.on_input(routed, now);
    }

    /// Hands out the frames that waited past the time-out.
    pub fn expire(&mut self) {
        let now = self.now();
        self.cameras.expire(now);
    }

    /// One `/diagnostics` report.
    pub async fn publish_diagnostics(&mut self, node: &Node, s: &Setup) {
        self.diagnostics.publish(node, s).await;
    }

    /// The periodic re-send of the last `map → odom` (while active).
    pub async fn resend_tf(&self, s: &Setup) {
        self.resend.publish(s).await;
    }

    fn now(&self) -> MonotonicNs {
        self.origin.elapsed().as_nanos().min(i64::MAX as u128) as MonotonicNs
    }

    /// Gives everything back: the readers and the configured node's services end (the ingest
    /// side is gone), the workers finish the frames already queued (published if still active)
    /// and end with their localizers and publishers, the last `/diagnostics` goes out, the map
    /// and its index go. Each camera's `/initialpose` gate and last `map → odom` are
    /// forgotten; its counters are kept (they only grow, as diagnostics readers expect).
    pub async fn release(self, s: &Setup) {
        let Self { rx, readers, cameras, diagnostics, resend, .. } = self;
        drop(rx);
        // Each reader thread ends at once and drops its subscription; none is waited for.
        drop(readers);
        cameras.shutdown().await;
        diagnostics.publish_last(s).await;
        drop(resend);
        for c in &s.cameras {
            *lock(&c.gate) = None;
            lock(&c.broadcast).forget_map_odom();
        }
    }
}

/// `node.map_path` read as the map (`None`: not set).
fn map_from_file(np: &NodeParams) -> Result<Option<DecodedMap>> {
    if np.map_path.is_empty() {
        return Ok(None);
    }
    let loaded = map_file::load(Path::new(&np.map_path), &np.map_frame_id)?;
    info(format!("map file {}: {} non-finite points left out", np.map_path, loaded.non_finite));
    Ok(Some(DecodedMap { map: loaded.map, notes: Vec::new() }))
}

/// Every reader, feeding one channel to the ingest, and `~/load_map`.
fn subscribe(node: &mut Node, s: &Setup) -> Result<(mpsc::Receiver<Routed>, Vec<JoinHandle<()>>)> {
    let (tx, rx) = mpsc::channel::<Routed>(256);
    let mut r = Readers { node, tx, camera: None, threads: Vec::new() };
    let rules = InputRules {
        limits: &s.limits,
        wants_prior: s.wants_prior,
        debug_image: s.np.debug_image,
        gate_width: &s.gate_width,
    };
    for (i, camera) in s.cameras.iter().enumerate() {
        cameras::subscribe(&mut r, i, camera, &s.names, &rules)?;
    }
    if s.np.map_source.takes_topic() {
        readers::subscribe_map(&mut r, &s.topics, s.np.map_qos, &s.limits)?;
    } else {
        readers::refuse_map_topic(&mut r, &s.topics)?;
    }
    if s.reads_tf {
        readers::subscribe_tf(&mut r, &s.topics, &s.tf_buffer)?;
    }
    readers::spawn_load_map(&mut r, &s.names, &s.np)?;
    Ok((rx, r.threads))
}

/// The node's `/diagnostics`: every camera's counters and inputs' health, QoS mismatches.
struct DiagnosticsOut {
    publisher: Publisher<msgs::DiagnosticArray>,
    qos_watch: QosWatch,
    fq_name: String,
    /// The node's map index (its `maps_indexed`).
    swap: Arc<MapSwap>,
    /// Whose discovered writers the QoS check reads.
    context: Context,
}

impl DiagnosticsOut {
    /// The report of every camera, stamped by the node's clock (`fallback` when no clock is
    /// known and no frame was heard).
    fn report(&self, s: &Setup, fallback: fn() -> Stamp) -> msgs::DiagnosticArray {
        let newest = s.cameras.iter().filter_map(|c| lock(&c.stats).last_stamp).max();
        let stamp = s.clock.now(newest).unwrap_or_else(fallback);
        cameras::report(&s.cameras, stamp, &self.fq_name, self.swap.indexed())
    }

    /// One report (every `diagnostics_period_ms`).
    async fn publish(&mut self, node: &Node, s: &Setup) {
        // ros2-client handles `use_sim_time` itself (no validator sees it): follow its value.
        if let Some(ParameterValue::Boolean(sim)) = node.get_parameter("use_sim_time") {
            s.clock.set_use_sim_time(sim);
        }
        let offered: Vec<OfferedQos> =
            self.context.domain_participant().discovered_writers().iter().map(OfferedQos::from_discovery).collect();
        for problem in self.qos_watch.check(&offered) {
            warn(&problem);
            for c in &s.cameras {
                lock(&c.stats).error("incompatible_qos", problem.to_string());
            }
        }
        for problem in s.clock.take_problems() {
            lock(&s.first().stats).error(problem.key, problem.detail);
        }
        let msg = self.report(s, || 0);
        s.recorder.write(&s.topics.diagnostics, &msg, &s.first().stats);
        if let Err(e) = self.publisher.async_publish(msg).await {
            warn(format!("publishing diagnostics failed: {e:?}"));
        }
    }

    /// The last report, when the node cleans up or stops (bounded wait).
    async fn publish_last(&self, s: &Setup) {
        let last = self.report(s, now_ns);
        s.recorder.write(&s.topics.diagnostics, &last, &s.first().stats);
        let _ = tokio::time::timeout(Duration::from_millis(500), self.publisher.async_publish(last)).await;
    }
}

/// The periodic re-send of the last `map → odom` (`tf_publish_rate_hz`), future-dated from the
/// node's clock as amcl does between updates; only while the node is active.
struct TfResend {
    publisher: Option<Arc<Publisher<msgs::TFMessage>>>,
    active: Activity,
}

impl TfResend {
    async fn publish(&self, s: &Setup) {
        let Some(publisher) = &self.publisher else { return };
        if !self.active.is_active() {
            return;
        }
        // The first camera sends `map → odom`.
        let first = s.first();
        let newest = lock(&first.stats).last_stamp;
        let Some(now) = s.clock.now(newest) else { return };
        let Some(msg) = lock(&first.broadcast).republish(now) else { return };
        s.recorder.write(&s.topics.tf, &msg, &first.stats);
        match publisher.async_publish(msg).await {
            Ok(()) => lock(&first.stats).count_tf("republished"),
            Err(e) => {
                warn(format!("re-sending map → odom failed: {e:?}"));
                lock(&first.stats).error("publish_failed", format!("{}: {e:?}", s.topics.tf));
            }
        }
    }
}

/// What each input topic needs from a publisher (the most lenient of the node's readers on
/// it); the frame inputs are read best effort and match any publisher.
fn input_requirements(topics: &Topics, map_qos: MapQos, reads_tf: bool) -> Vec<InputRequirement> {
    let need = |topic: &str, needs_reliable: bool, needs_transient_local: bool| InputRequirement {
        topic: topic.to_string(),
        needs_reliable,
        needs_transient_local,
    };
    let mut out = vec![need(&topics.map, true, map_qos == MapQos::TransientLocal)];
    if reads_tf {
        out.push(need(&topics.tf, true, false));
        out.push(need(&topics.tf_static, true, true));
    }
    out
}
