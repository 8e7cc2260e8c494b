//! The commands as a user runs them: synth → replay → eval, the evaluator's agreement with the
//! reference Python evaluator, and clear errors for broken input.

use std::process::Command;

mod common;
use common::{binary, manifest, onnx_runtime, python, record_skip, run_ok, shared_bag, skip_or_fail};

#[test]
fn synth_replay_eval_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let (bag, out_r, out_c) = (dir.path().join("in"), dir.path().join("ransac"), dir.path().join("consistency"));
    run_ok(
        Command::new(binary()).args(["synth", "--preset", "hard", "--frames", "4", "--seed", "9", "--out"]).arg(&bag),
    );
    for (m, out) in [("ransac", &out_r), ("consistency", &out_c)] {
        let text = run_ok(Command::new(binary()).arg("replay").arg(&bag).arg("--out").arg(out).args(["--method", m]));
        assert!(text.contains("4 frames"), "{text}");
    }
    let table = run_ok(Command::new(binary()).arg("eval").arg(&bag).arg("--est").arg(&out_r).arg("--est").arg(&out_c));
    assert!(table.contains("ransac") && table.contains("consistency") && table.contains("RR %"), "{table}");
    let json = run_ok(Command::new(binary()).arg("eval").arg(&bag).arg("--est").arg(&out_c).arg("--json"));
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(v["consistency"]["frames"], 4);
    assert!(v["consistency"]["RR"].as_f64().unwrap() >= 50.0, "{json}");
}

/// A kidnapped camera (#35): `synth --preset hard+kidnap` jumps half its path across the room
/// half-way through; replayed as a stream (tracking, the default), the first frame after the
/// jump publishes a correct pose again (within the issue's three frames) and no wrong pose in
/// between, and `eval` finds the jump and says so (text and JSON).
#[test]
fn a_kidnapped_camera_relocalizes_and_eval_measures_it() {
    // With odometry on /tf that does not see the jump (a robot carried away) as well.
    for preset in ["hard+kidnap", "hard+kidnap+odometry"] {
        kidnapped(preset);
    }
}

fn kidnapped(preset: &str) {
    let dir = tempfile::tempdir().unwrap();
    let (bag, out) = (dir.path().join("in"), dir.path().join("out"));
    run_ok(
        Command::new(binary()).args(["synth", "--preset", preset, "--frames", "24", "--seed", "3", "--out"]).arg(&bag),
    );
    let replay = Command::new(binary())
        .arg("replay")
        .arg(&bag)
        .arg("--out")
        .arg(&out)
        .args(["--method", "consistency"])
        .arg("--verbose")
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&replay.stderr);
    assert!(replay.status.success(), "{preset}: {log}");
    assert!(log.contains(", relocalized") && log.contains(", tracking"), "every frame reports its track state:\n{log}");
    let json = run_ok(Command::new(binary()).arg("eval").arg(&bag).arg("--est").arg(&out).arg("--json"));
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    let r = &v["consistency"]["recovery"];
    assert_eq!(r["jumps"], 1, "{preset}: {json}");
    assert!(r["frames_to_recover_max"].as_u64().is_some_and(|n| n <= 3), "{preset}: {json}");
    assert_eq!(
        (r["unrecovered"].as_u64(), r["wrong_while_recovering"].as_u64()),
        (Some(0), Some(0)),
        "{preset}: {json}"
    );
    let text = run_ok(Command::new(binary()).arg("eval").arg(&bag).arg("--est").arg(&out));
    assert!(text.contains("1 jump(s) of the camera: a correct pose again within"), "{preset}: {text}");
}

/// A bag with the robot's odometry on `/tf` (`odom → camera`, drifting as wheel odometry does):
/// replay looks each frame's up at its stamp and tracks with it; with `node.odom_frame` empty it
/// predicts from the poses' motion instead, and the poses do not change on this clean sequence.
#[test]
fn replay_tracks_with_odometry_from_tf() {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("in");
    run_ok(
        Command::new(binary())
            .args(["synth", "--preset", "hard+odometry", "--frames", "12", "--seed", "5", "--out"])
            .arg(&bag),
    );
    let replay = |name: &str, params: &[&str]| {
        let out = dir.path().join(name);
        let run = Command::new(binary())
            .arg("replay")
            .arg(&bag)
            .arg("--out")
            .arg(&out)
            .args(["--method", "consistency", "--verbose"])
            .args(params)
            .output()
            .unwrap();
        let log = String::from_utf8_lossy(&run.stderr).into_owned();
        assert!(run.status.success(), "{log}");
        let eval = run_ok(Command::new(binary()).arg("eval").arg(&bag).arg("--est").arg(&out).arg("--json"));
        (log, serde_json::from_str::<serde_json::Value>(&eval).unwrap())
    };
    let (with_odometry, eval_odometry) = replay("odometry", &[]);
    let frames =
        |log: &str, source: &str| log.lines().filter(|l| l.contains(&format!("(predicted by {source})"))).count();
    // Every frame after the first is predicted from the one before with odometry.
    assert_eq!(frames(&with_odometry, "odometry"), 11, "{with_odometry}");
    assert_eq!(frames(&with_odometry, "motion"), 0, "{with_odometry}");
    let (without, eval_motion) = replay("motion", &["-p", "node.odom_frame:=''"]);
    assert_eq!(frames(&without, "odometry"), 0, "{without}");
    assert!(frames(&without, "motion") >= 10, "{without}");
    assert_eq!(eval_odometry["consistency"]["RR"], 100.0, "{eval_odometry}");
    assert_eq!(eval_odometry["consistency"]["RR"], eval_motion["consistency"]["RR"]);
}

/// Without `--method` replay runs the default, the learned rejector (when ONNX Runtime is there).
#[test]
fn default_method_is_the_learned_rejector() {
    if onnx_runtime().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("default");
    let bag = manifest().join("bags/synth-extreme");
    run_ok(Command::new(binary()).arg("replay").arg(&bag).arg("--out").arg(&out));
    let json = run_ok(Command::new(binary()).arg("eval").arg(&bag).arg("--est").arg(&out).arg("--json"));
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(v["angle-i2p"]["frames"], 20, "{json}");
}

/// Topic names are remapped, not parameters (#36): a bag whose matcher publishes on another
/// topic replays and scores with `-r FROM:=TO` (inputs and outputs alike), and an old params
/// file's `topics.*` is refused with the rule that replaces it.
#[test]
fn a_bags_own_topic_names_are_remapped() {
    use angle_i2p::params::TopicMap;
    use angle_i2p::synth::SynthConfig;
    let dir = tempfile::tempdir().unwrap();
    let (bag, out) = (dir.path().join("in"), dir.path().join("out"));
    let mut config = SynthConfig::preset("hard").unwrap();
    (config.frames, config.seed) = (4, 9);
    let theirs = TopicMap { correspondences: "/their/matches".into(), ..TopicMap::default() };
    angle_i2p::synth::write_bag(&bag, &theirs, &config).unwrap();
    let remaps = ["-r", "/matcher/correspondences:=/their/matches", "-r", "/angle_i2p/pose:=/our/pose"];
    let text = run_ok(
        Command::new(binary()).arg("replay").arg(&bag).arg("--out").arg(&out).args(["--method", "ransac"]).args(remaps),
    );
    assert!(text.contains("4 frames"), "{text}");
    let json = run_ok(Command::new(binary()).arg("eval").arg(&bag).arg("--est").arg(&out).arg("--json").args(remaps));
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(v["ransac"]["frames"], 4, "{json}");
    assert_eq!(v["ransac"]["RR"], 100.0, "{json}");
    // Without the rules the matcher's topic is not there: no frame to localize.
    let plain =
        Command::new(binary()).arg("replay").arg(&bag).arg("--out").arg(dir.path().join("plain")).output().unwrap();
    let said = format!("{}{}", String::from_utf8_lossy(&plain.stdout), String::from_utf8_lossy(&plain.stderr));
    assert!(!said.contains("4 frames"), "{said}");
    let old = dir.path().join("old.yaml");
    std::fs::write(&old, "angle_i2p:\n  ros__parameters:\n    topics:\n      correspondences: /their/matches\n")
        .unwrap();
    let refused = Command::new(binary())
        .arg("replay")
        .arg(&bag)
        .arg("--out")
        .arg(dir.path().join("old"))
        .arg("--params-file")
        .arg(&old)
        .output()
        .unwrap();
    assert!(!refused.status.success());
    let why = String::from_utf8_lossy(&refused.stderr);
    assert!(why.contains("-r matcher/correspondences:=/their/matches"), "{why}");
}

/// `-p NAME:=VALUE` overrides a parameter at any depth; a misspelt name is an error naming it.
#[test]
fn parameter_overrides_apply_and_typos_are_errors() {
    let text =
        run_ok(Command::new(binary()).args(["params", "-p", "network.tau:=0.5", "-p", "pnp.coverage_cell_px:=0"]));
    assert!(text.contains("tau: 0.5") && text.contains("coverage_cell_px: 0.0"), "{text}");
    let out = Command::new(binary()).args(["params", "-p", "network.tauu:=0.5"]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("tauu"));
}

/// The CLI layers its parameters as the node does (one `params::resolve`): a params file with
/// wildcard and dotted sections, then `-p` overrides, flat node keys under `node`; what
/// `params` prints is a params file that gives the same parameters back.
#[test]
fn params_layer_as_in_the_node_and_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("p.yaml");
    std::fs::write(
        &file,
        "/**:\n  ros__parameters:\n    queue_depth: 3\n    pnp.min_inliers: 9\n\
         angle_i2p:\n  ros__parameters:\n    method: ransac\n    pnp: {threshold_px: 5.0}\n",
    )
    .unwrap();
    let text = run_ok(
        Command::new(binary()).arg("params").arg("--params-file").arg(&file).args(["-p", "pnp.min_inliers:=11"]),
    );
    let doc: serde_yaml::Value = serde_yaml::from_str(&text).unwrap();
    let p = &doc["angle_i2p"]["ros__parameters"];
    assert_eq!(p["method"].as_str(), Some("ransac"), "{text}");
    assert_eq!(p["pnp"]["threshold_px"].as_f64(), Some(5.0), "{text}");
    assert_eq!(p["pnp"]["min_inliers"].as_u64(), Some(11), "-p wins over the file: {text}");
    assert_eq!(p["node"]["queue_depth"].as_u64(), Some(3), "a flat node key lands under node: {text}");
    let printed = dir.path().join("printed.yaml");
    std::fs::write(&printed, &text).unwrap();
    let again = run_ok(Command::new(binary()).arg("params").arg("--params-file").arg(&printed));
    assert_eq!(again, text);
    // A value out of range stops the command with its key.
    let out = Command::new(binary()).args(["params", "-p", "queue_depth:=0"]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("node.queue_depth"));
}

#[test]
fn shipped_bags_replay() {
    for tier in ["sift", "hard", "extreme"] {
        let bag = manifest().join("bags").join(format!("synth-{tier}"));
        assert!(bag.join("metadata.yaml").exists(), "{} missing: run `make bags`", bag.display());
        let input = angle_i2p::bag::read_frames(&bag, &Default::default()).unwrap();
        assert_eq!(input.frames.len(), 20);
        assert!(input.incomplete.is_empty() && input.map.is_some());
    }
}

/// On a one-thread rayon pool (a one-CPU machine or container, or `RAYON_NUM_THREADS=1`) replay
/// still finishes: the thread that localizes is the pool's only one, and nothing it waits on may
/// need the pool (indexing the map once deadlocked there).
#[test]
fn replay_finishes_on_a_one_thread_pool() {
    let dir = tempfile::tempdir().unwrap();
    let method = if onnx_runtime().is_some() { "angle-i2p" } else { "consistency" };
    let mut child = Command::new(binary())
        .arg("replay")
        .arg(manifest().join("bags/synth-hard"))
        .arg("--out")
        .arg(dir.path().join("out"))
        .args(["--method", method])
        .env("RAYON_NUM_THREADS", "1")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // A guard against a hang, not a speed check: the replay takes about a second.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if std::time::Instant::now() > deadline {
            child.kill().ok();
            panic!("replay on a one-thread pool did not finish in 120 s (deadlock)");
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    };
    let mut text = String::new();
    std::io::Read::read_to_string(&mut child.stdout.take().unwrap(), &mut text).unwrap();
    assert!(status.success() && text.contains("20 frames, 20 with a pose"), "{text}");
}

#[test]
fn corrupt_input_gives_an_error_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("broken.mcap");
    std::fs::write(&bad, b"\x89MCAP0\r\nthis is not a bag").unwrap();
    let out = Command::new(binary()).arg("replay").arg(&bad).arg("--out").arg(dir.path().join("o")).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("broken.mcap"), "{err}");
}

/// `eval` must agree with `../shared/tools/baseline_opencv.py --est` on the same output bag.
#[test]
fn eval_agrees_with_the_reference_evaluator() {
    let Some(bag) = shared_bag("redkitchen-hard-val") else { return };
    let tool = bag.join("../../tools/baseline_opencv.py");
    let Some(py) = python() else {
        return skip_or_fail("no Python with the evaluator's packages (make py-venv)");
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    run_ok(Command::new(binary()).arg("replay").arg(&bag).arg("--out").arg(&out));
    let ours: serde_json::Value = serde_json::from_str(&run_ok(
        Command::new(binary()).arg("eval").arg(&bag).arg("--est").arg(&out).arg("--json"),
    ))
    .unwrap();
    let ours = ours.as_object().and_then(|o| o.values().next()).expect("one row");
    let theirs: serde_json::Value =
        serde_json::from_str(&run_ok(Command::new(py).arg(&tool).arg(&bag).arg("--est").arg(&out))).unwrap();
    let theirs = &theirs["system under test"];
    for key in ["frames", "IR", "RR", "MRE", "MTE", "MedRE", "MedTE"] {
        let (a, b) = (ours[key].as_f64().unwrap(), theirs[key].as_f64().unwrap());
        // The reference rounds to 3 decimals.
        assert!((a - b).abs() <= 0.0006, "{key}: ours {a}, reference {b}");
    }
}

/// Training samples for the learned rejector: one folder of `.npy` arrays per frame, consistent
/// shapes, labels from the 5 cm rule, readable by numpy.
#[test]
fn export_writes_training_samples_numpy_reads() {
    let dir = tempfile::tempdir().unwrap();
    let (bag, out) = (dir.path().join("in"), dir.path().join("samples"));
    run_ok(
        Command::new(binary()).args(["synth", "--preset", "hard", "--frames", "2", "--seed", "4", "--out"]).arg(&bag),
    );
    let text = run_ok(Command::new(binary()).arg("export").arg(&bag).arg("--out").arg(&out));
    assert!(text.starts_with("2 samples"), "{text}");
    // Beside them, the network.* values they were built with: what a model trained on them carries.
    let constants = std::fs::read_to_string(out.join("model_constants.json")).expect("model_constants.json");
    let constants: serde_json::Value = serde_json::from_str(&constants).expect("JSON");
    assert_eq!((&constants["angle_i2p.format"], &constants["angle_i2p.neighbours"]), (&"1".into(), &"32".into()));
    assert_eq!(constants["angle_i2p.keypoint_ranking"], "spectral_matcher");
    let Some(py) = python() else {
        return skip_or_fail("no Python with numpy (make py-venv)");
    };
    let script = r#"
import glob, sys, numpy as np
frames = sorted(glob.glob(sys.argv[1] + "/*/"))
assert len(frames) == 2, frames
for d in frames:
    a = {k: np.load(d + k + ".npy") for k in ["features", "local_index", "local_theta", "global_index",
         "global_theta", "cross_theta", "spectral", "labels", "correspondences"]}
    n = len(a["labels"])
    v, k = a["local_index"].shape
    m = len(a["global_index"])
    assert a["features"].shape == (n, 24) and a["correspondences"].shape == (n, 6)
    assert a["local_theta"].shape == (v, k, k) and a["global_theta"].shape == (m, m) and a["cross_theta"].shape == (n, m)
    assert k == 32 and m == 100 and a["local_index"].max() < n
    assert set(np.unique(a["labels"])) <= {-1.0, 0.0, 1.0}
    ratio = (a["labels"] == 1).sum() / (a["labels"] >= 0).sum()
    assert 0.1 < ratio < 0.2, ratio
print("ok")
"#;
    let out_text = run_ok(Command::new(py).arg("-c").arg(script).arg(&out));
    assert_eq!(out_text.trim(), "ok");
}

/// A check that did not run is recorded for the summary `make test` prints after the tests
/// (#36): one line per skip, the test's name and the reason, appended across tests.
#[test]
fn a_skipped_check_is_recorded_for_the_summary() {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let log = dir.path().join(common::SKIP_LOG);
    record_skip(&log, "some_test", "no shared data at ../shared/data");
    record_skip(&log, "other_test", "two\nlines");
    let text = std::fs::read_to_string(&log).expect("the skip log");
    assert_eq!(text, "some_test: no shared data at ../shared/data\nother_test: two lines\n");
}

/// SROS2's Enforce mode: DDS security is not built in, so the node refuses to start (rcl refuses
/// too where it cannot secure the node) instead of running unsecured; it stops at once, before
/// any DDS participant exists, naming the variables.
#[test]
fn node_refuses_enforced_security_without_its_enclave() {
    let mut node = Command::new(binary())
        .args(["node", "--ros-args", "--enclave", "/angle_i2p"])
        .env("ROS_SECURITY_ENABLE", "true")
        .env("ROS_SECURITY_STRATEGY", "Enforce")
        .env("ROS_SECURITY_KEYSTORE", "/nonexistent/keystore")
        .env("ROS_DOMAIN_ID", "231")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run node");
    // A node that started after all would run until stopped: give it 20 s, then stop it.
    let end = std::time::Instant::now() + std::time::Duration::from_secs(20);
    while node.try_wait().expect("wait").is_none() && std::time::Instant::now() < end {
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let _ = node.kill();
    let out = node.wait_with_output().expect("node output");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("Enforce") && stderr.contains("refusing to start"), "{stderr}");
    assert!(stderr.contains("/nonexistent/keystore") && stderr.contains("/angle_i2p"), "{stderr}");
}
