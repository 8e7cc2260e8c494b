//! The live node as a ROS 2 user meets it (issue 12), over DDS in a private network namespace:
//! namespaces, QoS of other publishers, ROS-style params files and arguments.

mod common;
mod netns;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use angle_i2p::frame::Frame;
use angle_i2p::msgs::{self, convert};
use angle_i2p::node::dds;
use common::manifest;
use netns::camera::{trigger, Camera};
use netns::{enter_netns, mark_done, run_in_netns, Guard};

const DOMAIN: &str = "19";

fn start_node(log: &Path, args: &[&str]) -> Guard {
    netns::spawn_node(log, args, DOMAIN)
}

fn read(log: &Path) -> String {
    netns::read_log(log)
}

/// A numeric value of the diagnostics of node `fq_name` (0 when absent).
fn diag_of(d: &msgs::DiagnosticArray, fq_name: &str, key: &str) -> u64 {
    d.status
        .iter()
        .filter(|s| s.hardware_id == fq_name)
        .flat_map(|s| &s.values)
        .find(|kv| kv.key == key)
        .and_then(|kv| kv.value.parse().ok())
        .unwrap_or(0)
}

/// The first frame of the shipped bag that plain RANSAC localizes, with the bag's map.
fn ransac_frame() -> (Frame, angle_i2p::frame::MapCloud, nalgebra::Isometry3<f64>) {
    let (mut frames, map) = netns::camera::ransac_frames(1);
    let first = frames.remove(0);
    (first.frame, map, first.pose)
}

#[test]
fn live_namespaces_qos_and_ros_params() {
    run_in_netns("inner_namespaces_qos_and_ros_params");
}

/// Two nodes under `/cam0` and `/cam1` (a dotted-key params file, `--log-level`, `-e`,
/// `use_sim_time`), fed by best-effort matchers and volatile map publishers: each localizes its
/// own camera's frame on its own topics and nothing reaches the root names. A third node that
/// insists on a latched map says why a volatile map publisher never reaches it; a fourth reads its
/// map from a PLY file (`map_path`).
#[test]
#[ignore = "runs inside a network namespace, via live_namespaces_qos_and_ros_params"]
fn inner_namespaces_qos_and_ros_params() {
    enter_netns("live_namespaces_qos_and_ros_params", DOMAIN);
    let (frame, map, want) = ransac_frame();
    let tmp = tempfile::tempdir().expect("tmp");
    let params = tmp.path().join("params.yaml");
    std::fs::write(
        &params,
        "/**:\n  ros__parameters:\n    method: ransac\n    node.diagnostics_period_ms: 200\n    \
         node.frame_timeout_ms: 3000\n    pnp.min_inliers: 6\n",
    )
    .expect("params");
    let params = params.to_str().expect("utf-8 path");
    let logs: Vec<_> = ["cam0.log", "cam1.log", "latched.log"].iter().map(|n| tmp.path().join(n)).collect();
    let common_args = ["--params-file", params, "--log-level", "info", "-e", "/angle_i2p", "-p", "use_sim_time:=true"];
    let _cam0 = start_node(&logs[0], &[&["-r", "__ns:=/cam0"][..], &common_args].concat());
    let _cam1 = start_node(&logs[1], &[&["-r", "__ns:=/cam1"][..], &common_args].concat());
    let _latched =
        start_node(&logs[2], &[&["-r", "__ns:=/cam2", "-p", "map_qos:=transient_local"][..], &common_args].concat());
    // The fourth camera's node reads its map from a binary PLY file (`map_path`), nothing on the topic.
    let ply = tmp.path().join("map.ply");
    let mut bytes = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\n\
         property float z\nend_header\n",
        map.points.len()
    )
    .into_bytes();
    for p in &map.points {
        [p.x, p.y, p.z].iter().for_each(|v| bytes.extend(v.to_le_bytes()));
    }
    std::fs::write(&ply, bytes).expect("ply");
    let map_path = format!("map_path:={}", ply.display());
    let map_frame = format!("map_frame_id:={}", map.frame_id);
    let ply_log = tmp.path().join("ply.log");
    // Its map may come from the file only (`map_source: file`): a map on its topic is refused.
    let file_only = ["-r", "__ns:=/cam3", "-p", &map_path, "-p", &map_frame, "-p", "map_source:=file"];
    let _cam3 = start_node(&ply_log, &[&file_only[..], &common_args].concat());
    let mut logs = logs;
    logs.push(ply_log);
    let log_refs: Vec<&Path> = logs.iter().map(|p| p.as_path()).collect();

    let context = dds::context().expect("context");
    let mut ros = dds::node(&context, "/", "issue12_test").expect("node");
    let _spinner = dds::spawn_spinner(&mut ros).expect("spinner");
    let cams = [
        Camera::new(&mut ros, "/cam0", "/cam0/map/points"),
        Camera::new(&mut ros, "/cam1", "/cam1/map/points"),
        Camera::new(&mut ros, "/cam3", "/cam3/map/points"),
    ];
    let cam2_map = dds::publisher::<msgs::PointCloud2>(&mut ros, "/cam2/map/points", &dds::reliable(1)).expect("pub");
    let root_pose =
        dds::subscription::<msgs::PoseStamped>(&mut ros, "/angle_i2p/pose", &dds::reliable(10)).expect("sub");
    let diag = dds::subscription::<msgs::DiagnosticArray>(&mut ros, "/diagnostics", &dds::reliable(50)).expect("sub");
    netns::wait_for("the namespaced nodes' readers match", &log_refs, || cams.iter().all(|c| c.matched(&ros)));
    std::thread::sleep(Duration::from_millis(300));
    for c in &cams[..2] {
        c.map.publish(convert::point_cloud(frame.stamp, &map)).expect("map");
    }
    cam2_map.publish(convert::point_cloud(frame.stamp, &map)).expect("map");
    // A map 5 m off on /cam3's topic: counted and refused before any frame, so /cam3's pose
    // below (within 1e-6 m of the truth) is still from its file.
    let moved = angle_i2p::frame::MapCloud {
        points: map.points.iter().map(|p| p + nalgebra::Vector3::new(5.0, 0.0, 0.0)).collect(),
        frame_id: map.frame_id.clone(),
    };
    cams[2].map.publish(convert::point_cloud(frame.stamp, &moved)).expect("map");
    let mut refused = 0;
    netns::wait_for("/cam3 refuses the map on its topic", &log_refs, || {
        while let Ok(Some((d, _))) = diag.take() {
            refused = refused.max(diag_of(&d, "/cam3/angle_i2p", "error.map_refused"));
        }
        refused >= 1
    });
    assert!(read(&logs[3]).contains("node.map_source is file"), "{}", read(&logs[3]));

    // Each camera gets its own frame (its own stamp) and only its node answers.
    let stamps = [frame.stamp + 1_000_000_000, frame.stamp + 2_000_000_000, frame.stamp + 3_000_000_000];
    let mut got: [Option<msgs::PoseStamped>; 3] = [None, None, None];
    let mut next_send = Instant::now();
    netns::wait_for("a pose from each namespaced node", &log_refs, || {
        // Best effort: resend until the node has the map and answers.
        if Instant::now() >= next_send {
            for (c, s) in cams.iter().zip(stamps) {
                c.publish_frame(&frame, s);
            }
            next_send = Instant::now() + Duration::from_secs(1);
        }
        for (i, c) in cams.iter().enumerate() {
            while let Ok(Some((p, _))) = c.pose.take() {
                got[i] = Some(p);
            }
        }
        got.iter().all(Option::is_some)
    });
    for (i, p) in got.iter().enumerate() {
        let p = p.as_ref().expect("pose");
        assert_eq!(convert::stamp(&p.header), stamps[i], "camera {i} answered another camera's frame");
        let t = want.translation.vector;
        let d =
            ((p.pose.position.x - t.x).powi(2) + (p.pose.position.y - t.y).powi(2) + (p.pose.position.z - t.z).powi(2))
                .sqrt();
        assert!(d < 1e-6, "camera {i}: position off by {d}");
    }
    assert!(matches!(root_pose.take(), Ok(None)), "a pose on the root /angle_i2p/pose");

    // The latched-only node names the volatile map publisher it cannot hear.
    // diagnostic_updater's names: the node that hears nothing is STALE, the camera info of
    // /cam0 (heard) gets a topic status that is not.
    let mut incompatible = 0;
    let mut cam0_info_heard = false;
    let mut cam2_level = None;
    netns::wait_for("the latched-only node counts the incompatible map publisher", &log_refs, || {
        while let Ok(Some((d, _))) = diag.take() {
            incompatible = incompatible.max(diag_of(&d, "/cam2/angle_i2p", "error.incompatible_qos"));
            for s in &d.status {
                if s.hardware_id == "/cam2/angle_i2p" && s.name == "angle_i2p: localization" {
                    cam2_level = Some(s.level);
                }
                cam0_info_heard |= s.hardware_id == "/cam0/angle_i2p"
                    && s.name == "angle_i2p: /cam0/camera/camera_info topic status"
                    && s.level != msgs::DiagnosticStatus::STALE;
            }
        }
        incompatible >= 1 && cam0_info_heard
    });
    assert_eq!(cam2_level, Some(msgs::DiagnosticStatus::STALE));
    let latched_log = read(&logs[2]);
    assert!(
        latched_log.contains("/cam2/map/points offers durability volatile"),
        "no QoS warning in the log:\n{latched_log}"
    );
    // `~/load_map` answers: it reloads the PLY, and says why when the file has gone bad.
    let ok = trigger(&mut ros, "/cam3/angle_i2p/load_map", "reload", &logs[3]);
    assert!(ok.success, "{ok:?}");
    assert!(ok.message.starts_with(&format!("{} points", map.points.len())), "{ok:?}");
    std::fs::write(&ply, b"ply\nformat ascii 1.0\nelement vertex 1\n").expect("break the file");
    let bad = trigger(&mut ros, "/cam3/angle_i2p/load_map", "reload a broken file", &logs[3]);
    assert!(!bad.success && bad.message.contains("map.ply"), "{bad:?}");
    // An /initialpose far from the camera withholds /cam0's next pose; ~/relocalize drops it.
    let initial = dds::publisher::<msgs::PoseWithCovarianceStamped>(&mut ros, "/cam0/initialpose", &dds::reliable(10))
        .expect("pub");
    netns::wait_for("the initialpose reader matches", &log_refs, || initial.get_subscription_count(&ros) > 0);
    std::thread::sleep(Duration::from_millis(300));
    let far = nalgebra::Isometry3::translation(want.translation.x + 10.0, want.translation.y, want.translation.z);
    let mut covariance = [0.0; 36];
    [0, 7, 14, 21, 28, 35].iter().for_each(|&i| covariance[i] = 0.01);
    let prior = msgs::PoseWithCovarianceStamped {
        header: msgs::Header::new(frame.stamp, &frame.map_frame_id),
        pose: msgs::PoseWithCovariance { pose: convert::pose_from_isometry(&far), covariance },
    };
    initial.publish(prior).expect("initialpose");
    std::thread::sleep(Duration::from_millis(500));
    let gated_stamp = frame.stamp + 7_000_000_000;
    let no_pose = |d: &msgs::DiagnosticArray| {
        diag_of(d, "/cam0/angle_i2p", "error.outside_initialpose_gate") + diag_of(d, "/cam0/angle_i2p", "error.pnp")
    };
    let mut before = 0;
    while let Ok(Some((d, _))) = diag.take() {
        before = before.max(no_pose(&d));
    }
    let mut gated = 0;
    let mut next_send = Instant::now();
    netns::wait_for("the far initial pose withholds the pose", &log_refs, || {
        if Instant::now() >= next_send {
            cams[0].publish_frame(&frame, gated_stamp);
            next_send = Instant::now() + Duration::from_secs(1);
        }
        // The gate steers PnP: with no pose near the prior the frame fails in PnP (or, had
        // refinement moved it out, the published pose would be withheld at the gate).
        while let Ok(Some((d, _))) = diag.take() {
            gated = gated.max(no_pose(&d));
        }
        gated > before
    });
    while let Ok(Some((p, _))) = cams[0].pose.take() {
        assert_ne!(convert::stamp(&p.header), gated_stamp, "a pose outside the initial pose's gate was published");
    }
    let dropped = trigger(&mut ros, "/cam0/angle_i2p/relocalize", "relocalize", &logs[0]);
    assert!(dropped.success && dropped.message.contains("dropped"), "{dropped:?}");
    let free_stamp = frame.stamp + 9_000_000_000;
    let mut freed = false;
    let mut next_send = Instant::now();
    netns::wait_for("a pose again after ~/relocalize", &log_refs, || {
        if Instant::now() >= next_send {
            cams[0].publish_frame(&frame, free_stamp);
            next_send = Instant::now() + Duration::from_secs(1);
        }
        while let Ok(Some((p, _))) = cams[0].pose.take() {
            freed |= convert::stamp(&p.header) == free_stamp;
        }
        freed
    });
    for log in [&logs[0], &logs[1], &logs[3]] {
        assert!(!read(log).contains("incompatible"), "{}", read(log));
    }
    mark_done();
}

#[test]
fn live_python_matcher_example() {
    run_in_netns("inner_python_matcher_example");
}

/// Frames the example matcher is sent (and answers) in `inner_python_matcher_example`.
const FRAMES: i64 = 8;

/// examples/matcher_cyclonedds.py (Cyclone DDS, another DDS stack) as the matcher of a node in
/// `/cam5`: it hears each camera info, publishes that frame's correspondences with the image's
/// stamp and frame, and the node localizes the frames.
#[test]
#[ignore = "runs inside a network namespace, via live_python_matcher_example"]
fn inner_python_matcher_example() {
    enter_netns("live_python_matcher_example", DOMAIN);
    let Some(py) = common::python() else {
        common::skip_or_fail("no Python with cyclonedds (make py-venv)");
        return;
    };
    let (frame, map, want) = ransac_frame();
    // One stamp per camera frame the test sends: the matcher answers each stamp once, best
    // effort, so a lost answer is followed by the next frame, as on a real camera.
    let stamps: Vec<i64> = (0..FRAMES).map(|k| frame.stamp + 5_000_000_000 + k * 1_000_000_000).collect();
    let tmp = tempfile::tempdir().expect("tmp");
    let rows: Vec<[f64; 6]> = frame
        .correspondences
        .iter()
        .map(|c| [c.pixel.x, c.pixel.y, c.point.x, c.point.y, c.point.z, f64::from(c.score)])
        .collect();
    let replay = tmp.path().join("replay.json");
    let by_stamp: serde_json::Map<String, serde_json::Value> =
        stamps.iter().map(|s| (s.to_string(), serde_json::json!(rows))).collect();
    std::fs::write(&replay, serde_json::Value::Object(by_stamp).to_string()).expect("replay");
    let log = tmp.path().join("node.log");
    let _node = start_node(&log, &["-r", "__ns:=/cam5", "-p", "method:=ransac", "-p", "pnp.min_inliers:=6"]);
    let mut matcher = Guard(
        Command::new(py)
            .arg(manifest().join("examples/matcher_cyclonedds.py"))
            .args(["--namespace", "/cam5", "--domain", DOMAIN, "--count", &FRAMES.to_string(), "--timeout", "60"])
            .arg("--replay")
            .arg(&replay)
            .args(["--map-frame", &frame.map_frame_id])
            .env(
                "CYCLONEDDS_URI",
                "<General><Interfaces><NetworkInterface name=\"lo\" multicast=\"true\"/></Interfaces></General>",
            )
            .stdout(Stdio::piped())
            .spawn()
            .expect("spawn the example matcher"),
    );
    let mut lines = std::io::BufRead::lines(std::io::BufReader::new(matcher.0.stdout.take().expect("stdout")));
    match lines.next() {
        Some(Ok(l)) if l == "READY" => {}
        other => {
            if let Ok(Some(s)) = matcher.0.try_wait() {
                if s.code() == Some(3) {
                    common::skip_or_fail("the cyclonedds Python package is missing (scripts/requirements-eval.txt)");
                    return;
                }
            }
            panic!("the example matcher never matched the node: {other:?}\n{}", read(&log));
        }
    }

    let context = dds::context().expect("context");
    let mut ros = dds::node(&context, "/", "example_test").expect("node");
    let _spinner = dds::spawn_spinner(&mut ros).expect("spinner");
    let cam = Camera::new(&mut ros, "/cam5", "/cam5/map/points");
    netns::wait_for("the node's readers match", &[&log], || {
        cam.info.get_subscription_count(&ros) > 0 && cam.map.get_subscription_count(&ros) > 0
    });
    std::thread::sleep(Duration::from_millis(300));
    cam.map.publish(convert::point_cloud(frame.stamp, &map)).expect("map");
    // Frames start once the whole map has arrived (a CI run lost the matcher's one answer, most
    // likely among the map's fragments, which were still arriving), one a second until a pose
    // comes back; then the rest, so that the matcher reaches its count and exits.
    netns::wait_for("the node indexes the map", &[&log], || read(&log).contains("map indexed:"));
    let send = |s: i64| {
        cam.info.publish(convert::camera_info(s, &frame.camera_frame_id, &frame.intrinsics)).expect("info");
    };
    let mut unsent = stamps.iter().copied();
    let mut next_send = Instant::now();
    let mut pose = None;
    netns::wait_for("a pose for the example matcher's frame", &[&log], || {
        if Instant::now() >= next_send {
            if let Some(s) = unsent.next() {
                send(s);
            }
            next_send = Instant::now() + Duration::from_secs(1);
        }
        while let Ok(Some((p, _))) = cam.pose.take() {
            pose = Some(p);
        }
        pose.is_some()
    });
    drop(unsent);
    // Every stamp again until the matcher has answered them all (it skips stamps it answered; a
    // camera info it missed comes round again).
    let end = Instant::now() + Duration::from_secs(30);
    while matcher.0.try_wait().is_ok_and(|s| s.is_none()) && Instant::now() < end {
        for &s in &stamps {
            send(s);
            std::thread::sleep(Duration::from_millis(100));
        }
    }
    let p = pose.expect("pose");
    assert!(stamps.contains(&convert::stamp(&p.header)), "a pose stamped with no frame's stamp: {:?}", p.header);
    let t = want.translation.vector;
    let d = ((p.pose.position.x - t.x).powi(2) + (p.pose.position.y - t.y).powi(2) + (p.pose.position.z - t.z).powi(2))
        .sqrt();
    assert!(d < 1e-4, "position off by {d}");
    let status = netns::wait_bounded(&mut matcher.0, Duration::from_secs(30)).expect("the matcher exits");
    assert!(status.success(), "the example matcher failed: {status}");
    mark_done();
}
