//! SROS2 (#37): a node secured with an enclave of a test keystore (`scripts/make_test_keystore.sh`,
//! openssl) localizes what a secured `play` sends and delivers its poses to a secured reader;
//! an unauthenticated player injects nothing (no map, no frame: no pose), and an
//! unauthenticated reader receives no pose. Inside a private network namespace.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

mod common;
mod netns;

use angle_i2p::bag::TopicMap;
use angle_i2p::msgs;
use angle_i2p::node::dds;
use angle_i2p::node::security::SecurityPlan;
use common::{binary, manifest, skip_or_fail};
use netns::{mark_done, run_in_netns, wait_bounded, Guard};

const DOMAIN: &str = "23";
/// Of the shipped bag's 20 frames played, at least this many reach the secured reader as poses.
const MIN_POSES: usize = 18;

#[test]
fn live_sros2_node_serves_only_authenticated_participants() {
    run_in_netns("inner_sros2");
}

/// Security's environment for `enclave` of `keystore`, Enforce mode.
fn secured<'a>(cmd: &'a mut Command, keystore: &Path) -> &'a mut Command {
    cmd.env("ROS_SECURITY_ENABLE", "true")
        .env("ROS_SECURITY_STRATEGY", "Enforce")
        .env("ROS_SECURITY_KEYSTORE", keystore)
}

/// `angle-i2p play` of the shipped bag after the node's frame readers matched (or 20 s).
fn play(keystore: Option<&Path>) -> Command {
    let mut cmd = Command::new(binary());
    cmd.arg("play")
        .arg(manifest().join("bags/synth-hard"))
        .args(["--rate", "0.5", "--wait-timeout", "20", "--linger", "2", "--wait-for", "/matcher/correspondences"])
        .env("ROS_DOMAIN_ID", DOMAIN)
        .stdout(Stdio::null());
    if let Some(keys) = keystore {
        secured(&mut cmd, keys).args(["--enclave", "/player"]);
    }
    cmd
}

/// The poses a subscription holds now.
fn drain(sub: &ros2_client::Subscription<msgs::PoseStamped>) -> usize {
    std::iter::from_fn(|| sub.take().ok().flatten()).count()
}

#[test]
#[ignore = "runs inside a network namespace, via live_sros2_node_serves_only_authenticated_participants"]
fn inner_sros2() {
    netns::enter_netns("live_sros2_node_serves_only_authenticated_participants", DOMAIN);
    let tmp = tempfile::tempdir().expect("tmp");
    let keys = tmp.path().join("keystore");
    let made = Command::new("bash")
        .arg(manifest().join("scripts/make_test_keystore.sh"))
        .arg(&keys)
        .args(["/angle_i2p", "/player", "/reader"])
        .status();
    if !made.is_ok_and(|s| s.success()) {
        skip_or_fail("openssl could not make a test keystore (scripts/make_test_keystore.sh)");
        return;
    }
    let log = std::fs::File::create(tmp.path().join("node.log")).expect("log");
    let mut cmd = Command::new(binary());
    secured(&mut cmd, &keys).args(["node", "--ros-args", "-e", "/angle_i2p"]);
    let mut node = Guard(cmd.env("ROS_DOMAIN_ID", DOMAIN).stdout(Stdio::null()).stderr(log).spawn().expect("node"));
    let node_log = || std::fs::read_to_string(tmp.path().join("node.log")).unwrap_or_default();

    // Readers of the pose: one secured with its own enclave, one not.
    let plan = SecurityPlan::Secured { enclave: "/reader".into(), dir: keys.join("enclaves/reader") };
    let (secured_cx, plain_cx) = (dds::context_for(&plan).expect("secured context"), dds::context().expect("context"));
    let mut secured_node = dds::node(&secured_cx, "/", "secured_reader").expect("node");
    let mut plain_node = dds::node(&plain_cx, "/", "plain_reader").expect("node");
    let _spinners =
        (dds::spawn_spinner(&mut secured_node).expect("spin"), dds::spawn_spinner(&mut plain_node).expect("spin"));
    let pose = TopicMap::default().pose;
    let secured_sub =
        dds::subscription::<msgs::PoseStamped>(&mut secured_node, &pose, &dds::reliable(50)).expect("sub");
    let plain_sub = dds::subscription::<msgs::PoseStamped>(&mut plain_node, &pose, &dds::reliable(50)).expect("sub");

    // An unauthenticated player: the whole bag, map and frames. Nothing of it gets in.
    let mut intruder = Guard(play(None).spawn().expect("play"));
    assert!(wait_bounded(&mut intruder.0, Duration::from_secs(90)).is_some_and(|s| s.success()), "intruder's play");
    std::thread::sleep(Duration::from_secs(2));
    let (after_intruder, plain_early) = (drain(&secured_sub), drain(&plain_sub));
    assert_eq!(after_intruder, 0, "an unauthenticated player's frames were localized\n{}", node_log());

    // The secured player: the node localizes its frames, for the secured reader only.
    let mut player = Guard(play(Some(&keys)).spawn().expect("play"));
    assert!(wait_bounded(&mut player.0, Duration::from_secs(90)).is_some_and(|s| s.success()), "secured play");
    let (mut poses, mut plain) = (0, plain_early);
    let until = Instant::now() + Duration::from_secs(10);
    while Instant::now() < until && poses < 20 {
        std::thread::sleep(Duration::from_millis(200));
        poses += drain(&secured_sub);
        plain += drain(&plain_sub);
    }
    eprintln!("SROS2: secured reader {poses} poses of 20 frames, unauthenticated reader {plain}, after the intruder 0");
    assert!(poses >= MIN_POSES, "{poses} poses reached the secured reader\n{}", node_log());
    assert_eq!(plain, 0, "an unauthenticated reader received poses");
    let _ = Command::new("kill").args(["-INT", &node.0.id().to_string()]).status();
    let status = wait_bounded(&mut node.0, Duration::from_secs(40)).expect("node stops on SIGINT");
    assert!(status.success(), "node exit {status}\n{}", node_log());
    assert!(node_log().contains("secured (SROS2) as enclave \"/angle_i2p\""), "{}", node_log());
    mark_done();
}
