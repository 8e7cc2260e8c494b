//! The commands as a user runs them: synth → replay → eval, the evaluator's agreement with the
//! reference Python evaluator, and clear errors for broken input.

use std::process::Command;

mod common;
use common::{binary, manifest, python, run_ok, shared_bag, skip_or_fail};

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
    let Some(bag) = shared_bag("redkitchen-hard-val") else {
        eprintln!("SKIP: ../shared/data/redkitchen-hard-val is absent");
        return;
    };
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
    let ours = &ours["consistency"];
    let theirs: serde_json::Value =
        serde_json::from_str(&run_ok(Command::new(py).arg(&tool).arg(&bag).arg("--est").arg(&out))).unwrap();
    let theirs = &theirs["system under test"];
    for key in ["frames", "IR", "RR", "MRE", "MTE", "MedRE", "MedTE"] {
        let (a, b) = (ours[key].as_f64().unwrap(), theirs[key].as_f64().unwrap());
        // The reference rounds to 3 decimals.
        assert!((a - b).abs() <= 0.0006, "{key}: ours {a}, reference {b}");
    }
}
