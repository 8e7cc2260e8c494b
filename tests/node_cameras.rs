//! One node, several cameras, one map (issue 13), over DDS in a private network namespace: a
//! node started with `-p cameras:=[cam0,cam1]` localizes each camera's frames on that camera's
//! topics, takes and indexes the map once for both, and moves both cameras to a new map.

mod common;
mod netns;

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

use angle_i2p::msgs::{self, convert};
use angle_i2p::node::dds;
use netns::camera::{ransac_frames, trigger, Camera, Localized};
use netns::{enter_netns, mark_done, run_in_netns};

const DOMAIN: &str = "23";
const CAMERAS: [&str; 2] = ["cam0", "cam1"];

/// The numeric values of each camera's localization status (`angle_i2p/<camera>: localization`).
fn per_camera(d: &msgs::DiagnosticArray, into: &mut BTreeMap<(String, String), u64>) {
    for s in &d.status {
        let Some(camera) = s.name.strip_prefix("angle_i2p/").and_then(|n| n.strip_suffix(": localization")) else {
            continue;
        };
        for kv in &s.values {
            if let Ok(v) = kv.value.parse::<u64>() {
                into.insert((camera.to_string(), kv.key.clone()), v);
            }
        }
    }
}

fn value(values: &BTreeMap<(String, String), u64>, camera: &str, key: &str) -> u64 {
    values.get(&(camera.to_string(), key.to_string())).copied().unwrap_or(0)
}

/// Sends each camera its own frame (resent every second: best effort) until a pose comes back on
/// each camera's topic for that frame's stamp; checks each pose is its own frame's.
fn poses_per_camera(cams: &[Camera], sent: &[(&Localized, i64)], log: &Path) {
    let mut got: Vec<Option<msgs::PoseStamped>> = vec![None; cams.len()];
    let mut next_send = Instant::now();
    netns::wait_for("a pose on each camera's topic", &[log], || {
        if Instant::now() >= next_send {
            for (c, (l, stamp)) in cams.iter().zip(sent) {
                c.publish_frame(&l.frame, *stamp);
            }
            next_send = Instant::now() + Duration::from_secs(1);
        }
        for (i, c) in cams.iter().enumerate() {
            while let Ok(Some((p, _))) = c.pose.take() {
                let stamp = convert::stamp(&p.header);
                let others = sent.iter().enumerate().filter(|(j, _)| *j != i);
                assert!(others.clone().all(|(_, s)| s.1 != stamp), "{} answered another camera's frame", CAMERAS[i]);
                // A pose of an earlier round (a resent frame) is not this round's.
                if stamp == sent[i].1 {
                    got[i] = Some(p);
                }
            }
        }
        got.iter().all(Option::is_some)
    });
    for (i, p) in got.iter().enumerate() {
        let p = p.as_ref().expect("a pose");
        let t = sent[i].0.pose.translation.vector;
        let d =
            ((p.pose.position.x - t.x).powi(2) + (p.pose.position.y - t.y).powi(2) + (p.pose.position.z - t.z).powi(2))
                .sqrt();
        assert!(d < 1e-6, "{}: position off its own frame's by {d} m", CAMERAS[i]);
    }
}

#[test]
fn live_two_cameras_share_one_map() {
    run_in_netns("inner_two_cameras_share_one_map");
}

/// Two cameras of one node (`cameras:=[cam0,cam1]` on the command line), each fed another frame of
/// the shipped bag on its own namespace: each camera's pose arrives on its own topic for its own
/// frame, nothing on the node's root topics; the map is taken and indexed once; a new map is taken
/// and indexed once and both cameras localize against it; each camera's `relocalize` answers.
#[test]
#[ignore = "runs inside a network namespace, via live_two_cameras_share_one_map"]
fn inner_two_cameras_share_one_map() {
    enter_netns("live_two_cameras_share_one_map", DOMAIN);
    let (frames, map) = ransac_frames(2);
    let tmp = tempfile::tempdir().expect("tmp");
    let log = tmp.path().join("node.log");
    let args = [
        "-p",
        "cameras:=[cam0, cam1]",
        "-p",
        "method:=ransac",
        "-p",
        "pnp.min_inliers:=6",
        "-p",
        "node.diagnostics_period_ms:=200",
        "-p",
        "node.frame_timeout_ms:=3000",
        "--log-level",
        "info",
    ];
    let _node = netns::spawn_node(&log, &args, DOMAIN);

    let context = dds::context().expect("context");
    let mut ros = dds::node(&context, "/", "issue13_cameras_test").expect("node");
    let _spinner = dds::spawn_spinner(&mut ros).expect("spinner");
    let cams: Vec<Camera> = CAMERAS.iter().map(|c| Camera::new(&mut ros, &format!("/{c}"), "/map/points")).collect();
    let root_pose =
        dds::subscription::<msgs::PoseStamped>(&mut ros, "/angle_i2p/pose", &dds::reliable(10)).expect("sub");
    let diag = dds::subscription::<msgs::DiagnosticArray>(&mut ros, "/diagnostics", &dds::reliable(50)).expect("sub");
    netns::wait_for("the cameras' readers match", &[&log], || cams.iter().all(|c| c.matched(&ros)));
    std::thread::sleep(Duration::from_millis(300));
    // Both "map servers" publish the same map: one map for the node.
    for c in &cams {
        c.map.publish(convert::point_cloud(frames[0].frame.stamp, &map)).expect("map");
    }
    let first = [(&frames[0], frames[0].frame.stamp), (&frames[1], frames[1].frame.stamp)];
    assert_ne!(first[0].1, first[1].1, "the cameras' frames need their own stamps");
    poses_per_camera(&cams, &first, &log);
    assert!(matches!(root_pose.take(), Ok(None)), "a pose on the root /angle_i2p/pose");

    let mut values = BTreeMap::new();
    netns::wait_for("both cameras report a localized frame", &[&log], || {
        while let Ok(Some((d, _))) = diag.take() {
            per_camera(&d, &mut values);
        }
        CAMERAS.iter().all(|c| value(&values, c, "frames_localized") >= 1)
    });
    for c in CAMERAS {
        assert_eq!(value(&values, c, "maps_received"), 1, "{c}: {values:?}");
        assert_eq!(value(&values, c, "maps_indexed"), 1, "{c}: the map is indexed once for both cameras");
    }
    let text = netns::read_log(&log);
    assert_eq!(text.matches("map received:").count(), 1, "{text}");
    assert_eq!(text.matches("map indexed:").count(), 1, "{text}");

    // A new map (one point fewer): taken once, indexed once, both cameras localize on it.
    let mut smaller = map.clone();
    smaller.points.pop();
    cams[0].map.publish(convert::point_cloud(frames[0].frame.stamp, &smaller)).expect("map");
    netns::wait_for("the new map is indexed", &[&log], || {
        while let Ok(Some((d, _))) = diag.take() {
            per_camera(&d, &mut values);
        }
        CAMERAS.iter().all(|c| value(&values, c, "maps_indexed") == 2 && value(&values, c, "maps_received") == 2)
    });
    for c in CAMERAS {
        assert_eq!(value(&values, c, "map_points"), smaller.points.len() as u64, "{c}");
    }
    let later = 1_000_000_000_000;
    let second = [(&frames[1], frames[1].frame.stamp + later), (&frames[0], frames[0].frame.stamp + later)];
    poses_per_camera(&cams, &second, &log);
    let text = netns::read_log(&log);
    assert_eq!(text.matches("map indexed:").count(), 2, "{text}");

    // Each camera has its own relocalize, named as a node of its own in its namespace has it.
    for c in CAMERAS {
        let answer = trigger(&mut ros, &format!("/{c}/angle_i2p/relocalize"), "relocalize", &log);
        assert!(answer.success && answer.message.contains("no initial pose"), "{c}: {answer:?}");
    }
    assert!(!netns::read_log(&log).contains("incompatible"), "{}", netns::read_log(&log));
    mark_done();
}
