//! The node's life in named steps, as nav2_amcl's `on_configure` has them: parameters →
//! publishers → subscriptions → the loop (ingest, time-outs, diagnostics) → shutdown. The
//! rooms it wires: [`super::readers`] → [`super::ingest`] → queue → [`super::worker`] →
//! [`super::outputs`].

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Result;
use ros2_client::parameters::ParameterValue;
use ros2_client::{Context, Node, NodeOptions, Publisher};
use tokio::sync::mpsc;

use super::cameras::{self, Cameras, InputRules, WorkerContext};
use super::clock;
use super::dds;
use super::ingest::{IngestRules, Input, Routed};
use super::log::{self, info, lock, now_ns, warn};
use super::map_file;
use super::outputs::Recorder;
use super::qos_watch::{InputRequirement, OfferedQos, QosWatch};
use super::readers::{self, Readers};
use super::ros_params::{self, LiveParams, LiveTargets};
use super::setup::{log_started, Setup};
use super::topics::Topics;
use crate::frame::{MonotonicNs, Stamp};
use crate::map_index::swap::MapSwap;
use crate::msgs::{self, convert::DecodedMap};
use crate::params::{AppParams, MapQos, Names};

/// Step 3, subscriptions: every reader, feeding one channel to the ingest task.
fn subscribe(node: &mut Node, s: &Setup) -> Result<(mpsc::Receiver<Routed>, Vec<std::thread::JoinHandle<()>>)> {
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
    readers::subscribe_map(&mut r, &s.topics, s.np.map_qos, &s.limits)?;
    if s.reads_tf {
        readers::subscribe_tf(&mut r, &s.topics, &s.tf_buffer)?;
    }
    // Always: `use_sim_time` may be switched on while the node runs.
    r.threads.push(clock::subscribe(r.node, &s.clock)?);
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
}

impl DiagnosticsOut {
    /// The report of every camera, stamped by the node's clock (`None`: the newest frame's stamp
    /// when no clock is known).
    fn report(&self, s: &Setup, fallback: fn() -> Stamp) -> msgs::DiagnosticArray {
        let newest = s.cameras.iter().filter_map(|c| lock(&c.stats).last_stamp).max();
        let stamp = s.clock.now(newest).unwrap_or_else(fallback);
        cameras::report(&s.cameras, stamp, &self.fq_name, self.swap.indexed())
    }

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
            for c in &s.cameras {
                lock(&c.stats).error("incompatible_qos", problem.to_string());
            }
        }
        let msg = self.report(s, || 0);
        s.recorder.write(&s.topics.diagnostics, &msg, &s.first().stats);
        if let Err(e) = self.publisher.async_publish(msg).await {
            warn(format!("publishing diagnostics failed: {e:?}"));
        }
    }

    /// The last report, at shutdown (bounded wait).
    async fn publish_last(&self, s: &Setup) {
        let last = self.report(s, now_ns);
        s.recorder.write(&s.topics.diagnostics, &last, &s.first().stats);
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
    // 1. Parameters.
    let s = Setup::new(names, &resolved, record.as_deref())?;
    let live = LiveParams::new(
        resolved.clone(),
        LiveTargets {
            stats: s.cameras.iter().map(|c| c.stats.clone()).collect(),
            broadcast: s.cameras.iter().map(|c| c.broadcast.clone()).collect(),
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
    // 2. Publishers (the node's; each camera's come with its worker).
    let tf = if s.np.publish_tf {
        Some(Arc::new(dds::publisher(&mut node, &s.topics.tf, &dds::reliable(100))?))
    } else {
        None
    };
    let mut resend = TfResend { publisher: tf.clone() };
    let swap = Arc::new(MapSwap::default());
    let mut diagnostics = DiagnosticsOut {
        publisher: dds::publisher(&mut node, &s.topics.diagnostics, &dds::reliable(10))?,
        qos_watch: QosWatch::new(input_requirements(&s.topics, s.np.map_qos, s.reads_tf)),
        fq_name: s.names.fully_qualified(),
        swap: swap.clone(),
    };
    // 3. Subscriptions, each camera's localizer and worker, the ingest behind them.
    let (rx, reader_threads) = subscribe(&mut node, &s)?;
    let rules = IngestRules {
        expected: s.expected_parts(),
        stamp_tolerance_ns: s.np.stamp_tolerance_ns,
        frame_timeout: Duration::from_millis(s.np.frame_timeout_ms),
        require_map: s.np.require_map,
        limits: s.limits.clone(),
        pixels: s.pixels,
    };
    let cx =
        WorkerContext { np: s.np.clone(), params: s.params.clone(), rules, tf, recorder: s.recorder.clone(), swap };
    let mut cameras = Cameras::start(&mut node, &s.cameras, &cx)?;
    let clock = Instant::now();
    if !s.np.map_path.is_empty() {
        let loaded = map_file::load(Path::new(&s.np.map_path), &s.np.map_frame_id)?;
        info(format!("map file {}: {} non-finite points left out", s.np.map_path, loaded.non_finite));
        let input = Input::Map(Ok(DecodedMap { map: loaded.map, notes: Vec::new() }));
        cameras.on_input(Routed { camera: None, input }, 0);
    }
    log_started(&s, &context, &diagnostics.fq_name);
    // 4. The loop.
    run_loop(&s, &context, &node, rx, &mut cameras, &mut diagnostics, &mut resend, clock).await;
    // 5. Shutdown.
    info("shutting down");
    // Reader threads end when they next see a message (the ingest side is gone) or with
    // the process.
    drop(reader_threads);
    cameras.shutdown().await;
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
    mut rx: mpsc::Receiver<Routed>,
    cameras: &mut Cameras,
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
                Some(routed) => cameras.on_input(routed, now()),
                None => break,
            },
            _ = tick.tick() => cameras.expire(now()),
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
