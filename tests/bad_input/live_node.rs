//! The live node's rows of the bad-input matrix: crafted messages over DDS, inside a private
//! network namespace, each asserting that the node survives and counts the input in
//! `/diagnostics` under its reason (a frame skipped, or a part refused while the frame goes on).

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use angle_i2p::bag::{read_frames, TopicMap};
use angle_i2p::frame::Frame;
use angle_i2p::msgs::{self, convert};
use angle_i2p::node::dds;
use angle_i2p::node::diagnostics::status_value;
use angle_i2p::pipeline::Localizer;
use angle_i2p::pipeline::LocalizerParams;

use crate::common::{binary, manifest};
use crate::netns::{self, mark_done, run_in_netns, wait_bounded, Guard};

pub(super) const DOMAIN: &str = "23";
/// The node's `frame_timeout_ms`: how long a frame waits, and a stamp is remembered.
const FRAME_TIMEOUT_MS: u64 = 1000;

#[test]
fn live_node_counts_each_bad_message_and_keeps_going() {
    run_in_netns("live_node::inner_live_node_bad_messages");
}

/// The test's DDS participant: publishes frame parts as a camera, a depth network and a
/// matcher would, and hears the node's diagnostics and poses.
pub(super) struct Wire {
    ros: ros2_client::Node,
    _spinner: std::thread::JoinHandle<()>,
    info: ros2_client::Publisher<msgs::CameraInfo>,
    pub(super) corr: ros2_client::Publisher<msgs::Correspondences>,
    prior: ros2_client::Publisher<msgs::Image>,
    image: ros2_client::Publisher<msgs::CompressedImage>,
    pub(super) map: ros2_client::Publisher<msgs::PointCloud2>,
    /// The map topic from a volatile publisher that queues (a storm of maps, each delivered).
    pub(super) map_stream: ros2_client::Publisher<msgs::PointCloud2>,
    pub(super) tf: ros2_client::Publisher<msgs::TFMessage>,
    pub(super) initialpose: ros2_client::Publisher<msgs::PoseWithCovarianceStamped>,
    diag: ros2_client::Subscription<msgs::DiagnosticArray>,
    pose: ros2_client::Subscription<msgs::PoseStamped>,
    last_diag: Option<msgs::DiagnosticArray>,
}

impl Wire {
    pub(super) fn new(context: &ros2_client::Context) -> Self {
        let mut ros = dds::node(context, "/", "bad_input_wire").expect("node");
        let _spinner = dds::spawn_spinner(&mut ros).expect("spinner");
        let t = TopicMap::default();
        let q = dds::reliable(10);
        Self {
            info: dds::publisher(&mut ros, &t.camera_info, &q).expect("pub"),
            corr: dds::publisher(&mut ros, &t.correspondences, &q).expect("pub"),
            prior: dds::publisher(&mut ros, &t.depth_prior, &q).expect("pub"),
            image: dds::publisher(&mut ros, &t.image, &q).expect("pub"),
            map: dds::publisher(&mut ros, &t.map, &dds::latched()).expect("pub"),
            map_stream: dds::publisher(&mut ros, &t.map, &dds::reliable(50)).expect("pub"),
            tf: dds::publisher(&mut ros, "/tf", &dds::reliable(100)).expect("pub"),
            initialpose: dds::publisher(&mut ros, "/initialpose", &dds::reliable(10)).expect("pub"),
            diag: dds::subscription(&mut ros, "/diagnostics", &dds::reliable(50)).expect("sub"),
            pose: dds::subscription(&mut ros, &t.pose, &dds::reliable(50)).expect("sub"),
            ros,
            _spinner,
            last_diag: None,
        }
    }

    /// Waits (30 s at most) until the node reads every frame part.
    pub(super) fn wait_matched(&self, log: &Path) {
        let by = Instant::now() + Duration::from_secs(30);
        loop {
            let counts = [
                self.info.get_subscription_count(&self.ros),
                self.corr.get_subscription_count(&self.ros),
                self.prior.get_subscription_count(&self.ros),
                self.image.get_subscription_count(&self.ros),
            ];
            if !counts.contains(&0) {
                break;
            }
            assert!(Instant::now() < by, "the node's readers never matched\n{}", read(log));
            std::thread::sleep(Duration::from_millis(50));
        }
        std::thread::sleep(Duration::from_millis(300));
    }

    /// A diagnostics counter (0 when absent) once `ok` holds for it, waiting 20 s at most.
    pub(super) fn wait_diag(&mut self, key: &str, ok: impl Fn(u64) -> bool, log: &Path) -> u64 {
        let end = Instant::now() + Duration::from_secs(20);
        loop {
            while let Ok(Some((d, _))) = self.diag.take() {
                self.last_diag = Some(d);
            }
            let v = self.value(key);
            if ok(v) {
                return v;
            }
            assert!(Instant::now() < end, "diagnostics {key} = {v}, condition never met\n{}", read(log));
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    pub(super) fn value(&self, key: &str) -> u64 {
        let d = self.last_diag.as_ref();
        d.and_then(|d| status_value(d, key)).and_then(|v| v.parse().ok()).unwrap_or(0)
    }

    /// The node's pose of the frame at `stamp` (camera-to-map), `None` when none comes within
    /// `within` (poses of other stamps heard meanwhile are dropped).
    pub(super) fn pose_of(&self, stamp: i64, within: Duration) -> Option<nalgebra::Isometry3<f64>> {
        let end = Instant::now() + within;
        while Instant::now() < end {
            if let Ok(Some((p, _))) = self.pose.take() {
                if convert::stamp(&p.header) == stamp {
                    return convert::isometry_from_pose(&p.pose).ok();
                }
            } else {
                std::thread::sleep(Duration::from_millis(10));
            }
        }
        None
    }

    /// Waits for the node's pose of the frame at `stamp`.
    pub(super) fn wait_pose(&self, stamp: i64, log: &Path) {
        let end = Instant::now() + Duration::from_secs(20);
        loop {
            if let Ok(Some((p, _))) = self.pose.take() {
                if convert::stamp(&p.header) == stamp {
                    return;
                }
            }
            assert!(Instant::now() < end, "no pose for frame {stamp}\n{}", read(log));
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

/// One frame's messages, each of which a row may spoil.
pub(super) struct Parts {
    info: msgs::CameraInfo,
    corr: msgs::Correspondences,
    prior: msgs::Image,
    pub(super) image: msgs::CompressedImage,
}

impl Parts {
    /// The good frame's parts at `stamp`, with a tiny PNG as its camera image.
    pub(super) fn of(good: &Frame, stamp: i64) -> Self {
        let cam = good.camera_frame_id.as_str();
        let prior = good.depth_prior.as_ref().expect("prior in the bag");
        Self {
            info: convert::camera_info(stamp, cam, &good.intrinsics),
            corr: convert::correspondences_msg(stamp, cam, &good.map_frame_id, &good.correspondences),
            prior: convert::image_32fc1(stamp, cam, prior),
            image: msgs::CompressedImage {
                header: msgs::Header::new(stamp, cam),
                format: "png".into(),
                data: png(4, 4),
            },
        }
    }

    pub(super) fn publish(self, wire: &Wire) {
        wire.info.publish(self.info).expect("publish info");
        wire.prior.publish(self.prior).expect("publish prior");
        wire.image.publish(self.image).expect("publish image");
        wire.corr.publish(self.corr).expect("publish corr");
    }
}

/// A `width`×`height` grey PNG.
pub(super) fn png(width: u32, height: u32) -> Vec<u8> {
    let mut out = Vec::new();
    image::GrayImage::from_pixel(width, height, image::Luma([128]))
        .write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)
        .expect("png");
    out
}

/// The CRC-32 (ISO-HDLC, as PNG chunks carry it) of `bytes`.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 { (c >> 1) ^ 0xEDB8_8320 } else { c >> 1 };
        }
    }
    !c
}

/// A 1×1 PNG whose header declares `side`×`side` (a few dozen bytes that would decode huge).
pub(super) fn png_declaring(side: u32) -> Vec<u8> {
    let mut data = png(1, 1);
    // Signature (8), IHDR length (4), "IHDR" (4), width (4), height (4), 5 more bytes, CRC.
    data[16..20].copy_from_slice(&side.to_be_bytes());
    data[20..24].copy_from_slice(&side.to_be_bytes());
    let crc = crc32(&data[12..29]);
    data[29..33].copy_from_slice(&crc.to_be_bytes());
    data
}

pub(super) fn read(log: &Path) -> String {
    std::fs::read_to_string(log).unwrap_or_default()
}

/// The node with a debug image (so frames take camera images) and at most
/// `max_correspondences` a frame (small, so the oversized message stays small on the wire).
pub(super) fn start_node(log: &Path, max_correspondences: usize) -> Guard {
    let file = std::fs::File::create(log).expect("node log");
    let timeout = format!("frame_timeout_ms:={FRAME_TIMEOUT_MS}");
    let limit = format!("limits.max_correspondences:={max_correspondences}");
    let mut cmd = Command::new(binary());
    cmd.args(["node", "--ros-args", "-p", &timeout, "-p", "diagnostics_period_ms:=200", "-p", "queue_depth:=8"]);
    cmd.args(["-p", &limit]);
    cmd.args(["-p", "debug_image:=true"]).env("ROS_DOMAIN_ID", DOMAIN).stdout(Stdio::null()).stderr(file);
    Guard(cmd.spawn().expect("spawn angle-i2p node"))
}

/// The good frame's correspondences and `extra` more with score 0 at distinct pixels.
fn oversized(good: &Frame, stamp: i64, extra: usize) -> msgs::Correspondences {
    let mut msg = convert::correspondences_msg(stamp, &good.camera_frame_id, &good.map_frame_id, &good.correspondences);
    msg.correspondences.extend((0..extra).map(|k| msgs::Correspondence {
        u: (k % 600) as f32 + 0.5,
        v: (k / 600) as f32 + 0.25,
        x: 1.0,
        y: 2.0,
        z: 3.0,
        score: 0.0,
    }));
    msg
}

/// The shipped hard bag's map and a frame of it that localizes offline.
pub(super) fn map_and_good_frame() -> (angle_i2p::frame::MapCloud, Frame) {
    let input = read_frames(manifest().join("bags/synth-hard"), &TopicMap::default()).expect("read bag");
    let map = input.map.clone().expect("map");
    let mut localizer = Localizer::new(LocalizerParams::default()).expect("a localizer");
    localizer.set_map(&map);
    let good = input.frames.iter().find(|f| localizer.process(f).pose.is_some()).cloned().expect("a posed frame");
    (map, good)
}

#[test]
#[ignore = "runs inside a network namespace, via live_node_counts_each_bad_message_and_keeps_going"]
fn inner_live_node_bad_messages() {
    netns::enter_netns("live_node_counts_each_bad_message_and_keeps_going", DOMAIN);
    let (map, good) = map_and_good_frame();
    let max_correspondences = good.correspondences.len() + 50;
    let tmp = tempfile::tempdir().expect("tmp");
    let log = tmp.path().join("node.log");
    let mut node = start_node(&log, max_correspondences);
    let context = dds::context().expect("context");
    let mut wire = Wire::new(&context);
    wire.wait_matched(&log);
    wire.map.publish(convert::point_cloud(0, &map)).expect("publish map");
    wire.wait_diag("maps_received", |v| v == 1, &log);
    let s = |k: i64| good.stamp + k * 1_000_000_000;
    let pause = || std::thread::sleep(Duration::from_millis(150));

    // A NaN correspondence: the part is refused, the frame dropped for want of it.
    let mut p = Parts::of(&good, s(1));
    p.corr.correspondences[0].u = f32::NAN;
    p.publish(&wire);
    wire.wait_diag("error.invalid_correspondences", |v| v == 1, &log);
    wire.wait_diag("dropped.missing_correspondences", |v| v == 1, &log);
    // More correspondences than limits.max_correspondences: the best kept, the frame goes on.
    let mut p = Parts::of(&good, s(2));
    p.corr = oversized(&good, s(2), 150);
    assert!(p.corr.correspondences.len() > max_correspondences);
    p.publish(&wire);
    wire.wait_diag("error.correspondences_over_limit", |v| v == 1, &log);
    // A CameraInfo of 4e9 × 4e9: refused before anything is allocated; the frame is dropped.
    let mut p = Parts::of(&good, s(3));
    (p.info.width, p.info.height) = (4_000_000_000, 4_000_000_000);
    p.publish(&wire);
    wire.wait_diag("error.invalid_camera_info", |v| v == 1, &log);
    wire.wait_diag("dropped.missing_camera_info", |v| v == 1, &log);
    // An image declaring 10000×10000: refused from its header; the frame is localized without it.
    let mut p = Parts::of(&good, s(4));
    p.image.data = png_declaring(10_000);
    p.publish(&wire);
    wire.wait_diag("error.invalid_image", |v| v == 1, &log);
    wire.wait_pose(s(4), &log);
    // The same stamp twice: the second frame is a repeated stamp, skipped.
    Parts::of(&good, s(5)).publish(&wire);
    pause();
    Parts::of(&good, s(5)).publish(&wire);
    wire.wait_diag("dropped.repeated_stamp", |v| v == 1, &log);
    // A correspondences message for a frame already handed out: a late part, not a frame.
    Parts::of(&good, s(6)).publish(&wire);
    pause();
    wire.corr.publish(Parts::of(&good, s(6)).corr).expect("publish late part");
    wire.wait_diag("error.late_part", |v| v == 1, &log);
    assert_eq!(wire.value("dropped.missing_camera_info"), 1, "a late part is not a frame missing its camera info");

    // After all that: a good frame is localized, every frame heard of is accounted for.
    Parts::of(&good, s(7)).publish(&wire);
    wire.wait_pose(s(7), &log);
    let accounted = |w: &Wire| {
        w.value("frames_received") == w.value("frames_localized") + w.value("frames_failed") + w.value("dropped_total")
    };
    // Seven stamps, one of them twice (the late part is no frame): wait for the last of them.
    wire.wait_diag("frames_received", |v| v >= 8, &log);
    let end = Instant::now() + Duration::from_secs(20);
    while !accounted(&wire) {
        assert!(Instant::now() < end, "frames not accounted for\n{}", read(&log));
        std::thread::sleep(Duration::from_millis(100));
        wire.wait_diag("frames_received", |_| true, &log);
    }
    assert_eq!(wire.value("frames_received"), 8, "seven stamps, one of them twice");
    assert!(wire.value("frames_localized") >= 4, "the good frames are localized");
    assert!(matches!(node.0.try_wait(), Ok(None)), "the node exited\n{}", read(&log));
    let _ = Command::new("kill").args(["-INT", &node.0.id().to_string()]).status();
    let status = wait_bounded(&mut node.0, Duration::from_secs(40)).expect("node did not stop on SIGINT");
    assert!(status.success(), "node exit {status}\n{}", read(&log));
    mark_done();
}
