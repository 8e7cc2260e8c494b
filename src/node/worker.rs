//! The worker (one per camera): takes frames from its queue, runs its localizer on tokio's
//! blocking pool and, within it, on one of rayon's threads (one frame at a time; a panic
//! becomes a counted failure and a fresh localizer), applies the `/initialpose` gate and
//! publishes, while the node is active (lifecycle). A new map index is taken from the node's
//! shared [`MapSwap`] between two frames.

use std::sync::{Arc, Mutex};

use super::diagnostics::Stats;
use super::ingest::Job;
use super::initial_pose::{self, GateOutcome, InitialPose, PoseGate};
use super::lifecycle::Activity;
use super::log::{lock, warn};
use super::outputs::Outputs;
use super::queue::DropOldestQueue;
use crate::frame::{Frame, Stamp};
use crate::map_index::swap::{MapSwap, MapTaker};
use crate::pipeline::{Localization, Localizer, LocalizerParams, SetupError};

/// Why a frame got no localization at all (not even a failure value).
#[derive(Debug, thiserror::Error)]
pub enum LocalizeError {
    #[error("frame {stamp}: the localizer panicked")]
    Panicked { stamp: Stamp },
    #[error("frame {stamp}: the localizer's task ended abnormally: {reason}")]
    TaskFailed { stamp: Stamp, reason: String },
}

/// A localized frame with the localizer that did it and the worker's map hand-over (both
/// handed back for the next frame).
struct Localized {
    localizer: Localizer,
    maps: MapTaker,
    frame: Frame,
    localization: Localization,
}

/// Runs `localizer` on `frame` on the blocking pool, on the newest map index first when one is
/// ready (the first one is waited for). On an error the localizer is lost: the caller starts a
/// fresh one.
async fn localize(localizer: Localizer, maps: MapTaker, frame: Frame) -> Result<Localized, LocalizeError> {
    let stamp = frame.stamp;
    let handle = tokio::task::spawn_blocking(move || {
        let (mut localizer, mut maps) = (localizer, maps);
        if let Some(index) = maps.take_ready() {
            localizer.set_map_index(index);
        }
        // The frame runs on one of rayon's threads, so its parallel parts start there rather
        // than each waiting for a pool thread to wake.
        let out =
            std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| rayon::scope(|_| localizer.process(&frame))));
        out.map(|localization| Localized { localizer, maps, frame, localization })
    });
    match handle.await {
        Ok(Ok(done)) => Ok(done),
        Ok(Err(_panic)) => Err(LocalizeError::Panicked { stamp }),
        Err(join) => Err(LocalizeError::TaskFailed { stamp, reason: join.to_string() }),
    }
}

/// A fresh localizer with `params`, and a fresh hand-over that gives it the current index.
fn fresh_localizer(params: &LocalizerParams, swap: &Arc<MapSwap>) -> Result<(Localizer, MapTaker), SetupError> {
    Ok((Localizer::new(params.clone())?, swap.taker()))
}

/// Drops a frame the node may not localize or publish now (it is not active: the lifecycle's
/// inactive state), counted as `inactive`; true when dropped.
fn dropped_inactive(active: &Activity, stamp: Stamp, stats: &Mutex<Stats>) -> bool {
    if active.is_active() {
        return false;
    }
    lock(stats).drop_paused("inactive", format!("frame {stamp}: dropped, the node is not active"));
    true
}

/// Localizes and publishes every queued frame until the queue is closed; while the node is not
/// `active`, frames are dropped before they are localized, and a frame localized when the node
/// was deactivated is dropped instead of published.
pub async fn run(
    queue: Arc<DropOldestQueue<Job>>,
    localizer: Localizer,
    swap: Arc<MapSwap>,
    outputs: Outputs,
    gate: Arc<Mutex<Option<InitialPose>>>,
    active: Activity,
) {
    let params = localizer.params().clone();
    let mut localizer = Some((localizer, swap.taker()));
    while let Some(job) = queue.pop().await {
        if dropped_inactive(&active, job.frame.stamp, &outputs.stats) {
            continue;
        }
        let (mut current, maps) = match localizer.take().map_or_else(|| fresh_localizer(&params, &swap), Ok) {
            Ok(current) => current,
            Err(e) => {
                // It was set up once with these parameters; count the frame and try again next time.
                warn(format!("frame {}: no fresh localizer: {e}", job.frame.stamp));
                let mut s = lock(&outputs.stats);
                s.frames_failed += 1;
                s.error("setup", e.to_string());
                continue;
            }
        };
        // The `/initialpose` gate steers PnP itself, not only the published pose.
        current.set_pose_gate(gate_for(&gate, &job.frame, &outputs.stats));
        let mut frame = job.frame;
        frame.odometry = outputs.odometry_at(&frame.camera_frame_id, frame.stamp);
        let done = match localize(current, maps, frame).await {
            Ok(done) => done,
            Err(e) => {
                warn(format!("{e}; continuing with a fresh localizer"));
                let mut s = lock(&outputs.stats);
                s.frames_failed += 1;
                s.error("panic", e.to_string());
                continue;
            }
        };
        let Localized { localizer: back, maps, frame, localization: mut loc } = done;
        localizer = Some((back, maps));
        if dropped_inactive(&active, frame.stamp, &outputs.stats) {
            continue;
        }
        apply_gate(&gate, &mut loc, &outputs.stats);
        outputs.publish(&loc, &frame).await;
        record_outcome(&outputs.stats, &loc, job.handed_out.elapsed().as_secs_f64() * 1e3);
    }
}

/// Counts a localized (or failed) frame in the statistics.
fn record_outcome(stats: &Mutex<Stats>, loc: &Localization, latency_ms: f64) {
    let stamp = loc.stamp;
    let mut s = lock(stats);
    s.frame_done(stamp, loc.pose.is_some(), latency_ms, loc.timings.total_ms);
    s.frame_track(loc.track, loc.prediction);
    if loc.pose.is_some() {
        s.frame_evidence(loc.prior_quality, loc.fast_path);
    }
    if let Some(f) = &loc.failure {
        s.error(f.key(), format!("frame {stamp}: {f}"));
        drop(s);
        warn(format!("frame {stamp}: no pose: {f}"));
    }
}

/// The `/initialpose` gate for `frame`: none without an initial pose, and none (the initial pose
/// dropped and counted as `invalid_initialpose`) when it was given in a frame other than the
/// frame's map.
fn gate_for(initial: &Mutex<Option<InitialPose>>, frame: &Frame, stats: &Mutex<Stats>) -> Option<PoseGate> {
    let mut guard = lock(initial);
    let pose = guard.as_ref()?;
    if pose.applies_to(&frame.map_frame_id) {
        return Some(pose.gate.clone());
    }
    let detail = format!(
        "frame {}: initial pose in frame {:?}, the map is in {:?}: dropped (global localization)",
        frame.stamp, pose.frame_id, frame.map_frame_id
    );
    warn(&detail);
    lock(stats).error("invalid_initialpose", detail);
    *guard = None;
    None
}

/// With an `/initialpose` gate set: a pose outside it is withdrawn (counted), one inside moves
/// it, a frame that contradicts it releases it (logged; the frame's failure is counted).
fn apply_gate(gate: &Mutex<Option<InitialPose>>, loc: &mut Localization, stats: &Mutex<Stats>) {
    match initial_pose::apply_gate(&mut lock(gate), loc) {
        GateOutcome::Ungated | GateOutcome::Followed => {}
        GateOutcome::Withdrawn(miss) => {
            let detail = format!("frame {}: outside the initial pose gate: {miss}", loc.stamp);
            warn(&detail);
            lock(stats).error("outside_initialpose_gate", detail);
        }
        GateOutcome::Released => warn(format!(
            "frame {}: the initial pose gate is released (global localization): {}",
            loc.stamp,
            loc.failure.as_ref().map_or_else(String::new, ToString::to_string)
        )),
    }
}
