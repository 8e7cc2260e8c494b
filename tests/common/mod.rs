//! Helpers shared by the integration tests: where the repo, the shared data and the Python
//! tools are, and how a missing optional resource is handled.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

pub fn manifest() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Where `../shared/data` is looked for (`$ANGLE_I2P_DATA` overrides).
fn shared_data_dir() -> PathBuf {
    std::env::var_os("ANGLE_I2P_DATA").map(PathBuf::from).unwrap_or_else(|| manifest().join("../shared/data"))
}

/// `../shared/data` (or `$ANGLE_I2P_DATA`) when present; when absent the calling test's check
/// is recorded as skipped ([`skip`]): the shared data is optional, even in CI.
pub fn shared_data() -> Option<PathBuf> {
    let dir = shared_data_dir();
    if dir.is_dir() {
        return Some(dir);
    }
    skip(&format!("no shared data at {} (set ANGLE_I2P_DATA)", dir.display()));
    None
}

/// A bag of the shared data, when present: skipped (recorded) without the shared data, a
/// failure in CI when the shared data is there but the bag is not.
pub fn shared_bag(name: &str) -> Option<PathBuf> {
    let bag = shared_data()?.join(name);
    if bag.join("metadata.yaml").exists() {
        return Some(bag);
    }
    skip_or_fail(&format!("the shared data has no bag {name}"));
    None
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
    skip(reason);
}

/// The calling test did not run its check: said on stderr and recorded in the run's skip log
/// ([`SKIP_LOG`]), which `make test` prints after the test summary, so a run that checked less
/// says so instead of passing silently.
pub fn skip(reason: &str) {
    let test = std::thread::current().name().unwrap_or("?").to_owned();
    eprintln!("SKIP {test}: {reason}");
    record_skip(&skip_log(), &test, reason);
}

/// The skip log's name in the test run's scratch directory (`make test` empties it first).
pub const SKIP_LOG: &str = "test-skips.log";

pub fn skip_log() -> PathBuf {
    PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(SKIP_LOG)
}

/// Appends `test: reason` to the skip log at `path` (a failure to write is said, not fatal: the
/// log reports, the test's outcome stands).
pub fn record_skip(path: &Path, test: &str, reason: &str) {
    use std::io::Write;
    let line = format!("{test}: {}\n", reason.replace('\n', " "));
    let written =
        std::fs::OpenOptions::new().create(true).append(true).open(path).and_then(|mut f| f.write_all(line.as_bytes()));
    if let Err(e) = written {
        eprintln!("cannot record the skip in {}: {e}", path.display());
    }
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
