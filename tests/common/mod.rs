//! Helpers shared by the integration tests: where the repo, the shared data and the Python
//! tools are, and how a missing optional resource is handled.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

pub fn manifest() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `../shared/data` (or `$ANGLE_I2P_DATA`) when present.
pub fn shared_data() -> Option<PathBuf> {
    let dir =
        std::env::var_os("ANGLE_I2P_DATA").map(PathBuf::from).unwrap_or_else(|| manifest().join("../shared/data"));
    dir.is_dir().then_some(dir)
}

/// A bag of the shared data, when present.
pub fn shared_bag(name: &str) -> Option<PathBuf> {
    shared_data().map(|d| d.join(name)).filter(|p| p.join("metadata.yaml").exists())
}

/// The Python with the readers and the evaluator's packages (`make py-venv`).
pub fn python() -> Option<PathBuf> {
    let p =
        std::env::var_os("ANGLE_I2P_PYTHON").map(PathBuf::from).unwrap_or_else(|| manifest().join(".venv/bin/python"));
    p.exists().then_some(p)
}

/// A missing optional resource skips a test locally, but fails it in CI (`CI` set), where the
/// setup must have provided it.
pub fn skip_or_fail(reason: &str) {
    if std::env::var_os("CI").is_some() {
        panic!("{reason} (CI is set, so this is a failure)");
    }
    eprintln!("SKIP: {reason}");
}

/// ONNX Runtime's library where the learned rejector looks for it (`make ort`); `None`, after
/// [`skip_or_fail`], when it is missing.
pub fn onnx_runtime() -> Option<PathBuf> {
    let path = angle_i2p::reject::network::runtime_path(&Default::default());
    if path.exists() {
        return Some(path);
    }
    skip_or_fail(&format!("no ONNX Runtime at {} (make ort)", path.display()));
    None
}

/// The release or debug `angle-i2p` binary built for this test run.
pub fn binary() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_angle-i2p"))
}

pub fn run_ok(cmd: &mut std::process::Command) -> String {
    let out = cmd.output().expect("spawn");
    assert!(
        out.status.success(),
        "{cmd:?} failed:\nstdout: {}\nstderr: {}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

pub fn exists(p: &Path) -> bool {
    p.exists()
}
