//! Building scale from the command line: `synth --preset building` with a chosen map size makes
//! a bag that replays and evaluates as a building (more points than `verify.cull_above_budgets`
//! render budgets: verification culls the map, normals come from the per-voxel trees).

use std::process::Command;

mod common;
use common::{binary, run_ok};

#[test]
fn a_building_bag_replays_and_evaluates() {
    let dir = tempfile::tempdir().unwrap();
    let (bag, out) = (dir.path().join("building"), dir.path().join("out"));
    let made = run_ok(
        Command::new(binary())
            .args(["synth", "--preset", "building", "--frames", "6", "--map-points", "150000", "--seed", "3", "--out"])
            .arg(&bag),
    );
    let points: usize = made
        .split(", ")
        .find_map(|part| part.strip_suffix(" map points"))
        .and_then(|n| n.trim().parse().ok())
        .unwrap_or_else(|| panic!("no map size in {made:?}"));
    assert!((135_000..165_000).contains(&points), "{made}");
    assert!(made.contains("6 frames"), "{made}");
    let text = run_ok(Command::new(binary()).arg("replay").arg(&bag).arg("--out").arg(&out).args([
        "--method",
        "consistency",
        "-p",
        "verify.cull_above_budgets:=5",
    ]));
    assert!(text.contains("6 frames"), "{text}");
    let json = run_ok(Command::new(binary()).arg("eval").arg(&bag).arg("--est").arg(&out).arg("--json"));
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(v["consistency"]["frames"], 6, "{json}");
    assert!(v["consistency"]["RR"].as_f64().unwrap() >= 50.0, "{json}");
}
