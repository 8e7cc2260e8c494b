//! A camera as the node's tests play it over DDS: frames of the shipped bag that plain RANSAC
//! localizes, publishers as a best-effort matcher and a map server have them, the pose
//! subscription, and `std_srvs/Trigger` calls.

use std::path::Path;
use std::time::{Duration, Instant};

use angle_i2p::bag::{read_frames, TopicMap};
use angle_i2p::frame::{Frame, MapCloud};
use angle_i2p::msgs::{self, convert};
use angle_i2p::node::dds;
use angle_i2p::params::LocalizerParams;
use angle_i2p::pipeline::{Localizer, Method};

use crate::common::manifest;

/// A frame and the pose plain RANSAC finds for it.
pub struct Localized {
    pub frame: Frame,
    pub pose: nalgebra::Isometry3<f64>,
}

/// The first `count` frames of the shipped bag that plain RANSAC localizes, with the bag's map.
pub fn ransac_frames(count: usize) -> (Vec<Localized>, MapCloud) {
    let input = read_frames(manifest().join("bags/synth-hard"), &TopicMap::default()).expect("read bag");
    let map = input.map.clone().expect("map");
    let mut localizer =
        Localizer::new(LocalizerParams { method: Method::Ransac, ..LocalizerParams::default() }).expect("a localizer");
    localizer.set_map(&map);
    let frames: Vec<Localized> = input
        .frames
        .iter()
        .filter_map(|f| localizer.process(f).pose.map(|pose| Localized { frame: f.clone(), pose }))
        .take(count)
        .collect();
    assert_eq!(frames.len(), count, "frames RANSAC localizes");
    (frames, map)
}

/// One camera's publishers as a best-effort matcher and a volatile map server have them, and a
/// subscription to its pose.
pub struct Camera {
    pub info: ros2_client::Publisher<msgs::CameraInfo>,
    pub corr: ros2_client::Publisher<msgs::Correspondences>,
    pub map: ros2_client::Publisher<msgs::PointCloud2>,
    pub pose: ros2_client::Subscription<msgs::PoseStamped>,
}

impl Camera {
    /// The camera under namespace `ns` (its inputs there, its pose at `ns/angle_i2p/pose`), the
    /// map published on `map_topic`.
    pub fn new(ros: &mut ros2_client::Node, ns: &str, map_topic: &str) -> Self {
        let best_effort = dds::sensor_data(10);
        Self {
            info: dds::publisher(ros, &format!("{ns}/camera/camera_info"), &best_effort).expect("pub"),
            corr: dds::publisher(ros, &format!("{ns}/matcher/correspondences"), &best_effort).expect("pub"),
            map: dds::publisher(ros, map_topic, &dds::reliable(1)).expect("pub"),
            pose: dds::subscription(ros, &format!("{ns}/angle_i2p/pose"), &dds::reliable(10)).expect("sub"),
        }
    }

    pub fn matched(&self, ros: &ros2_client::Node) -> bool {
        self.info.get_subscription_count(ros) > 0
            && self.corr.get_subscription_count(ros) > 0
            && self.map.get_subscription_count(ros) > 0
            && self.pose.get_publisher_count(ros) > 0
    }

    pub fn publish_frame(&self, frame: &Frame, stamp: i64) {
        let cam = frame.camera_frame_id.as_str();
        self.info.publish(convert::camera_info(stamp, cam, &frame.intrinsics)).expect("info");
        let corr = convert::correspondences_msg(stamp, cam, &frame.map_frame_id, &frame.correspondences);
        self.corr.publish(corr).expect("corr");
    }
}

/// Calls the std_srvs/Trigger `service` and returns its answer, once the service has appeared
/// (20 s at most). A request sent before the server's reply writer has matched this client gets
/// no answer, so an unanswered call is repeated (3 s each, 30 s at most): call only services
/// whose answer a repeat does not change.
pub fn trigger(
    ros: &mut ros2_client::Node,
    service: &str,
    what: &str,
    log: &Path,
) -> angle_i2p::node::services::TriggerResponse {
    use angle_i2p::node::services::{trigger_type, TriggerRequest, TriggerResponse, SERVICE_MAPPING};
    let qos = dds::reliable(10);
    let client = ros
        .create_client::<TriggerRequest, TriggerResponse>(
            SERVICE_MAPPING,
            &dds::topic_name(service).expect("name"),
            &trigger_type(),
            qos.clone(),
            qos,
        )
        .expect("client");
    let appeared = super::service_appeared(&client, ros, Duration::from_secs(20));
    assert!(appeared, "{what}: {service} never appeared\n{}", super::read_log(log));
    let end = Instant::now() + Duration::from_secs(30);
    while Instant::now() < end {
        let call = client.async_call_service(TriggerRequest::default());
        if let Some(Ok(answer)) = futures::executor::block_on(super::with_timeout(call, Duration::from_secs(3))) {
            return answer;
        }
    }
    panic!("{what}: no answer from {service} in 30 s\n{}", super::read_log(log))
}
