//! What the node sends: the publishers of the results (pose, pose with covariance, kept
//! correspondences, TF, debug image), built from the same conversions `replay` writes
//! ([`convert::localization_messages`]), and the `--record` bag.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use anyhow::{anyhow, Result};
use ros2_client::Publisher;

use super::dds;
use super::diagnostics::Stats;
use super::image as img;
use super::log::{lock, now_ns, warn};
use super::tf;
use super::tf_buffer::TfHistory;
use super::topics::Topics;
use crate::bag::BagWriter;
use crate::frame::Frame;
use crate::msgs::{self, convert, RosMessage};
use crate::params::NodeParams;
use crate::pipeline::Localization;

/// Writes what the node publishes to a bag (`--record`); write errors are logged and counted,
/// never fatal.
#[derive(Clone, Default)]
pub struct Recorder {
    writer: Arc<Mutex<Option<BagWriter>>>,
}

impl Recorder {
    /// Records to a new bag at `path`.
    pub fn create(path: &std::path::Path) -> Result<Self> {
        let w = BagWriter::create(path).map_err(|e| anyhow!("--record {}: {e}", path.display()))?;
        Ok(Self { writer: Arc::new(Mutex::new(Some(w))) })
    }

    pub fn write<M: RosMessage>(&self, topic: &str, msg: &M, stats: &Mutex<Stats>) {
        let mut guard = lock(&self.writer);
        if let Some(w) = guard.as_mut() {
            if let Err(e) = w.write(topic, now_ns(), msg) {
                warn(format!("recording {topic} failed: {e}"));
                lock(stats).error("record_failed", format!("recording {topic}: {e}"));
            }
        }
    }

    /// Closes the bag; `None` when not recording.
    pub fn finish(&self) -> Option<Result<PathBuf>> {
        let w = lock(&self.writer).take()?;
        Some(w.finish().map_err(Into::into))
    }
}

/// The worker's publishers.
pub struct Outputs {
    topics: Topics,
    pose: Publisher<msgs::PoseStamped>,
    pose_cov: Publisher<msgs::PoseWithCovarianceStamped>,
    kept: Publisher<msgs::Correspondences>,
    tf: Option<Publisher<msgs::TFMessage>>,
    /// With `node.odom_frame` set: that frame and the transforms heard on /tf.
    odom: Option<(String, Arc<Mutex<TfHistory>>)>,
    /// How far `map → odom` is future-dated, ns.
    tolerance_ns: i64,
    debug: Option<Publisher<msgs::Image>>,
    recorder: Recorder,
    pub stats: Arc<Mutex<Stats>>,
}

/// Where TF goes: `map → camera`, or with an odom frame `map → odom` from the transforms heard.
pub struct TfSetup {
    pub odom_frame: String,
    pub buffer: Option<Arc<Mutex<TfHistory>>>,
    /// `node.transform_tolerance_s` in ns.
    pub tolerance_ns: i64,
}

impl Outputs {
    /// Creates the result publishers on `node`.
    pub fn create(
        node: &mut ros2_client::Node,
        topics: &Topics,
        np: &NodeParams,
        tf_setup: &TfSetup,
        recorder: Recorder,
        stats: Arc<Mutex<Stats>>,
    ) -> Result<Self> {
        let out_qos = dds::reliable(10);
        let tf = if np.publish_tf { Some(dds::publisher(node, &topics.tf, &dds::reliable(100))?) } else { None };
        let debug =
            if np.debug_image { Some(dds::publisher(node, &topics.debug_image, &dds::sensor_data(5))?) } else { None };
        Ok(Self {
            pose: dds::publisher(node, &topics.pose, &out_qos)?,
            pose_cov: dds::publisher(node, &topics.pose_with_covariance, &out_qos)?,
            kept: dds::publisher(node, &topics.output_correspondences, &out_qos)?,
            tf,
            odom: tf_setup.buffer.clone().map(|b| (tf_setup.odom_frame.clone(), b)),
            tolerance_ns: tf_setup.tolerance_ns,
            debug,
            topics: topics.clone(),
            recorder,
            stats,
        })
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
        if let (Some(tf), Some(pose)) = (&self.tf, &loc.pose) {
            match self.tf_message(loc, pose) {
                Ok(msg) => self.send(tf, &topics.tf, msg).await,
                Err(detail) => {
                    warn(&detail);
                    lock(&self.stats).error("no_odom_transform", detail);
                }
            }
        }
        self.send(&self.kept, &topics.output_correspondences, out.kept).await;
        if let Some(debug) = &self.debug {
            match debug_image(frame, loc) {
                Ok(img) => self.send(debug, &topics.debug_image, img).await,
                Err(e) => lock(&self.stats).error("debug_image", format!("frame {}: {e}", loc.stamp)),
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
        let odom_camera = lock(buffer).lookup(odom, &loc.camera_frame_id, loc.stamp);
        let odom_camera = odom_camera.map_err(|e| {
            format!(
                "frame {}: no transform {odom} → {} at its stamp ({e}); no TF published",
                loc.stamp, loc.camera_frame_id
            )
        })?;
        // Future-dated (REP 105, as amcl): valid until the next localization is due.
        let stamp = loc.stamp.saturating_add(self.tolerance_ns);
        Ok(tf::tf_message(stamp, &loc.map_frame_id, odom, &tf::map_to_odom(pose, &odom_camera)))
    }
}

/// The camera image (rgb8) with kept correspondences as green and rejected ones as red
/// 5×5 squares.
fn debug_image(frame: &Frame, loc: &Localization) -> Result<msgs::Image> {
    let image = frame.image.as_ref().ok_or_else(|| anyhow!("no camera image for this frame"))?;
    let mut rgb = img::from_encoded(image).map_err(|e| anyhow!(e))?;
    img::draw_matches(&mut rgb, &frame.correspondences, &loc.kept);
    Ok(img::image_msg(loc.stamp, &loc.camera_frame_id, rgb))
}
