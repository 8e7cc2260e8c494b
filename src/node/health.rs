//! The node's health over a recent window, as `diagnostic_updater` reports it: a level for the
//! localization task and a frequency status per input topic.
//!
//! Levels of the localization task, first match wins:
//! - STALE: nothing heard on any input within the window;
//! - ERROR: no map yet, or every frame that ended within the window failed or was dropped;
//! - WARN: frames arrive slower than `min_rate_hz`, or an input is quiet while others deliver;
//! - OK otherwise.
//!
//! Each input topic gets `<node>: <topic> topic status` (as `diagnostic_updater`'s
//! `TopicDiagnostic` names it) with its rate over the window and the age of its last message:
//! STALE before its first message, WARN when quiet for the window or below `min_rate_hz`.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use crate::msgs::{DiagnosticStatus, KeyValue};

/// Arrivals on one input topic.
#[derive(Debug)]
struct InputActivity {
    /// The part kind's name (`camera_info`, `correspondences`, …).
    kind: String,
    topic: String,
    arrivals: VecDeque<Instant>,
    total: u64,
}

/// The recent window of inputs and frame outcomes.
#[derive(Debug)]
pub struct Health {
    window: Duration,
    min_rate_hz: f64,
    inputs: Vec<InputActivity>,
    /// (when, localized) of frames that ended: localized, or failed/dropped.
    outcomes: VecDeque<(Instant, bool)>,
    /// When the window began to be watched (nothing is STALE-for-silence before one window);
    /// again when frames end after a pause.
    since: Instant,
    /// Frames dropped within the window because the node is not active (lifecycle), while no
    /// frame has ended since: a pause asked for, not a failure.
    paused: VecDeque<Instant>,
}

impl Default for Health {
    fn default() -> Self {
        Self::new(Duration::from_secs(5), 1.0, Instant::now())
    }
}

/// A level and its message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Level {
    pub level: u8,
    pub message: String,
}

impl Health {
    pub fn new(window: Duration, min_rate_hz: f64, now: Instant) -> Self {
        Self { window, min_rate_hz, inputs: Vec::new(), outcomes: VecDeque::new(), since: now, paused: VecDeque::new() }
    }

    /// A new `min_rate_hz` (a live parameter change).
    pub fn set_min_rate_hz(&mut self, min_rate_hz: f64) {
        self.min_rate_hz = min_rate_hz;
    }

    /// Watches the input `topic`, which carries frame parts of `kind`.
    pub fn watch_input(&mut self, kind: &str, topic: &str) {
        self.inputs.push(InputActivity { kind: kind.into(), topic: topic.into(), arrivals: VecDeque::new(), total: 0 });
    }

    /// A message of part `kind` arrived.
    pub fn heard(&mut self, kind: &str, now: Instant) {
        let window = self.window;
        if let Some(input) = self.inputs.iter_mut().find(|i| i.kind == kind) {
            input.arrivals.push_back(now);
            input.total += 1;
            trim(&mut input.arrivals, now, window, |t| *t);
        }
    }

    /// A frame ended: localized (`true`) or failed / dropped. The first after a pause starts
    /// the window afresh (the rate is not judged on the paused seconds).
    pub fn outcome(&mut self, localized: bool, now: Instant) {
        if !self.paused.is_empty() {
            self.paused.clear();
            self.since = now;
        }
        self.outcomes.push_back((now, localized));
        trim(&mut self.outcomes, now, self.window, |(t, _)| *t);
    }

    /// A frame dropped because the node is not active (lifecycle): not an outcome.
    pub fn paused(&mut self, now: Instant) {
        self.paused.push_back(now);
        trim(&mut self.paused, now, self.window, |t| *t);
    }

    fn recent<'a, T: 'a>(
        &self,
        items: impl IntoIterator<Item = &'a T>,
        now: Instant,
        at: impl Fn(&T) -> Instant,
    ) -> usize {
        items.into_iter().filter(|x| now.duration_since(at(x)) <= self.window).count()
    }

    /// The localization task's level at `now`.
    pub fn level(&self, now: Instant, has_map: bool) -> Level {
        let secs = self.window.as_secs_f64();
        let heard: Vec<usize> = self.inputs.iter().map(|i| self.recent(&i.arrivals, now, |t| *t)).collect();
        let ended = self.recent(&self.outcomes, now, |(t, _)| *t);
        let localized = self.outcomes.iter().filter(|(t, ok)| *ok && now.duration_since(*t) <= self.window).count();
        let warmed_up = now.duration_since(self.since) >= self.window;
        let say = |level: u8, message: String| Level { level, message };
        if heard.iter().all(|&n| n == 0) && ended == 0 {
            let map = if has_map { "" } else { "; no map yet" };
            return say(DiagnosticStatus::STALE, format!("no input in the last {secs:.0} s{map}"));
        }
        if !has_map {
            return say(DiagnosticStatus::ERROR, "no map: frames cannot be localized".into());
        }
        let paused = self.recent(&self.paused, now, |t| *t);
        if paused > 0 {
            return say(
                DiagnosticStatus::OK,
                format!("inactive (lifecycle): {paused} frames of the last {secs:.0} s dropped, not localized"),
            );
        }
        if ended > 0 && localized == 0 {
            return say(
                DiagnosticStatus::ERROR,
                format!("all {ended} frames of the last {secs:.0} s failed or dropped"),
            );
        }
        let rate = ended as f64 / secs;
        if warmed_up && self.min_rate_hz > 0.0 && rate < self.min_rate_hz {
            return say(
                DiagnosticStatus::WARN,
                format!("{rate:.2} frames/s over {secs:.0} s, below min_rate_hz {}", self.min_rate_hz),
            );
        }
        if let Some(quiet) = self.inputs.iter().zip(&heard).find(|(_, n)| **n == 0).map(|(i, _)| &i.topic) {
            return say(DiagnosticStatus::WARN, format!("{quiet}: no message in the last {secs:.0} s"));
        }
        say(DiagnosticStatus::OK, format!("{localized} of {ended} frames of the last {secs:.0} s localized"))
    }

    /// One frequency status per input topic.
    pub fn topic_statuses(&self, now: Instant, node_name: &str, hardware_id: &str) -> Vec<DiagnosticStatus> {
        let secs = self.window.as_secs_f64();
        self.inputs
            .iter()
            .map(|i| {
                let n = self.recent(&i.arrivals, now, |t| *t);
                let rate = n as f64 / secs;
                let age = i.arrivals.back().map(|t| now.duration_since(*t).as_secs_f64());
                let (level, message) = match age {
                    None => (DiagnosticStatus::STALE, "no message yet".to_string()),
                    Some(_) if n == 0 => (DiagnosticStatus::WARN, format!("no message in the last {secs:.0} s")),
                    Some(_) if self.min_rate_hz > 0.0 && rate < self.min_rate_hz => {
                        (DiagnosticStatus::WARN, format!("{rate:.2} Hz, below min_rate_hz {}", self.min_rate_hz))
                    }
                    Some(_) => (DiagnosticStatus::OK, format!("{rate:.2} Hz")),
                };
                let values = [
                    ("rate_hz", format!("{rate:.2}")),
                    ("messages_in_window", n.to_string()),
                    ("messages_total", i.total.to_string()),
                    ("last_message_age_s", age.map(|a| format!("{a:.2}")).unwrap_or_default()),
                    ("window_s", format!("{secs:.1}")),
                ];
                DiagnosticStatus {
                    level,
                    name: format!("{node_name}: {} topic status", i.topic),
                    message,
                    hardware_id: hardware_id.into(),
                    values: values.into_iter().map(|(k, v)| KeyValue { key: k.into(), value: v }).collect(),
                }
            })
            .collect()
    }
}

/// Drops the entries older than `window` (they are time-ordered).
fn trim<T>(items: &mut VecDeque<T>, now: Instant, window: Duration, at: impl Fn(&T) -> Instant) {
    while items.front().is_some_and(|x| now.duration_since(at(x)) > window) {
        items.pop_front();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn health(t0: Instant) -> Health {
        let mut h = Health::new(Duration::from_secs(2), 1.0, t0);
        h.watch_input("camera_info", "/cam0/camera/camera_info");
        h.watch_input("correspondences", "/cam0/matcher/correspondences");
        h
    }

    #[test]
    fn levels_follow_the_recent_window() {
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        let mut h = health(t0);
        assert_eq!(h.level(at(100), false).level, DiagnosticStatus::STALE);
        // Frames arrive but there is no map.
        h.heard("camera_info", at(200));
        h.heard("correspondences", at(200));
        h.outcome(false, at(200));
        assert_eq!(h.level(at(300), false).level, DiagnosticStatus::ERROR);
        // A map, but every recent frame failed.
        assert_eq!(h.level(at(300), true).level, DiagnosticStatus::ERROR);
        // 10 Hz, all localized: OK; the topic statuses say so too.
        for k in 0..30 {
            let t = at(300 + k * 100);
            h.heard("camera_info", t);
            h.heard("correspondences", t);
            h.outcome(true, t);
        }
        let ok = h.level(at(3250), true);
        assert_eq!(ok.level, DiagnosticStatus::OK, "{ok:?}");
        let topics = h.topic_statuses(at(3250), "angle_i2p", "/cam0/angle_i2p");
        assert_eq!(topics.len(), 2);
        assert_eq!(topics[0].name, "angle_i2p: /cam0/camera/camera_info topic status");
        assert!(topics.iter().all(|s| s.level == DiagnosticStatus::OK), "{topics:?}");
        // The matcher goes quiet: frames stop, the rate falls below 1 Hz within the window.
        for k in 0..3 {
            h.heard("camera_info", at(3300 + k * 100));
        }
        let low = h.level(at(5150), true);
        assert_eq!(low.level, DiagnosticStatus::WARN, "{low:?}");
        let topics = h.topic_statuses(at(5600), "angle_i2p", "/cam0/angle_i2p");
        assert_eq!(topics[1].level, DiagnosticStatus::WARN, "{topics:?}");
        // Everything quiet for a window: STALE.
        assert_eq!(h.level(at(9000), true).level, DiagnosticStatus::STALE);
    }

    /// Frames dropped while the node is inactive (lifecycle) are a pause, not failures: OK and
    /// said so; once active, frames are judged afresh (no ERROR left over from the pause, no
    /// low-rate WARN for the paused seconds).
    #[test]
    fn an_inactive_node_is_paused_not_failing() {
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        let mut h = health(t0);
        for k in 0..40 {
            let t = at(k * 100);
            h.heard("camera_info", t);
            h.heard("correspondences", t);
            h.paused(t);
        }
        let inactive = h.level(at(4000), true);
        assert_eq!(inactive.level, DiagnosticStatus::OK, "{inactive:?}");
        assert!(inactive.message.contains("inactive"), "{inactive:?}");
        // Activated: the first frames localize; the level is OK at once.
        for k in 0..3 {
            let t = at(4100 + k * 100);
            h.heard("camera_info", t);
            h.heard("correspondences", t);
            h.outcome(true, t);
        }
        let active = h.level(at(4400), true);
        assert_eq!(active.level, DiagnosticStatus::OK, "{active:?}");
        assert!(active.message.contains("3 of 3"), "{active:?}");
    }
}
