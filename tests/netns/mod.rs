//! Running a test body inside a private network namespace (`unshare -rn`, loopback only,
//! multicast on): no packet leaves the test and parallel tests cannot hear each other. The
//! `#[test]` launcher re-runs the test binary inside the namespace with one `#[ignore]`d body
//! selected; without `unshare`/`ip` (or user namespaces) it skips with a printed reason, or
//! fails when `CI` is set.

#![allow(dead_code)]

pub mod camera;

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::common::skip_or_fail;

const IN_NETNS: &str = "ANGLE_I2P_IN_NETNS";
const DONE_MARKER: &str = "ANGLE_I2P_NETNS_DONE";

/// Runs the ignored test `inner` of this binary inside a fresh network namespace.
pub fn run_in_netns(inner: &str) {
    let usable = Command::new("unshare")
        .args(["-rn", "sh", "-c", "ip link set lo up && ip link set lo multicast on"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    if !usable {
        skip_or_fail("cannot make a private network namespace (`unshare -rn` + `ip` unavailable or not permitted)");
        return;
    }
    let exe = std::env::current_exe().expect("test binary path");
    let marker_dir = tempfile::tempdir().expect("tmp");
    let marker = marker_dir.path().join("done");
    let script = "ip link set lo up && ip link set lo multicast on && \
                  (ip route add 224.0.0.0/4 dev lo 2>/dev/null || true) && exec \"$0\" \"$@\"";
    let mut child = Command::new("unshare")
        .args(["-rn", "sh", "-c", script])
        .arg(&exe)
        .args(["--ignored", "--exact", inner, "--nocapture", "--test-threads=1"])
        .env(IN_NETNS, "1")
        .env(DONE_MARKER, &marker)
        .spawn()
        .expect("spawn unshare");
    let status = wait_bounded(&mut child, Duration::from_secs(400)).expect("the namespaced test timed out");
    assert!(status.success(), "{inner} failed inside the network namespace ({status})");
    // `--exact` with a stale name would run nothing and succeed: the body leaves a marker.
    assert!(marker.exists(), "{inner} did not run inside the namespace");
}

/// The start of an inner test: it must run inside the namespace `via` made, on `domain`.
pub fn enter_netns(via: &str, domain: &str) {
    assert!(std::env::var_os(IN_NETNS).is_some(), "run via {via}");
    std::env::set_var("ROS_DOMAIN_ID", domain);
}

/// Called by a namespaced body when it got to its end.
pub fn mark_done() {
    if let Some(p) = std::env::var_os(DONE_MARKER) {
        std::fs::write(p, "ok").expect("marker");
    }
}

pub fn wait_bounded(child: &mut Child, limit: Duration) -> Option<std::process::ExitStatus> {
    let end = Instant::now() + limit;
    loop {
        if let Ok(Some(s)) = child.try_wait() {
            return Some(s);
        }
        if Instant::now() >= end {
            let _ = child.kill();
            let _ = child.wait();
            return None;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Kills a child on drop (a failing assertion never leaves a node running).
pub struct Guard(pub Child);

impl Drop for Guard {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

/// `angle-i2p node --ros-args ARGS` on DDS domain `domain`, its log (stderr) in `log`.
pub fn spawn_node(log: &std::path::Path, args: &[&str], domain: &str) -> Guard {
    let log = std::fs::File::create(log).expect("node log");
    let mut cmd = Command::new(crate::common::binary());
    cmd.arg("node").arg("--ros-args").args(args).env("ROS_DOMAIN_ID", domain).stdout(Stdio::null()).stderr(log);
    Guard(cmd.spawn().expect("spawn angle-i2p node"))
}

/// A node's log so far (empty when it cannot be read).
pub fn read_log(log: &std::path::Path) -> String {
    std::fs::read_to_string(log).unwrap_or_default()
}

/// `fut`, or `None` after `limit` (a plain timer thread: the test has no async runtime).
pub async fn with_timeout<F: std::future::Future>(fut: F, limit: Duration) -> Option<F::Output> {
    let (tx, rx) = futures::channel::oneshot::channel::<()>();
    std::thread::spawn(move || {
        std::thread::sleep(limit);
        let _ = tx.send(());
    });
    futures::pin_mut!(fut);
    match futures::future::select(fut, rx).await {
        futures::future::Either::Left((out, _)) => Some(out),
        futures::future::Either::Right(_) => None,
    }
}

/// Whether `client`'s service appeared within `limit`. ros2-client's `wait_for_service` wakes on
/// graph events and re-reads the match tables only then: a match recorded after the last event
/// it saw leaves it waiting for good. Waiting in one-second slices re-reads the tables each time.
pub fn service_appeared<Q: ros2_client::Message + 'static, A: ros2_client::Message + 'static>(
    client: &ros2_client::Client<Q, A>,
    ros: &ros2_client::Node,
    limit: Duration,
) -> bool {
    let end = Instant::now() + limit;
    while Instant::now() < end {
        let slice = with_timeout(client.wait_for_service(ros), Duration::from_secs(1));
        if futures::executor::block_on(slice).is_some() {
            return true;
        }
    }
    false
}

/// Waits until `ok` (polled every 50 ms), failing after 30 s with the nodes' logs.
pub fn wait_for(what: &str, logs: &[&std::path::Path], mut ok: impl FnMut() -> bool) {
    let end = Instant::now() + Duration::from_secs(30);
    while !ok() {
        assert!(
            Instant::now() < end,
            "{what}: timed out\n{}",
            logs.iter().map(|l| format!("{}:\n{}", l.display(), read_log(l))).collect::<Vec<_>>().join("\n")
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}
