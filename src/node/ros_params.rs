//! The node's parameters as ROS parameters: every parameter of [`AppParams`] declared under its
//! dotted name (`pnp.threshold_px`, `node.queue_depth`, `node.odom_frame`; `use_sim_time` at the top
//! level, as ROS has it) with its resolved value, served by ros2-client's parameter services,
//! so `ros2 param list/get/dump/describe` work and a dump reads back as a params file.
//!
//! A few can change while the node runs ([`LIVE`]); a write to any other is refused as
//! read-only (it takes effect only at start). A live change is checked as a start-up value is
//! ([`AppParams::validate`]) and then applied where it acts.

use std::sync::{Arc, Mutex};

use ros2_client::parameters::{Parameter, ParameterValue};
use serde_yaml::Value;
use thiserror::Error;

use super::clock::NodeClock;
use super::diagnostics::Stats;
use super::initial_pose::GateWidth;
use super::log::lock;
use super::tf::{tolerance_ns, TfBroadcast};
use crate::params::tree::{deep_merge, dotted, leaf_keys};
use crate::params::AppParams;

/// The parameters that may change while the node runs (ROS names).
pub const LIVE: [&str; 6] = [
    "node.min_rate_hz",
    "node.transform_tolerance_s",
    "node.initialpose_gate_sigmas",
    "node.initialpose_min_radius_m",
    "node.initialpose_min_angle_deg",
    "use_sim_time",
];

/// `use_sim_time`, a node parameter of ours that ROS has at the top level.
const USE_SIM_TIME: &str = "use_sim_time";
const NODE_USE_SIM_TIME: &str = "node.use_sim_time";

/// Why a parameter cannot be declared or set.
#[derive(Debug, Error, PartialEq)]
pub enum ParamError {
    #[error("parameter {name} = {value} has no ROS parameter type")]
    NoRosType { name: String, value: String },
    #[error("parameter {name} is read-only: it takes effect only at start (restart the node with -p {name}:=VALUE); these can change live: {}", LIVE.join(", "))]
    ReadOnly { name: String },
    #[error("parameter {name}: {reason}")]
    Rejected { name: String, reason: String },
}

/// The ROS name of a parameter tree path, and back.
fn ros_name(path: &str) -> &str {
    if path == NODE_USE_SIM_TIME {
        USE_SIM_TIME
    } else {
        path
    }
}

fn tree_path(name: &str) -> &str {
    if name == USE_SIM_TIME {
        NODE_USE_SIM_TIME
    } else {
        name
    }
}

/// A YAML leaf as a ROS parameter value (`None`: no such type, e.g. a mixed sequence).
fn to_parameter_value(v: &Value) -> Option<ParameterValue> {
    Some(match v {
        Value::Bool(b) => ParameterValue::Boolean(*b),
        Value::Number(n) if n.is_f64() => ParameterValue::Double(n.as_f64()?),
        Value::Number(n) => ParameterValue::Integer(n.as_i64()?),
        Value::String(s) => ParameterValue::String(s.clone()),
        Value::Sequence(items) => sequence_value(items)?,
        _ => return None,
    })
}

fn sequence_value(items: &[Value]) -> Option<ParameterValue> {
    if items.is_empty() {
        // No element to tell the type by: the node's one list parameter (`node.cameras`) is of names.
        Some(ParameterValue::StringArray(Vec::new()))
    } else if items.iter().all(Value::is_bool) {
        Some(ParameterValue::BooleanArray(items.iter().filter_map(Value::as_bool).collect()))
    } else if items.iter().all(|v| v.as_i64().is_some()) {
        Some(ParameterValue::IntegerArray(items.iter().filter_map(Value::as_i64).collect()))
    } else if items.iter().all(|v| v.as_f64().is_some()) {
        Some(ParameterValue::DoubleArray(items.iter().filter_map(Value::as_f64).collect()))
    } else if items.iter().all(Value::is_string) {
        Some(ParameterValue::StringArray(items.iter().filter_map(|v| v.as_str().map(str::to_string)).collect()))
    } else {
        None
    }
}

/// A ROS parameter value as YAML (for the parameter tree).
fn to_yaml(v: &ParameterValue) -> Value {
    match v {
        ParameterValue::NotSet => Value::Null,
        ParameterValue::Boolean(b) => Value::Bool(*b),
        ParameterValue::Integer(i) => Value::from(*i),
        ParameterValue::Double(d) => Value::from(*d),
        ParameterValue::String(s) => Value::String(s.clone()),
        ParameterValue::ByteArray(a) => Value::Sequence(a.iter().map(|b| Value::from(*b)).collect()),
        ParameterValue::BooleanArray(a) => Value::Sequence(a.iter().map(|b| Value::Bool(*b)).collect()),
        ParameterValue::IntegerArray(a) => Value::Sequence(a.iter().map(|i| Value::from(*i)).collect()),
        ParameterValue::DoubleArray(a) => Value::Sequence(a.iter().map(|d| Value::from(*d)).collect()),
        ParameterValue::StringArray(a) => Value::Sequence(a.iter().map(|s| Value::String(s.clone())).collect()),
    }
}

/// The leaf at dotted `path` of `tree`.
fn leaf<'a>(tree: &'a Value, path: &str) -> Option<&'a Value> {
    path.split('.').try_fold(tree, |node, key| node.get(key))
}

/// Every parameter of `params` as a ROS parameter, by ROS name.
pub fn declared(params: &AppParams) -> Result<Vec<Parameter>, ParamError> {
    let tree = serde_yaml::to_value(params)
        .map_err(|e| ParamError::Rejected { name: "(all)".into(), reason: e.to_string() })?;
    let mut out = Vec::new();
    for path in leaf_keys(&tree) {
        let v = leaf(&tree, &path).unwrap_or(&Value::Null);
        let value = to_parameter_value(v)
            .ok_or_else(|| ParamError::NoRosType { name: path.clone(), value: format!("{v:?}") })?;
        out.push(Parameter { name: ros_name(&path).to_string(), value });
    }
    Ok(out)
}

/// `params` with the ROS parameter `name` set to `value`, checked as at start.
pub fn with_value(params: &AppParams, name: &str, value: &ParameterValue) -> Result<AppParams, ParamError> {
    let rejected = |reason: String| ParamError::Rejected { name: name.to_string(), reason };
    let mut tree = serde_yaml::to_value(params).map_err(|e| rejected(e.to_string()))?;
    deep_merge(&mut tree, &dotted(tree_path(name), to_yaml(value)));
    let changed: AppParams = serde_yaml::from_value(tree).map_err(|e| rejected(e.to_string()))?;
    changed.validate().map_err(|e| rejected(e.to_string()))?;
    Ok(changed)
}

/// Where the live parameters act (the statistics and TF of every camera).
#[derive(Clone)]
pub struct LiveTargets {
    pub stats: Vec<Arc<Mutex<Stats>>>,
    pub broadcast: Vec<Arc<Mutex<TfBroadcast>>>,
    pub gate_width: Arc<Mutex<GateWidth>>,
    pub clock: NodeClock,
}

/// The node's parameters while it runs: checks writes and applies the live ones.
#[derive(Clone)]
pub struct LiveParams {
    current: Arc<Mutex<AppParams>>,
    targets: LiveTargets,
}

impl LiveParams {
    pub fn new(resolved: AppParams, targets: LiveTargets) -> Self {
        Self { current: Arc::new(Mutex::new(resolved)), targets }
    }

    /// Whether `name` may be set to `value` now (the parameter services' validator).
    pub fn check(&self, name: &str, value: &ParameterValue) -> Result<AppParams, ParamError> {
        let current = lock(&self.current).clone();
        let changed = with_value(&current, name, value)?;
        let same = serde_yaml::to_value(&changed).ok() == serde_yaml::to_value(&current).ok();
        if !same && !LIVE.contains(&name) {
            return Err(ParamError::ReadOnly { name: name.to_string() });
        }
        Ok(changed)
    }

    /// The localizers' parameters as loaded (`running`: the model's constants in place of the
    /// params' `network.*`) become the current ones; the parameters whose value that changed,
    /// to set on the node, so `ros2 param get network.*` says what the model runs with.
    pub fn adopt(&self, running: &crate::params::LocalizerParams) -> Result<Vec<Parameter>, ParamError> {
        let mut current = lock(&self.current);
        let before = declared(&current)?;
        current.localizer = running.clone();
        let after = declared(&current)?;
        let unchanged = |p: &Parameter| before.iter().any(|b| b.name == p.name && b.value == p.value);
        Ok(after.into_iter().filter(|p| !unchanged(p)).collect())
    }

    /// Sets `name` (checked again) and applies it where it acts; true when the value changed.
    pub fn apply(&self, name: &str, value: &ParameterValue) -> Result<bool, ParamError> {
        let changed = self.check(name, value)?;
        if serde_yaml::to_value(&changed).ok() == serde_yaml::to_value(&*lock(&self.current)).ok() {
            return Ok(false);
        }
        let n = &changed.node;
        let t = &self.targets;
        for stats in &t.stats {
            lock(stats).health.set_min_rate_hz(n.min_rate_hz);
        }
        for broadcast in &t.broadcast {
            lock(broadcast).set_tolerance_ns(tolerance_ns(n.transform_tolerance_s));
        }
        *lock(&t.gate_width) = GateWidth {
            sigmas: n.initialpose_gate_sigmas,
            min_radius_m: n.initialpose_min_radius_m,
            min_angle_deg: n.initialpose_min_angle_deg,
        };
        t.clock.set_use_sim_time(n.use_sim_time);
        *lock(&self.current) = changed;
        Ok(true)
    }
}

#[cfg(test)]
#[path = "ros_params_tests.rs"]
mod tests;
