//! Fuzzing on stable Rust with proptest: the CDR decoders, the MCAP reader (mutated bytes of a
//! shipped bag), the frame assembler and `Localizer::process` (arbitrary frames and maps) get
//! arbitrary and mutated input and must answer with a value or an error, never a panic, an abort
//! or an unbounded allocation.
//!
//! The suite runs a short mode (`ANGLE_I2P_FUZZ_CASES` unset: a few dozen cases per target,
//! seconds); `make fuzz` raises the case count for minutes. Inputs that once crashed are kept
//! under `tests/fixtures/fuzz/` and replayed first, every run.

use std::path::{Path, PathBuf};

use angle_i2p::bag::{decode_part, BagReader, FrameStream, TopicMap};
use angle_i2p::frame::{FrameAssembler, FramePart, PartKind};
use angle_i2p::geometry::{DepthImage, Intrinsics};
use angle_i2p::limits::InputLimits;
use angle_i2p::msgs::{self, from_cdr, to_cdr};
use proptest::prelude::*;

mod common;
use common::manifest;

/// Cases per target: `ANGLE_I2P_FUZZ_CASES`, else `short`.
fn cases(short: u32) -> u32 {
    std::env::var("ANGLE_I2P_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(short)
}

fn config(short: u32) -> ProptestConfig {
    ProptestConfig { cases: cases(short), failure_persistence: None, ..ProptestConfig::default() }
}

/// Every decoder of an input message, on the same bytes.
fn decode_all(data: &[u8]) {
    let _ = from_cdr::<msgs::Header>(data);
    let _ = from_cdr::<msgs::CameraInfo>(data);
    let _ = from_cdr::<msgs::Image>(data);
    let _ = from_cdr::<msgs::CompressedImage>(data);
    let _ = from_cdr::<msgs::PointCloud2>(data);
    let _ = from_cdr::<msgs::PoseStamped>(data);
    let _ = from_cdr::<msgs::Correspondences>(data);
    let _ = from_cdr::<msgs::DiagnosticArray>(data);
    let _ = from_cdr::<msgs::TFMessage>(data);
    let _ = msgs::peek_header(data);
    for kind in PartKind::ALL {
        let _ = decode_part(kind, data);
    }
    let _ = angle_i2p::bag::decode_map(data, &InputLimits::default());
}

/// Valid encodings of each input type, to mutate.
fn seeds() -> Vec<Vec<u8>> {
    let k = Intrinsics { fx: 500.0, fy: 500.0, cx: 32.0, cy: 24.0, width: 64, height: 48 };
    let depth = DepthImage::new(3, 2, vec![1.0, 2.0, 0.0, 4.0, 5.0, 6.0]);
    let c = angle_i2p::frame::Correspondence {
        pixel: nalgebra::Point2::new(1.0, 2.0),
        point: nalgebra::Point3::new(1.0, 2.0, 3.0),
        score: 0.5,
    };
    let map = angle_i2p::frame::MapCloud {
        frame_id: "map".into(),
        points: vec![nalgebra::Point3::new(1.0, 2.0, 3.0), nalgebra::Point3::new(4.0, 5.0, 6.0)],
    };
    use angle_i2p::msgs::convert;
    vec![
        to_cdr(&convert::camera_info(5, "cam", &k)),
        to_cdr(&convert::image_32fc1(5, "cam", &depth)),
        to_cdr(&convert::image_16uc1_mm(5, "cam", &depth)),
        to_cdr(&convert::correspondences_msg(5, "cam", "map", &[c, c])),
        to_cdr(&convert::pose_stamped(5, "map", &nalgebra::Isometry3::identity())),
        to_cdr(&convert::point_cloud(5, &map)),
    ]
}

/// Applies byte edits (position share, new byte) and an optional cut to `data`.
fn mutate(mut data: Vec<u8>, edits: &[(f64, u8)], cut: Option<f64>) -> Vec<u8> {
    if data.is_empty() {
        return data;
    }
    for (at, byte) in edits {
        let i = ((*at * data.len() as f64) as usize).min(data.len() - 1);
        data[i] = *byte;
    }
    if let Some(cut) = cut {
        data.truncate((cut * data.len() as f64) as usize);
    }
    data
}

fn fixtures() -> PathBuf {
    manifest().join("tests/fixtures/fuzz")
}

/// Every kept crashing input still gives a value or an error.
#[test]
fn kept_crashing_inputs_stay_fixed() {
    let Ok(entries) = std::fs::read_dir(fixtures()) else { return };
    for e in entries.flatten() {
        let path = e.path();
        let bytes = std::fs::read(&path).unwrap();
        if path.extension().is_some_and(|x| x == "md") {
            continue;
        }
        if path.extension().is_some_and(|x| x == "mcap") {
            let _ = read_everything(&path);
        } else {
            decode_all(&bytes);
        }
    }
}

proptest! {
    #![proptest_config(config(256))]

    #[test]
    fn cdr_decoders_take_any_bytes(data in proptest::collection::vec(any::<u8>(), 0..512)) {
        decode_all(&data);
    }

    #[test]
    fn cdr_decoders_take_mutated_messages(
        seed in 0usize..6,
        edits in proptest::collection::vec((0.0f64..1.0, any::<u8>()), 0..8),
        cut in proptest::option::of(0.0f64..1.0),
    ) {
        let data = mutate(seeds()[seed].clone(), &edits, cut);
        decode_all(&data);
    }
}

/// Reads a bag fully: messages, then frames with the default limits.
fn read_everything(path: &Path) -> Result<usize, String> {
    let n = BagReader::open(path).map_err(|e| e.to_string())?.messages().len();
    let mut stream =
        FrameStream::open(path, &TopicMap::default(), &InputLimits::default()).map_err(|e| e.to_string())?;
    while stream.next_frame().map_err(|e| e.to_string())?.is_some() {}
    Ok(n)
}

/// The bags mutated: the Python-written fixtures (uncompressed, lz4) and a zstd bag of ours.
fn shipped_bags() -> &'static [Vec<u8>] {
    static BAGS: std::sync::OnceLock<Vec<Vec<u8>>> = std::sync::OnceLock::new();
    BAGS.get_or_init(|| {
        let fixtures = manifest().join("tests/fixtures");
        let mut out: Vec<Vec<u8>> =
            ["python_written/python_written.mcap", "python_written_lz4/python_written_lz4.mcap"]
                .iter()
                .map(|p| std::fs::read(fixtures.join(p)).unwrap())
                .collect();
        let dir = tempfile::tempdir().unwrap();
        let bag = dir.path().join("zstd");
        let mut w = angle_i2p::bag::BagWriter::create(&bag).unwrap();
        for (t, seed) in seeds().iter().enumerate() {
            let topics = TopicMap::default();
            let topic = [
                &topics.camera_info,
                &topics.depth_prior,
                &topics.ground_truth_depth,
                &topics.correspondences,
                &topics.ground_truth_pose,
                &topics.map,
            ][t];
            let type_name = [
                "sensor_msgs/msg/CameraInfo",
                "sensor_msgs/msg/Image",
                "sensor_msgs/msg/Image",
                "angle_i2p_msgs/msg/Correspondences",
                "geometry_msgs/msg/PoseStamped",
                "sensor_msgs/msg/PointCloud2",
            ][t];
            w.write_raw(topic, type_name, "", 5, seed).unwrap();
        }
        w.finish().unwrap();
        out.push(std::fs::read(bag.join("zstd.mcap")).unwrap());
        out
    })
}

proptest! {
    #![proptest_config(config(48))]

    /// Mutated bytes of a shipped bag: an error naming the file, or messages; never a crash.
    #[test]
    fn mcap_reader_takes_mutated_bags(
        bag in 0usize..3,
        edits in proptest::collection::vec((0.0f64..1.0, any::<u8>()), 0..6),
        lengths in proptest::collection::vec((0.0f64..1.0, prop_oneof![Just(1u64 << 48), Just(1u64 << 63), Just(4_000_000_000u64), any::<u64>()]), 0..2),
        cut in proptest::option::of(0.5f64..1.0),
    ) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("mutated.mcap");
        let mut bytes = shipped_bags()[bag].clone();
        // Absurd values over what may be a length field.
        for (at, value) in &lengths {
            let i = ((at * bytes.len() as f64) as usize).min(bytes.len().saturating_sub(8));
            bytes[i..i + 8].copy_from_slice(&value.to_le_bytes());
        }
        let bytes = mutate(bytes, &edits, cut);
        std::fs::write(&path, &bytes).unwrap();
        if let Err(e) = read_everything(&path) {
            prop_assert!(e.contains("mutated.mcap"), "error does not name the file: {}", e);
        }
    }
}

/// One step of an assembler run.
#[derive(Clone, Debug)]
enum Step {
    Part(PartKind, i64),
    Error(PartKind, i64),
    Expire(i64),
    TakeOldest,
}

fn part(kind: PartKind, stamp: i64) -> FramePart {
    let depth = || DepthImage::new(1, 1, vec![1.0]);
    match kind {
        PartKind::CameraInfo => FramePart::CameraInfo {
            stamp,
            camera: angle_i2p::camera::CameraModel::pinhole(Intrinsics {
                fx: 1.0,
                fy: 1.0,
                cx: 0.0,
                cy: 0.0,
                width: 1,
                height: 1,
            }),
        },
        PartKind::Correspondences => FramePart::Correspondences {
            stamp,
            camera_frame_id: "c".into(),
            map_frame_id: "m".into(),
            correspondences: vec![],
        },
        PartKind::DepthPrior => FramePart::DepthPrior { stamp, depth: depth() },
        PartKind::Image => {
            let image = angle_i2p::frame::EncodedImage { format: "png".into(), data: vec![] };
            FramePart::Image { stamp, image: angle_i2p::frame::CameraImage::Compressed(image) }
        }
        PartKind::GroundTruthPose => FramePart::GroundTruthPose { stamp, pose: nalgebra::Isometry3::identity() },
        PartKind::GroundTruthDepth => FramePart::GroundTruthDepth { stamp, depth: depth() },
    }
}

fn step() -> impl Strategy<Value = Step> {
    let kind = (0usize..6).prop_map(|i| PartKind::ALL[i]);
    let stamp = -2i64..8;
    prop_oneof![
        6 => (kind.clone(), stamp.clone()).prop_map(|(k, s)| Step::Part(k, s)),
        1 => (kind, stamp.clone()).prop_map(|(k, s)| Step::Error(k, s)),
        1 => stamp.prop_map(Step::Expire),
        1 => Just(Step::TakeOldest),
    ]
}

proptest! {
    #![proptest_config(config(256))]

    /// Any order of parts, errors, expiries and forced hand-outs: every stamp that got a part
    /// is handed out (as a frame or a report) and nothing is left waiting after `finish`.
    #[test]
    fn frame_assembler_takes_any_order(
        expected in proptest::collection::vec((0usize..6).prop_map(|i| PartKind::ALL[i]), 0..4),
        steps in proptest::collection::vec(step(), 0..60),
        detect_repeats in any::<bool>(),
    ) {
        let mut a = FrameAssembler::new(&expected).with_arrival_timeout(2);
        if detect_repeats {
            a = a.with_repeat_detection();
        }
        let mut out = Vec::new();
        let mut stamps = std::collections::BTreeSet::new();
        // The assembler's clock: one tick a step, plus what an expiry skips ahead.
        let mut now = 0i64;
        for s in steps {
            now += 1;
            match s {
                Step::Part(k, t) => { stamps.insert(t); out.extend(a.push(part(k, t), now)); }
                Step::Error(k, t) => { stamps.insert(t); out.extend(a.push_error(t, k, "bad", now)); }
                Step::Expire(skip) => { now += skip.rem_euclid(4); out.extend(a.expire(now)) }
                Step::TakeOldest => out.extend(a.take_oldest("forced".into(), now)),
            }
        }
        out.extend(a.finish(now));
        prop_assert_eq!(a.pending(), 0);
        let handed: std::collections::BTreeSet<i64> = out.iter().map(|x| x.stamp()).collect();
        prop_assert_eq!(handed, stamps);
        for item in &out {
            if let angle_i2p::frame::Assembled::Complete(f) | angle_i2p::frame::Assembled::Partial(f, _) = item {
                prop_assert!(f.stamp >= 0, "a frame with a negative stamp was handed out");
            }
        }
    }
}

proptest! {
    #![proptest_config(config(48))]

    /// A well-formed bag (valid CRCs) whose messages are mutated: the frame stream decodes,
    /// limits and assembles them into frames or reports, never a crash.
    #[test]
    fn frame_stream_takes_mutated_messages(
        messages in proptest::collection::vec(
            (0usize..6, proptest::collection::vec((0.0f64..1.0, any::<u8>()), 0..4), proptest::option::of(0.3f64..1.0)),
            1..12,
        ),
    ) {
        let dir = tempfile::tempdir().unwrap();
        let bag = dir.path().join("bag");
        let topics = TopicMap::default();
        let mut w = angle_i2p::bag::BagWriter::create(&bag).unwrap();
        for (k, (seed, edits, cut)) in messages.iter().enumerate() {
            let (topic, type_name) = [
                (&topics.camera_info, "sensor_msgs/msg/CameraInfo"),
                (&topics.depth_prior, "sensor_msgs/msg/Image"),
                (&topics.ground_truth_depth, "sensor_msgs/msg/Image"),
                (&topics.correspondences, "angle_i2p_msgs/msg/Correspondences"),
                (&topics.ground_truth_pose, "geometry_msgs/msg/PoseStamped"),
                (&topics.map, "sensor_msgs/msg/PointCloud2"),
            ][*seed];
            let data = mutate(seeds()[*seed].clone(), edits, *cut);
            w.write_raw(topic, type_name, "", k as i64, &data).unwrap();
        }
        w.finish().unwrap();
        let mut stream = FrameStream::open(&bag, &topics, &InputLimits::default()).unwrap();
        while stream.next_frame().unwrap().is_some() {}
    }
}

/// A number as inputs bring them: mostly ordinary, sometimes 0, negative, huge or not a number.
fn wild(lo: f64, hi: f64) -> impl Strategy<Value = f64> {
    prop_oneof![
        8 => lo..hi,
        1 => Just(0.0),
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(-1e30),
        1 => Just(1e30),
        1 => -1.0f64..0.0,
    ]
}

/// A frame as the edges can hand it to the core (sides and counts within the default input
/// limits, scores clamped), with arbitrary values everywhere else.
fn frame() -> impl Strategy<Value = angle_i2p::frame::Frame> {
    let intrinsics =
        (wild(100.0, 900.0), wild(100.0, 900.0), wild(0.0, 640.0), wild(0.0, 480.0), 0u32..1300, 0u32..1000)
            .prop_map(|(fx, fy, cx, cy, width, height)| Intrinsics { fx, fy, cx, cy, width, height });
    let correspondence =
        (wild(-50.0, 700.0), wild(-50.0, 500.0), wild(-3.0, 3.0), wild(-3.0, 3.0), wild(0.2, 6.0), 0.0f32..=1.0)
            .prop_map(|(u, v, x, y, z, score)| angle_i2p::frame::Correspondence {
                pixel: nalgebra::Point2::new(u, v),
                point: nalgebra::Point3::new(x, y, z),
                score,
            });
    let prior = proptest::option::of((1u32..24, 1u32..18).prop_flat_map(|(w, h)| {
        proptest::collection::vec(wild(0.1, 8.0).prop_map(|v| v as f32), (w * h) as usize)
            .prop_map(move |data| DepthImage::new(w, h, data))
    }));
    (intrinsics, proptest::collection::vec(correspondence, 0..80), prior).prop_map(
        |(intrinsics, correspondences, depth_prior)| angle_i2p::frame::Frame {
            stamp: 1,
            camera_frame_id: "camera".into(),
            map_frame_id: "map".into(),
            intrinsics,
            correspondences,
            depth_prior,
            image: None,
            ground_truth: None,
            lens: None,
            odometry: None,
        },
    )
}

proptest! {
    #![proptest_config(config(24))]

    /// `Localizer::process` on arbitrary frames and maps: a pose or a failure with its reason,
    /// never a panic, for every method that needs no model file (the learned one too when
    /// ONNX Runtime is there), with and without the cascade's fast path.
    #[test]
    fn localizer_takes_any_frame(
        frame in frame(),
        map in proptest::collection::vec((-5.0f32..5.0, -5.0f32..5.0, -1.0f32..8.0), 0..300),
        fast_path in any::<bool>(),
    ) {
        use angle_i2p::pipeline::{Localizer, Method};
        let map = angle_i2p::frame::MapCloud {
            frame_id: "map".into(),
            points: map.into_iter().map(|(x, y, z)| nalgebra::Point3::new(x, y, z)).collect(),
        };
        for method in [Method::Ransac, Method::Consistency, Method::AngleI2p] {
            let mut params = angle_i2p::params::LocalizerParams { method, ..Default::default() };
            params.cascade.enabled = fast_path;
            params.pnp.max_iterations = 2000;
            let Ok(mut localizer) = Localizer::new(params) else { continue };
            localizer.set_map(&map);
            let loc = localizer.process(&frame);
            prop_assert!(loc.pose.is_some() || loc.failure.is_some());
        }
    }
}
