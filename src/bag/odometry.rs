//! A robot's odometry in a bag, as the live node hears it: `/tf` and `/tf_static` read into a
//! TF buffer as the frames stream past, and each frame's `odom → camera` looked up at its stamp
//! through any chain of frames (REP 105). A bag without them, or without the odometry frame,
//! gives frames without odometry (not an error: many robots have none).

use nalgebra::Isometry3;

use crate::frame::Stamp;
use crate::msgs::{from_cdr, TFMessage};
use crate::params::{NodeParams, TopicMap};
use crate::tf_buffer::TfHistory;

/// Transforms left out of a bag's TF reported by name, at most (the rest are counted).
const REPORTED: usize = 10;

/// Where a bag's odometry is: the TF topics and the odometry frame.
#[derive(Clone, Debug, PartialEq)]
pub struct OdometryTopics {
    pub tf: String,
    pub tf_static: String,
    /// REP 105's `odom`; empty: odometry is not read.
    pub odom_frame: String,
}

impl OdometryTopics {
    /// The TF topics of `topics` and the node's own `odom_frame`, so one configuration serves
    /// the robot live and its recordings.
    pub fn of(topics: &TopicMap, node: &NodeParams) -> Self {
        Self { tf: topics.tf.clone(), tf_static: topics.tf_static.clone(), odom_frame: node.odom_frame.clone() }
    }
}

impl Default for OdometryTopics {
    fn default() -> Self {
        Self::of(&TopicMap::default(), &NodeParams::default())
    }
}

/// The TF a bag carried so far, for its frames' odometry.
#[derive(Debug, Default)]
pub struct BagOdometry {
    topics: OdometryTopics,
    buffer: TfHistory,
    /// Why transforms or messages were left out (the first [`REPORTED`]), and how many.
    pub issues: Vec<String>,
    pub left_out: usize,
}

impl BagOdometry {
    pub fn new(topics: OdometryTopics) -> Self {
        Self { topics, ..Self::default() }
    }

    /// Whether `topic` is one of the TF topics (then `data` went into the buffer).
    pub fn take(&mut self, topic: &str, data: &[u8]) -> bool {
        let is_static = topic == self.topics.tf_static;
        if self.topics.odom_frame.is_empty() || !(is_static || topic == self.topics.tf) {
            return false;
        }
        let problems = match from_cdr::<TFMessage>(data) {
            Ok(msg) => self.buffer.update(&msg, is_static),
            Err(e) => vec![format!("{topic}: {e}")],
        };
        for problem in problems {
            self.left_out += 1;
            if self.issues.len() < REPORTED {
                self.issues.push(problem);
            }
        }
        true
    }

    /// The camera's pose in the odometry frame at `stamp` (odom-from-camera); `None` where the
    /// bag's TF does not give it.
    pub fn at(&self, camera_frame: &str, stamp: Stamp) -> Option<Isometry3<f64>> {
        if self.topics.odom_frame.is_empty() {
            return None;
        }
        self.buffer.lookup(&self.topics.odom_frame, camera_frame, stamp).ok()
    }
}
