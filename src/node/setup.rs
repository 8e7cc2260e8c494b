//! Step 1 of the node's life, its parameters: what the node was configured with, resolved once
//! (the node's own topics, TF buffer, clock, recorder, and its cameras), and the start-up lines
//! that say so.

use std::path::Path;
use std::sync::{Arc, Mutex};

use anyhow::Result;
use ros2_client::Context;

use super::cameras::CameraSetup;
use super::clock::NodeClock;
use super::initial_pose::GateWidth;
use super::log::{info, lock};
use super::recorder::Recorder;
use super::topics::{self, Topics};
use crate::frame::PartKind;
use crate::limits::InputLimits;
use crate::params::{AppParams, Names, NodeParams, TfMode};
use crate::pipeline::{LocalizerParams, Method};
use crate::tf_buffer::TfHistory;

/// Step 1, parameters: what the node was configured with, resolved once.
pub struct Setup {
    pub names: Names,
    /// The node's own topics (the map, TF, `/diagnostics`); each camera has its own.
    pub topics: Topics,
    pub np: NodeParams,
    pub params: LocalizerParams,
    pub limits: InputLimits,
    pub pixels: crate::camera::PixelSpace,
    /// A frame waits for a depth prior (`expect_depth_prior`, and a method that uses one).
    pub wants_prior: bool,
    /// What was heard on /tf and /tf_static (read when `reads_tf`), for every camera.
    pub tf_buffer: Arc<Mutex<TfHistory>>,
    pub reads_tf: bool,
    pub clock: NodeClock,
    pub recorder: Recorder,
    /// The gates' width for the next `/initialpose` (a live parameter).
    pub gate_width: Arc<Mutex<GateWidth>>,
    /// One camera, or one per `node.cameras`; the first sends `map → odom`.
    pub cameras: Vec<CameraSetup>,
}

impl Setup {
    pub fn new(names: Names, resolved: &AppParams, record: Option<&Path>) -> Result<Self> {
        let topics = topics::of_node(&names);
        let np: NodeParams = resolved.node.clone();
        let params = resolved.localizer.clone();
        let recorder = match record {
            Some(path) => Recorder::create(path)?,
            None => Recorder::default(),
        };
        let wants_prior = np.expect_depth_prior && params.method != Method::Ransac;
        let tolerance_ns = super::tf::tolerance_ns(np.transform_tolerance_s);
        let tf_buffer = Arc::new(Mutex::new(TfHistory::with_slack(tolerance_ns)));
        let cameras = CameraSetup::all(resolved, &names, &tf_buffer, wants_prior)?;
        let first = lock(&cameras[0].broadcast);
        let reads_tf = (np.publish_tf && first.mode() != TfMode::MapToCamera) || !first.frames().base.is_empty();
        drop(first);
        Ok(Self {
            names,
            topics,
            params,
            limits: resolved.limits.clone(),
            pixels: resolved.camera.pixels,
            wants_prior,
            tf_buffer,
            reads_tf,
            clock: NodeClock::new(np.use_sim_time),
            recorder,
            gate_width: Arc::new(Mutex::new(GateWidth {
                sigmas: np.initialpose_gate_sigmas,
                min_radius_m: np.initialpose_min_radius_m,
                min_angle_deg: np.initialpose_min_angle_deg,
            })),
            cameras,
            np,
        })
    }

    /// The parts a frame waits for.
    pub fn expected_parts(&self) -> Vec<PartKind> {
        let mut expected = vec![PartKind::CameraInfo, PartKind::Correspondences];
        if self.wants_prior {
            expected.push(PartKind::DepthPrior);
        }
        if self.np.debug_image {
            expected.push(PartKind::Image);
        }
        expected
    }

    /// The first camera, whose statistics also count the node's own problems and whose TF the
    /// re-send repeats.
    pub fn first(&self) -> &CameraSetup {
        &self.cameras[0]
    }
}

/// The start-up lines: the node, its method, the topics it shares, and each camera's.
pub fn log_started(s: &Setup, context: &Context, fq_name: &str) {
    let (t, np) = (&s.topics, &s.np);
    let tf = if np.publish_tf {
        let b = lock(&s.first().broadcast);
        let f = b.frames();
        let what = match b.mode() {
            TfMode::MapToCamera => format!("{} → camera", f.map),
            TfMode::MapToOdom => format!("{} → {}", f.map, f.odom),
            TfMode::Auto => format!("{} → {} once heard, {} → camera until then", f.map, f.odom, f.map),
        };
        let owner = if s.cameras.len() > 1 {
            format!("; {} → {} from camera {}", f.map, f.odom, s.first().name)
        } else {
            String::new()
        };
        format!(" {} ({what}, re-sent at {} Hz{owner})", t.tf, np.tf_publish_rate_hz)
    } else {
        String::new()
    };
    info(format!(
        "node {fq_name} on domain {}: method {}, queue_depth {}, frame_timeout {} ms, {} camera(s); inputs {}{}; outputs{} {}",
        context.domain_id(),
        s.params.method.name(),
        np.queue_depth,
        np.frame_timeout_ms,
        s.cameras.len(),
        t.map,
        if s.reads_tf { format!(" {} {}", t.tf, t.tf_static) } else { String::new() },
        tf,
        t.diagnostics,
    ));
    for c in &s.cameras {
        let t = &c.topics;
        let base = lock(&c.broadcast).frames().base.clone();
        let base = if base.is_empty() { String::new() } else { format!(" {} (pose of {base})", t.base_pose) };
        info(format!(
            "camera {:?}: inputs {} {} {}{} {}; outputs {} {} {}{}",
            c.name,
            t.camera_info,
            t.correspondences,
            if s.wants_prior { t.depth_prior.as_str() } else { "" },
            if np.debug_image { format!(" {}|{}", t.image, t.image_raw) } else { String::new() },
            t.initial_pose,
            t.pose,
            t.pose_with_covariance,
            t.output_correspondences,
            base,
        ));
    }
}
