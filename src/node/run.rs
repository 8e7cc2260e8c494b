//! The node's life in named steps, as nav2_amcl's `on_configure` has them: parameters →
//! publishers → subscriptions → the loop (ingest, time-outs, diagnostics) → shutdown. The
//! rooms it wires: [`super::readers`] → [`super::ingest`] → queue → [`super::worker`] →
//! [`super::outputs`].

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Result;
use ros2_client::parameters::ParameterValue;
use ros2_client::{Context, Node, NodeOptions, Publisher};
use tokio::sync::mpsc;

use super::clock::{self, NodeClock};
use super::dds;
use super::diagnostics::Stats;
use super::health::Health;
use super::ingest::{Ingest, IngestRules, Input, Job};
use super::initial_pose::{GateWidth, PoseGate};
use super::log::{self, info, lock, now_ns, warn};
use super::map_file;
use super::outputs::{Outputs, Recorder};
use super::qos_watch::{InputRequirement, OfferedQos, QosWatch};
use super::queue::DropOldestQueue;
use super::readers::{self, Readers};
use super::ros_params::{self, LiveParams, LiveTargets};
use super::tf::TfBroadcast;
use super::tf_buffer::TfHistory;
use super::topics::Topics;
use crate::frame::{MonotonicNs, PartKind};
use crate::limits::InputLimits;
use crate::msgs::{self, convert::DecodedMap};
use crate::params::{AppParams, MapQos, Names, NodeParams, TfMode};
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
    /// What was heard on /tf and /tf_static (read when `reads_tf`).
    tf_buffer: Arc<Mutex<TfHistory>>,
    reads_tf: bool,
    broadcast: Arc<Mutex<TfBroadcast>>,
    clock: NodeClock,
    recorder: Recorder,
    stats: Arc<Mutex<Stats>>,
    /// The gate set on `initialpose`, shared by its reader, `~/relocalize` and the worker.
    gate: Arc<Mutex<Option<PoseGate>>>,
    /// The gate's width for the next `/initialpose` (a live parameter).
    gate_width: Arc<Mutex<GateWidth>>,
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
        let tolerance_ns = super::tf::tolerance_ns(np.transform_tolerance_s);
        let tf_buffer = Arc::new(Mutex::new(TfHistory::with_slack(tolerance_ns)));
        let broadcast = TfBroadcast::new(&np, tf_buffer.clone());
        let reads_tf =
            (np.publish_tf && broadcast.mode() != TfMode::MapToCamera) || !broadcast.frames().base.is_empty();
        let broadcast = Arc::new(Mutex::new(broadcast));
        let clock = NodeClock::new(np.use_sim_time);
        Ok(Self {
            names,
            topics,
            params,
            limits,
            pixels,
            wants_prior,
            tf_buffer,
            reads_tf,
            broadcast,
            clock,
            recorder,
            stats,
            gate: Arc::new(Mutex::new(None)),
            gate_width: Arc::new(Mutex::new(GateWidth {
                sigmas: np.initialpose_gate_sigmas,
                min_radius_m: np.initialpose_min_radius_m,
                min_angle_deg: np.initialpose_min_angle_deg,
            })),
            np,
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
    if s.reads_tf {
        readers::subscribe_tf(&mut r, &s.topics, &s.tf_buffer)?;
    }
    // Always: `use_sim_time` may be switched on while the node runs.
    r.threads.push(clock::subscribe(r.node, &s.clock)?);
    readers::spawn_services(&mut r, &s.names, &s.np, &s.gate)?;
    readers::subscribe_initial_pose(&mut r, &s.topics, &s.gate_width, &s.gate)?;
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
    async fn publish(&mut self, context: &Context, node: &Node, s: &Setup) {
        // ros2-client handles `use_sim_time` itself (no validator sees it): follow its value.
        if let Some(ParameterValue::Boolean(sim)) = node.get_parameter("use_sim_time") {
            s.clock.set_use_sim_time(sim);
        }
        let offered: Vec<OfferedQos> =
            context.domain_participant().discovered_writers().iter().map(OfferedQos::from_discovery).collect();
        for problem in self.qos_watch.check(&offered) {
            warn(&problem);
            lock(&s.stats).error("incompatible_qos", problem.to_string());
        }
        let msg = {
            let mut stats = lock(&s.stats);
            let stamp = s.clock.now(stats.last_stamp).unwrap_or(0);
            stats.report(stamp, &s.names.node_name, &self.fq_name)
        };
        s.recorder.write(&s.topics.diagnostics, &msg, &s.stats);
        if let Err(e) = self.publisher.async_publish(msg).await {
            warn(format!("publishing diagnostics failed: {e:?}"));
        }
    }

    /// The last report, at shutdown (bounded wait).
    async fn publish_last(&self, s: &Setup) {
        let last = {
            let mut stats = lock(&s.stats);
            let stamp = s.clock.now(stats.last_stamp).unwrap_or_else(now_ns);
            stats.report(stamp, &s.names.node_name, &self.fq_name)
        };
        s.recorder.write(&s.topics.diagnostics, &last, &s.stats);
        let _ = tokio::time::timeout(Duration::from_millis(500), self.publisher.async_publish(last)).await;
    }
}

/// The node's options: every parameter declared with its resolved value, the parameter
/// services (writes checked and applied by `live`), rosout.
fn node_options(resolved: &AppParams, live: &LiveParams, rosout: bool) -> Result<NodeOptions> {
    let mut options = NodeOptions::new().enable_rosout(rosout).start_parameter_services(true);
    for p in ros_params::declared(resolved)? {
        options = options.declare_parameter(&p.name, p.value);
    }
    let (check, apply) = (live.clone(), live.clone());
    Ok(options
        .parameter_validator(Box::new(move |name, value| {
            check.check(name, value).map(|_| ()).map_err(|e| e.to_string())
        }))
        .parameter_set_action(Box::new(move |name, value| match apply.apply(name, value) {
            Ok(true) => {
                info(format!("parameter {name} set to {value:?}"));
                Ok(())
            }
            Ok(false) => Ok(()),
            Err(e) => Err(e.to_string()),
        })))
}

/// Runs the node until SIGINT/SIGTERM; `record` also writes every published message to a bag;
/// `rosout`: log lines also go to `/rosout`.
pub async fn run_node(names: Names, resolved: AppParams, record: Option<PathBuf>, rosout: bool) -> Result<()> {
    // 1. Parameters (and the localizer they configure).
    let s = Setup::new(names, &resolved, record.as_deref())?;
    let localizer =
        Localizer::new(s.params.clone()).map_err(|e| anyhow::anyhow!("method {}: {e}", s.params.method.name()))?;
    let live = LiveParams::new(
        resolved.clone(),
        LiveTargets {
            stats: s.stats.clone(),
            broadcast: s.broadcast.clone(),
            gate_width: s.gate_width.clone(),
            clock: s.clock.clone(),
        },
    );
    let context = dds::context()?;
    let options = node_options(&resolved, &live, rosout)?;
    let mut node = dds::node_with_options(&context, &s.names.namespace, &s.names.node_name, options)?;
    if rosout {
        log::enable_rosout(node.logging_handle(), log::logger_name(&s.names.fully_qualified()));
    }
    let spinner = dds::spawn_spinner(&mut node)?;
    // 2. Publishers.
    let outputs =
        Outputs::create(&mut node, &s.topics, &s.np, s.broadcast.clone(), s.recorder.clone(), s.stats.clone())?;
    let mut resend = TfResend { publisher: outputs.tf_publisher() };
    let mut diagnostics = DiagnosticsOut {
        publisher: dds::publisher(&mut node, &s.topics.diagnostics, &dds::reliable(10))?,
        qos_watch: QosWatch::new(input_requirements(&s.topics, s.np.map_qos, s.reads_tf)),
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
    run_loop(&s, &context, &node, rx, &mut ingest, &mut diagnostics, &mut resend, clock).await;
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
#[allow(clippy::too_many_arguments)]
async fn run_loop(
    s: &Setup,
    context: &Context,
    node: &Node,
    mut rx: mpsc::Receiver<Input>,
    ingest: &mut Ingest,
    diagnostics: &mut DiagnosticsOut,
    resend: &mut TfResend,
    clock: Instant,
) {
    let now = || clock.elapsed().as_nanos().min(i64::MAX as u128) as MonotonicNs;
    let mut tick = tokio::time::interval(Duration::from_millis(20));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut diag_tick = tokio::time::interval(Duration::from_millis(s.np.diagnostics_period_ms.max(50)));
    diag_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    // 0 Hz: no re-send (an interval that never fires in practice).
    let tf_period = if s.np.tf_publish_rate_hz > 0.0 {
        Duration::from_secs_f64((1.0 / s.np.tf_publish_rate_hz).max(1e-3))
    } else {
        Duration::from_secs(365 * 24 * 3600)
    };
    let mut tf_tick = tokio::time::interval(tf_period);
    tf_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
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
            _ = diag_tick.tick() => diagnostics.publish(context, node, s).await,
            _ = tf_tick.tick() => resend.publish(s).await,
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
    let tf = if np.publish_tf {
        let b = lock(&s.broadcast);
        let f = b.frames();
        let what = match b.mode() {
            TfMode::MapToCamera => format!("{} → camera", f.map),
            TfMode::MapToOdom => format!("{} → {}", f.map, f.odom),
            TfMode::Auto => format!("{} → {} once heard, {} → camera until then", f.map, f.odom, f.map),
        };
        format!(" {} ({what}, re-sent at {} Hz)", t.tf, np.tf_publish_rate_hz)
    } else {
        String::new()
    };
    let base = lock(&s.broadcast).frames().base.clone();
    let base = if base.is_empty() { String::new() } else { format!(" {} (pose of {base})", t.base_pose) };
    info(format!(
        "node {fq_name} on domain {}: method {}, queue_depth {}, frame_timeout {} ms; inputs {} {} {}{} {}{}; outputs {} {} {}{}{} {}",
        context.domain_id(),
        s.params.method.name(),
        np.queue_depth,
        np.frame_timeout_ms,
        t.camera_info,
        t.correspondences,
        if s.wants_prior { t.depth_prior.as_str() } else { "" },
        if np.debug_image { format!(" {}|{}", t.image, t.image_raw) } else { String::new() },
        t.map,
        if s.reads_tf { format!(" {} {}", t.tf, t.tf_static) } else { String::new() },
        t.pose,
        t.pose_with_covariance,
        t.output_correspondences,
        tf,
        base,
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

/// The periodic re-send of the last `map → odom` (`tf_publish_rate_hz`), future-dated from the
/// node's clock as amcl does between updates.
struct TfResend {
    publisher: Option<Arc<Publisher<msgs::TFMessage>>>,
}

impl TfResend {
    async fn publish(&mut self, s: &Setup) {
        let Some(publisher) = &self.publisher else { return };
        let newest = lock(&s.stats).last_stamp;
        let Some(now) = s.clock.now(newest) else { return };
        let Some(msg) = lock(&s.broadcast).republish(now) else { return };
        s.recorder.write(&s.topics.tf, &msg, &s.stats);
        match publisher.async_publish(msg).await {
            Ok(()) => lock(&s.stats).count_tf("republished"),
            Err(e) => {
                warn(format!("re-sending map → odom failed: {e:?}"));
                lock(&s.stats).error("publish_failed", format!("{}: {e:?}", s.topics.tf));
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
