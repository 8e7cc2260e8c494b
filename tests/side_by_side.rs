//! The side-by-side benchmark (`scripts/side_by_side.py`, `make side-by-side`) on the shipped bag
//! `bags/synth-hard`: its table has our rows and PoseLib's, its numbers are sane, the PoseLib row
//! is scored with eval's definitions (checked by rescoring our own rows in Python), per-bag
//! parameters reach the replay, and its verdict logic holds on hand-made cases.

use std::path::Path;
use std::process::{Command, Output};

mod common;
use common::{binary, manifest, onnx_runtime, python, skip_or_fail};

fn side_by_side(python: &Path, out: &Path, extra: &[&str]) -> Output {
    Command::new(python)
        .arg(manifest().join("scripts/side_by_side.py"))
        .arg(manifest().join("bags/synth-hard"))
        .arg("--out")
        .arg(out)
        .arg("--binary")
        .arg(binary())
        .args(extra)
        .output()
        .expect("spawn the side-by-side script")
}

fn eval_python() -> Option<std::path::PathBuf> {
    let p = python();
    if p.is_none() {
        skip_or_fail("no Python venv with poselib and rosbags (make py-venv, or set ANGLE_I2P_PYTHON)");
    }
    p
}

fn number(v: &serde_json::Value, key: &str) -> f64 {
    v[key].as_f64().unwrap_or_else(|| panic!("{key} is not a number in {v}"))
}

#[test]
fn ransac_beside_poselib_on_the_shipped_hard_bag() {
    let Some(py) = eval_python() else { return };
    let dir = tempfile::tempdir().unwrap();
    // A --bag-param whose glob matches no bag must not reach the replay (the name is not a parameter).
    let out = side_by_side(
        &py,
        dir.path(),
        &["--methods", "ransac", "--rounds", "2", "--bag-param", "no-such-bag*:bogus.name:=1"],
    );
    let (stdout, stderr) = (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(
        stdout.contains("### synth-hard (hard tier, shared prior; 20 frames; times: per-frame median of 2 rounds)"),
        "{stdout}"
    );
    let row = |label: &str| stdout.lines().find(|l| l.starts_with(&format!("| {label} |"))).map(str::to_owned);
    let poselib_row = row("PoseLib LO-RANSAC (10k it, 8 px)").unwrap_or_else(|| panic!("no PoseLib row:\n{stdout}"));
    let ransac_row = row("ransac").unwrap_or_else(|| panic!("no ransac row:\n{stdout}"));
    assert!(poselib_row.ends_with("| 1.00 | – |"), "{poselib_row}");
    assert!(ransac_row.contains("| PASS |") || ransac_row.contains("| FAIL: "), "{ransac_row}");

    let text = std::fs::read_to_string(dir.path().join("side_by_side.json")).unwrap();
    let doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    let bag = &doc["bags"][0];
    assert_eq!(bag["tier"]["name"], "hard");
    let poselib = &bag["poselib"]["summary"];
    assert_eq!(poselib["frames"], 20, "{poselib}");
    // The hard synthetic tier is within PoseLib's reach: most frames register, with small errors.
    assert!(number(poselib, "RR") >= 80.0, "{poselib}");
    assert!(number(poselib, "MRE") < 5.0 && number(poselib, "MTE") < 0.2, "{poselib}");
    assert!(number(poselib, "median_ms") > 0.0, "{poselib}");
    let poselib_frames = bag["poselib"]["frames"].as_array().unwrap();
    assert!(poselib_frames.iter().all(|f| f["iterations"].as_u64().is_some_and(|i| (100..=10_000).contains(&i))));

    let runs = bag["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 1, "--methods ransac runs ransac only");
    let ransac = &runs[0];
    assert_eq!(ransac["method"], "ransac");
    let (eval, rescored) = (&ransac["eval_summary"], &ransac["rescored"]);
    assert_eq!(eval["frames"], 20);
    assert!(number(eval, "RR") >= 80.0 && number(eval, "median_ms") > 0.0, "{eval}");
    // Our rows rescored by the script's Python metrics equal eval's: PoseLib's row, scored by the
    // same Python, follows eval's definitions.
    assert_eq!(eval["RR"], rescored["RR"], "{eval} vs {rescored}");
    for key in ["MRE", "MTE", "median_ms"] {
        assert!((number(eval, key) - number(rescored, key)).abs() < 1e-6, "{key}: {eval} vs {rescored}");
    }
    let frames = ransac["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 20);
    assert!(frames.iter().all(|f| f["ms"].as_f64().is_some_and(|ms| ms > 0.0) && f.get("failure").is_some()));
    // Two timing rounds: each frame's time is the median (here the mean) of its two, and the
    // table's median is over those.
    let mut per_frame: Vec<f64> = frames
        .iter()
        .map(|f| {
            let rounds: Vec<f64> = f["ms_rounds"].as_array().unwrap().iter().filter_map(|v| v.as_f64()).collect();
            assert_eq!(rounds.len(), 2, "{f}");
            assert!((number(f, "ms") - (rounds[0] + rounds[1]) / 2.0).abs() < 1e-9, "{f}");
            number(f, "ms")
        })
        .collect();
    per_frame.sort_by(f64::total_cmp);
    let median = (per_frame[9] + per_frame[10]) / 2.0;
    assert!((number(&ransac["summary"], "median_ms") - median).abs() < 1e-9, "{}", ransac["summary"]);
    assert_eq!(ransac["summary"]["timing_rounds"], 2);
    assert!(ransac["failed_criteria"].is_array(), "a hard-tier bag gets a verdict");
    assert!(std::fs::read_to_string(dir.path().join("side_by_side.md")).unwrap().contains(&poselib_row));
}

#[test]
fn a_matching_bag_param_reaches_the_replay() {
    let Some(py) = eval_python() else { return };
    let dir = tempfile::tempdir().unwrap();
    // The misspelt parameter fails synth-hard's replay; the next bag is still benchmarked.
    let out = Command::new(&py)
        .arg(manifest().join("scripts/side_by_side.py"))
        .arg(manifest().join("bags/synth-hard"))
        .arg(manifest().join("bags/synth-sift"))
        .arg("--out")
        .arg(dir.path())
        .arg("--binary")
        .arg(binary())
        .args(["--methods", "ransac", "--bag-param", "synth-h*:bogus.name:=1"])
        .output()
        .unwrap();
    let (stdout, stderr) = (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert_eq!(out.status.code(), Some(1), "a failed bag fails the run: {stderr}");
    assert!(stderr.starts_with("error: ") && stderr.contains("bogus.name"), "{stderr}");
    assert!(stdout.contains("### synth-sift (sift tier") && stdout.contains("| ransac |"), "{stdout}");
    let text = std::fs::read_to_string(dir.path().join("side_by_side.json")).unwrap();
    let doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert!(doc["bags"][0]["error"].as_str().is_some_and(|e| e.contains("bogus.name")), "{doc}");
    assert_eq!(doc["bags"][1]["runs"][0]["summary"]["frames"], 20);
    let bad = side_by_side(&py, dir.path(), &["--bag-param", "synth-hard"]);
    assert!(String::from_utf8_lossy(&bad.stderr).contains("expected GLOB:NAME:=VALUE"));
}

/// A `side_by_side.yaml` in the bag directory gives that bag's parameters.
#[test]
fn a_bag_params_file_reaches_the_replay() {
    let Some(py) = eval_python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("synth-hard");
    std::fs::create_dir(&bag).unwrap();
    for entry in std::fs::read_dir(manifest().join("bags/synth-hard")).unwrap() {
        let path = entry.unwrap().path();
        std::fs::copy(&path, bag.join(path.file_name().unwrap())).unwrap();
    }
    let run = |yaml: &str| {
        std::fs::write(bag.join("side_by_side.yaml"), yaml).unwrap();
        Command::new(&py)
            .arg(manifest().join("scripts/side_by_side.py"))
            .arg(&bag)
            .arg("--out")
            .arg(dir.path().join("out"))
            .arg("--binary")
            .arg(binary())
            .args(["--methods", "ransac"])
            .output()
            .unwrap()
    };
    let out = run("params:\n  pnp.max_iterations: 200\n");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(dir.path().join("out/side_by_side.json")).unwrap();
    let doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    let args = &doc["bags"][0]["runs"][0]["replay_args"];
    assert_eq!(args, &serde_json::json!(["--method", "ransac", "-p", "pnp.max_iterations:=200"]));
    let out = run("params:\n  pnp.max_iterations: 200\n  bogus.from_file: true\n");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("bogus.from_file"), "{stderr}");
}

#[test]
fn verdicts_follow_the_issue_criteria() {
    let Some(py) = eval_python() else { return };
    let out = Command::new(py).arg(manifest().join("tests/python/side_by_side_criteria.py")).output().unwrap();
    assert!(
        out.status.success() && String::from_utf8_lossy(&out.stdout).trim() == "ok",
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `--synth PRESET` makes the preset's bag and benchmarks it like a given one.
#[test]
fn a_synth_preset_is_made_and_benchmarked() {
    let Some(py) = eval_python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(&py)
        .arg(manifest().join("scripts/side_by_side.py"))
        .args(["--synth", "sift", "--synth-frames", "3", "--methods", "ransac", "--out"])
        .arg(dir.path())
        .arg("--binary")
        .arg(binary())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("### synth-sift (sift tier, shared prior; 3 frames)"), "{stdout}");
    assert!(dir.path().join("bags/synth-sift/metadata.yaml").exists());
}

/// `--methods default,alone`: the default method tracking (its default) and with frames alone,
/// each its own row (#35).
#[test]
fn tracked_and_frames_alone_are_rows_of_their_own() {
    let Some(py) = eval_python() else { return };
    if onnx_runtime().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(&py)
        .arg(manifest().join("scripts/side_by_side.py"))
        .args(["--synth", "sift", "--synth-frames", "3", "--methods", "default,alone", "--out"])
        .arg(dir.path())
        .arg("--binary")
        .arg(binary())
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(dir.path().join("side_by_side.json")).unwrap();
    let doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    let runs = doc["bags"][0]["runs"].as_array().unwrap();
    assert_eq!(runs[0]["label"], "angle-i2p (default)");
    assert_eq!(runs[0]["replay_args"], serde_json::json!([]));
    assert_eq!(runs[1]["label"], "angle-i2p (frames alone)");
    assert_eq!(runs[1]["replay_args"], serde_json::json!(["-p", "tracking.enabled:=false"]));
}
