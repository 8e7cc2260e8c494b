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
use super::log::info;
use super::log::{lock, now_ns, warn};
use super::tf::{FrameTf, TfBroadcast};
use super::topics::Topics;
use crate::bag::BagWriter;
use crate::frame::{Correspondence, Frame};
use crate::limits::InputLimits;
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
    debug: Option<Publisher<msgs::Image>>,
    /// What a camera image is decoded within to draw the debug image (`limits.*`, as its
    /// reader checked it): the defaults until [`Outputs::with_image_limits`].
    image_limits: InputLimits,
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
        let debug =
            if np.debug_image { Some(dds::publisher(node, &topics.debug_image, &dds::sensor_data(5))?) } else { None };
        Ok(Self {
            pose: dds::publisher(node, &topics.pose, &out_qos)?,
            pose_cov: dds::publisher(node, &topics.pose_with_covariance, &out_qos)?,
            kept: dds::publisher(node, &topics.output_correspondences, &out_qos)?,
            tf,
            broadcast,
            base_pose,
            debug,
            image_limits: InputLimits::default(),
            topics: topics.clone(),
            recorder,
            stats,
        })
    }

    /// The limits camera images are decoded within for the debug image: the node's `limits`.
    pub fn with_image_limits(mut self, limits: &InputLimits) -> Self {
        self.image_limits = limits.clone();
        self
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
        if let Some(debug) = &self.debug {
            match debug_image(frame, loc, &self.image_limits) {
                Ok(img) => self.send(debug, &topics.debug_image, img).await,
                Err(e) => lock(&self.stats).error("debug_image", format!("frame {}: {e}", loc.stamp)),
            }
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

/// The camera image (rgb8) with kept correspondences as green and rejected ones as red
/// 5×5 squares, at the matcher's pixels of the (raw) image: a frame whose pixels were
/// undistorted for the localizer (`frame.lens`) has them distorted back. A compressed image is
/// decoded here, within `limits`.
fn debug_image(frame: &Frame, loc: &Localization, limits: &InputLimits) -> Result<msgs::Image> {
    let image = frame.image.as_ref().ok_or_else(|| anyhow!("no camera image for this frame"))?;
    let mut rgb = img::from_encoded(image, limits).map_err(|e| anyhow!(e))?;
    let in_image = |cs: &[Correspondence]| -> Vec<Correspondence> {
        match &frame.lens {
            Some(lens) => cs.iter().map(|c| Correspondence { pixel: lens.distort_pixel(&c.pixel), ..*c }).collect(),
            None => cs.to_vec(),
        }
    };
    img::draw_matches(&mut rgb, &in_image(&frame.correspondences), &in_image(&loc.kept));
    Ok(img::image_msg(loc.stamp, &loc.camera_frame_id, rgb))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{CameraModel, Distortion};
    use crate::frame::CameraImage;
    use crate::geometry::Intrinsics;
    use crate::pipeline::Method;
    use nalgebra::{Point2, Point3};

    #[test]
    fn the_debug_image_draws_undistorted_matches_at_their_raw_pixels() {
        let raw = Intrinsics { fx: 300.0, fy: 300.0, cx: 160.0, cy: 120.0, width: 320, height: 240 };
        let lens = CameraModel {
            raw,
            distortion: Distortion::PlumbBob([-0.3, 0.1, 0.0, 0.0, 0.0]),
            projection: [0.0; 12],
            unsupported_model: None,
        };
        // Near a corner, where the lens moves pixels most: the matcher saw (290, 220).
        let seen = Point2::new(290.0, 220.0);
        let ideal = lens.undistort_pixel(&seen).expect("inside the lens' range");
        assert!((ideal - seen).norm() > 10.0, "the test needs a visible displacement");
        let c = Correspondence { pixel: ideal, point: Point3::origin(), score: 1.0 };
        let frame = Frame {
            stamp: 1,
            camera_frame_id: "cam".into(),
            map_frame_id: "map".into(),
            intrinsics: raw,
            correspondences: vec![c],
            depth_prior: None,
            image: Some(CameraImage::Raw(image::RgbImage::new(320, 240))),
            ground_truth: None,
            lens: Some(lens),
        };
        let loc = Localization { kept: vec![c], ..Localization::nothing_yet(&frame, Method::AngleI2p) };
        let msg = debug_image(&frame, &loc, &InputLimits::default()).expect("an image");
        let at = |x: f64, y: f64| {
            let i = (y.round() as usize * msg.width as usize + x.round() as usize) * 3;
            [msg.data[i], msg.data[i + 1], msg.data[i + 2]]
        };
        assert_eq!(at(seen.x, seen.y), img::KEPT, "drawn where the matcher saw it");
        assert_eq!(at(ideal.x, ideal.y), [0, 0, 0], "not at the undistorted pixel");
    }
}
