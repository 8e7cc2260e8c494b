//! The node's clock, as rclcpp's `use_sim_time` has it: wall time, or with `use_sim_time` the
//! time of `/clock` (rosgraph_msgs/Clock, published by a simulator or `ros2 bag play --clock`).
//! It stamps the node's own messages (diagnostics, the re-sent `map → odom`); outputs of a frame
//! always carry the frame's stamp.
//!
//! Until `/clock` is heard, sim time falls back to the newest input stamp handled (a bag played
//! without `--clock` still gets its own time), and to nothing before any: a re-send of
//! `map → odom` waits for a time.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use anyhow::{anyhow, Result};
use futures::StreamExt;
use ros2_client::{Message, MessageTypeName, Node};
use serde::{Deserialize, Serialize};

use super::dds;
use super::log::{lock, now_ns, warn};
use crate::frame::Stamp;
use crate::msgs::Time;

/// `rosgraph_msgs/msg/Clock`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Clock {
    pub clock: Time,
}
impl Message for Clock {}

/// The `/clock` topic (absolute, as rclcpp's time source reads it).
pub const CLOCK_TOPIC: &str = "/clock";

/// Wall time, or the simulated time of `/clock`.
#[derive(Clone, Debug, Default)]
pub struct NodeClock {
    /// The `use_sim_time` parameter (it may change while the node runs).
    use_sim_time: Arc<AtomicBool>,
    /// The newest `/clock` time heard.
    sim: Arc<Mutex<Option<Stamp>>>,
    /// What `/clock` did that diagnostics count (taken by [`NodeClock::take_problems`]; at most
    /// [`MAX_PROBLEMS`] wait, the rest are dropped with a count).
    problems: Arc<Mutex<Vec<ClockProblem>>>,
}

/// Problems kept between two diagnostics reports, at most (a flood of bad `/clock` messages
/// holds no more).
const MAX_PROBLEMS: usize = 64;

/// A `/clock` message diagnostics count (`error.<key>`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ClockProblem {
    pub key: &'static str,
    pub detail: String,
}

impl NodeClock {
    pub fn new(use_sim_time: bool) -> Self {
        Self { use_sim_time: Arc::new(AtomicBool::new(use_sim_time)), sim: Arc::default(), problems: Arc::default() }
    }

    pub fn uses_sim_time(&self) -> bool {
        self.use_sim_time.load(Ordering::Relaxed)
    }

    /// Follows a change of the `use_sim_time` parameter.
    pub fn set_use_sim_time(&self, use_sim_time: bool) {
        self.use_sim_time.store(use_sim_time, Ordering::Relaxed);
    }

    /// A `/clock` message heard. A time before 1970 is no time a simulator or a bag gives: it is
    /// ignored and counted (`error.invalid_clock`; #38: −2³¹ s stamped the diagnostics in 1901).
    /// A time before the last is taken — a looped or restarted bag starts its time again, as
    /// rclcpp's time source allows with its jump callbacks — and counted
    /// (`error.clock_jumped_back`). Whether it was taken.
    pub fn heard(&self, clock: &Clock) -> bool {
        let time = clock.clock.to_nanos();
        if time < 0 {
            self.problem("invalid_clock", format!("{CLOCK_TOPIC}: time {} s is before 1970, ignored", clock.clock.sec));
            return false;
        }
        let mut sim = lock(&self.sim);
        if let Some(last) = sim.filter(|&last| time < last) {
            let back = (last - time) as f64 * 1e-9;
            self.problem("clock_jumped_back", format!("{CLOCK_TOPIC}: time went back {back:.3} s (a bag restarted?)"));
        }
        *sim = Some(time);
        true
    }

    fn problem(&self, key: &'static str, detail: String) {
        let mut problems = lock(&self.problems);
        if problems.len() < MAX_PROBLEMS {
            problems.push(ClockProblem { key, detail });
        }
    }

    /// What `/clock` did since the last call, for diagnostics to count.
    pub fn take_problems(&self) -> Vec<ClockProblem> {
        std::mem::take(&mut *lock(&self.problems))
    }

    /// The time now: wall time, or with sim time the `/clock` time, else `newest_input`.
    pub fn now(&self, newest_input: Option<Stamp>) -> Option<Stamp> {
        if !self.uses_sim_time() {
            return Some(now_ns());
        }
        let sim = *lock(&self.sim);
        sim.or(newest_input)
    }
}

/// Subscribes `/clock` (best effort: matches reliable and best-effort clock publishers) and
/// feeds `clock` on its own thread.
pub fn subscribe(node: &mut Node, clock: &NodeClock) -> Result<std::thread::JoinHandle<()>> {
    let qos = dds::sensor_data(1);
    let topic = node
        .create_topic(&dds::topic_name(CLOCK_TOPIC)?, MessageTypeName::new("rosgraph_msgs", "Clock"), &qos)
        .map_err(|e| anyhow!("creating topic {CLOCK_TOPIC}: {e:?}"))?;
    let sub = node
        .create_subscription::<Clock>(&topic, Some(qos))
        .map_err(|e| anyhow!("subscribing {CLOCK_TOPIC}: {e:?}"))?;
    let clock = clock.clone();
    std::thread::Builder::new()
        .name("reader /clock".into())
        .spawn(move || {
            futures::executor::block_on(async move {
                let stream = sub.async_stream();
                futures::pin_mut!(stream);
                while let Some(r) = stream.next().await {
                    match r {
                        Ok((msg, _)) => {
                            if !clock.heard(&msg) {
                                warn(format!("{CLOCK_TOPIC}: time {} s is before 1970, ignored", msg.clock.sec));
                            }
                        }
                        Err(e) => warn(format!("{CLOCK_TOPIC}: unreadable message: {e:?}")),
                    }
                }
            })
        })
        .map_err(|e| anyhow!("spawning the {CLOCK_TOPIC} reader: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sim_time_follows_clock_then_inputs() {
        let wall = NodeClock::new(false);
        let before = now_ns();
        assert!(wall.now(Some(5)).is_some_and(|t| t >= before), "wall time ignores inputs");
        let sim = NodeClock::new(true);
        assert_eq!(sim.now(None), None, "no time before /clock or any input");
        assert_eq!(sim.now(Some(7)), Some(7), "the newest input before /clock");
        sim.heard(&Clock { clock: Time::from_nanos(42_000_000_123) });
        assert_eq!(sim.now(Some(7)), Some(42_000_000_123));
        sim.heard(&Clock { clock: Time::from_nanos(3) });
        assert_eq!(sim.now(None), Some(3), "a restarted bag's clock goes back");
        assert!(!sim.heard(&Clock { clock: Time { sec: i32::MIN, nanosec: 0 } }), "1901 is no time");
        assert_eq!(sim.now(None), Some(3), "the absurd time is ignored");
        let keys: Vec<_> = sim.take_problems().into_iter().map(|p| p.key).collect();
        assert_eq!(keys, ["clock_jumped_back", "invalid_clock"], "both counted");
        assert!(sim.take_problems().is_empty(), "taken once");
        sim.set_use_sim_time(false);
        assert!(sim.now(None).is_some_and(|t| t >= before), "back to wall time");
    }

    #[test]
    fn clock_is_one_time_on_the_wire() {
        let c = Clock { clock: Time { sec: 12, nanosec: 34 } };
        let bytes = crate::msgs::to_cdr(&c);
        assert_eq!(&bytes[4..], &[12, 0, 0, 0, 34, 0, 0, 0]);
    }
}
