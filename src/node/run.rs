//! The node's tasks: readers → ingest (assembly, time-outs, map) → queue → worker → outputs,
//! and the diagnostics timer.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context as _, Result};
use futures::StreamExt;
use ros2_client::{Publisher, Subscription};
use tokio::sync::mpsc;

use super::args::{LogLevel, MapQos, Names, NodeParams, ResolvedParams};
use super::dds;
use super::diagnostics::Stats;
use super::health::Health;
use super::image as img;
use super::initial_pose::{GateWidth, PoseGate};
use super::map_file;
use super::qos_watch::{InputRequirement, OfferedQos, QosWatch};
use super::queue::DropOldestQueue;
use super::services;
use super::tf::{self, TfBuffer};
pub use super::topics::Topics;
use crate::bag::BagWriter;
use crate::frame::{Assembled, Frame, FrameAssembler, FramePart, IncompleteFrame, MapCloud, PartKind, Stamp};
use crate::msgs::{self, convert, RosMessage};
use crate::pipeline::{Localization, Localizer, Method};

/// The node's `--log-level` (`LogLevel as u8`; info by default).
static LOG_LEVEL: AtomicU8 = AtomicU8::new(LogLevel::Info as u8);

/// Sets the level below which the node's messages are not printed.
pub fn set_log_level(level: LogLevel) {
    LOG_LEVEL.store(level as u8, Ordering::Relaxed);
}

fn log_at(level: LogLevel, msg: impl std::fmt::Display) {
    if level as u8 >= LOG_LEVEL.load(Ordering::Relaxed) {
        let tag = if level >= LogLevel::Warn { "WARN " } else { "" };
        eprintln!("[angle_i2p] {tag}{msg}");
    }
}

/// Progress (info).
fn log(msg: impl std::fmt::Display) {
    log_at(LogLevel::Info, msg);
}

/// Something dropped, refused or failed (warn).
fn warn(msg: impl std::fmt::Display) {
    log_at(LogLevel::Warn, msg);
}

fn now_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos().min(i64::MAX as u128) as i64)
        .unwrap_or(0)
}

/// What a reader task hands to the ingest task.
enum Input {
    Part(FramePart),
    /// A message that decoded but did not convert; `stamp` from its header.
    PartError {
        kind: PartKind,
        stamp: Stamp,
        reason: String,
    },
    Map(Result<MapCloud, String>),
    /// The DDS sample could not be deserialized (no header to attribute it to).
    ReadError {
        topic: String,
        reason: String,
    },
    /// A message outside frames (e.g. a transform) was unusable: counted under `reason`.
    Invalid {
        reason: &'static str,
        detail: String,
    },
}

/// Writes what the node publishes to a bag (`--record`); write errors are logged once and
/// counted, never fatal.
#[derive(Clone, Default)]
struct Recorder {
    writer: Arc<Mutex<Option<BagWriter>>>,
}

impl Recorder {
    fn write<M: RosMessage>(&self, topic: &str, msg: &M, stats: &Mutex<Stats>) {
        let mut guard = self.writer.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(w) = guard.as_mut() {
            if let Err(e) = w.write(topic, now_ns(), msg) {
                warn(format!("recording {topic} failed: {e}"));
                lock(stats).error("record_failed", format!("recording {topic}: {e}"));
            }
        }
    }

    fn finish(&self) -> Option<Result<PathBuf>> {
        let w = self.writer.lock().unwrap_or_else(|p| p.into_inner()).take()?;
        Some(w.finish().map_err(Into::into))
    }
}

fn lock(stats: &Mutex<Stats>) -> std::sync::MutexGuard<'_, Stats> {
    stats.lock().unwrap_or_else(|p| p.into_inner())
}

/// One frame waiting for the worker.
struct Job {
    frame: Frame,
    arrived: Instant,
    /// A map that arrived since the previous job: the worker's localizer takes it first.
    new_map: Option<Arc<MapCloud>>,
}

/// Spawns a reader thread that drains `sub`, converting each message with `convert` (`None`:
/// nothing for the ingest task). (ros2-client's sample streams are not `Send`, so each reader
/// gets its own small thread; it only decodes and converts, and ends when the ingest side is
/// gone.)
fn spawn_reader<M, F>(
    sub: Subscription<M>,
    topic: String,
    tx: mpsc::Sender<Input>,
    convert: F,
) -> Result<std::thread::JoinHandle<()>>
where
    M: RosMessage + Send + 'static,
    F: Fn(M) -> Option<Input> + Send + 'static,
{
    std::thread::Builder::new()
        .name(format!("reader {topic}"))
        .spawn(move || {
            futures::executor::block_on(async move {
                let stream = sub.async_stream();
                futures::pin_mut!(stream);
                while let Some(r) = stream.next().await {
                    let input = match r {
                        Ok((msg, _info)) => convert(msg),
                        Err(e) => Some(Input::ReadError { topic: topic.clone(), reason: format!("{e:?}") }),
                    };
                    let Some(input) = input else { continue };
                    if tx.send(input).await.is_err() {
                        break;
                    }
                }
            })
        })
        .with_context(|| "spawning a reader thread".to_string())
}

fn part_or_error<E: std::fmt::Display>(kind: PartKind, stamp: Stamp, r: Result<FramePart, E>) -> Option<Input> {
    Some(match r {
        Ok(p) => Input::Part(p),
        Err(e) => Input::PartError { kind, stamp, reason: e.to_string() },
    })
}

/// Which image topic feeds the frames: the first that delivers wins, the other is then
/// ignored (cameras often publish both raw and compressed; one image per frame is enough).
#[derive(Clone, Default)]
struct ImageSource(Arc<AtomicU8>);

impl ImageSource {
    const COMPRESSED: u8 = 1;
    const RAW: u8 = 2;

    /// True when images of `source` are used (claiming the slot if it is free).
    fn accept(&self, source: u8, topic: &str) -> bool {
        match self.0.compare_exchange(0, source, Ordering::AcqRel, Ordering::Acquire) {
            Ok(_) => {
                log(format!("camera images from {topic}"));
                true
            }
            Err(current) => current == source,
        }
    }
}

/// A camera image message → the frame's image part (decoded to RGB here, in the reader).
fn image_part(
    source: &ImageSource,
    which: u8,
    topic: &str,
    header: &msgs::Header,
    rgb: impl FnOnce() -> Result<image::RgbImage, String>,
) -> Option<Input> {
    if !source.accept(which, topic) {
        return None;
    }
    let stamp = convert::stamp(header);
    part_or_error(PartKind::Image, stamp, rgb().map(|rgb| FramePart::Image { stamp, image: img::to_encoded(rgb) }))
}

/// `part` with its stamp replaced (stamp-tolerant matching).
fn restamp(part: FramePart, s: Stamp) -> FramePart {
    match part {
        FramePart::CameraInfo { intrinsics, .. } => FramePart::CameraInfo { stamp: s, intrinsics },
        FramePart::Correspondences { camera_frame_id, map_frame_id, correspondences, .. } => {
            FramePart::Correspondences { stamp: s, camera_frame_id, map_frame_id, correspondences }
        }
        FramePart::DepthPrior { depth, .. } => FramePart::DepthPrior { stamp: s, depth },
        FramePart::Image { image, .. } => FramePart::Image { stamp: s, image },
        FramePart::GroundTruthPose { pose, .. } => FramePart::GroundTruthPose { stamp: s, pose },
        FramePart::GroundTruthDepth { depth, .. } => FramePart::GroundTruthDepth { stamp: s, depth },
    }
}

/// Joins parts into frames, times out incomplete ones, holds the map, feeds the queue.
struct Ingest {
    assembler: FrameAssembler,
    /// Stamps waiting in the assembler → arrival of their first part.
    pending: BTreeMap<Stamp, Instant>,
    tolerance_ns: i64,
    timeout: Duration,
    require_map: bool,
    map: Option<Arc<MapCloud>>,
    /// The map changed since the last queued job.
    map_changed: bool,
    queue: Arc<DropOldestQueue<Job>>,
    stats: Arc<Mutex<Stats>>,
    /// The input limits applied to each assembled frame (`limits.*`).
    limits: crate::limits::InputLimits,
    limit_counts: crate::limits::LimitCounts,
}

impl Ingest {
    /// The pending stamp within tolerance of `stamp`, else `stamp` itself.
    fn snap(&self, stamp: Stamp) -> Stamp {
        if self.tolerance_ns <= 0 || self.pending.contains_key(&stamp) {
            return stamp;
        }
        let lo = stamp.saturating_sub(self.tolerance_ns);
        let hi = stamp.saturating_add(self.tolerance_ns);
        self.pending.range(lo..=hi).map(|(s, _)| *s).min_by_key(|s| (s - stamp).unsigned_abs()).unwrap_or(stamp)
    }

    fn on_input(&mut self, input: Input) {
        match input {
            Input::Part(part) => {
                lock(&self.stats).health.heard(part.kind().name(), Instant::now());
                let stamp = self.snap(part.stamp());
                self.open(stamp);
                let done = self.assembler.push(restamp(part, stamp));
                self.handle(done);
            }
            Input::PartError { kind, stamp, reason } => {
                lock(&self.stats).health.heard(kind.name(), Instant::now());
                let stamp = self.snap(stamp);
                warn(format!("frame {stamp}: bad {}: {reason}", kind.name()));
                lock(&self.stats)
                    .error(&format!("invalid_{}", kind.name()), format!("frame {stamp}: {}: {reason}", kind.name()));
                self.open(stamp);
                let done = self.assembler.push_error(stamp, kind, format!("{reason} (counted)"));
                self.handle(done);
            }
            Input::Map(Ok(map)) => {
                if self.map.as_deref().is_some_and(|m| m.frame_id == map.frame_id && m.points == map.points) {
                    // `map_qos: auto` reads the map twice from a latched publisher.
                    return;
                }
                log(format!("map received: {} points in frame {:?}", map.points.len(), map.frame_id));
                let mut s = lock(&self.stats);
                s.maps_received += 1;
                s.map_points = map.points.len();
                self.map = Some(Arc::new(map));
                self.map_changed = true;
            }
            Input::Map(Err(reason)) => {
                warn(format!("bad map (kept the previous one): {reason}"));
                lock(&self.stats).error("invalid_map", format!("map: {reason}"));
            }
            Input::ReadError { topic, reason } => {
                warn(format!("{topic}: undecodable message: {reason}"));
                lock(&self.stats).error("undecodable_message", format!("{topic}: {reason}"));
            }
            Input::Invalid { reason, detail } => {
                warn(&detail);
                lock(&self.stats).error(reason, detail);
            }
        }
    }

    /// Notes the first part of a frame (a stamp not waiting yet): every such frame is later
    /// localized, failed or dropped, each counted.
    fn open(&mut self, stamp: Stamp) {
        if let std::collections::btree_map::Entry::Vacant(e) = self.pending.entry(stamp) {
            e.insert(Instant::now());
            lock(&self.stats).frames_received += 1;
        }
    }

    /// Hands out, oldest first, the frames whose first part arrived more than the time-out ago.
    fn expire(&mut self) {
        let now = Instant::now();
        while let Some((&stamp, &first)) = self.pending.iter().next() {
            if now.duration_since(first) < self.timeout {
                break;
            }
            let reason = format!("timed out after {} ms waiting for parts", self.timeout.as_millis());
            let out = self.assembler.take(stamp, reason);
            self.pending.remove(&stamp);
            self.handle(out);
        }
    }

    fn handle(&mut self, done: Option<Assembled>) {
        let Some(done) = done else { return };
        let done = crate::bag::limit_frame(done, &self.limits, &mut self.limit_counts);
        let arrived = self.pending.remove(&done.stamp()).unwrap_or_else(Instant::now);
        match done {
            Assembled::Complete(frame) => self.enqueue(frame, arrived),
            Assembled::Partial(frame, report) => {
                self.count_incomplete(&report);
                self.enqueue(frame, arrived);
            }
            Assembled::Dropped(report) => self.count_incomplete(&report),
        }
    }

    fn count_incomplete(&self, r: &IncompleteFrame) {
        let detail = crate::app::describe(r);
        warn(&detail);
        let mut s = lock(&self.stats);
        if r.dropped {
            let required = PartKind::REQUIRED.iter().map(|k| k.name()).find(|n| r.missing.contains(n));
            let reason = format!("missing_{}", required.unwrap_or("parts"));
            s.drop_frame(&reason, detail);
        } else {
            for m in &r.missing {
                s.error(&format!("partial_missing_{m}"), detail.clone());
            }
            if r.missing.is_empty() && !r.errors.is_empty() {
                s.error("partial_frame", detail);
            }
        }
    }

    fn enqueue(&mut self, frame: Frame, arrived: Instant) {
        let stamp = frame.stamp;
        let mut s = lock(&self.stats);
        s.frames_in += 1;
        if self.require_map && self.map.is_none() {
            s.drop_frame("no_map", format!("frame {stamp}: no map received yet"));
            warn(format!("frame {stamp}: dropped, no map received yet"));
            return;
        }
        if let Some(map) = &self.map {
            if !map.frame_id.is_empty() && !frame.map_frame_id.is_empty() && map.frame_id != frame.map_frame_id {
                s.error(
                    "map_frame_mismatch",
                    format!("frame {stamp}: correspondences in {:?}, map in {:?}", frame.map_frame_id, map.frame_id),
                );
            }
        }
        drop(s);
        let new_map = if self.map_changed { self.map.clone() } else { None };
        self.map_changed = false;
        let dropped = self.queue.push(Job { frame, arrived, new_map });
        let mut stats = lock(&self.stats);
        stats.queued_max = stats.queued_max.max(self.queue.len());
        if let Some(old) = dropped {
            let msg = format!("frame {}: dropped, queue full (newer frame {stamp} arrived)", old.frame.stamp);
            warn(&msg);
            stats.drop_frame("queue_full", msg);
        }
    }
}

/// The worker's publishers.
struct Outputs {
    topics: Topics,
    pose: Publisher<msgs::PoseStamped>,
    pose_cov: Publisher<msgs::PoseWithCovarianceStamped>,
    kept: Publisher<msgs::Correspondences>,
    tf: Option<Publisher<msgs::TFMessage>>,
    /// With `node.odom_frame` set: that frame and the transforms heard on /tf.
    odom: Option<(String, Arc<Mutex<TfBuffer>>)>,
    debug: Option<Publisher<msgs::Image>>,
    recorder: Recorder,
    stats: Arc<Mutex<Stats>>,
}

impl Outputs {
    async fn send<M: RosMessage + Clone + std::fmt::Debug>(&self, p: &Publisher<M>, topic: &str, msg: M) {
        self.recorder.write(topic, &msg, &self.stats);
        if let Err(e) = p.async_publish(msg).await {
            warn(format!("publishing on {topic} failed: {e:?}"));
            lock(&self.stats).error("publish_failed", format!("{topic}: {e:?}"));
        }
    }

    /// Publishes one frame's results as `replay` writes them (same conversions).
    async fn publish(&self, loc: &Localization, frame: &Frame) {
        let t = loc.stamp;
        let topics = &self.topics;
        if let Some(pose) = &loc.pose {
            self.send(&self.pose, &topics.pose, convert::pose_stamped(t, &loc.map_frame_id, pose)).await;
            if let Some(cov) = &loc.covariance {
                let m = convert::pose_with_covariance_stamped(t, &loc.map_frame_id, pose, cov);
                self.send(&self.pose_cov, &topics.pose_with_covariance, m).await;
            }
            if let Some(tf) = &self.tf {
                match self.tf_message(loc, pose) {
                    Ok(msg) => self.send(tf, &topics.tf, msg).await,
                    Err(detail) => {
                        warn(&detail);
                        lock(&self.stats).error("no_odom_transform", detail);
                    }
                }
            }
        }
        let kept = convert::correspondences_msg(t, &loc.camera_frame_id, &loc.map_frame_id, &loc.kept);
        self.send(&self.kept, &topics.output_correspondences, kept).await;
        if let Some(debug) = &self.debug {
            match debug_image(frame, loc) {
                Ok(img) => self.send(debug, &topics.debug_image, img).await,
                Err(e) => lock(&self.stats).error("debug_image", format!("frame {t}: {e}")),
            }
        }
        // The recording also gets the per-frame status `replay` writes (timings for `eval`).
        self.recorder.write(crate::app::DIAGNOSTICS_TOPIC, &crate::app::localization_diagnostics(loc), &self.stats);
    }

    /// TF of a localized frame: `map → camera`, or `map → odom` when an odom frame is set
    /// (an error naming what is missing when odom → camera is unknown).
    fn tf_message(&self, loc: &Localization, pose: &nalgebra::Isometry3<f64>) -> Result<msgs::TFMessage, String> {
        let Some((odom, buffer)) = &self.odom else {
            return Ok(tf::tf_message(loc.stamp, &loc.map_frame_id, &loc.camera_frame_id, pose));
        };
        let odom_camera = buffer.lock().unwrap_or_else(|p| p.into_inner()).lookup(odom, &loc.camera_frame_id);
        let odom_camera = odom_camera.ok_or_else(|| {
            format!(
                "frame {}: no transform {odom} → {} on {} yet; no TF published",
                loc.stamp, loc.camera_frame_id, self.topics.tf
            )
        })?;
        Ok(tf::tf_message(loc.stamp, &loc.map_frame_id, odom, &tf::map_to_odom(pose, &odom_camera)))
    }
}

/// The camera image (rgb8) with kept correspondences as green and rejected ones as red
/// 5×5 squares.
fn debug_image(frame: &Frame, loc: &Localization) -> Result<msgs::Image> {
    let enc = frame.image.as_ref().ok_or_else(|| anyhow!("no camera image for this frame"))?;
    let mut rgb = img::from_encoded(enc).map_err(|e| anyhow!(e))?;
    img::draw_matches(&mut rgb, &frame.correspondences, &loc.kept);
    Ok(img::image_msg(loc.stamp, &loc.camera_frame_id, rgb))
}

/// Runs `localizer` on `frame` on the blocking pool; a panic becomes a counted failure and a
/// fresh localizer.
async fn localize(localizer: Localizer, frame: Frame) -> (Localizer, Frame, Option<Localization>) {
    let params = localizer.params().clone();
    let handle = tokio::task::spawn_blocking(move || {
        let mut localizer = localizer;
        let out = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| localizer.process(&frame)));
        (localizer, frame, out.ok())
    });
    match handle.await {
        Ok(r) => r,
        // The task itself died (cannot happen with catch_unwind, but never stop the worker).
        Err(_) => (Localizer::new(params.clone()), dummy_frame(), None),
    }
}

fn dummy_frame() -> Frame {
    Frame {
        stamp: 0,
        camera_frame_id: String::new(),
        map_frame_id: String::new(),
        intrinsics: crate::geometry::Intrinsics { fx: 0.0, fy: 0.0, cx: 0.0, cy: 0.0, width: 0, height: 0 },
        correspondences: Vec::new(),
        depth_prior: None,
        image: None,
        ground_truth: None,
    }
}

async fn worker(
    queue: Arc<DropOldestQueue<Job>>,
    mut localizer: Localizer,
    outputs: Outputs,
    gate: Arc<Mutex<Option<PoseGate>>>,
) {
    let mut maps = crate::map_index::swap::MapSwap::default();
    while let Some(job) = queue.pop().await {
        if let Some(new) = job.new_map {
            maps.new_map(new, crate::map_index::IndexSettings::from_verify(&localizer.params().verify));
        }
        if let Some(index) = maps.take_ready() {
            localizer.set_map_index(index);
        }
        let stamp = job.frame.stamp;
        let (back, frame, loc) = localize(localizer, job.frame).await;
        localizer = back;
        let Some(mut loc) = loc else {
            warn(format!("frame {stamp}: the localizer panicked; continuing with a fresh one"));
            let mut s = lock(&outputs.stats);
            s.frames_failed += 1;
            s.error("panic", format!("frame {stamp}: localizer panicked"));
            drop(s);
            localizer = Localizer::new(localizer.params().clone());
            if let Some(index) = maps.current() {
                localizer.set_map_index(index);
            }
            continue;
        };
        apply_gate(&gate, &mut loc, &outputs.stats);
        outputs.publish(&loc, &frame).await;
        let latency = job.arrived.elapsed().as_secs_f64() * 1e3;
        let mut s = lock(&outputs.stats);
        s.frame_done(stamp, loc.pose.is_some(), latency, loc.timings.total_ms);
        if loc.pose.is_some() {
            s.frame_evidence(loc.prior_quality, loc.fast_path);
        }
        if let Some(f) = &loc.failure {
            s.error(f.key(), format!("frame {stamp}: {f}"));
            drop(s);
            warn(format!("frame {stamp}: no pose: {f}"));
        }
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

/// The stamp of the node's own messages (diagnostics): wall time, or with `use_sim_time` the
/// newest input stamp the node has handled (the bag's time during a replay; 0 before any frame).
fn node_stamp(use_sim_time: bool, stats: &Stats) -> Stamp {
    if use_sim_time {
        stats.last_stamp.unwrap_or(0)
    } else {
        now_ns()
    }
}

fn gate_width(np: &NodeParams) -> GateWidth {
    GateWidth {
        sigmas: np.initialpose_gate_sigmas,
        min_radius_m: np.initialpose_min_radius_m,
        min_angle_deg: np.initialpose_min_angle_deg,
    }
}

/// With an `/initialpose` gate set: a pose outside it is withdrawn (counted), one inside moves it.
fn apply_gate(gate: &Mutex<Option<PoseGate>>, loc: &mut Localization, stats: &Mutex<Stats>) {
    let mut guard = gate.lock().unwrap_or_else(|p| p.into_inner());
    let (Some(g), Some(pose)) = (guard.as_mut(), loc.pose) else { return };
    match g.check(&pose) {
        Ok(()) => g.follow(&pose),
        Err(miss) => {
            let detail = format!("frame {}: outside the initial pose gate: {miss}", loc.stamp);
            warn(&detail);
            lock(stats).error("outside_initialpose_gate", detail);
            loc.pose = None;
            loc.covariance = None;
        }
    }
}

/// The map subscription(s) of `map_qos`: reliable, keep last 1.
fn map_qos_profiles(map_qos: MapQos) -> Vec<ros2_client::QosProfile> {
    match map_qos {
        MapQos::Auto => vec![dds::latched(), dds::reliable(1)],
        MapQos::TransientLocal => vec![dds::latched()],
        MapQos::Volatile => vec![dds::reliable(1)],
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

/// Runs the node until SIGINT/SIGTERM; `record` also writes every published message to a bag.
pub async fn run_node(names: Names, resolved: ResolvedParams, record: Option<PathBuf>) -> Result<()> {
    let topics = Topics::new(&resolved, &names);
    let np: NodeParams = resolved.node.clone();
    let params = resolved.params.clone();
    let recorder = Recorder::default();
    if let Some(path) = &record {
        let w = BagWriter::create(path).with_context(|| format!("--record {}", path.display()))?;
        *recorder.writer.lock().unwrap_or_else(|p| p.into_inner()) = Some(w);
    }

    let context = dds::context()?;
    let mut node = dds::node(&context, &names.namespace, &names.node_name)?;
    let spinner = dds::spawn_spinner(&mut node)?;
    let mut health = Health::new(Duration::from_secs_f64(np.diagnostics_window_s), np.min_rate_hz, Instant::now());
    health.watch_input(PartKind::CameraInfo.name(), &topics.camera_info);
    health.watch_input(PartKind::Correspondences.name(), &topics.correspondences);
    if np.expect_depth_prior && params.method != Method::Ransac {
        health.watch_input(PartKind::DepthPrior.name(), &topics.depth_prior);
    }
    let mut initial = Stats::default();
    initial.health = health;
    let stats = Arc::new(Mutex::new(initial));
    let odom_frame = np.odom_frame.trim().trim_start_matches('/').to_string();
    let tf_buffer = (np.publish_tf && !odom_frame.is_empty()).then(|| Arc::new(Mutex::new(TfBuffer::default())));

    // Outputs.
    let out_qos = dds::reliable(10);
    let outputs = Outputs {
        pose: dds::publisher(&mut node, &topics.pose, &out_qos)?,
        pose_cov: dds::publisher(&mut node, &topics.pose_with_covariance, &out_qos)?,
        kept: dds::publisher(&mut node, &topics.output_correspondences, &out_qos)?,
        tf: if np.publish_tf { Some(dds::publisher(&mut node, &topics.tf, &dds::reliable(100))?) } else { None },
        odom: tf_buffer.clone().map(|b| (odom_frame.clone(), b)),
        debug: if np.debug_image {
            Some(dds::publisher(&mut node, &topics.debug_image, &dds::sensor_data(5))?)
        } else {
            None
        },
        topics: topics.clone(),
        recorder: recorder.clone(),
        stats: stats.clone(),
    };
    let diag_pub: Publisher<msgs::DiagnosticArray> =
        dds::publisher(&mut node, &topics.diagnostics, &dds::reliable(10))?;

    // Inputs: what a frame waits for.
    let mut expected = vec![PartKind::CameraInfo, PartKind::Correspondences];
    let wants_prior = np.expect_depth_prior && params.method != Method::Ransac;
    if wants_prior {
        expected.push(PartKind::DepthPrior);
    }
    if np.debug_image {
        expected.push(PartKind::Image);
    }
    let (tx, mut rx) = mpsc::channel::<Input>(256);
    let gate: Arc<Mutex<Option<PoseGate>>> = Arc::new(Mutex::new(None));
    let mut readers = Vec::new();
    let sensor = dds::sensor_data(10);
    readers.push(spawn_reader(
        dds::subscription::<msgs::CameraInfo>(&mut node, &topics.camera_info, &sensor)?,
        topics.camera_info.clone(),
        tx.clone(),
        {
            let limits = params.limits.clone();
            move |m| {
                let stamp = convert::stamp(&m.header);
                let r = crate::limits::check_image_side("CameraInfo", m.width, m.height, &limits).and_then(|()| {
                    convert::intrinsics_from_camera_info(&m)
                        .map(|intrinsics| FramePart::CameraInfo { stamp, intrinsics })
                        .map_err(|e| e.to_string())
                });
                part_or_error(PartKind::CameraInfo, stamp, r)
            }
        },
    )?);
    readers.push(spawn_reader(
        // Best effort: matches reliable and best-effort matchers alike.
        dds::subscription::<msgs::Correspondences>(&mut node, &topics.correspondences, &dds::sensor_data(10))?,
        topics.correspondences.clone(),
        tx.clone(),
        |m| {
            let stamp = convert::stamp(&m.header);
            let r = convert::correspondences_from_msg(&m).map(|correspondences| FramePart::Correspondences {
                stamp,
                correspondences,
                camera_frame_id: m.header.frame_id.clone(),
                map_frame_id: m.map_frame_id.clone(),
            });
            part_or_error(PartKind::Correspondences, stamp, r)
        },
    )?);
    if wants_prior {
        readers.push(spawn_reader(
            dds::subscription::<msgs::Image>(&mut node, &topics.depth_prior, &sensor)?,
            topics.depth_prior.clone(),
            tx.clone(),
            {
                let limits = params.limits.clone();
                move |m| {
                    let stamp = convert::stamp(&m.header);
                    let r = crate::limits::check_image_side("depth prior", m.width, m.height, &limits).and_then(|()| {
                        convert::depth_from_image(&m)
                            .map(|depth| FramePart::DepthPrior { stamp, depth })
                            .map_err(|e| e.to_string())
                    });
                    part_or_error(PartKind::DepthPrior, stamp, r)
                }
            },
        )?);
    }
    if np.debug_image {
        let source = ImageSource::default();
        let (src, topic) = (source.clone(), topics.image.clone());
        readers.push(spawn_reader(
            dds::subscription::<msgs::CompressedImage>(&mut node, &topics.image, &sensor)?,
            topics.image.clone(),
            tx.clone(),
            {
                let side = params.limits.max_image_side;
                move |m| {
                    let rgb = || img::rgb_from_compressed_within(&m, side);
                    image_part(&src, ImageSource::COMPRESSED, &topic, &m.header, rgb)
                }
            },
        )?);
        let (src, topic) = (source, topics.image_raw.clone());
        readers.push(spawn_reader(
            dds::subscription::<msgs::Image>(&mut node, &topics.image_raw, &sensor)?,
            topics.image_raw.clone(),
            tx.clone(),
            move |m| image_part(&src, ImageSource::RAW, &topic, &m.header, || img::rgb_from_image(&m)),
        )?);
    }
    for qos in map_qos_profiles(np.map_qos) {
        let limits = params.limits.clone();
        readers.push(spawn_reader(
            dds::subscription::<msgs::PointCloud2>(&mut node, &topics.map, &qos)?,
            topics.map.clone(),
            tx.clone(),
            move |m| {
                let map = convert::map_cloud_from_point_cloud(&m).map(|mut map| {
                    crate::limits::limit_map(&mut map, &limits);
                    map
                });
                Some(Input::Map(map.map_err(|e| e.to_string())))
            },
        )?);
    }
    if let Some(buffer) = &tf_buffer {
        for (topic, qos) in [(&topics.tf, dds::reliable(100)), (&topics.tf_static, dds::latched())] {
            let buffer = buffer.clone();
            readers.push(spawn_reader(
                dds::subscription::<msgs::TFMessage>(&mut node, topic, &qos)?,
                topic.clone(),
                tx.clone(),
                move |m| {
                    let bad = buffer.lock().unwrap_or_else(|p| p.into_inner()).update(&m);
                    (!bad.is_empty()).then(|| Input::Invalid { reason: "invalid_transform", detail: bad.join("; ") })
                },
            )?);
        }
    }
    let (load_map_tx, map_path, map_frame_id) = (tx.clone(), np.map_path.clone(), np.map_frame_id.clone());
    let load_map = move || {
        let (response, map) = services::load_map_answer(&map_path, &map_frame_id);
        if let Some(map) = map {
            // The node is shutting down when the ingest side is gone.
            let _ = load_map_tx.blocking_send(Input::Map(Ok(map)));
        }
        response
    };
    readers.push(services::spawn_trigger(&mut node, &names.resolve("~/load_map"), load_map, |m| log(m))?);
    let gate_for_service = gate.clone();
    let relocalize = move || {
        let had = gate_for_service.lock().unwrap_or_else(|p| p.into_inner()).take().is_some();
        let message = if had { "initial pose dropped: localizing globally" } else { "no initial pose was set" };
        services::TriggerResponse { success: true, message: message.into() }
    };
    readers.push(services::spawn_trigger(&mut node, &names.resolve("~/relocalize"), relocalize, |m| log(m))?);
    let (gate_for_reader, width) = (gate.clone(), gate_width(&np));
    readers.push(spawn_reader(
        dds::subscription::<msgs::PoseWithCovarianceStamped>(&mut node, &topics.initial_pose, &dds::reliable(10))?,
        topics.initial_pose.clone(),
        tx.clone(),
        move |m| match PoseGate::from_msg(&m, None, width) {
            Ok(g) => {
                log(format!("initial pose: gate {:.2} m / {:.1}°", g.radius_m, g.max_angle_rad.to_degrees()));
                *gate_for_reader.lock().unwrap_or_else(|p| p.into_inner()) = Some(g);
                None
            }
            Err(e) => Some(Input::Invalid { reason: "invalid_initialpose", detail: e.to_string() }),
        },
    )?);
    drop(tx);

    let localizer = Localizer::new(params.clone());
    if let Some(e) = localizer.setup_error() {
        anyhow::bail!("method {}: {e}", params.method.name());
    }
    let queue = Arc::new(DropOldestQueue::new(np.queue_depth));
    let worker_task = tokio::spawn(worker(queue.clone(), localizer, outputs, gate.clone()));

    let mut ingest = Ingest {
        assembler: FrameAssembler::new(&expected),
        pending: BTreeMap::new(),
        tolerance_ns: np.stamp_tolerance_ns.max(0),
        timeout: Duration::from_millis(np.frame_timeout_ms),
        require_map: np.require_map,
        map: None,
        map_changed: false,
        queue: queue.clone(),
        stats: stats.clone(),
        limits: params.limits.clone(),
        limit_counts: Default::default(),
    };
    if !np.map_path.is_empty() {
        let loaded = map_file::load(Path::new(&np.map_path), &np.map_frame_id)?;
        log(format!("map file {}: {} non-finite points left out", np.map_path, loaded.non_finite));
        ingest.on_input(Input::Map(Ok(loaded.map)));
    }
    let diag_period = Duration::from_millis(np.diagnostics_period_ms.max(50));
    let fq_name = names.fully_qualified();
    log(format!(
        "node {fq_name} on domain {}: method {}, queue_depth {}, frame_timeout {} ms; inputs {} {} {}{} {}; outputs {} {} {}{} {}",
        context.domain_id(),
        params.method.name(),
        np.queue_depth,
        np.frame_timeout_ms,
        topics.camera_info,
        topics.correspondences,
        if wants_prior { topics.depth_prior.as_str() } else { "" },
        if np.debug_image { format!(" {}|{}", topics.image, topics.image_raw) } else { String::new() },
        topics.map,
        topics.pose,
        topics.pose_with_covariance,
        topics.output_correspondences,
        match (np.publish_tf, odom_frame.is_empty()) {
            (false, _) => String::new(),
            (true, true) => format!(" {} (map → camera)", topics.tf),
            (true, false) => format!(" {} (map → {odom_frame}, reading {} {})", topics.tf, topics.tf, topics.tf_static),
        },
        topics.diagnostics,
    ));

    let mut qos_watch = QosWatch::new(input_requirements(&topics, np.map_qos, tf_buffer.is_some()));
    let mut tick = tokio::time::interval(Duration::from_millis(20));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut diag_tick = tokio::time::interval(diag_period);
    diag_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let shutdown = shutdown_signal();
    futures::pin_mut!(shutdown);
    loop {
        tokio::select! {
            _ = &mut shutdown => break,
            input = rx.recv() => match input {
                Some(i) => ingest.on_input(i),
                None => break,
            },
            _ = tick.tick() => ingest.expire(),
            _ = diag_tick.tick() => {
                let offered: Vec<OfferedQos> =
                    context.domain_participant().discovered_writers().iter().map(OfferedQos::from_discovery).collect();
                for problem in qos_watch.check(&offered) {
                    warn(&problem);
                    lock(&stats).error("incompatible_qos", problem.to_string());
                }
                let msg = {
                    let mut s = lock(&stats);
                    let stamp = node_stamp(np.use_sim_time, &s);
                    s.report(stamp, &names.node_name, &fq_name)
                };
                recorder.write(&topics.diagnostics, &msg, &stats);
                if let Err(e) = diag_pub.async_publish(msg).await {
                    warn(format!("publishing diagnostics failed: {e:?}"));
                }
            }
        }
    }

    log("shutting down");
    // Reader threads end when they next see a message (the ingest side is gone) or with
    // the process.
    drop(rx);
    drop(readers);
    queue.close();
    if tokio::time::timeout(Duration::from_secs(30), worker_task).await.is_err() {
        warn("the worker did not finish within 30 s");
    }
    let last = lock(&stats).report(now_ns(), &names.node_name, &fq_name);
    recorder.write(&topics.diagnostics, &last, &stats);
    let _ = tokio::time::timeout(Duration::from_millis(500), diag_pub.async_publish(last)).await;
    if let Some(r) = recorder.finish() {
        match r {
            Ok(p) => log(format!("recorded to {}", p.display())),
            Err(e) => warn(format!("finishing the recording failed: {e:#}")),
        }
    }
    node.stop_spinner();
    drop(node);
    // The spinner thread ends with the node; do not wait on it for long.
    let deadline = Instant::now() + Duration::from_secs(2);
    while !spinner.is_finished() && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Intrinsics;

    fn ingest(tolerance_ns: i64, timeout_ms: u64, require_map: bool) -> Ingest {
        Ingest {
            assembler: FrameAssembler::new(&[PartKind::DepthPrior]),
            pending: BTreeMap::new(),
            tolerance_ns,
            timeout: Duration::from_millis(timeout_ms),
            require_map,
            map: None,
            map_changed: false,
            queue: Arc::new(DropOldestQueue::new(2)),
            stats: Arc::new(Mutex::new(Stats::default())),
            limits: Default::default(),
            limit_counts: Default::default(),
        }
    }

    fn info(stamp: Stamp) -> Input {
        let intrinsics = Intrinsics { fx: 500.0, fy: 500.0, cx: 320.0, cy: 240.0, width: 640, height: 480 };
        Input::Part(FramePart::CameraInfo { stamp, intrinsics })
    }

    fn corr(stamp: Stamp) -> Input {
        Input::Part(FramePart::Correspondences {
            stamp,
            camera_frame_id: "cam".into(),
            map_frame_id: "map".into(),
            correspondences: vec![],
        })
    }

    fn prior(stamp: Stamp) -> Input {
        Input::Part(FramePart::DepthPrior { stamp, depth: crate::geometry::DepthImage::new(1, 1, vec![1.0]) })
    }

    #[test]
    fn tolerant_matching_joins_nearby_stamps() {
        let mut i = ingest(1000, 10_000, false);
        i.on_input(info(5_000));
        i.on_input(corr(5_400));
        i.on_input(prior(4_200));
        assert_eq!(i.queue.len(), 1);
        assert!(i.pending.is_empty());
        let mut exact = ingest(0, 10_000, false);
        exact.on_input(info(5_000));
        exact.on_input(corr(5_400));
        assert_eq!(exact.pending.len(), 2);
    }

    #[test]
    fn no_map_timeouts_queue_drops_and_bad_parts_are_counted() {
        let mut i = ingest(0, 0, true);
        for s in [1, 2] {
            i.on_input(info(s));
            i.on_input(corr(s));
            i.on_input(prior(s));
        }
        assert_eq!(lock(&i.stats).drop_count("no_map"), 2);
        i.on_input(Input::Map(Ok(MapCloud { frame_id: "map".into(), points: vec![] })));
        for s in [3, 4, 5] {
            i.on_input(info(s));
            i.on_input(corr(s));
            i.on_input(prior(s));
        }
        assert_eq!(lock(&i.stats).drop_count("queue_full"), 1);
        assert_eq!(i.queue.len(), 2);
        // Only camera info: times out, dropped for missing correspondences.
        i.on_input(info(6));
        // Bad correspondences: counted, frame dropped when it times out.
        i.on_input(Input::PartError { kind: PartKind::Correspondences, stamp: 7, reason: "#0 is not finite".into() });
        std::thread::sleep(Duration::from_millis(2));
        i.expire();
        assert!(i.pending.is_empty());
        let s = lock(&i.stats);
        assert_eq!(s.drop_count("missing_correspondences"), 1);
        assert_eq!(s.drop_count("missing_camera_info"), 1);
        assert_eq!(s.error_count("invalid_correspondences"), 1);
        assert_eq!(s.frames_in, 5);
        // Every frame heard of: dropped (with a reason) or waiting in the queue.
        assert_eq!(s.frames_received, 7);
        assert_eq!(s.frames_received, s.drops.values().sum::<u64>() + i.queue.len() as u64);
    }
}
