//! The bad-input matrix: one crafted input per class of issue 11, each with its clear outcome —
//! an error naming the file (bag-level damage), a frame skipped or trimmed with its reason while
//! the run goes on (frame-level damage), or a parameter error naming key, value and range.
//! Every case runs the release binary as a user would (`replay`, `eval`, `synth`, `params`) and
//! checks that it ends by itself with exit code 0 or 1: never a panic (101) or a signal. The
//! live node's rows are in `bad_input/live_node.rs`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use angle_i2p::bag::{read_frames, BagWriter, TopicMap};
use angle_i2p::frame::{Frame, MapCloud};
use angle_i2p::msgs::{self, convert};

mod common;
mod netns;
use common::{binary, manifest};

/// The live node under storms and floods (#38), with the same wire.
#[path = "bad_input/live_floods.rs"]
mod live_floods;
/// The live node's rows (over DDS, in a private network namespace).
#[path = "bad_input/live_node.rs"]
mod live_node;

/// The first `n` frames and the map of the shipped hard bag.
fn sample(n: usize) -> (MapCloud, Vec<Frame>) {
    let bag = read_frames(manifest().join("bags/synth-hard"), &TopicMap::default()).unwrap();
    (bag.map.unwrap(), bag.frames.into_iter().take(n).collect())
}

/// Writes one frame's messages in the shipped bags' layout, at `stamp` (log time = max(stamp, 0)).
fn write_frame(w: &mut BagWriter, f: &Frame, stamp: i64) {
    let (t, log, cam, topics) = (stamp, stamp.max(0), f.camera_frame_id.as_str(), TopicMap::default());
    w.write(&topics.camera_info, log, &convert::camera_info(t, cam, &f.intrinsics)).unwrap();
    if let Some(prior) = &f.depth_prior {
        w.write(&topics.depth_prior, log, &convert::image_32fc1(t, cam, prior)).unwrap();
    }
    let corr = convert::correspondences_msg(t, cam, &f.map_frame_id, &f.correspondences);
    w.write(&topics.correspondences, log, &corr).unwrap();
    let gt = f.ground_truth.as_ref().unwrap();
    w.write(&topics.ground_truth_pose, log, &convert::pose_stamped(t, &f.map_frame_id, gt.pose.as_ref().unwrap()))
        .unwrap();
    w.write(&topics.ground_truth_depth, log, &convert::image_16uc1_mm(t, cam, gt.depth.as_ref().unwrap())).unwrap();
}

/// A bag of the sample frames, each changed by `edit` (stamp, frame) first.
fn bag_with(dir: &Path, name: &str, map: &MapCloud, frames: &[Frame], edit: impl Fn(usize, &mut Frame)) -> PathBuf {
    let path = dir.join(name);
    let mut w = BagWriter::create(&path).unwrap();
    w.write("/map/points", 0, &convert::point_cloud(0, map)).unwrap();
    for (k, f) in frames.iter().enumerate() {
        let mut f = f.clone();
        edit(k, &mut f);
        write_frame(&mut w, &f, f.stamp);
    }
    w.finish().unwrap();
    path
}

fn run(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(binary()).args(args).output().expect("spawn")
}

fn replay(bag: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut cmd = Command::new(binary());
    cmd.arg("replay").arg(bag).arg("--out").arg(out).args(["--method", "consistency"]).args(extra);
    cmd.output().expect("spawn")
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

/// Exit code 1 (a clear error), never a panic or a signal, and the message contains `needles`.
fn assert_clear_error(o: &Output, needles: &[&str]) {
    let t = text(o);
    assert_eq!(o.status.code(), Some(1), "expected a clear error, got {:?}: {t}", o.status);
    assert!(!t.contains("panicked"), "{t}");
    for n in needles {
        assert!(t.contains(n), "{n:?} not in: {t}");
    }
}

fn assert_ok_with(o: &Output, needles: &[&str]) -> String {
    let t = text(o);
    assert!(o.status.success(), "{:?}: {t}", o.status);
    for n in needles {
        assert!(t.contains(n), "{n:?} not in: {t}");
    }
    t
}

/// An MCAP file of raw records between the magics, with a ros2 header first.
fn raw_mcap(records: &[(u8, Vec<u8>)]) -> Vec<u8> {
    let string = |s: &str| [(s.len() as u32).to_le_bytes().to_vec(), s.as_bytes().to_vec()].concat();
    let mut out = mcap::MAGIC.to_vec();
    let mut push = |op: u8, body: &[u8]| {
        out.push(op);
        out.extend((body.len() as u64).to_le_bytes());
        out.extend(body);
    };
    push(0x01, &[string("ros2"), string("crafted")].concat());
    for (op, body) in records {
        push(*op, body);
    }
    push(0x0F, &0u32.to_le_bytes());
    push(0x02, &[0u64.to_le_bytes().to_vec(), 0u64.to_le_bytes().to_vec(), 0u32.to_le_bytes().to_vec()].concat());
    out.extend(mcap::MAGIC);
    out
}

/// A chunk record: `inner` as its records, with the given declared sizes.
fn chunk(compression: &str, uncompressed_size: u64, crc: u32, inner: &[u8]) -> (u8, Vec<u8>) {
    let mut b = Vec::new();
    b.extend(1u64.to_le_bytes());
    b.extend(2u64.to_le_bytes());
    b.extend(uncompressed_size.to_le_bytes());
    b.extend(crc.to_le_bytes());
    b.extend((compression.len() as u32).to_le_bytes());
    b.extend(compression.as_bytes());
    b.extend((inner.len() as u64).to_le_bytes());
    b.extend(inner);
    (0x06, b)
}

#[test]
fn absurd_record_and_chunk_lengths_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    for (k, len) in [1u64 << 48, 1 << 63, 4_000_000_000].into_iter().enumerate() {
        // A message record inside an uncompressed chunk declaring `len` bytes.
        let mut inner = vec![0x05];
        inner.extend(len.to_le_bytes());
        inner.extend([0u8; 32]);
        let cases = [
            (format!("inner{k}.mcap"), raw_mcap(&[chunk("", inner.len() as u64, 0, &inner)])),
            (format!("zstd{k}.mcap"), raw_mcap(&[chunk("zstd", len, 1, &[0x28, 0xb5, 0x2f, 0xfd, 0, 0, 0, 0])])),
            (format!("plain{k}.mcap"), raw_mcap(&[(0x05, [len.to_le_bytes().to_vec(), vec![0; 8]].concat())])),
        ];
        for (name, bytes) in cases {
            let path = dir.path().join(&name);
            std::fs::write(&path, bytes).unwrap();
            let start = std::time::Instant::now();
            let o = replay(&path, &dir.path().join(format!("out-{name}")), &[]);
            assert_clear_error(&o, &[&name]);
            assert!(start.elapsed().as_secs() < 30, "{name}: {:?}", start.elapsed());
        }
    }
}

#[test]
fn a_flipped_bit_in_a_chunk_is_an_error_naming_the_file_and_the_chunk() {
    let dir = tempfile::tempdir().unwrap();
    let (map, frames) = sample(3);
    let path = dir.path().join("flipped");
    let mut w = BagWriter::create_with(&path, angle_i2p::bag::ChunkCompression::None).unwrap();
    w.write("/map/points", 0, &convert::point_cloud(0, &map)).unwrap();
    for f in &frames {
        write_frame(&mut w, f, f.stamp);
    }
    w.finish().unwrap();
    let file = path.join("flipped.mcap");
    let mut bytes = std::fs::read(&file).unwrap();
    let at = bytes.len() / 2;
    bytes[at] ^= 0x10;
    std::fs::write(&file, bytes).unwrap();
    let o = replay(&path, &dir.path().join("out"), &[]);
    assert_clear_error(&o, &["flipped.mcap", "CRC mismatch", "chunk ending before byte"]);
    assert!(!dir.path().join("out").exists(), "nothing is written for a damaged bag");
}

#[test]
fn metadata_paths_stay_in_the_bag_and_are_listed_once() {
    let dir = tempfile::tempdir().unwrap();
    let src = manifest().join("bags/synth-hard/synth-hard.mcap");
    for (name, listed) in [
        ("abs", "[/dev/zero]".to_string()),
        ("up", "[../outside.mcap]".to_string()),
        ("twice", "[b.mcap, b.mcap]".to_string()),
        ("twice_dot", "[b.mcap, ./b.mcap]".to_string()),
    ] {
        let bag = dir.path().join(name);
        std::fs::create_dir(&bag).unwrap();
        std::fs::copy(&src, bag.join("b.mcap")).unwrap();
        std::fs::write(
            bag.join("metadata.yaml"),
            format!(
                "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n  relative_file_paths: {listed}\n"
            ),
        )
        .unwrap();
        let o = replay(&bag, &dir.path().join(format!("out-{name}")), &[]);
        assert_clear_error(&o, &["metadata.yaml"]);
    }
    // A storage file given directly must be a regular file.
    let o = replay(Path::new("/dev/zero"), &dir.path().join("out-dev"), &[]);
    assert_clear_error(&o, &["/dev/zero"]);
}

#[test]
fn a_topic_with_the_wrong_type_names_expected_and_found() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("wrong_type");
    let mut w = BagWriter::create(&path).unwrap();
    w.write("/camera/camera_info", 5, &msgs::Header::new(5, "cam")).unwrap();
    w.finish().unwrap();
    let o = replay(&path, &dir.path().join("out"), &[]);
    assert_clear_error(&o, &["/camera/camera_info", "sensor_msgs/msg/CameraInfo", "std_msgs/msg/Header"]);
}

#[test]
fn bad_frames_are_skipped_with_their_reason_and_the_run_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let (map, frames) = sample(6);
    let bag = bag_with(dir.path(), "frames", &map, &frames, |k, f| match k {
        // A CameraInfo of 4e9 × 1 pixels: refused by limits.max_image_side.
        1 => f.intrinsics.width = 4_000_000_000,
        // Every correspondence ten times, and scores far outside [0, 1].
        2 => {
            f.correspondences = f.correspondences.iter().flat_map(|c| std::iter::repeat_n(*c, 10)).collect();
            f.correspondences[0].score = 1e30;
            f.correspondences[1].score = -1e30;
        }
        // Before 1970.
        3 => f.stamp = -5,
        _ => {}
    });
    let out = dir.path().join("out");
    let t = assert_ok_with(
        &replay(&bag, &out, &["-p", "limits.max_correspondences:=150"]),
        &["max_image_side", "exact duplicates merged", "clamped", "kept the best 150", "negative header.stamp -5"],
    );
    assert!(t.contains("4 frames, "), "six frames in, two skipped: {t}");
    assert!(t.contains("2 skipped"), "{t}");
    // eval scores all six frames of the input: the skipped ones are not registered.
    let json = run(&["eval".as_ref(), bag.as_os_str(), "--est".as_ref(), out.as_os_str(), "--json".as_ref()]);
    let v: serde_json::Value = serde_json::from_str(&String::from_utf8_lossy(&json.stdout)).unwrap();
    assert_eq!(v["consistency"]["frames"], 6, "{v}");
    let no_pose = v["consistency"]["no_pose"].as_object().unwrap();
    assert_eq!(no_pose.keys().filter(|k| k.starts_with("skipped")).count(), 2, "{v}");
    assert!(v["consistency"]["RR"].as_f64().unwrap() <= 100.0 * 4.0 / 6.0 + 1e-9, "{v}");
    let table = run(&["eval".as_ref(), bag.as_os_str(), "--est".as_ref(), out.as_os_str()]);
    assert_ok_with(
        &table,
        &["of 6 frames without a pose", "1 skipped: camera_info", "1 skipped: negative header.stamp"],
    );
}

#[test]
fn a_hundred_thousand_correspondences_keep_the_best_five_thousand() {
    let dir = tempfile::tempdir().unwrap();
    let (map, frames) = sample(2);
    let bag = bag_with(dir.path(), "many", &map, &frames, |k, f| {
        if k == 0 {
            let base = f.correspondences.clone();
            f.correspondences = (0..100_000)
                .map(|i| {
                    let mut c = base[i % base.len()];
                    c.pixel.x += (i / base.len()) as f64 * 1e-3;
                    c.score = (i % 997) as f32 / 997.0;
                    c
                })
                .collect();
        }
    });
    let start = std::time::Instant::now();
    assert_ok_with(&replay(&bag, &dir.path().join("out"), &[]), &["kept the best 5000", "2 frames, "]);
    assert!(start.elapsed().as_secs() < 60, "{:?}", start.elapsed());
}

/// A map recorded after the frames is still used for every frame: the first pass takes it.
#[test]
fn a_map_that_comes_last_is_used_for_every_frame() {
    let dir = tempfile::tempdir().unwrap();
    let (map, frames) = sample(3);
    let first = bag_with(dir.path(), "map_first", &map, &frames, |_, _| {});
    let last = dir.path().join("map_last");
    let mut w = BagWriter::create(&last).unwrap();
    for f in &frames {
        write_frame(&mut w, f, f.stamp);
    }
    let t = frames[2].stamp + 1;
    w.write("/map/points", t, &convert::point_cloud(t, &map)).unwrap();
    w.finish().unwrap();
    let mut scores = Vec::new();
    for bag in [&first, &last] {
        let out = dir.path().join(format!("out-{}", bag.file_name().unwrap().to_string_lossy()));
        assert_ok_with(&replay(bag, &out, &[]), &["3 frames, 3 with a pose"]);
        let o = run(&["eval".as_ref(), bag.as_os_str(), "--est".as_ref(), out.as_os_str(), "--json".as_ref()]);
        let v: serde_json::Value = serde_json::from_str(&assert_ok_with(&o, &[])).unwrap();
        scores.push((v["consistency"]["MRE"].clone(), v["consistency"]["MTE"].clone()));
    }
    assert_eq!(scores[0], scores[1], "the same poses whether the map comes first or last");
}

#[test]
fn frames_waiting_for_parts_are_bounded() {
    let dir = tempfile::tempdir().unwrap();
    let (map, frames) = sample(2);
    let path = dir.path().join("waiting");
    let mut w = BagWriter::create(&path).unwrap();
    w.write("/map/points", 0, &convert::point_cloud(0, &map)).unwrap();
    // 50 camera infos whose correspondences never come, then two whole frames.
    for k in 0..50 {
        let t = frames[0].stamp - 1000 + k;
        w.write("/camera/camera_info", t, &convert::camera_info(t, "cam", &frames[0].intrinsics)).unwrap();
    }
    for f in &frames {
        write_frame(&mut w, f, f.stamp);
    }
    w.finish().unwrap();
    let t = assert_ok_with(
        &replay(&path, &dir.path().join("out"), &["-p", "limits.max_pending_frames:=10"]),
        &["more than 10 frames were waiting", "2 frames, ", "50 skipped"],
    );
    assert!(t.contains("missing correspondences"), "{t}");
}

#[test]
fn repeated_stamps_and_late_parts_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let (map, frames) = sample(3);
    let path = dir.path().join("stamps");
    let topics = TopicMap::default();
    let mut w = BagWriter::create(&path).unwrap();
    w.write("/map/points", 0, &convert::point_cloud(0, &map)).unwrap();
    write_frame(&mut w, &frames[0], frames[0].stamp);
    // The second frame again at the first one's stamp.
    write_frame(&mut w, &frames[1], frames[0].stamp);
    write_frame(&mut w, &frames[2], frames[2].stamp);
    // A correspondences message for the first frame, after it completed.
    let f = &frames[0];
    let late = convert::correspondences_msg(f.stamp, &f.camera_frame_id, &f.map_frame_id, &f.correspondences);
    w.write(&topics.correspondences, frames[2].stamp + 1, &late).unwrap();
    w.finish().unwrap();
    let t = assert_ok_with(
        &replay(&path, &dir.path().join("out"), &[]),
        &["repeated stamp", "late part (correspondences)", "2 frames, "],
    );
    assert!(!t.contains("missing camera_info"), "a late part is not a frame missing its camera_info: {t}");
}

#[test]
fn a_map_with_non_finite_points_is_cleaned_and_said() {
    let dir = tempfile::tempdir().unwrap();
    let (mut map, frames) = sample(2);
    for p in map.points.iter_mut().step_by(2) {
        p.x = f32::INFINITY;
    }
    let bag = bag_with(dir.path(), "inf_map", &map, &frames, |_, _| {});
    assert_ok_with(&replay(&bag, &dir.path().join("out"), &[]), &["not finite; dropped", "2 frames, "]);
    for p in map.points.iter_mut() {
        p.y = f32::NAN;
    }
    let bag = bag_with(dir.path(), "nan_map", &map, &frames, |_, _| {});
    assert_ok_with(&replay(&bag, &dir.path().join("out2"), &[]), &["no usable point", "2 frames, "]);
}

#[test]
fn an_empty_ground_truth_depth_is_scored_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let (map, frames) = sample(2);
    let bag = bag_with(dir.path(), "empty_gt", &map, &frames, |k, f| {
        if k == 1 {
            if let Some(gt) = f.ground_truth.as_mut() {
                gt.depth = Some(angle_i2p::geometry::DepthImage::new(0, 0, vec![]));
            }
        }
    });
    let out = dir.path().join("out");
    assert_ok_with(&replay(&bag, &out, &[]), &["2 frames, "]);
    let o = run(&["eval".as_ref(), bag.as_os_str(), "--est".as_ref(), out.as_os_str(), "--json".as_ref()]);
    let t = assert_ok_with(&o, &[]);
    assert!(t.contains("\"frames\": 2"), "{t}");
}

#[test]
fn bad_parameters_stop_the_command_naming_key_value_and_range() {
    for (param, key) in [
        ("pnp.threshold_px:=-1", "pnp.threshold_px"),
        ("pnp.threshold_px:=.nan", "pnp.threshold_px"),
        ("pnp.confidence:=2", "pnp.confidence"),
        ("pnp.max_iterations:=0", "pnp.max_iterations"),
        ("network.tau:=1.5", "network.tau"),
        ("spectral.keep_ratio:=5", "spectral.keep_ratio"),
        ("verify.accept:=2", "verify.accept"),
        ("network.neighbours:=0", "network.neighbours"),
    ] {
        let o = run(&["params".as_ref(), "-p".as_ref(), param.as_ref()]);
        assert_clear_error(&o, &[key, "must be"]);
        let dir = tempfile::tempdir().unwrap();
        let bag = manifest().join("bags/synth-hard");
        assert_clear_error(&replay(&bag, &dir.path().join("o"), &["-p", param]), &[key]);
    }
}

#[test]
fn synth_refuses_a_non_empty_directory_without_force() {
    let dir = tempfile::tempdir().unwrap();
    let keep = dir.path().join("precious.txt");
    std::fs::write(&keep, "keep me").unwrap();
    let args = |force: bool| {
        let mut a: Vec<std::ffi::OsString> =
            vec!["synth".into(), "--frames".into(), "1".into(), "--out".into(), dir.path().into()];
        if force {
            a.push("--force".into());
        }
        a
    };
    let o = Command::new(binary()).args(args(false)).output().unwrap();
    assert_clear_error(&o, &["not empty", "--force"]);
    assert!(keep.exists());
    let o = Command::new(binary()).args(args(true)).output().unwrap();
    assert_ok_with(&o, &["1 frames"]);
    assert!(!keep.exists() && dir.path().join("metadata.yaml").exists());
}
