//! Parameters of the live node only (`node.*`, or flat: `-p queue_depth:=4`): queue, frame
//! matching, TF, diagnostics, debug image. The node reads them; they live here so that the
//! parameters depend on no edge.

use serde::{Deserialize, Serialize};

/// Parameters of the live node only (the localizer's are in [`super::LocalizerParams`]). In a params file they
/// sit beside the others under `ros__parameters` (flat, or under a `node:` mapping).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NodeParams {
    /// The node configures and activates itself at start (ROS 2 lifecycle), as an unmanaged
    /// node would; false: it starts unconfigured and waits for a lifecycle manager (nav2's
    /// `lifecycle_manager`, `ros2 lifecycle set`) on `~/change_state`.
    pub autostart: bool,
    /// Frames waiting for the worker; when full, the OLDEST waiting frame is dropped.
    pub queue_depth: usize,
    /// A frame whose parts have not all arrived this long after its first part is handed
    /// out with what it has (or dropped when a required part is missing).
    pub frame_timeout_ms: u64,
    /// Parts whose `header.stamp` differ by at most this are joined into one frame
    /// (0 = exact match, as in bags).
    pub stamp_tolerance_ns: i64,
    /// Broadcast the localization on `/tf` (which transform: `tf_mode`).
    pub publish_tf: bool,
    /// Which transform is broadcast (see [`TfMode`]).
    pub tf_mode: TfMode,
    /// The frame the poses and TF are in (REP 105's `map`); a frame whose correspondences name
    /// another map frame publishes no TF nor base pose (counted).
    pub map_frame: String,
    /// REP 105's `odom`: the TF broadcast is `map_frame → odom_frame` = (map→camera) ·
    /// (odom→camera)⁻¹, with `odom_frame → <camera frame>` looked up at the image's stamp through
    /// any chain of frames heard on `/tf` / `/tf_static` (interpolated between
    /// samples). Empty: `map → camera` (as `tf_mode: map_to_camera`).
    pub odom_frame: String,
    /// REP 105's `base_link`: its pose in the map (map→camera · (base→camera)⁻¹, base→camera
    /// looked up at the image's stamp) is published on `angle_i2p/base_pose` when that chain is
    /// known. Empty: no base pose.
    pub base_frame: String,
    /// The last `map → odom` is sent again at this rate, stamped `transform_tolerance_s` after
    /// the node's clock (as amcl does between updates); 0: only once per localized frame.
    pub tf_publish_rate_hz: f64,
    /// `map → odom` is stamped this far after the image (future-dated, as nav2's amcl does, so
    /// consumers can transform data up to then), and an odom chain may be this much older or newer
    /// than the image and still be used, seconds.
    pub transform_tolerance_s: f64,
    /// Drop frames (counted, reason `no_map`) until a map has arrived.
    pub require_map: bool,
    /// Wait for the depth prior before localizing a frame (only with a rejector that uses it).
    pub expect_depth_prior: bool,
    /// Period of the aggregated `/diagnostics` message.
    pub diagnostics_period_ms: u64,
    /// The recent window the diagnostics levels and topic rates are computed over.
    pub diagnostics_window_s: f64,
    /// Frames (and messages per input) per second below which the diagnostics WARN; 0: never.
    pub min_rate_hz: f64,
    /// Publish `angle_i2p/debug_image` (sensor_msgs/Image rgb8): the camera image with kept
    /// correspondences green and rejected ones red. Subscribes to the compressed image
    /// (`camera/image_raw/compressed`) and to `camera/image_raw` (sensor_msgs/Image rgb8, bgr8,
    /// mono8, rgba8, bgra8), and waits for one of them.
    pub debug_image: bool,
    /// Durability of the map subscription (see [`MapQos`]).
    pub map_qos: MapQos,
    /// Where the map may come from (see [`MapSource`]): who may change the map.
    pub map_source: MapSource,
    /// A PLY or PCD file read as the map at start (ASCII or binary); empty: the map comes only
    /// from the map topic. A map on the topic later replaces it (unless `map_source: file`).
    pub map_path: String,
    /// The frame of the points in `map_path`.
    pub map_frame_id: String,
    /// The gate of an `initialpose` (geometry_msgs/PoseWithCovarianceStamped of the camera in
    /// the map; see `crate::node::initial_pose`, `~/relocalize` drops it): its half-width in
    /// standard deviations of the initial pose's covariance …
    pub initialpose_gate_sigmas: f64,
    /// … but at least this far (metres) …
    pub initialpose_min_radius_m: f64,
    /// … and this much rotation (degrees).
    pub initialpose_min_angle_deg: f64,
    /// ROS's `use_sim_time`: the node's own stamps (diagnostics) follow `/clock` when true.
    /// Its outputs always carry the input messages' stamps.
    pub use_sim_time: bool,
    /// Several cameras in one node, sharing one map (`[cam0, cam1]`): each entry is a namespace
    /// (relative to the node's) that the camera's relative topics and its `relocalize` service
    /// move under (`cam0/camera/camera_info`, `cam0/angle_i2p/pose`, …), with its own frame
    /// assembly, queue and worker; the map, TF and diagnostics stay the node's. Empty: one camera,
    /// the node's own topics. See docs/multi-camera.md.
    pub cameras: Vec<String>,
}

/// Which transform the node broadcasts on `/tf` (REP 105).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TfMode {
    /// `map → odom` once `odom_frame` has been heard on `/tf` or `/tf_static`; before that (a
    /// camera without odometry, a bag) `map → camera`, with a warning the first time.
    #[default]
    Auto,
    /// `map → odom` only: a frame whose `odom → camera` is unknown at its stamp publishes no TF
    /// (counted as `error.no_odom_transform`, logged).
    MapToOdom,
    /// `map → camera`: the camera's pose as a transform (the camera frame must have no other parent).
    MapToCamera,
}

impl TfMode {
    pub fn name(self) -> &'static str {
        match self {
            TfMode::Auto => "auto",
            TfMode::MapToOdom => "map_to_odom",
            TfMode::MapToCamera => "map_to_camera",
        }
    }
}

/// How the map topic is subscribed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MapQos {
    /// Both a transient-local reader (a latched map published before the node started) and a
    /// volatile one (a volatile publisher, e.g. `ros2 bag play` of a bag without
    /// `offered_qos_profiles`); the same map heard twice is taken once.
    #[default]
    Auto,
    /// Reliable, transient local: only latched publishers match.
    TransientLocal,
    /// Reliable, volatile: every publisher matches, a map published before the node started is missed.
    Volatile,
}

/// Where the node's map may come from. On a network where anyone may publish, a map on the
/// topic relocates the robot wherever its sender wants; `file` closes that door.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MapSource {
    /// `map_path` at start (when set) and `~/load_map`, and any map on the map topic, which
    /// replaces it.
    #[default]
    FileAndTopic,
    /// Only `map_path` (which must be set) and `~/load_map`; a map heard on the map topic is
    /// refused, counted (`error.map_refused`) and logged.
    File,
    /// Only the map topic (`map_path` must be empty).
    Topic,
}

impl MapSource {
    pub fn name(self) -> &'static str {
        match self {
            MapSource::FileAndTopic => "file_and_topic",
            MapSource::File => "file",
            MapSource::Topic => "topic",
        }
    }

    /// Whether a map heard on the map topic may replace the one held.
    pub fn takes_topic(self) -> bool {
        self != MapSource::File
    }
}

impl Default for NodeParams {
    fn default() -> Self {
        Self {
            autostart: true,
            queue_depth: 2,
            frame_timeout_ms: 500,
            stamp_tolerance_ns: 0,
            publish_tf: true,
            tf_mode: TfMode::Auto,
            map_frame: "map".into(),
            odom_frame: "odom".into(),
            base_frame: "base_link".into(),
            tf_publish_rate_hz: 20.0,
            transform_tolerance_s: 0.1,
            require_map: true,
            expect_depth_prior: true,
            diagnostics_period_ms: 1000,
            diagnostics_window_s: 5.0,
            min_rate_hz: 1.0,
            debug_image: false,
            map_qos: MapQos::Auto,
            map_source: MapSource::FileAndTopic,
            map_path: String::new(),
            map_frame_id: "map".into(),
            initialpose_gate_sigmas: 3.0,
            initialpose_min_radius_m: 0.5,
            initialpose_min_angle_deg: 15.0,
            use_sim_time: false,
            cameras: Vec::new(),
        }
    }
}
