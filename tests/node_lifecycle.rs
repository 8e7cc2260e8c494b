//! The node as a managed node (issue 37), over DDS in a private network namespace: started with
//! `node.autostart: false`, driven through `~/change_state` with ros2-client's service client as
//! nav2's lifecycle manager drives it (by id) and `ros2 lifecycle set` does (by label): poses are
//! published only while active, a refused transition changes nothing, cleanup releases what
//! configure made and a second configure makes it again, shutdown ends the process cleanly, and
//! every step is announced on `~/transition_event`.

mod common;
mod netns;

use std::path::Path;
use std::time::{Duration, Instant};

use angle_i2p::frame::Frame;
use angle_i2p::msgs::{self, convert};
use angle_i2p::node::dds;
use angle_i2p::node::lifecycle_msgs::{self as wire, EmptyRequest};
use angle_i2p::node::services::SERVICE_MAPPING;
use netns::camera::{ransac_frames, Camera};
use netns::{enter_netns, mark_done, run_in_netns};
use ros2_client::{Client, Message, Subscription};

const DOMAIN: &str = "25";
const NS: &str = "/lc";
const FQ_NAME: &str = "/lc/angle_i2p";

/// A client of one of the node's lifecycle services, once it has appeared.
fn client<Q, A>(ros: &mut ros2_client::Node, service: &str, type_name: &str, log: &Path) -> Client<Q, A>
where
    Q: Message + Clone + 'static,
    A: Message + 'static,
{
    let qos = dds::reliable(10);
    let name = dds::topic_name(&format!("{FQ_NAME}/{service}")).expect("name");
    let c = ros
        .create_client::<Q, A>(SERVICE_MAPPING, &name, &wire::service_type(type_name), qos.clone(), qos)
        .expect("client");
    let appeared = netns::service_appeared(&c, ros, Duration::from_secs(20));
    assert!(appeared, "~/{service} never appeared\n{}", netns::read_log(log));
    c
}

/// Calls a service whose answer a repeat does not change: a request sent before the server's
/// reply writer has matched this client gets no answer, so an unanswered one is asked again.
fn ask<Q: Message + Clone + 'static, A: Message + 'static>(c: &Client<Q, A>, request: Q, what: &str, log: &Path) -> A {
    let end = Instant::now() + Duration::from_secs(30);
    while Instant::now() < end {
        let call = c.async_call_service(request.clone());
        if let Some(Ok(answer)) = futures::executor::block_on(netns::with_timeout(call, Duration::from_secs(3))) {
            return answer;
        }
    }
    panic!("{what}: no answer in 30 s\n{}", netns::read_log(log))
}

/// The node's lifecycle as a manager sees it.
struct Lifecycle<'a> {
    change: Client<wire::ChangeStateRequest, wire::ChangeStateResponse>,
    get_state: Client<EmptyRequest, wire::GetStateResponse>,
    available: Client<EmptyRequest, wire::GetAvailableTransitionsResponse>,
    events: Subscription<wire::TransitionEvent>,
    /// Every event heard so far: (transition id, start state id, goal state id).
    heard: Vec<(u8, u8, u8)>,
    log: &'a Path,
}

impl<'a> Lifecycle<'a> {
    /// Clients of the node's lifecycle services and a subscription to its transition events.
    fn connect(ros: &mut ros2_client::Node, log: &'a Path) -> Self {
        let qos = dds::reliable(100);
        let name = dds::topic_name(&format!("{FQ_NAME}/transition_event")).expect("name");
        let topic = ros.create_topic(&name, wire::transition_event_type(), &qos).expect("topic");
        let events = ros.create_subscription::<wire::TransitionEvent>(&topic, Some(qos)).expect("sub");
        let lc = Self {
            change: client(ros, "change_state", "ChangeState", log),
            get_state: client(ros, "get_state", "GetState", log),
            available: client(ros, "get_available_transitions", "GetAvailableTransitions", log),
            events,
            heard: Vec::new(),
            log,
        };
        netns::wait_for("the transition events match", &[log], || lc.events.get_publisher_count(ros) > 0);
        std::thread::sleep(Duration::from_millis(500));
        lc
    }

    fn state(&self) -> (u8, String) {
        let s = ask(&self.get_state, EmptyRequest::default(), "~/get_state", self.log).current_state;
        (s.id, s.label)
    }

    fn available(&self) -> Vec<String> {
        let a = ask(&self.available, EmptyRequest::default(), "~/get_available_transitions", self.log);
        a.available_transitions.into_iter().map(|t| t.transition.label).collect()
    }

    /// Asks for transition `id` / `label`; whether it succeeded. Not repeated blindly (a
    /// transition is no idempotent call): an unanswered request is asked again only when the
    /// state shows it was not taken.
    fn change(&mut self, id: u8, label: &str) -> bool {
        let before = self.state();
        let request = wire::ChangeStateRequest { transition: wire::Transition { id, label: label.into() } };
        for _ in 0..5 {
            let call = self.change.async_call_service(request.clone());
            if let Some(Ok(r)) = futures::executor::block_on(netns::with_timeout(call, Duration::from_secs(10))) {
                self.drain_events();
                return r.success;
            }
            if self.state() != before {
                self.drain_events();
                return true;
            }
        }
        panic!("~/change_state {id} {label:?}: no answer\n{}", netns::read_log(self.log))
    }

    /// Takes the events heard (for 200 ms: they are sent before the answer, reliably).
    fn drain_events(&mut self) {
        let end = Instant::now() + Duration::from_millis(200);
        while Instant::now() < end {
            while let Ok(Some((e, _))) = self.events.take() {
                self.heard.push((e.transition.id, e.start_state.id, e.goal_state.id));
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

/// `dropped.inactive` of the node in a diagnostics message (0 when absent).
fn inactive_drops(d: &msgs::DiagnosticArray) -> u64 {
    d.status
        .iter()
        .filter(|s| s.hardware_id == FQ_NAME)
        .flat_map(|s| &s.values)
        .find(|kv| kv.key == "dropped.inactive")
        .and_then(|kv| kv.value.parse().ok())
        .unwrap_or(0)
}

/// Publishes the map until the node has taken one since it was last configured (its log says
/// so; RustDDS may also hand a new reader the map its writer sent before).
fn publish_map_until_taken(cam: &Camera, frame: &Frame, map: &angle_i2p::frame::MapCloud, log: &Path) {
    let taken = || {
        let text = netns::read_log(log);
        text.rsplit("lifecycle: configure → inactive").next().is_some_and(|since| since.contains("map received"))
    };
    let mut next_send = Instant::now();
    netns::wait_for("the node takes the map", &[log], || {
        if Instant::now() >= next_send {
            cam.map.publish(convert::point_cloud(frame.stamp, map)).expect("map");
            next_send = Instant::now() + Duration::from_secs(1);
        }
        taken()
    });
}

/// Sends frames stamped `stamp` until a pose with that stamp comes back.
fn pose_for(cam: &Camera, frame: &Frame, stamp: i64, log: &Path) {
    let mut next_send = Instant::now();
    let mut got = false;
    netns::wait_for("a pose while active", &[log], || {
        if Instant::now() >= next_send {
            cam.publish_frame(frame, stamp);
            next_send = Instant::now() + Duration::from_secs(1);
        }
        while let Ok(Some((p, _))) = cam.pose.take() {
            got |= convert::stamp(&p.header) == stamp;
        }
        got
    });
}

/// Sends new frames (from stamp `first`, 1 ms apart) until the node has dropped one more as
/// `inactive` than it had (diagnostics of the last 600 ms: every 200 ms here); no pose may come
/// back for any of them.
fn dropped_while_inactive(
    cam: &Camera,
    diag: &Subscription<msgs::DiagnosticArray>,
    frame: &Frame,
    first: i64,
    log: &Path,
) {
    let mut before = 0;
    let settled = Instant::now() + Duration::from_millis(600);
    while Instant::now() < settled {
        while let Ok(Some((d, _))) = diag.take() {
            before = before.max(inactive_drops(&d));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let mut now = before;
    let mut sent = Vec::new();
    let mut next_send = Instant::now();
    netns::wait_for("frames dropped as inactive", &[log], || {
        while let Ok(Some((d, _))) = diag.take() {
            now = now.max(inactive_drops(&d));
        }
        if Instant::now() >= next_send {
            let stamp = first + sent.len() as i64 * 1_000_000;
            cam.publish_frame(frame, stamp);
            sent.push(stamp);
            next_send = Instant::now() + Duration::from_millis(500);
        }
        now > before
    });
    std::thread::sleep(Duration::from_millis(500));
    while let Ok(Some((p, _))) = cam.pose.take() {
        assert!(!sent.contains(&convert::stamp(&p.header)), "a pose published while inactive: {:?}", p.header);
    }
}

/// The steps the test takes, as `~/transition_event` announces them: (transition, start, goal).
fn expected_events() -> Vec<(u8, u8, u8)> {
    let configure = [(1, 1, 10), (10, 10, 2)];
    let activate = [(3, 2, 13), (30, 13, 3)];
    let deactivate = [(4, 3, 14), (40, 14, 2)];
    let cleanup = [(2, 2, 11), (20, 11, 1)];
    let shutdown = [(7, 3, 12), (50, 12, 4)];
    [configure, activate, deactivate, activate, deactivate, cleanup, configure, activate, shutdown].concat()
}

#[test]
fn live_lifecycle_managed_over_change_state() {
    run_in_netns("inner_lifecycle_managed_over_change_state");
}

#[test]
#[ignore = "runs inside a network namespace, via live_lifecycle_managed_over_change_state"]
fn inner_lifecycle_managed_over_change_state() {
    enter_netns("live_lifecycle_managed_over_change_state", DOMAIN);
    let (frames, map) = ransac_frames(1);
    let frame = &frames[0].frame;
    let tmp = tempfile::tempdir().expect("tmp");
    let log = tmp.path().join("node.log");
    let args = ["-r", "__ns:=/lc", "-p", "autostart:=false", "-p", "method:=ransac", "-p", "pnp.min_inliers:=6"];
    let mut node = netns::spawn_node(&log, &[&args[..], &["-p", "diagnostics_period_ms:=200"]].concat(), DOMAIN);

    let context = dds::context().expect("context");
    let mut ros = dds::node(&context, "/", "lifecycle_test").expect("node");
    let _spinner = dds::spawn_spinner(&mut ros).expect("spinner");
    let cam = Camera::new(&mut ros, NS, "/lc/map/points");
    let diag = dds::subscription::<msgs::DiagnosticArray>(&mut ros, "/diagnostics", &dds::reliable(50)).expect("sub");
    let mut lc = Lifecycle::connect(&mut ros, &log);

    // Unconfigured: the lifecycle answers, and the node reads and publishes nothing.
    assert_eq!(lc.state(), (1, "unconfigured".to_string()));
    assert_eq!(lc.available(), ["configure", "shutdown"]);
    assert_eq!(cam.info.get_subscription_count(&ros), 0, "a reader before configure");
    assert_eq!(cam.pose.get_publisher_count(&ros), 0, "a pose publisher before configure");

    // configure (by id, as nav2's lifecycle manager asks) → inactive: frames are dropped.
    assert!(lc.change(1, ""), "configure\n{}", netns::read_log(&log));
    assert_eq!(lc.state(), (2, "inactive".to_string()));
    netns::wait_for("the node's readers match", &[&log], || cam.matched(&ros));
    publish_map_until_taken(&cam, frame, &map, &log);
    dropped_while_inactive(&cam, &diag, frame, frame.stamp + 1_000_000_000, &log);

    // activate (by label, as `ros2 lifecycle set` asks) → poses.
    assert!(lc.change(0, "activate"));
    assert_eq!(lc.state(), (3, "active".to_string()));
    pose_for(&cam, frame, frame.stamp + 2_000_000_000, &log);

    // deactivate → silent again; a transition not open from inactive is refused.
    assert!(lc.change(4, ""));
    std::thread::sleep(Duration::from_millis(300));
    while let Ok(Some(_)) = cam.pose.take() {}
    dropped_while_inactive(&cam, &diag, frame, frame.stamp + 3_000_000_000, &log);
    assert!(!lc.change(4, ""), "deactivate from inactive");
    assert_eq!(lc.state(), (2, "inactive".to_string()));

    // activate again → poses again; cleanup is refused while active.
    assert!(lc.change(3, ""));
    pose_for(&cam, frame, frame.stamp + 4_000_000_000, &log);
    assert!(!lc.change(0, "cleanup"), "cleanup from active");
    assert_eq!(lc.state(), (3, "active".to_string()));

    // deactivate, cleanup → unconfigured: the readers go; configure, activate → poses again.
    assert!(lc.change(4, "") && lc.change(2, ""));
    assert_eq!(lc.state(), (1, "unconfigured".to_string()));
    netns::wait_for("cleanup drops the readers", &[&log], || cam.info.get_subscription_count(&ros) == 0);
    assert!(lc.change(1, "") && lc.change(3, ""), "configured again\n{}", netns::read_log(&log));
    netns::wait_for("the node's readers match again", &[&log], || cam.info.get_subscription_count(&ros) > 0);
    publish_map_until_taken(&cam, frame, &map, &log);
    pose_for(&cam, frame, frame.stamp + 5_000_000_000, &log);

    // shutdown → finalized: the answer comes, then the process ends cleanly.
    assert!(lc.change(0, "shutdown"));
    let status = netns::wait_bounded(&mut node.0, Duration::from_secs(20)).expect("the node exits after shutdown");
    assert!(status.success(), "node exit {status}\n{}", netns::read_log(&log));
    lc.drain_events();
    assert_eq!(lc.heard, expected_events(), "transition events");
    mark_done();
}
