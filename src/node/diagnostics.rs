//! Counters of the live node and their `/diagnostics` message.

use std::collections::{BTreeMap, VecDeque};
use std::time::Instant;

use super::health::Health;
use crate::eval::median;
use crate::frame::Stamp;
use crate::msgs::{DiagnosticArray, DiagnosticStatus, Header, KeyValue};

/// The node's main task: its status is named `<node name>: localization`, as
/// `diagnostic_updater` names a node's tasks.
pub const LOCALIZATION_TASK: &str = "localization";

/// The name of the localization status of node `node_name` (without namespace).
pub fn status_name(node_name: &str) -> String {
    format!("{node_name}: {LOCALIZATION_TASK}")
}

/// Latencies kept for the median.
const LATENCY_WINDOW: usize = 100;

/// What the node has seen and done. `drops` are frames (or messages) that never reached the
/// localizer, by reason; `errors` are localizer failures and bad messages, by reason.
#[derive(Debug)]
pub struct Stats {
    started: Instant,
    /// Frames heard of: stamps whose first part arrived. Each ends up localized, failed or
    /// dropped (all counted), unless still waiting or in flight.
    pub frames_received: u64,
    /// Frames assembled (before the map check and the queue).
    pub frames_in: u64,
    pub frames_localized: u64,
    pub frames_failed: u64,
    pub maps_received: u64,
    pub map_points: usize,
    /// Maps indexed by the node (one index shared by all its cameras).
    pub maps_indexed: u64,
    /// Debug images not drawn: a newer frame's came first (`node.debug_image`, drawn newest only).
    pub debug_images_superseded: u64,
    pub drops: BTreeMap<String, u64>,
    pub errors: BTreeMap<String, u64>,
    /// Transforms and base poses sent, by kind (`map_to_odom`, `map_to_camera`, `republished`,
    /// `base_pose`): `tf.<kind>` in the report.
    pub tf_sent: BTreeMap<String, u64>,
    pub last_failure: Option<String>,
    pub last_stamp: Option<Stamp>,
    /// Most frames ever waiting for the worker (just after a frame was queued).
    pub queued_max: usize,
    latencies_ms: VecDeque<f64>,
    processing_ms: VecDeque<f64>,
    /// The prior's quality of recent localized frames, and whether each was settled by the
    /// cascade's fast path (see [`Stats::frame_evidence`]).
    prior_quality: VecDeque<f64>,
    fast_path: VecDeque<bool>,
    /// The last localized frame's standing to the track (`None` with tracking off).
    track: Option<crate::pipeline::TrackState>,
    /// What predicted the last localized frame (`None`: nothing did).
    prediction: Option<crate::pipeline::PredictionSource>,
    /// (time, frames_in, frames_localized) at the last report, for rates.
    last_report: (Instant, u64, u64),
    /// Inputs and outcomes over the recent window: the levels.
    pub health: Health,
}

impl Default for Stats {
    fn default() -> Self {
        let now = Instant::now();
        Self {
            started: now,
            frames_received: 0,
            frames_in: 0,
            frames_localized: 0,
            frames_failed: 0,
            maps_received: 0,
            debug_images_superseded: 0,
            map_points: 0,
            maps_indexed: 0,
            drops: BTreeMap::new(),
            errors: BTreeMap::new(),
            tf_sent: BTreeMap::new(),
            last_failure: None,
            last_stamp: None,
            queued_max: 0,
            latencies_ms: VecDeque::new(),
            processing_ms: VecDeque::new(),
            prior_quality: VecDeque::new(),
            fast_path: VecDeque::new(),
            track: None,
            prediction: None,
            last_report: (now, 0, 0),
            health: Health::default(),
        }
    }
}

impl Stats {
    pub fn drop_frame(&mut self, reason: &str, detail: impl Into<String>) {
        self.health.outcome(false, Instant::now());
        *self.drops.entry(reason.to_string()).or_default() += 1;
        self.last_failure = Some(detail.into());
    }

    /// A frame dropped because the node is not active (lifecycle): counted under `reason`, and
    /// a pause for the health, not a failure.
    pub fn drop_paused(&mut self, reason: &str, detail: impl Into<String>) {
        self.health.paused(Instant::now());
        *self.drops.entry(reason.to_string()).or_default() += 1;
        self.last_failure = Some(detail.into());
    }

    pub fn error(&mut self, reason: &str, detail: impl Into<String>) {
        *self.errors.entry(reason.to_string()).or_default() += 1;
        self.last_failure = Some(detail.into());
    }

    /// One transform (or base pose) of `kind` sent.
    pub fn count_tf(&mut self, kind: &str) {
        *self.tf_sent.entry(kind.to_string()).or_default() += 1;
    }

    pub fn drop_count(&self, reason: &str) -> u64 {
        self.drops.get(reason).copied().unwrap_or(0)
    }

    pub fn error_count(&self, reason: &str) -> u64 {
        self.errors.get(reason).copied().unwrap_or(0)
    }

    /// One frame went through the localizer: `latency_ms` from its first part's arrival to its
    /// outputs being published, `processing_ms` the localizer's own time.
    pub fn frame_done(&mut self, stamp: Stamp, localized: bool, latency_ms: f64, processing_ms: f64) {
        self.health.outcome(localized, Instant::now());
        if localized {
            self.frames_localized += 1;
        } else {
            self.frames_failed += 1;
        }
        self.last_stamp = Some(stamp);
        for (window, v) in [(&mut self.latencies_ms, latency_ms), (&mut self.processing_ms, processing_ms)] {
            if window.len() == LATENCY_WINDOW {
                window.pop_front();
            }
            window.push_back(v);
        }
    }

    /// What a localized frame's evidence was: the prior's quality at its pose (`None` when
    /// unknown) and whether the cascade's fast path settled it.
    pub fn frame_evidence(&mut self, prior_quality: Option<f64>, fast_path: bool) {
        if let Some(q) = prior_quality {
            if self.prior_quality.len() == LATENCY_WINDOW {
                self.prior_quality.pop_front();
            }
            self.prior_quality.push_back(q);
        }
        if self.fast_path.len() == LATENCY_WINDOW {
            self.fast_path.pop_front();
        }
        self.fast_path.push_back(fast_path);
    }

    /// The last localized frame's standing to the track (`tracking`, `relocalized` or `lost`)
    /// and what predicted it (`odometry` or `motion`).
    pub fn frame_track(
        &mut self,
        track: Option<crate::pipeline::TrackState>,
        prediction: Option<crate::pipeline::PredictionSource>,
    ) {
        self.track = track;
        self.prediction = prediction;
    }

    /// The node's statuses: `<node_name>: localization` (cumulative counts, rates since the
    /// previous call, a level over the recent window) and one per input topic.
    pub fn report(&mut self, stamp: Stamp, node_name: &str, hardware_id: &str) -> DiagnosticArray {
        let now = Instant::now();
        let (t0, in0, loc0) = self.last_report;
        let dt = now.duration_since(t0).as_secs_f64().max(1e-3);
        let rate_in = (self.frames_in - in0) as f64 / dt;
        let rate_loc = (self.frames_localized - loc0) as f64 / dt;
        self.last_report = (now, self.frames_in, self.frames_localized);
        let lat: Vec<f64> = self.latencies_ms.iter().copied().collect();
        let proc_: Vec<f64> = self.processing_ms.iter().copied().collect();
        let quality: Vec<f64> = self.prior_quality.iter().copied().collect();
        let fast_share = (!self.fast_path.is_empty())
            .then(|| self.fast_path.iter().filter(|&&f| f).count() as f64 / self.fast_path.len() as f64);
        let mut values = vec![
            ("uptime_s", format!("{:.1}", now.duration_since(self.started).as_secs_f64())),
            ("frames_received", self.frames_received.to_string()),
            ("frames_in", self.frames_in.to_string()),
            ("frames_localized", self.frames_localized.to_string()),
            ("frames_failed", self.frames_failed.to_string()),
            ("rate_in_hz", format!("{rate_in:.2}")),
            ("rate_localized_hz", format!("{rate_loc:.2}")),
            ("latency_ms_median", median(&lat).map(|v| format!("{v:.2}")).unwrap_or_default()),
            ("processing_ms_median", median(&proc_).map(|v| format!("{v:.2}")).unwrap_or_default()),
            ("queued_max", self.queued_max.to_string()),
            ("prior_quality_median", median(&quality).map(|v| format!("{v:.3}")).unwrap_or_default()),
            ("prior_quality_last", self.prior_quality.back().map(|v| format!("{v:.3}")).unwrap_or_default()),
            ("fast_path_share", fast_share.map(|v| format!("{v:.2}")).unwrap_or_default()),
            ("track", self.track.map(|t| t.name().to_string()).unwrap_or_default()),
            ("prediction", self.prediction.map(|p| p.name().to_string()).unwrap_or_default()),
            ("maps_received", self.maps_received.to_string()),
            ("map_points", self.map_points.to_string()),
            ("maps_indexed", self.maps_indexed.to_string()),
            ("debug_images_superseded", self.debug_images_superseded.to_string()),
            ("dropped_total", self.drops.values().sum::<u64>().to_string()),
            ("errors_total", self.errors.values().sum::<u64>().to_string()),
            ("last_failure", self.last_failure.clone().unwrap_or_default()),
            ("last_stamp", self.last_stamp.map(|s| s.to_string()).unwrap_or_default()),
        ]
        .into_iter()
        .map(|(k, v)| KeyValue { key: k.into(), value: v })
        .collect::<Vec<_>>();
        values.extend(self.drops.iter().map(|(k, v)| KeyValue { key: format!("dropped.{k}"), value: v.to_string() }));
        values.extend(self.errors.iter().map(|(k, v)| KeyValue { key: format!("error.{k}"), value: v.to_string() }));
        values.extend(self.tf_sent.iter().map(|(k, v)| KeyValue { key: format!("tf.{k}"), value: v.to_string() }));
        let level = self.health.level(now, self.maps_received > 0);
        let mut status = vec![DiagnosticStatus {
            level: level.level,
            name: status_name(node_name),
            message: level.message,
            hardware_id: hardware_id.into(),
            values,
        }];
        status.extend(self.health.topic_statuses(now, node_name, hardware_id));
        DiagnosticArray { header: Header::new(stamp, ""), status }
    }
}

/// The value of `key` in the node's status of a diagnostics message.
pub fn status_value<'a>(msg: &'a DiagnosticArray, key: &str) -> Option<&'a str> {
    msg.status
        .iter()
        .filter(|s| s.name.ends_with(&format!(": {LOCALIZATION_TASK}")))
        .flat_map(|s| s.values.iter())
        .find(|kv| kv.key == key)
        .map(|kv| kv.value.as_str())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn report_counts_by_reason() {
        let mut s = Stats { frames_in: 3, maps_received: 1, ..Default::default() };
        s.drop_frame("queue_full", "frame 1 dropped");
        s.drop_frame("queue_full", "frame 2 dropped");
        s.error("pnp", "frame 3: PnP failed");
        s.frame_done(3, false, 12.0, 10.0);
        s.frame_done(4, true, 8.0, 6.0);
        s.frame_evidence(Some(0.8), false);
        s.frame_evidence(None, true);
        s.count_tf("map_to_odom");
        s.frame_track(
            Some(crate::pipeline::TrackState::Relocalized),
            Some(crate::pipeline::PredictionSource::Odometry),
        );
        let r = s.report(5, "angle_i2p", "/angle_i2p");
        assert_eq!(r.status[0].name, "angle_i2p: localization");
        assert_eq!(r.status[0].level, DiagnosticStatus::OK, "{}", r.status[0].message);
        assert_eq!(status_value(&r, "prior_quality_last"), Some("0.800"));
        assert_eq!(status_value(&r, "fast_path_share"), Some("0.50"));
        assert_eq!(status_value(&r, "track"), Some("relocalized"));
        assert_eq!(status_value(&r, "prediction"), Some("odometry"));
        assert_eq!(status_value(&r, "dropped.queue_full"), Some("2"));
        assert_eq!(status_value(&r, "error.pnp"), Some("1"));
        assert_eq!(status_value(&r, "tf.map_to_odom"), Some("1"));
        assert_eq!(status_value(&r, "frames_localized"), Some("1"));
        assert_eq!(status_value(&r, "latency_ms_median"), Some("10.00"));
        assert_eq!(status_value(&r, "last_stamp"), Some("4"));
        assert_eq!(r.header.stamp.to_nanos(), 5);
    }
}
