use super::*;

/// The ids are lifecycle_msgs' (State.msg, Transition.msg): a client compares numbers.
#[test]
fn ids_and_labels_are_lifecycle_msgs_and_rcl_ones() {
    let states: Vec<(u8, &str)> = State::ALL.iter().map(|s| (s.id(), s.label())).collect();
    assert_eq!(
        states,
        [
            (0, "unknown"),
            (1, "unconfigured"),
            (2, "inactive"),
            (3, "active"),
            (4, "finalized"),
            (10, "configuring"),
            (11, "cleaningup"),
            (12, "shuttingdown"),
            (13, "activating"),
            (14, "deactivating"),
            (15, "errorprocessing"),
        ]
    );
    let public: Vec<(u8, &str)> =
        [CONFIGURE, CLEANUP, ACTIVATE, DEACTIVATE, UNCONFIGURED_SHUTDOWN, INACTIVE_SHUTDOWN, ACTIVE_SHUTDOWN]
            .iter()
            .map(|t| (t.id, t.label))
            .collect();
    assert_eq!(
        public,
        [
            (1, "configure"),
            (2, "cleanup"),
            (3, "activate"),
            (4, "deactivate"),
            (5, "shutdown"),
            (6, "shutdown"),
            (7, "shutdown")
        ]
    );
    let internal: Vec<u8> = GRAPH.iter().map(|t| t.id).filter(|&id| id >= 10).collect();
    assert_eq!(internal, [10, 11, 12, 20, 21, 22, 30, 31, 32, 40, 41, 42, 50, 51, 52, 60, 61, 62]);
    assert_eq!([CallbackReturn::Success.id(), CallbackReturn::Failure.id(), CallbackReturn::Error.id()], [97, 98, 99]);
    for s in State::ALL {
        assert_eq!(State::from_id(s.id()), Some(s));
    }
    assert_eq!(State::from_id(5), None);
}

/// Every transition state has exactly a success, a failure and an error way out; every public
/// transition leads into a transition state; finalized is a dead end.
#[test]
fn the_graph_is_rcl_lifecycles_default_one() {
    for s in State::ALL.into_iter().filter(|s| !s.is_primary()) {
        let mut labels: Vec<&str> = GRAPH.iter().filter(|t| t.start == s).map(|t| t.label).collect();
        labels.sort_unstable();
        assert_eq!(labels, ["transition_error", "transition_failure", "transition_success"], "{s}");
    }
    for t in GRAPH.iter().filter(|t| t.start.is_primary()) {
        assert!(!t.goal.is_primary(), "{t:?}");
        assert!(t.id < 10, "{t:?}");
    }
    assert!(GRAPH.iter().all(|t| t.start != State::Finalized && t.start != State::Unknown));
    let open = |s: State| -> Vec<&str> {
        let l = Lifecycle { current: s };
        l.available().iter().map(|t| t.label).collect()
    };
    assert_eq!(open(State::Unconfigured), ["configure", "shutdown"]);
    assert_eq!(open(State::Inactive), ["cleanup", "activate", "shutdown"]);
    assert_eq!(open(State::Active), ["deactivate", "shutdown"]);
    assert!(open(State::Finalized).is_empty());
}

/// Runs `transition` with a callback that returned `result`; the steps taken.
fn change(l: &mut Lifecycle, transition: Transition, result: CallbackReturn) -> Vec<(u8, State, State)> {
    let first = l.begin(transition).expect("open from here");
    let second = l.finish(result).expect("in a transition state");
    [first, second].iter().map(|t| (t.id, t.start, t.goal)).collect()
}

/// The way nav2's lifecycle manager drives a node: configure, activate, deactivate, activate,
/// deactivate, cleanup, shutdown; each change in two steps.
#[test]
fn a_managers_round_trip() {
    use CallbackReturn::Success;
    use State::*;
    let mut l = Lifecycle::default();
    assert_eq!(l.current(), Unconfigured);
    assert_eq!(change(&mut l, CONFIGURE, Success), [(1, Unconfigured, Configuring), (10, Configuring, Inactive)]);
    assert_eq!(change(&mut l, ACTIVATE, Success), [(3, Inactive, Activating), (30, Activating, Active)]);
    assert_eq!(change(&mut l, DEACTIVATE, Success), [(4, Active, Deactivating), (40, Deactivating, Inactive)]);
    assert_eq!(change(&mut l, ACTIVATE, Success), [(3, Inactive, Activating), (30, Activating, Active)]);
    change(&mut l, DEACTIVATE, Success);
    assert_eq!(change(&mut l, CLEANUP, Success), [(2, Inactive, CleaningUp), (20, CleaningUp, Unconfigured)]);
    let shutdown = l.resolve(0, "shutdown").expect("shutdown from unconfigured");
    assert_eq!(shutdown, UNCONFIGURED_SHUTDOWN);
    assert_eq!(change(&mut l, shutdown, Success), [(5, Unconfigured, ShuttingDown), (50, ShuttingDown, Finalized)]);
    assert!(l.available().is_empty());
    assert_eq!(l.resolve(1, ""), Err(LifecycleError::NotAvailable { id: 1, state: Finalized }));
}

/// A failed callback goes back where it came from; an error goes through errorprocessing.
#[test]
fn failures_go_back_and_errors_are_processed() {
    use CallbackReturn::*;
    use State::*;
    let mut l = Lifecycle::default();
    assert_eq!(change(&mut l, CONFIGURE, Failure), [(1, Unconfigured, Configuring), (11, Configuring, Unconfigured)]);
    change(&mut l, CONFIGURE, Success);
    assert_eq!(change(&mut l, ACTIVATE, Failure)[1], (31, Activating, Inactive));
    change(&mut l, ACTIVATE, Success);
    assert_eq!(change(&mut l, DEACTIVATE, Failure)[1], (41, Deactivating, Active));
    assert_eq!(change(&mut l, DEACTIVATE, Error)[1], (42, Deactivating, ErrorProcessing));
    assert_eq!(l.finish(Success).map(|t| (t.id, t.goal)), Ok((60, Unconfigured)));
    change(&mut l, CONFIGURE, Error);
    assert_eq!(l.finish(Failure).map(|t| (t.id, t.goal)), Ok((61, Finalized)));
    let mut l = Lifecycle { current: ShuttingDown };
    assert_eq!(l.finish(Failure).map(|t| (t.id, t.goal)), Ok((51, Finalized)), "shutdown finalizes even when it fails");
}

/// rclcpp's reading of a request: the label wins over the id; an id or label not open from the
/// current state is refused, and nothing changes.
#[test]
fn requests_are_resolved_from_the_current_state() {
    let mut l = Lifecycle::default();
    assert_eq!(l.resolve(1, ""), Ok(CONFIGURE));
    assert_eq!(l.resolve(99, "configure"), Ok(CONFIGURE), "the label wins");
    assert_eq!(l.resolve(3, ""), Err(LifecycleError::NotAvailable { id: 3, state: State::Unconfigured }));
    assert_eq!(
        l.resolve(0, "activate"),
        Err(LifecycleError::NoSuchLabel { label: "activate".into(), state: State::Unconfigured })
    );
    assert_eq!(l.resolve(10, ""), Err(LifecycleError::NotAvailable { id: 10, state: State::Unconfigured }));
    assert_eq!(l.resolve(6, ""), Err(LifecycleError::NotAvailable { id: 6, state: State::Unconfigured }));
    assert!(l.begin(ACTIVATE).is_err());
    assert!(l.finish(CallbackReturn::Success).is_err(), "nothing to finish in a primary state");
    assert_eq!(l.current(), State::Unconfigured);
    l.begin(CONFIGURE).expect("configure");
    assert!(l.begin(CONFIGURE).is_err(), "one transition at a time");
    assert_eq!(l.resolve(0, "transition_success").map(|t| t.id), Ok(10));
    l.finish(CallbackReturn::Success).expect("configured");
    assert_eq!(l.resolve(0, "shutdown"), Ok(INACTIVE_SHUTDOWN));
    assert_eq!(l.resolve(6, ""), Ok(INACTIVE_SHUTDOWN));
    assert_eq!(l.resolve(7, ""), Err(LifecycleError::NotAvailable { id: 7, state: State::Inactive }));
    let internal = GRAPH[1];
    assert!(l.begin(internal).is_err(), "an internal transition cannot be begun");
}

#[test]
fn activity_is_shared() {
    let a = Activity::default();
    let b = a.clone();
    assert!(!b.is_active());
    a.set(true);
    assert!(b.is_active());
}
