//! The node's parameters as ROS has them: every one declared, live ones applied, others refused.

use super::*;
use crate::params::NodeParams;
use crate::tf_buffer::TfHistory;

fn live(params: &AppParams) -> (LiveParams, LiveTargets) {
    let buffer = Arc::new(Mutex::new(TfHistory::default()));
    let targets = LiveTargets {
        stats: vec![Arc::new(Mutex::new(Stats::default()))],
        broadcast: vec![Arc::new(Mutex::new(TfBroadcast::new(&params.node, buffer)))],
        gate_width: Arc::new(Mutex::new(GateWidth { sigmas: 3.0, min_radius_m: 0.5, min_angle_deg: 15.0 })),
        clock: NodeClock::new(false),
    };
    (LiveParams::new(params.clone(), targets.clone()), targets)
}

fn value_of<'a>(declared: &'a [Parameter], name: &str) -> &'a ParameterValue {
    &declared.iter().find(|p| p.name == name).unwrap_or_else(|| panic!("{name} not declared")).value
}

#[test]
fn every_parameter_is_declared_under_its_dotted_name_with_its_value() {
    let mut params = AppParams::default();
    params.localizer.pnp.threshold_px = 4.5;
    params.node.queue_depth = 7;
    params.node.use_sim_time = true;
    let declared = declared(&params).unwrap();
    let tree = serde_yaml::to_value(&params).unwrap();
    assert_eq!(declared.len(), leaf_keys(&tree).len());
    assert_eq!(value_of(&declared, "pnp.threshold_px"), &ParameterValue::Double(4.5));
    assert_eq!(value_of(&declared, "node.queue_depth"), &ParameterValue::Integer(7));
    assert_eq!(value_of(&declared, "node.tf_mode"), &ParameterValue::String("auto".into()));
    assert_eq!(value_of(&declared, "node.odom_frame"), &ParameterValue::String("odom".into()));
    assert!(
        declared.iter().all(|p| !p.name.starts_with("topics.") && !p.name.ends_with("_topic")),
        "topic names are remapped, not parameters"
    );
    // use_sim_time where ROS tools look for it, not under node.
    assert_eq!(value_of(&declared, "use_sim_time"), &ParameterValue::Boolean(true));
    assert!(declared.iter().all(|p| p.name != "node.use_sim_time"));
    // The camera list is a string array, empty or not (an empty YAML list has no element type).
    assert_eq!(value_of(&declared, "node.cameras"), &ParameterValue::StringArray(vec![]));
    let two = AppParams {
        node: NodeParams { cameras: vec!["cam0".into(), "cam1".into()], ..NodeParams::default() },
        ..AppParams::default()
    };
    let cams = ParameterValue::StringArray(vec!["cam0".into(), "cam1".into()]);
    let two_declared = super::declared(&two).unwrap();
    assert_eq!(value_of(&two_declared, "node.cameras"), &cams);
    assert_eq!(with_value(&AppParams::default(), "node.cameras", &cams).unwrap().node.cameras, two.node.cameras);
    // Each declared value reads back as the same parameters (a `ros2 param dump` is a params file).
    let mut again = AppParams::default();
    for p in &declared {
        again = with_value(&again, &p.name, &p.value).unwrap_or_else(|e| panic!("{}: {e}", p.name));
    }
    assert_eq!(serde_yaml::to_value(&again).unwrap(), tree);
}

#[test]
fn live_parameters_change_and_are_applied_where_they_act() {
    let (live, targets) = live(&AppParams::default());
    assert_eq!(live.apply("node.min_rate_hz", &ParameterValue::Double(5.0)), Ok(true));
    assert_eq!(live.apply("node.min_rate_hz", &ParameterValue::Double(5.0)), Ok(false), "no change the second time");
    assert_eq!(live.apply("node.initialpose_gate_sigmas", &ParameterValue::Double(2.0)), Ok(true));
    assert_eq!(lock(&targets.gate_width).sigmas, 2.0);
    assert_eq!(live.apply("node.transform_tolerance_s", &ParameterValue::Double(0.25)), Ok(true));
    // The new tolerance future-dates the next map → odom.
    let buffer = Arc::new(Mutex::new(TfHistory::default()));
    lock(&buffer)
        .update(&crate::msgs::convert::transform_message(0, "odom", "cam", &nalgebra::Isometry3::identity()), true);
    let mut b =
        TfBroadcast::new(&NodeParams { tf_mode: crate::params::TfMode::MapToOdom, ..NodeParams::default() }, buffer);
    b.set_tolerance_ns(tolerance_ns(0.25));
    let out = b.for_frame(1_000_000_000, "cam", "map", &nalgebra::Isometry3::identity(), true);
    let tf = out.tf.expect("map → odom");
    assert_eq!(crate::msgs::convert::stamp(&tf.transforms[0].header), 1_250_000_000);
    assert_eq!(live.apply("use_sim_time", &ParameterValue::Boolean(true)), Ok(true));
    assert!(targets.clock.uses_sim_time());
}

#[test]
fn other_parameters_are_read_only_and_bad_values_are_refused() {
    let (live, _) = live(&AppParams::default());
    let e = live.check("pnp.threshold_px", &ParameterValue::Double(2.0)).unwrap_err();
    assert_eq!(e, ParamError::ReadOnly { name: "pnp.threshold_px".into() });
    assert!(e.to_string().contains("read-only") && e.to_string().contains("node.min_rate_hz"), "{e}");
    assert!(matches!(live.check("node.queue_depth", &ParameterValue::Integer(9)), Err(ParamError::ReadOnly { .. })));
    // Setting a read-only one to its current value is no change, so not refused.
    assert!(live.check("node.queue_depth", &ParameterValue::Integer(2)).is_ok());
    // Ranges as at start.
    let e = live.check("node.min_rate_hz", &ParameterValue::Double(-1.0)).unwrap_err();
    assert!(matches!(e, ParamError::Rejected { .. }) && e.to_string().contains("node.min_rate_hz"), "{e}");
    // A value of the wrong type.
    let e = live.check("node.min_rate_hz", &ParameterValue::String("fast".into())).unwrap_err();
    assert!(matches!(e, ParamError::Rejected { .. }), "{e}");
    // Nothing applied on a refusal.
    assert!(live.apply("node.min_rate_hz", &ParameterValue::Double(-1.0)).is_err());
    assert_eq!(live.apply("node.min_rate_hz", &ParameterValue::Double(1.0)), Ok(false));
}

/// The model's constants become the current values: `adopt` names what changed, and setting it
/// on the node then passes the read-only check (it changes nothing more).
#[test]
fn the_models_constants_are_adopted_and_then_settable_as_they_are() {
    let params = AppParams::default();
    let (live, _) = live(&params);
    let mut running = params.localizer.clone();
    running.network.missing_confidence = 0.5;
    let changed = live.adopt(&running).expect("adopt");
    assert_eq!(changed.len(), 1, "{changed:?}");
    assert_eq!(changed[0].name, "network.missing_confidence");
    assert_eq!(changed[0].value, ParameterValue::Double(0.5));
    assert!(live.check(&changed[0].name, &changed[0].value).is_ok());
    assert_eq!(live.apply(&changed[0].name, &changed[0].value).ok(), Some(false));
    // Another value is still refused: the parameter is read-only.
    assert!(live.check("network.missing_confidence", &ParameterValue::Double(0.3)).is_err());
    assert!(live.adopt(&running).expect("again").is_empty());
}
