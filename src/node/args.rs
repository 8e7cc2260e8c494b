//! ROS 2 command-line arguments (`--ros-args …`) and parameter resolution for the node.
//!
//! Supported, as `ros2 run` passes them: `-r from:=to` / `--remap from:=to` (topic remaps,
//! `node:from:=to` for this node only, `__ns:=/ns`, `__node:=name`), `-p name:=value` /
//! `--param name:=value` (dotted names for nested parameters, YAML values), `--params-file F`,
//! and `--` (end of the ROS arguments). Anything else is an error naming the argument.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::params::Params;

/// Parameters of the live node only (the localizer's are in [`Params`]). In a params file they
/// sit beside the others under `ros__parameters` (flat, or under a `node:` mapping).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NodeParams {
    /// Frames waiting for the worker; when full, the OLDEST waiting frame is dropped.
    pub queue_depth: usize,
    /// A frame whose parts have not all arrived this long after its first part is handed
    /// out with what it has (or dropped when a required part is missing).
    pub frame_timeout_ms: u64,
    /// Parts whose `header.stamp` differ by at most this are joined into one frame
    /// (0 = exact match, as in bags).
    pub stamp_tolerance_ns: i64,
    /// Broadcast `map → <camera frame>` on `/tf` (or `map → odom_frame`, see there).
    pub publish_tf: bool,
    /// When set, broadcast `map → odom_frame` = (map→camera) · (odom→camera)⁻¹ instead, with
    /// `odom_frame → <camera frame>` (direct, or through one frame) heard on `tf_topic` /
    /// `tf_static_topic`; a frame without it publishes no TF (counted). Empty: off.
    pub odom_frame: String,
    /// Drop frames (counted, reason `no_map`) until a map has arrived.
    pub require_map: bool,
    /// Wait for the depth prior before localizing a frame (only with a rejector that uses it).
    pub expect_depth_prior: bool,
    /// Period of the aggregated `/diagnostics` message.
    pub diagnostics_period_ms: u64,
    /// The recent window the diagnostics levels and topic rates are computed over.
    pub diagnostics_window_s: f64,
    /// Frames (and messages per input) per second below which the diagnostics WARN; 0: never.
    pub min_rate_hz: f64,
    /// Publish `debug_image_topic` (sensor_msgs/Image rgb8): the camera image with kept
    /// correspondences green and rejected ones red. Subscribes to the compressed image topic
    /// (`topics.image`) and to `image_raw_topic` (sensor_msgs/Image rgb8, bgr8, mono8, rgba8,
    /// bgra8), and waits for one of them.
    pub debug_image: bool,
    pub debug_image_topic: String,
    pub image_raw_topic: String,
    /// Output topics that are not in the topic map.
    pub diagnostics_topic: String,
    pub tf_topic: String,
    /// Static transforms, read with `odom_frame` set.
    pub tf_static_topic: String,
    /// Durability of the map subscription (see [`MapQos`]).
    pub map_qos: MapQos,
    /// A PLY or PCD file read as the map at start (ASCII or binary); empty: the map comes only
    /// from `topics.map`. A map on the topic later replaces it.
    pub map_path: String,
    /// The frame of the points in `map_path`.
    pub map_frame_id: String,
    /// geometry_msgs/PoseWithCovarianceStamped of the camera in the map: a gate on the poses
    /// (see [`super::initial_pose`]), `~/relocalize` drops it.
    pub initialpose_topic: String,
    /// The gate's half-width in standard deviations of the initial pose's covariance …
    pub initialpose_gate_sigmas: f64,
    /// … but at least this far (metres) …
    pub initialpose_min_radius_m: f64,
    /// … and this much rotation (degrees).
    pub initialpose_min_angle_deg: f64,
    /// ROS's `use_sim_time`: the node's own stamps (diagnostics) follow `/clock` when true.
    /// Its outputs always carry the input messages' stamps.
    pub use_sim_time: bool,
}

/// How the map topic is subscribed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MapQos {
    /// Both a transient-local reader (a latched map published before the node started) and a
    /// volatile one (a volatile publisher, e.g. `ros2 bag play` of a bag without
    /// `offered_qos_profiles`); the same map heard twice is taken once.
    #[default]
    Auto,
    /// Reliable, transient local: only latched publishers match.
    TransientLocal,
    /// Reliable, volatile: every publisher matches, a map published before the node started is missed.
    Volatile,
}

impl Default for NodeParams {
    fn default() -> Self {
        Self {
            queue_depth: 2,
            frame_timeout_ms: 500,
            stamp_tolerance_ns: 0,
            publish_tf: true,
            odom_frame: String::new(),
            require_map: true,
            expect_depth_prior: true,
            diagnostics_period_ms: 1000,
            diagnostics_window_s: 5.0,
            min_rate_hz: 1.0,
            debug_image: false,
            debug_image_topic: "angle_i2p/debug_image".into(),
            image_raw_topic: "camera/image_raw".into(),
            diagnostics_topic: "/diagnostics".into(),
            tf_topic: "/tf".into(),
            tf_static_topic: "/tf_static".into(),
            map_qos: MapQos::Auto,
            map_path: String::new(),
            map_frame_id: "map".into(),
            initialpose_topic: "initialpose".into(),
            initialpose_gate_sigmas: 3.0,
            initialpose_min_radius_m: 0.5,
            initialpose_min_angle_deg: 15.0,
            use_sim_time: false,
        }
    }
}

/// A topic remap rule; `node` limits it to the node of that name.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Remap {
    pub node: Option<String>,
    pub from: String,
    pub to: String,
}

/// The parsed `--ros-args` section.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RosArgs {
    pub remaps: Vec<Remap>,
    /// `name:=value` parameter overrides in order; `node` set for `node:name:=value`.
    pub params: Vec<(Option<String>, String, String)>,
    pub params_files: Vec<PathBuf>,
    pub namespace: Option<String>,
    pub node_name: Option<String>,
    /// `--log-level LEVEL` (or `--log-level NAME:=LEVEL` for this node's logger).
    pub log_level: Option<LogLevel>,
    /// `-e`/`--enclave`: accepted; DDS security is not built in, so it has no effect (logged).
    pub enclave: Option<String>,
    /// Accepted logging options that have no effect here (e.g. `--disable-rosout-logs`).
    pub ignored: Vec<String>,
}

/// rcutils' severities, lowest first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum LogLevel {
    Debug,
    Info,
    Warn,
    Error,
    Fatal,
}

impl LogLevel {
    fn parse(value: &str) -> Option<Self> {
        Some(match value.to_ascii_lowercase().as_str() {
            "debug" => Self::Debug,
            "info" => Self::Info,
            "warn" | "warning" => Self::Warn,
            "error" => Self::Error,
            "fatal" => Self::Fatal,
            _ => return None,
        })
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ArgsError {
    #[error("ROS arguments must start with --ros-args, got {0:?}")]
    NoRosArgs(String),
    #[error("{flag} needs a value")]
    MissingValue { flag: String },
    #[error("bad {what} {value:?}: expected name:=value")]
    BadRule { what: &'static str, value: String },
    #[error(
        "unknown ROS argument {0:?} (supported: -r/--remap, -p/--param, --params-file, --log-level, -e/--enclave, \
         --log-config-file, --[enable|disable]-{{rosout,stdout,external-lib}}-logs, --)"
    )]
    Unknown(String),
    #[error("bad log level {0:?}: expected debug, info, warn, error or fatal (or NAME:=LEVEL)")]
    BadLogLevel(String),
    #[error("{0}")]
    Params(String),
}

fn split_rule(what: &'static str, rule: &str) -> Result<(Option<String>, String, String), ArgsError> {
    let bad = || ArgsError::BadRule { what, value: rule.to_string() };
    let (lhs, rhs) = rule.split_once(":=").ok_or_else(bad)?;
    if lhs.is_empty() {
        return Err(bad());
    }
    // `node:name` (a node-specific rule); a leading `/` topic cannot contain ':' otherwise.
    let (node, name) = match lhs.split_once(':') {
        Some((n, name)) if !n.is_empty() && !name.is_empty() => (Some(n.to_string()), name.to_string()),
        Some(_) => return Err(bad()),
        None => (None, lhs.to_string()),
    };
    Ok((node, name, rhs.to_string()))
}

impl RosArgs {
    /// Parses the tokens of a `--ros-args` section (the first token must be `--ros-args`;
    /// an empty list is fine). Repeated `--ros-args` sections are allowed.
    pub fn parse<S: AsRef<str>>(tokens: &[S]) -> Result<Self, ArgsError> {
        let mut out = RosArgs::default();
        let mut it = tokens.iter().map(AsRef::as_ref);
        match it.next() {
            None => return Ok(out),
            Some("--ros-args") => {}
            Some(other) => return Err(ArgsError::NoRosArgs(other.to_string())),
        }
        while let Some(tok) = it.next() {
            let mut value =
                |flag: &str| it.next().map(str::to_string).ok_or(ArgsError::MissingValue { flag: flag.into() });
            match tok {
                "--ros-args" => {}
                "--" => break,
                "-r" | "--remap" => {
                    let rule = value(tok)?;
                    let (node, from, to) = split_rule("remap rule", &rule)?;
                    match from.as_str() {
                        "__ns" => out.namespace = Some(to),
                        "__node" | "__name" => out.node_name = Some(to),
                        _ => out.remaps.push(Remap { node, from, to }),
                    }
                }
                "-p" | "--param" => {
                    let rule = value(tok)?;
                    out.params.push(split_rule("parameter", &rule)?);
                }
                "--params-file" => out.params_files.push(PathBuf::from(value(tok)?)),
                "--log-level" => {
                    let v = value(tok)?;
                    // `NAME:=LEVEL` sets one logger; only this node's (or a bare level) counts.
                    let level = v.rsplit_once(":=").map_or(v.as_str(), |(_, l)| l);
                    out.log_level = Some(LogLevel::parse(level).ok_or(ArgsError::BadLogLevel(v.clone()))?);
                }
                "-e" | "--enclave" => out.enclave = Some(value(tok)?),
                "--log-config-file" => out.ignored.push(format!("{tok} {}", value(tok)?)),
                "--enable-rosout-logs"
                | "--disable-rosout-logs"
                | "--enable-stdout-logs"
                | "--disable-stdout-logs"
                | "--enable-external-lib-logs"
                | "--disable-external-lib-logs" => out.ignored.push(tok.to_string()),
                other => return Err(ArgsError::Unknown(other.to_string())),
            }
        }
        Ok(out)
    }
}

/// Node identity and topic name resolution (namespace + remaps), as `rcl` does it for
/// plain names: relative names get the namespace, then the first matching remap wins.
#[derive(Clone, Debug)]
pub struct Names {
    pub node_name: String,
    /// Absolute namespace, `/` for none.
    pub namespace: String,
    remaps: Vec<Remap>,
}

impl Names {
    pub fn new(default_node_name: &str, args: &RosArgs) -> Self {
        let node_name = args.node_name.clone().unwrap_or_else(|| default_node_name.to_string());
        let ns = args.namespace.clone().unwrap_or_else(|| "/".into());
        let namespace = if ns.starts_with('/') { ns } else { format!("/{ns}") };
        let namespace = if namespace.len() > 1 { namespace.trim_end_matches('/').to_string() } else { namespace };
        Self { node_name, namespace, remaps: args.remaps.clone() }
    }

    fn absolute(&self, name: &str) -> String {
        if name.starts_with('/') {
            name.to_string()
        } else if let Some(rest) = name.strip_prefix("~/") {
            format!("{}/{}/{rest}", self.namespace.trim_end_matches('/'), self.node_name)
        } else {
            format!("{}/{name}", self.namespace.trim_end_matches('/'))
        }
    }

    /// The fully resolved topic name of `name`.
    pub fn resolve(&self, name: &str) -> String {
        let full = self.absolute(name);
        for r in &self.remaps {
            if r.node.as_deref().is_some_and(|n| n != self.node_name) {
                continue;
            }
            if self.absolute(&r.from) == full {
                return self.absolute(&r.to);
            }
        }
        full
    }

    /// Fully qualified node name, e.g. `/ns/angle_i2p`.
    pub fn fully_qualified(&self) -> String {
        format!("{}/{}", self.namespace.trim_end_matches('/'), self.node_name)
    }
}

/// Every parameter of the node: the localizer's and the node's own.
#[derive(Clone, Debug)]
pub struct ResolvedParams {
    pub params: Params,
    pub node: NodeParams,
}

/// The `ros__parameters` of this node in a ROS 2 params file: every section whose key matches
/// the node, wildcard ones (`/**`, `/cam0/*`, `/**/angle_i2p`) first, then exact ones (the bare
/// node name, `/name` or the fully qualified name); later sections override earlier ones.
fn params_section(doc: &serde_yaml::Value, names: &Names) -> Option<serde_yaml::Value> {
    let fq = names.fully_qualified();
    let sections = doc.as_mapping()?;
    let mut matching: Vec<(bool, &serde_yaml::Value)> = Vec::new();
    for (key, body) in sections {
        let Some(key) = key.as_str() else { continue };
        let Some(p) = body.get("ros__parameters") else { continue };
        let exact = key == names.node_name || key.trim_start_matches('/') == fq.trim_start_matches('/');
        let wild = key.contains('*') && node_pattern_matches(key, &fq);
        if exact || wild {
            matching.push((exact, p));
        }
    }
    matching.sort_by_key(|(exact, _)| *exact);
    let mut merged: Option<serde_yaml::Value> = None;
    for (_, p) in matching {
        let p = undot(p);
        match &mut merged {
            None => merged = Some(p),
            Some(m) => deep_merge(m, &p),
        }
    }
    merged
}

/// rcl's node-name patterns: `*` matches one name token, `**` any number (also none).
fn node_pattern_matches(pattern: &str, fully_qualified: &str) -> bool {
    fn matches(p: &[&str], n: &[&str]) -> bool {
        match p.split_first() {
            None => n.is_empty(),
            Some((&"**", rest)) => (0..=n.len()).any(|skip| matches(rest, &n[skip..])),
            Some((tok, rest)) => {
                n.split_first().is_some_and(|(first, n_rest)| (*tok == "*" || tok == first) && matches(rest, n_rest))
            }
        }
    }
    let split = |s: &str| -> Vec<String> { s.split('/').filter(|t| !t.is_empty()).map(str::to_string).collect() };
    let (p, n) = (split(pattern), split(fully_qualified));
    let p: Vec<&str> = p.iter().map(String::as_str).collect();
    let n: Vec<&str> = n.iter().map(String::as_str).collect();
    matches(&p, &n)
}

fn deep_merge(base: &mut serde_yaml::Value, over: &serde_yaml::Value) {
    match (base.as_mapping_mut(), over.as_mapping()) {
        (Some(b), Some(o)) => {
            for (k, v) in o {
                match b.get_mut(k) {
                    Some(slot) if slot.is_mapping() && v.is_mapping() => deep_merge(slot, v),
                    _ => {
                        b.insert(k.clone(), v.clone());
                    }
                }
            }
        }
        _ => *base = over.clone(),
    }
}

/// A params-file mapping with dotted keys (`pnp.threshold_px: 4.0`, as rcl accepts and
/// launch_ros writes) turned into nested mappings; nested and dotted forms may mix.
fn undot(value: &serde_yaml::Value) -> serde_yaml::Value {
    let Some(m) = value.as_mapping() else { return value.clone() };
    let mut out = serde_yaml::Value::Mapping(Default::default());
    for (k, v) in m {
        let v = undot(v);
        let entry = match k.as_str() {
            Some(name) if name.contains('.') => dotted(name, v),
            _ => {
                let mut one = serde_yaml::Mapping::new();
                one.insert(k.clone(), v);
                serde_yaml::Value::Mapping(one)
            }
        };
        deep_merge(&mut out, &entry);
    }
    out
}

/// `a.b.c` + value → `{a: {b: {c: value}}}`.
fn dotted(name: &str, value: serde_yaml::Value) -> serde_yaml::Value {
    name.rsplit('.').fold(value, |acc, key| {
        let mut m = serde_yaml::Mapping::new();
        m.insert(key.into(), acc);
        serde_yaml::Value::Mapping(m)
    })
}

const NODE_KEYS: &[&str] = &[
    "queue_depth",
    "frame_timeout_ms",
    "stamp_tolerance_ns",
    "publish_tf",
    "odom_frame",
    "require_map",
    "expect_depth_prior",
    "diagnostics_period_ms",
    "diagnostics_window_s",
    "min_rate_hz",
    "debug_image",
    "debug_image_topic",
    "image_raw_topic",
    "diagnostics_topic",
    "tf_topic",
    "tf_static_topic",
    "map_qos",
    "map_path",
    "map_frame_id",
    "initialpose_topic",
    "initialpose_gate_sigmas",
    "initialpose_min_radius_m",
    "initialpose_min_angle_deg",
    "use_sim_time",
];

/// Resolves parameters: defaults < `params_file` < `--ros-args --params-file` (in order) <
/// `-p name:=value` (in order). Unknown names are errors (typos do not pass silently).
pub fn resolve_params(params_file: Option<&Path>, args: &RosArgs, names: &Names) -> Result<ResolvedParams, ArgsError> {
    let mut overrides = serde_yaml::Value::Mapping(Default::default());
    for path in params_file.into_iter().chain(args.params_files.iter().map(PathBuf::as_path)) {
        let text = std::fs::read_to_string(path)
            .map_err(|e| ArgsError::Params(format!("cannot read params file {}: {e}", path.display())))?;
        let doc: serde_yaml::Value = serde_yaml::from_str(&text)
            .map_err(|e| ArgsError::Params(format!("params file {}: {e}", path.display())))?;
        let section = params_section(&doc, names).ok_or_else(|| {
            ArgsError::Params(format!(
                "params file {}: no `{}:` (or `/**:`) section with `ros__parameters:`",
                path.display(),
                names.node_name
            ))
        })?;
        deep_merge(&mut overrides, &section);
    }
    for (node, name, value) in &args.params {
        if node.as_deref().is_some_and(|n| n != names.node_name) {
            continue;
        }
        let v: serde_yaml::Value =
            serde_yaml::from_str(value).unwrap_or_else(|_| serde_yaml::Value::String(value.clone()));
        deep_merge(&mut overrides, &dotted(name, v));
    }
    // The node's own keys may also be given flat (`-p queue_depth:=4`): move them under `node`.
    if let Some(m) = overrides.as_mapping_mut() {
        let mut flat = serde_yaml::Value::Mapping(Default::default());
        for key in NODE_KEYS {
            if let Some(v) = m.remove(*key) {
                deep_merge(&mut flat, &dotted(key, v));
            }
        }
        if flat.as_mapping().is_some_and(|f| !f.is_empty()) {
            let mut node = m.remove("node").unwrap_or(serde_yaml::Value::Mapping(Default::default()));
            deep_merge(&mut node, &flat);
            m.insert("node".into(), node);
        }
    }
    let mut base = serde_yaml::to_value(Params::default()).map_err(|e| ArgsError::Params(e.to_string()))?;
    deep_merge(&mut base, &overrides);
    let params: Params = serde_yaml::from_value(base).map_err(|e| ArgsError::Params(format!("parameters: {e}")))?;
    params.validate().map_err(|e| ArgsError::Params(e.to_string()))?;
    let node = params.node.clone();
    if !(node.diagnostics_window_s.is_finite() && node.diagnostics_window_s > 0.0) {
        return Err(ArgsError::Params(format!("diagnostics_window_s must be > 0, got {}", node.diagnostics_window_s)));
    }
    if !(node.min_rate_hz.is_finite() && node.min_rate_hz >= 0.0) {
        return Err(ArgsError::Params(format!("min_rate_hz must be >= 0, got {}", node.min_rate_hz)));
    }
    if node.queue_depth == 0 {
        return Err(ArgsError::Params("queue_depth must be at least 1".into()));
    }
    Ok(ResolvedParams { params, node })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::Method;

    #[test]
    fn parses_remaps_params_and_special_names() {
        let a = RosArgs::parse(&[
            "--ros-args",
            "-r",
            "/matcher/correspondences:=/m/c",
            "--remap",
            "other:/x:=/y",
            "-r",
            "__ns:=/robot",
            "-r",
            "__node:=loc",
            "-p",
            "method:=ransac",
            "--params-file",
            "f.yaml",
        ])
        .unwrap();
        assert_eq!(a.remaps.len(), 2);
        assert_eq!(a.remaps[1].node.as_deref(), Some("other"));
        assert_eq!(a.namespace.as_deref(), Some("/robot"));
        assert_eq!(a.node_name.as_deref(), Some("loc"));
        assert_eq!(a.params, vec![(None, "method".into(), "ransac".into())]);
        assert_eq!(a.params_files, vec![PathBuf::from("f.yaml")]);
        assert!(RosArgs::parse(&["--ros-args", "-r"]).is_err());
        assert!(RosArgs::parse(&["--ros-args", "-r", "nope"]).is_err());
        assert!(RosArgs::parse(&["--ros-args", "--bogus"]).is_err());
        assert!(RosArgs::parse(&["-r", "a:=b"]).is_err());
        assert_eq!(RosArgs::parse::<&str>(&[]).unwrap(), RosArgs::default());
    }

    #[test]
    fn names_resolve_with_namespace_and_remaps() {
        let a = RosArgs::parse(&["--ros-args", "-r", "__ns:=/robot", "-r", "pose:=/out/pose", "-r", "other:/tf:=/x"])
            .unwrap();
        let n = Names::new("angle_i2p", &a);
        assert_eq!(n.fully_qualified(), "/robot/angle_i2p");
        assert_eq!(n.resolve("/camera/camera_info"), "/camera/camera_info");
        assert_eq!(n.resolve("image"), "/robot/image");
        assert_eq!(n.resolve("pose"), "/out/pose");
        assert_eq!(n.resolve("/robot/pose"), "/out/pose");
        assert_eq!(n.resolve("/tf"), "/tf");
        assert_eq!(n.resolve("~/debug"), "/robot/angle_i2p/debug");
    }

    #[test]
    fn params_merge_files_and_overrides_and_split_node_keys() {
        let tmp = tempfile::tempdir().unwrap();
        let f = tmp.path().join("p.yaml");
        std::fs::write(
            &f,
            "/**:\n  ros__parameters:\n    queue_depth: 5\nangle_i2p:\n  ros__parameters:\n    method: ransac\n    pnp:\n      min_inliers: 7\n    node:\n      publish_tf: false\n",
        )
        .unwrap();
        let a = RosArgs::parse(&[
            "--ros-args",
            "-p",
            "stamp_tolerance_ns:=1000",
            "-p",
            "topics.pose:=/p",
            "-p",
            "other:seed:=1",
        ])
        .unwrap();
        let names = Names::new("angle_i2p", &a);
        let r = resolve_params(Some(&f), &a, &names).unwrap();
        assert_eq!(r.params.method, Method::Ransac);
        assert_eq!(r.params.pnp.min_inliers, 7);
        assert_eq!(r.params.topics.pose, "/p");
        assert_eq!(r.params.seed, Params::default().seed);
        assert_eq!(r.node.queue_depth, 5);
        assert!(!r.node.publish_tf);
        assert_eq!(r.node.stamp_tolerance_ns, 1000);
        // Typos are errors.
        let bad = RosArgs::parse(&["--ros-args", "-p", "methd:=ransac"]).unwrap();
        assert!(resolve_params(None, &bad, &names).is_err());
        let bad = RosArgs::parse(&["--ros-args", "-p", "queue_depth:=0"]).unwrap();
        assert!(resolve_params(None, &bad, &names).is_err());
        // The shipped params file is accepted as is and holds the node's defaults.
        let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("params/angle_i2p.yaml");
        let r = resolve_params(Some(&shipped), &RosArgs::default(), &names).unwrap();
        assert_eq!(r.node, NodeParams::default());
    }

    #[test]
    fn standard_ros_arguments_are_accepted_or_named() {
        let a = RosArgs::parse(&[
            "--ros-args",
            "--log-level",
            "warn",
            "-e",
            "/cam0",
            "--disable-rosout-logs",
            "--log-level",
            "angle_i2p:=debug",
        ])
        .unwrap();
        assert_eq!(a.log_level, Some(LogLevel::Debug));
        assert_eq!(a.enclave.as_deref(), Some("/cam0"));
        assert_eq!(a.ignored, vec!["--disable-rosout-logs".to_string()]);
        let e = RosArgs::parse(&["--ros-args", "--log-level", "loud"]).unwrap_err();
        assert!(e.to_string().contains("loud"), "{e}");
        let e = RosArgs::parse(&["--ros-args", "--enclave"]).unwrap_err();
        assert!(matches!(e, ArgsError::MissingValue { .. }), "{e}");
    }

    #[test]
    fn params_files_take_dotted_keys_and_wildcards() {
        let tmp = tempfile::tempdir().unwrap();
        let f = tmp.path().join("p.yaml");
        std::fs::write(
            &f,
            "/cam0/*:\n  ros__parameters:\n    pnp.min_inliers: 9\n    queue_depth: 3\n\
             /**/angle_i2p:\n  ros__parameters:\n    node.frame_timeout_ms: 900\n\
             /cam1/**:\n  ros__parameters:\n    queue_depth: 7\n\
             /cam0/angle_i2p:\n  ros__parameters:\n    pnp:\n      threshold_px: 4.0\n    use_sim_time: true\n    map_qos: volatile\n",
        )
        .unwrap();
        let a = RosArgs::parse(&["--ros-args", "-r", "__ns:=/cam0"]).unwrap();
        let r = resolve_params(Some(&f), &a, &Names::new("angle_i2p", &a)).unwrap();
        assert_eq!(r.params.pnp.min_inliers, 9);
        assert_eq!(r.params.pnp.threshold_px, 4.0);
        assert_eq!(r.node.queue_depth, 3);
        assert_eq!(r.node.frame_timeout_ms, 900);
        assert!(r.node.use_sim_time);
        assert_eq!(r.node.map_qos, MapQos::Volatile);
        // In /cam1 only the `/cam1/**` and `/**/angle_i2p` sections apply.
        let a = RosArgs::parse(&["--ros-args", "-r", "__ns:=/cam1"]).unwrap();
        let r = resolve_params(Some(&f), &a, &Names::new("angle_i2p", &a)).unwrap();
        assert_eq!(r.node.queue_depth, 7);
        assert_eq!(r.params.pnp.min_inliers, Params::default().pnp.min_inliers);
        assert_eq!(r.node.frame_timeout_ms, 900);
        // A misspelt dotted key is still an error.
        std::fs::write(&f, "/**:\n  ros__parameters:\n    pnp.treshold_px: 4.0\n").unwrap();
        assert!(resolve_params(Some(&f), &RosArgs::default(), &Names::new("angle_i2p", &RosArgs::default())).is_err());
    }

    #[test]
    fn node_patterns() {
        assert!(node_pattern_matches("/**", "/angle_i2p"));
        assert!(node_pattern_matches("/**", "/a/b/angle_i2p"));
        assert!(node_pattern_matches("/**/angle_i2p", "/angle_i2p"));
        assert!(node_pattern_matches("/*/angle_i2p", "/cam0/angle_i2p"));
        assert!(!node_pattern_matches("/*/angle_i2p", "/angle_i2p"));
        assert!(!node_pattern_matches("/cam0/**", "/cam1/angle_i2p"));
        assert!(!node_pattern_matches("/**/other", "/angle_i2p"));
    }
}
