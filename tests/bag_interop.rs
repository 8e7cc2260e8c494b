//! Interop of our CDR and rosbag2 MCAP code with bags written and read by Python tools.

use std::path::{Path, PathBuf};
use std::process::Command;

use angle_i2p::bag::{BagError, BagReader, BagWriter};
use angle_i2p::msgs::{self, convert, from_cdr, to_cdr, MsgError, RosMessage};
use nalgebra::{Isometry3, Matrix6, Point2, Point3, Vector3};

mod common;
use common::{manifest, python, shared_data, skip_or_fail};

fn fixture(name: &str) -> PathBuf {
    manifest().join("tests/fixtures").join(name)
}

/// Decodes as `M`, re-encodes, and returns the new bytes (or the decode error).
fn reencode<M: RosMessage>(data: &[u8]) -> Result<Vec<u8>, MsgError> {
    from_cdr::<M>(data).map(|m| to_cdr(&m))
}

/// Round trip by type name; `None` for a type we do not model.
fn reencode_by_name(type_name: &str, data: &[u8]) -> Option<(Result<Vec<u8>, MsgError>, &'static str)> {
    macro_rules! by_name {
        ($($t:ty),*) => {
            $(if type_name == <$t>::TYPE_NAME { return Some((reencode::<$t>(data), <$t>::SCHEMA)); })*
        };
    }
    by_name!(
        msgs::Time,
        msgs::Header,
        msgs::Image,
        msgs::CompressedImage,
        msgs::CameraInfo,
        msgs::RegionOfInterest,
        msgs::PointCloud2,
        msgs::PointField,
        msgs::Point,
        msgs::Quaternion,
        msgs::Pose,
        msgs::PoseStamped,
        msgs::PoseWithCovariance,
        msgs::PoseWithCovarianceStamped,
        msgs::Correspondence,
        msgs::Correspondences,
        msgs::DiagnosticArray,
        msgs::DiagnosticStatus,
        msgs::KeyValue,
        msgs::TFMessage,
        msgs::TransformStamped,
        msgs::Transform,
        msgs::Vector3
    );
    None
}

/// Checks every message of a bag re-encodes byte for byte and its schema is ours; returns the
/// set of type names seen.
fn check_round_trip(bag: &Path) -> std::collections::BTreeSet<String> {
    let reader = BagReader::open(bag).unwrap_or_else(|e| panic!("{e}"));
    let mut seen = std::collections::BTreeSet::new();
    assert!(!reader.messages().is_empty(), "{}: no messages", bag.display());
    let mut last = 0;
    for m in reader.messages() {
        assert!(m.log_time >= last, "messages not in log-time order");
        last = m.log_time;
        let (result, schema) = reencode_by_name(m.type_name(), &m.data)
            .unwrap_or_else(|| panic!("{}: unexpected type {}", bag.display(), m.type_name()));
        let bytes = result.unwrap_or_else(|e| panic!("{} {} @{}: {e}", bag.display(), m.topic(), m.log_time));
        assert!(bytes == m.data, "{} {} @{}: re-encoded bytes differ", bag.display(), m.topic(), m.log_time);
        assert_eq!(m.channel.schema, schema, "{}: schema of {} differs", bag.display(), m.type_name());
        seen.insert(m.type_name().to_string());
    }
    seen
}

#[test]
fn python_written_fixture_round_trips_byte_for_byte() {
    let seen = check_round_trip(&fixture("python_written"));
    for t in [
        "sensor_msgs/msg/PointCloud2",
        "sensor_msgs/msg/CameraInfo",
        "sensor_msgs/msg/CompressedImage",
        "sensor_msgs/msg/Image",
        "angle_i2p_msgs/msg/Correspondences",
        "geometry_msgs/msg/PoseStamped",
        "geometry_msgs/msg/PoseWithCovarianceStamped",
        "diagnostic_msgs/msg/DiagnosticArray",
        "tf2_msgs/msg/TFMessage",
    ] {
        assert!(seen.contains(t), "fixture lacks {t}");
    }
    // The same messages in lz4 chunks.
    assert_eq!(check_round_trip(&fixture("python_written_lz4/python_written_lz4.mcap")), seen);
}

#[test]
fn python_written_fixture_decodes_to_frames() {
    let read = angle_i2p::bag::read_frames(fixture("python_written"), &Default::default()).unwrap();
    let map = read.map.unwrap();
    assert_eq!(map.points.len(), 4, "the NaN point is skipped");
    assert_eq!(read.frames.len(), 3);
    // The fixture's scores are random normals: those outside [0, 1] are clamped, and said so.
    assert!(
        read.incomplete.iter().all(|i| !i.dropped && i.errors.iter().all(|e| e.contains("clamped"))),
        "{:?}",
        read.incomplete
    );
    let f = &read.frames[0];
    assert_eq!(f.intrinsics.fx, 525.0);
    assert_eq!(f.correspondences.len(), 4);
    assert_eq!(f.depth_prior.as_ref().unwrap().width, 5);
    assert_eq!(f.ground_truth.as_ref().unwrap().depth.as_ref().unwrap().height, 4);
}

#[test]
fn shared_bags_round_trip_byte_for_byte() {
    let Some(data) = shared_data() else { return };
    let mut bags: Vec<PathBuf> = std::fs::read_dir(&data)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("metadata.yaml").exists())
        .collect();
    bags.sort();
    assert!(!bags.is_empty(), "{}: no bags", data.display());
    for bag in &bags {
        let seen = check_round_trip(bag);
        assert_eq!(seen.len(), 6, "{}: {seen:?}", bag.display());
        let read = angle_i2p::bag::read_frames(bag, &Default::default()).unwrap();
        assert!(read.map.is_some_and(|m| m.points.len() > 1000));
        assert!(!read.frames.is_empty() && read.incomplete.is_empty(), "{}: {:?}", bag.display(), read.incomplete);
        eprintln!("{}: {} frames round-trip", bag.display(), read.frames.len());
    }
}

/// Compares JSON values, numbers to a relative 1e-6 (f32 values printed as f64).
fn assert_json_close(ours: &serde_json::Value, theirs: &serde_json::Value, at: &str) {
    use serde_json::Value::*;
    match (ours, theirs) {
        (Number(a), Number(b)) => {
            let (a, b) = (a.as_f64().unwrap(), b.as_f64().unwrap());
            assert!((a - b).abs() <= 1e-6 * a.abs().max(b.abs()).max(1.0), "{at}: {a} != {b}");
        }
        (Bool(a), Number(b)) | (Number(b), Bool(a)) => assert_eq!(*a as u64, b.as_u64().unwrap(), "{at}"),
        (Array(a), Array(b)) => {
            assert_eq!(a.len(), b.len(), "{at}: lengths differ");
            for (i, (x, y)) in a.iter().zip(b).enumerate() {
                assert_json_close(x, y, &format!("{at}[{i}]"));
            }
        }
        (Object(a), Object(b)) => {
            let (ka, kb): (Vec<_>, Vec<_>) = (a.keys().collect(), b.keys().collect());
            assert_eq!(ka, kb, "{at}: fields differ");
            for (k, x) in a {
                assert_json_close(x, &b[k], &format!("{at}.{k}"));
            }
        }
        _ => assert_eq!(ours, theirs, "{at}"),
    }
}

#[test]
fn our_bags_open_in_python_readers() {
    let Some(python) = python() else {
        return skip_or_fail("no Python found (set ANGLE_I2P_PYTHON or create .venv)");
    };
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("out_bag");
    let mut w = BagWriter::create(&dir).unwrap();
    let mut expected: Vec<(String, String, u64, serde_json::Value)> = Vec::new();
    let mut record = |topic: &str, t: i64, value: serde_json::Value, type_name: &str| {
        expected.push((topic.to_string(), type_name.to_string(), t as u64, value));
    };
    for k in 0..3i64 {
        let t = 1_700_000_000_000_000_000 + k * 100_000_000;
        let pose = Isometry3::new(Vector3::new(1.0 + k as f64, -2.0, 0.5), Vector3::new(0.1, -0.2 * k as f64, 0.3));
        let ps = convert::pose_stamped(t, "map", &pose);
        w.write("/angle_i2p/pose", t, &ps).unwrap();
        record("/angle_i2p/pose", t, serde_json::to_value(&ps).unwrap(), msgs::PoseStamped::TYPE_NAME);
        let cov = Matrix6::from_fn(|r, c| (r * 6 + c) as f64 * 0.01 + k as f64);
        let pwc = convert::pose_with_covariance_stamped(t, "map", &pose, &cov);
        w.write("/angle_i2p/pose_with_covariance", t, &pwc).unwrap();
        record(
            "/angle_i2p/pose_with_covariance",
            t,
            serde_json::to_value(&pwc).unwrap(),
            msgs::PoseWithCovarianceStamped::TYPE_NAME,
        );
        let corr: Vec<_> = (0..(k + 2))
            .map(|i| angle_i2p::frame::Correspondence {
                pixel: Point2::new(10.25 * i as f64, 3.5),
                point: Point3::new(0.1, -0.2 * i as f64, 2.0),
                score: 0.125 * i as f32,
            })
            .collect();
        let cm = convert::correspondences_msg(t, "camera_color_optical_frame", "map", &corr);
        w.write("/angle_i2p/correspondences", t + 1, &cm).unwrap();
        record(
            "/angle_i2p/correspondences",
            t + 1,
            serde_json::to_value(&cm).unwrap(),
            msgs::Correspondences::TYPE_NAME,
        );
    }
    let diag = msgs::DiagnosticArray {
        header: msgs::Header::new(5, ""),
        status: vec![msgs::DiagnosticStatus {
            level: msgs::DiagnosticStatus::WARN,
            name: "angle_i2p".into(),
            message: "few inliers".into(),
            hardware_id: "".into(),
            values: vec![msgs::KeyValue { key: "inliers".into(), value: "7".into() }],
        }],
    };
    w.write("/diagnostics", 1_700_000_000_500_000_000, &diag).unwrap();
    record(
        "/diagnostics",
        1_700_000_000_500_000_000,
        serde_json::to_value(&diag).unwrap(),
        msgs::DiagnosticArray::TYPE_NAME,
    );
    w.finish().unwrap();

    let out = Command::new(&python).arg(manifest().join("tests/python/read_bag.py")).arg(&dir).output().unwrap();
    if out.status.code() == Some(3) {
        return skip_or_fail(&format!("Python readers unavailable: {}", String::from_utf8_lossy(&out.stderr).trim()));
    }
    assert!(out.status.success(), "read_bag.py failed: {}", String::from_utf8_lossy(&out.stderr));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    expected.sort_by_key(|e| e.2);
    for reader in ["rosbags", "mcap_ros2"] {
        let got = json[reader].as_array().unwrap();
        assert_eq!(got.len(), expected.len(), "{reader}: message count");
        for (g, (topic, type_name, t, value)) in got.iter().zip(&expected) {
            assert_eq!(g["topic"], serde_json::json!(topic), "{reader}");
            assert_eq!(g["type"], serde_json::json!(type_name), "{reader}");
            assert_eq!(g["log_time"], serde_json::json!(t), "{reader}");
            assert_json_close(value, &g["msg"], &format!("{reader} {topic}"));
        }
    }
}

fn expect_err(path: &Path) -> BagError {
    match BagReader::open(path) {
        Ok(_) => panic!("{}: opened", path.display()),
        Err(e) => {
            let text = e.to_string();
            assert!(text.contains(&path.display().to_string()), "error does not name the file: {text}");
            e
        }
    }
}

#[test]
fn broken_and_foreign_bags_give_clear_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let good = std::fs::read(fixture("python_written/python_written.mcap")).unwrap();

    let truncated = tmp.path().join("truncated.mcap");
    std::fs::write(&truncated, &good[..good.len() / 2]).unwrap();
    assert!(matches!(expect_err(&truncated), BagError::Truncated { .. }));

    // Damage inside: keep both magics but cut a middle chunk.
    let holed = tmp.path().join("holed.mcap");
    let mut bytes = good[..good.len() / 3].to_vec();
    bytes.extend_from_slice(&good[good.len() - 200..]);
    std::fs::write(&holed, &bytes).unwrap();
    assert!(matches!(expect_err(&holed), BagError::Corrupt { .. }));

    let garbage = tmp.path().join("garbage.mcap");
    let noise: Vec<u8> = (0..4096u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
    std::fs::write(&garbage, &noise).unwrap();
    assert!(matches!(expect_err(&garbage), BagError::NotMcap { .. }));

    let write_mcap = |path: &Path, profile: &str, encoding: &str| {
        let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
        let mut w = mcap::WriteOptions::new().profile(profile).create(file).unwrap();
        let schema = w.add_schema("std_msgs/msg/Header", "ros2msg", msgs::Header::SCHEMA.as_bytes()).unwrap();
        let ch = w.add_channel(schema, "/h", encoding, &Default::default()).unwrap();
        let header = mcap::records::MessageHeader { channel_id: ch, sequence: 0, log_time: 1, publish_time: 1 };
        w.write_to_known_channel(&header, &to_cdr(&msgs::Header::new(1, "x"))).unwrap();
        w.finish().unwrap();
    };
    let foreign = tmp.path().join("foreign.mcap");
    write_mcap(&foreign, "ros1", "cdr");
    match expect_err(&foreign) {
        BagError::ForeignProfile { profile, .. } => assert_eq!(profile, "ros1"),
        e => panic!("{e}"),
    }
    let json = tmp.path().join("json.mcap");
    write_mcap(&json, "ros2", "json");
    assert!(matches!(expect_err(&json), BagError::MessageEncoding { .. }));
    let fine = tmp.path().join("fine.mcap");
    write_mcap(&fine, "ros2", "cdr");
    assert_eq!(BagReader::open(&fine).unwrap().messages().len(), 1);

    // A bag directory whose metadata lists a missing file.
    let dir = tmp.path().join("missing_file");
    std::fs::create_dir(&dir).unwrap();
    std::fs::write(
        dir.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n  relative_file_paths: [gone.mcap]\n",
    )
    .unwrap();
    let err = BagReader::open(&dir).unwrap_err();
    assert!(err.to_string().contains("gone.mcap"), "{err}");
    let err = BagReader::open(tmp.path().join("nope")).unwrap_err();
    assert!(err.to_string().contains("nope"), "{err}");
}
