//! The node's life in named steps, as nav2_amcl's `on_configure` has them: parameters →
//! publishers → subscriptions → the loop (ingest, time-outs, diagnostics) → shutdown. The
//! rooms it wires: [`super::readers`] → [`super::ingest`] → queue → [`super::worker`] →
//! [`super::outputs`].

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Result;
use ros2_client::{Context, Node, Publisher};
use tokio::sync::mpsc;

use super::dds;
use super::diagnostics::Stats;
use super::health::Health;
use super::ingest::{Ingest, IngestRules, Input, Job};
use super::initial_pose::PoseGate;
use super::log::{info, lock, now_ns, warn};
use super::map_file;
use super::outputs::{Outputs, Recorder, TfSetup};
use super::qos_watch::{InputRequirement, OfferedQos, QosWatch};
use super::queue::DropOldestQueue;
use super::readers::{self, Readers};
use super::tf_buffer::TfHistory;
use super::topics::Topics;
use crate::frame::{MonotonicNs, PartKind, Stamp};
use crate::limits::InputLimits;
use crate::msgs::{self, convert::DecodedMap};
use crate::params::{AppParams, MapQos, Names, NodeParams};
use crate::pipeline::{Localizer, LocalizerParams, Method};

/// Step 1, parameters: what the node was configured with, resolved once.
struct Setup {
    names: Names,
    topics: Topics,
    np: NodeParams,
    params: LocalizerParams,
    limits: InputLimits,
    pixels: crate::camera::PixelSpace,
    /// A frame waits for a depth prior (`expect_depth_prior`, and a method that uses one).
    wants_prior: bool,
    tf: TfSetup,
    recorder: Recorder,
    stats: Arc<Mutex<Stats>>,
    /// The gate set on `initialpose`, shared by its reader, `~/relocalize` and the worker.
    gate: Arc<Mutex<Option<PoseGate>>>,
}

impl Setup {
    fn new(names: Names, resolved: &AppParams, record: Option<&Path>) -> Result<Self> {
        let topics = Topics::new(resolved, &names);
        let np: NodeParams = resolved.node.clone();
        let params = resolved.localizer.clone();
        let limits = resolved.limits.clone();
        let pixels = resolved.camera.pixels;
        let recorder = match record {
            Some(path) => Recorder::create(path)?,
            None => Recorder::default(),
        };
        let wants_prior = np.expect_depth_prior && params.method != Method::Ransac;
        let mut health = Health::new(Duration::from_secs_f64(np.diagnostics_window_s), np.min_rate_hz, Instant::now());
        health.watch_input(PartKind::CameraInfo.name(), &topics.camera_info);
        health.watch_input(PartKind::Correspondences.name(), &topics.correspondences);
        if wants_prior {
            health.watch_input(PartKind::DepthPrior.name(), &topics.depth_prior);
        }
        let mut initial = Stats::default();
        initial.health = health;
        let stats = Arc::new(Mutex::new(initial));
        let odom_frame = np.odom_frame.trim().trim_start_matches('/').to_string();
        let tolerance_ns = (np.transform_tolerance_s * 1e9).round().min(i64::MAX as f64) as i64;
        let buffer = (np.publish_tf && !odom_frame.is_empty())
            .then(|| Arc::new(Mutex::new(TfHistory::with_slack(tolerance_ns))));
        let tf = TfSetup { odom_frame, buffer, tolerance_ns };
        Ok(Self {
            names,
            topics,
            np,
            params,
            limits,
            pixels,
            wants_prior,
            tf,
            recorder,
            stats,
            gate: Arc::new(Mutex::new(None)),
        })
    }

    /// The parts a frame waits for.
    fn expected_parts(&self) -> Vec<PartKind> {
        let mut expected = vec![PartKind::CameraInfo, PartKind::Correspondences];
        if self.wants_prior {
            expected.push(PartKind::DepthPrior);
        }
        if self.np.debug_image {
            expected.push(PartKind::Image);
        }
        expected
    }
}

/// Step 3, subscriptions: every reader, feeding one channel to the ingest task.
fn subscribe(node: &mut Node, s: &Setup) -> Result<(mpsc::Receiver<Input>, Vec<std::thread::JoinHandle<()>>)> {
    let (tx, rx) = mpsc::channel::<Input>(256);
    let mut r = Readers { node, tx, threads: Vec::new() };
    let limits = &s.limits;
    readers::subscribe_frame_parts(&mut r, &s.topics, limits, s.wants_prior)?;
    if s.np.debug_image {
        readers::subscribe_images(&mut r, &s.topics, limits)?;
    }
    readers::subscribe_map(&mut r, &s.topics, s.np.map_qos, limits)?;
    if let Some(buffer) = &s.tf.buffer {
        readers::subscribe_tf(&mut r, &s.topics, buffer)?;
    }
    readers::spawn_services(&mut r, &s.names, &s.np, &s.gate)?;
    readers::subscribe_initial_pose(&mut r, &s.topics, &s.np, &s.gate)?;
    Ok((rx, r.threads))
}

/// The node's `/diagnostics`: the counters, the inputs' health and QoS mismatches.
struct DiagnosticsOut {
    publisher: Publisher<msgs::DiagnosticArray>,
    qos_watch: QosWatch,
    fq_name: String,
}

impl DiagnosticsOut {
    /// One report (every `diagnostics_period_ms`).
    async fn publish(&mut self, context: &Context, s: &Setup) {
        let offered: Vec<OfferedQos> =
            context.domain_participant().discovered_writers().iter().map(OfferedQos::from_discovery).collect();
        for problem in self.qos_watch.check(&offered) {
            warn(&problem);
            lock(&s.stats).error("incompatible_qos", problem.to_string());
        }
        let msg = {
            let mut stats = lock(&s.stats);
            let stamp = node_stamp(s.np.use_sim_time, &stats);
            stats.report(stamp, &s.names.node_name, &self.fq_name)
        };
        s.recorder.write(&s.topics.diagnostics, &msg, &s.stats);
        if let Err(e) = self.publisher.async_publish(msg).await {
            warn(format!("publishing diagnostics failed: {e:?}"));
        }
    }

    /// The last report, at shutdown (bounded wait).
    async fn publish_last(&self, s: &Setup) {
        let last = lock(&s.stats).report(now_ns(), &s.names.node_name, &self.fq_name);
        s.recorder.write(&s.topics.diagnostics, &last, &s.stats);
        let _ = tokio::time::timeout(Duration::from_millis(500), self.publisher.async_publish(last)).await;
    }
}

/// Runs the node until SIGINT/SIGTERM; `record` also writes every published message to a bag.
pub async fn run_node(names: Names, resolved: AppParams, record: Option<PathBuf>) -> Result<()> {
    // 1. Parameters (and the localizer they configure).
    let s = Setup::new(names, &resolved, record.as_deref())?;
    let localizer =
        Localizer::new(s.params.clone()).map_err(|e| anyhow::anyhow!("method {}: {e}", s.params.method.name()))?;
    let context = dds::context()?;
    let mut node = dds::node(&context, &s.names.namespace, &s.names.node_name)?;
    let spinner = dds::spawn_spinner(&mut node)?;
    // 2. Publishers.
    let outputs = Outputs::create(&mut node, &s.topics, &s.np, &s.tf, s.recorder.clone(), s.stats.clone())?;
    let mut diagnostics = DiagnosticsOut {
        publisher: dds::publisher(&mut node, &s.topics.diagnostics, &dds::reliable(10))?,
        qos_watch: QosWatch::new(input_requirements(&s.topics, s.np.map_qos, s.tf.buffer.is_some())),
        fq_name: s.names.fully_qualified(),
    };
    // 3. Subscriptions, the worker and the ingest behind them.
    let (rx, reader_threads) = subscribe(&mut node, &s)?;
    let queue = Arc::new(DropOldestQueue::<Job>::new(s.np.queue_depth));
    let worker_task = tokio::spawn(super::worker::run(queue.clone(), localizer, outputs, s.gate.clone()));
    let rules = IngestRules {
        expected: s.expected_parts(),
        stamp_tolerance_ns: s.np.stamp_tolerance_ns,
        frame_timeout: Duration::from_millis(s.np.frame_timeout_ms),
        require_map: s.np.require_map,
        limits: s.limits.clone(),
        pixels: s.pixels,
    };
    let mut ingest = Ingest::new(rules, queue.clone(), s.stats.clone());
    let clock = Instant::now();
    if !s.np.map_path.is_empty() {
        let loaded = map_file::load(Path::new(&s.np.map_path), &s.np.map_frame_id)?;
        info(format!("map file {}: {} non-finite points left out", s.np.map_path, loaded.non_finite));
        ingest.on_input(Input::Map(Ok(DecodedMap { map: loaded.map, notes: Vec::new() })), 0);
    }
    log_started(&s, &context, &diagnostics.fq_name);
    // 4. The loop.
    run_loop(&s, &context, rx, &mut ingest, &mut diagnostics, clock).await;
    // 5. Shutdown.
    info("shutting down");
    // Reader threads end when they next see a message (the ingest side is gone) or with
    // the process.
    drop(reader_threads);
    queue.close();
    if tokio::time::timeout(Duration::from_secs(30), worker_task).await.is_err() {
        warn("the worker did not finish within 30 s");
    }
    diagnostics.publish_last(&s).await;
    finish_recording(&s.recorder);
    node.stop_spinner();
    drop(node);
    // The spinner thread ends with the node; do not wait on it for long.
    let deadline = Instant::now() + Duration::from_secs(2);
    while !spinner.is_finished() && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    Ok(())
}

/// Inputs to the ingest, time-outs every 20 ms, diagnostics every period; until a signal or
/// until every reader is gone. `clock` is the origin of the ingest's monotonic clock.
async fn run_loop(
    s: &Setup,
    context: &Context,
    mut rx: mpsc::Receiver<Input>,
    ingest: &mut Ingest,
    diagnostics: &mut DiagnosticsOut,
    clock: Instant,
) {
    let now = || clock.elapsed().as_nanos().min(i64::MAX as u128) as MonotonicNs;
    let mut tick = tokio::time::interval(Duration::from_millis(20));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut diag_tick = tokio::time::interval(Duration::from_millis(s.np.diagnostics_period_ms.max(50)));
    diag_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let shutdown = shutdown_signal();
    futures::pin_mut!(shutdown);
    loop {
        tokio::select! {
            _ = &mut shutdown => break,
            input = rx.recv() => match input {
                Some(i) => ingest.on_input(i, now()),
                None => break,
            },
            _ = tick.tick() => ingest.expire(now()),
            _ = diag_tick.tick() => diagnostics.publish(context, s).await,
        }
    }
}

fn finish_recording(recorder: &Recorder) {
    match recorder.finish() {
        Some(Ok(p)) => info(format!("recorded to {}", p.display())),
        Some(Err(e)) => warn(format!("finishing the recording failed: {e:#}")),
        None => {}
    }
}

/// The start-up line: the node, its method and every topic it reads and writes.
fn log_started(s: &Setup, context: &Context, fq_name: &str) {
    let (t, np) = (&s.topics, &s.np);
    let tf = match (np.publish_tf, s.tf.odom_frame.is_empty()) {
        (false, _) => String::new(),
        (true, true) => format!(" {} (map → camera)", t.tf),
        (true, false) => format!(" {} (map → {}, reading {} {})", t.tf, s.tf.odom_frame, t.tf, t.tf_static),
    };
    info(format!(
        "node {fq_name} on domain {}: method {}, queue_depth {}, frame_timeout {} ms; inputs {} {} {}{} {}; outputs {} {} {}{} {}",
        context.domain_id(),
        s.params.method.name(),
        np.queue_depth,
        np.frame_timeout_ms,
        t.camera_info,
        t.correspondences,
        if s.wants_prior { t.depth_prior.as_str() } else { "" },
        if np.debug_image { format!(" {}|{}", t.image, t.image_raw) } else { String::new() },
        t.map,
        t.pose,
        t.pose_with_covariance,
        t.output_correspondences,
        tf,
        t.diagnostics,
    ));
}

async fn shutdown_signal() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        match signal(SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {}
                    _ = term.recv() => {}
                }
            }
            Err(_) => {
                let _ = tokio::signal::ctrl_c().await;
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
    }
}

/// The stamp of the node's own messages (diagnostics): wall time, or with `use_sim_time` the
/// newest input stamp the node has handled (the bag's time during a replay; 0 before any frame).
fn node_stamp(use_sim_time: bool, stats: &Stats) -> Stamp {
    if use_sim_time {
        stats.last_stamp.unwrap_or(0)
    } else {
        now_ns()
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
