//! What the node sends: the publishers of the results (pose, pose with covariance, kept
//! correspondences, TF, debug image), built from the same conversions `replay` writes
//! ([`convert::localization_messages`]), and the `--record` bag.

use std::sync::{Arc, Mutex};

use anyhow::Result;
use ros2_client::Publisher;

use super::dds;
use super::debug_image::DebugImages;
use super::diagnostics::Stats;
use super::log::info;
use super::log::{lock, warn};
use super::recorder::Recorder;
use super::tf::{FrameTf, TfBroadcast};
use super::topics::Topics;
use crate::frame::Frame;
use crate::limits::InputLimits;
use crate::msgs::{self, convert, RosMessage};
use crate::params::NodeParams;
use crate::pipeline::Localization;

/// The debug image's output: off, its publisher (not started yet), or its drawer.
enum DebugOutput {
    Off,
    Publisher(Publisher<msgs::Image>),
    Drawer(DebugImages),
}

/// The worker's publishers (one set per camera; `/tf` is the node's, shared).
pub struct Outputs {
    topics: Topics,
    pose: Publisher<msgs::PoseStamped>,
    pose_cov: Publisher<msgs::PoseWithCovarianceStamped>,
    kept: Publisher<msgs::Correspondences>,
    tf: Option<Arc<Publisher<msgs::TFMessage>>>,
    /// What goes on /tf and the base pose, shared with the periodic `map → odom` re-send.
    broadcast: Arc<Mutex<TfBroadcast>>,
    base_pose: Option<Publisher<msgs::PoseStamped>>,
    /// The debug image's drawer (`node.debug_image`); its publisher until
    /// [`Outputs::with_image_limits`] starts it.
    debug: DebugOutput,
    recorder: Recorder,
    pub stats: Arc<Mutex<Stats>>,
}

impl Outputs {
    /// Creates the result publishers of one camera on `node`; `tf`: the node's `/tf` publisher
    /// (`None`: `publish_tf` is off).
    pub fn create(
        node: &mut ros2_client::Node,
        topics: &Topics,
        np: &NodeParams,
        tf: Option<Arc<Publisher<msgs::TFMessage>>>,
        broadcast: Arc<Mutex<TfBroadcast>>,
        recorder: Recorder,
        stats: Arc<Mutex<Stats>>,
    ) -> Result<Self> {
        let out_qos = dds::reliable(10);
        let base_pose = if lock(&broadcast).frames().base.is_empty() {
            None
        } else {
            Some(dds::publisher(node, &topics.base_pose, &out_qos)?)
        };
        let debug = match np.debug_image {
            // Keep last 1: a viewer wants the newest, and each sample held is a whole RGB image.
            true => DebugOutput::Publisher(dds::publisher(node, &topics.debug_image, &dds::sensor_data(1))?),
            false => DebugOutput::Off,
        };
        Ok(Self {
            pose: dds::publisher(node, &topics.pose, &out_qos)?,
            pose_cov: dds::publisher(node, &topics.pose_with_covariance, &out_qos)?,
            kept: dds::publisher(node, &topics.output_correspondences, &out_qos)?,
            tf,
            broadcast,
            base_pose,
            debug,
            topics: topics.clone(),
            recorder,
            stats,
        })
    }

    /// Starts the debug image's drawer (when `node.debug_image` is on), camera images decoded
    /// within the node's `limits`.
    pub fn with_image_limits(mut self, limits: &InputLimits) -> Self {
        if let DebugOutput::Publisher(publisher) = std::mem::replace(&mut self.debug, DebugOutput::Off) {
            let (topic, recorder, stats) = (self.topics.debug_image.clone(), self.recorder.clone(), self.stats.clone());
            self.debug = DebugOutput::Drawer(DebugImages::start(publisher, topic, limits.clone(), recorder, stats));
        }
        self
    }

    /// The camera's pose in the odometry frame at `stamp`, as heard on `/tf` (a frame's
    /// odometry, for tracking).
    pub fn odometry_at(&self, camera: &str, stamp: crate::frame::Stamp) -> Option<nalgebra::Isometry3<f64>> {
        lock(&self.broadcast).odometry_at(camera, stamp)
    }

    async fn send<M: RosMessage + Clone + std::fmt::Debug>(&self, p: &Publisher<M>, topic: &str, msg: M) {
        self.recorder.write(topic, &msg, &self.stats);
        if let Err(e) = p.async_publish(msg).await {
            warn(format!("publishing on {topic} failed: {e:?}"));
            lock(&self.stats).error("publish_failed", format!("{topic}: {e:?}"));
        }
    }

    /// Publishes one frame's results as `replay` writes them (the same conversions).
    pub async fn publish(&self, loc: &Localization, frame: &Frame) {
        let topics = &self.topics;
        let out = convert::localization_messages(loc, frame.lens.as_ref());
        if let Some(pose) = out.pose {
            self.send(&self.pose, &topics.pose, pose).await;
        }
        if let Some(pose_with_covariance) = out.pose_with_covariance {
            self.send(&self.pose_cov, &topics.pose_with_covariance, pose_with_covariance).await;
        }
        if let Some(pose) = &loc.pose {
            self.publish_tf(loc, pose).await;
        }
        self.send(&self.kept, &topics.output_correspondences, out.kept).await;
        if let DebugOutput::Drawer(debug) = &self.debug {
            debug.submit(frame, loc);
        }
        // The recording also gets the per-frame status `replay` writes (timings for `eval`).
        self.recorder.write(crate::app::DIAGNOSTICS_TOPIC, &crate::app::localization_diagnostics(loc), &self.stats);
    }

    /// The TF and base pose of a localized frame (problems counted, news logged).
    async fn publish_tf(&self, loc: &Localization, pose: &nalgebra::Isometry3<f64>) {
        let FrameTf { tf, kind, base_pose, problems, notes } = lock(&self.broadcast).for_frame(
            loc.stamp,
            &loc.camera_frame_id,
            &loc.map_frame_id,
            pose,
            self.tf.is_some(),
        );
        for note in notes {
            info(note);
        }
        for problem in problems {
            if problem.log {
                warn(format!("{} (logged once until it works)", problem.error));
            }
            lock(&self.stats).error(problem.error.key(), problem.error.to_string());
        }
        if let (Some(publisher), Some(msg)) = (&self.tf, tf) {
            if let Some(kind) = kind {
                lock(&self.stats).count_tf(kind);
            }
            self.send(publisher, &self.topics.tf, msg).await;
        }
        if let (Some(publisher), Some(msg)) = (&self.base_pose, base_pose) {
            lock(&self.stats).count_tf("base_pose");
            self.send(publisher, &self.topics.base_pose, msg).await;
        }
    }
}
