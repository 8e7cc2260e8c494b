//! One resolution of the parameters for the CLI and the node alike. Layers, later ones
//! winning: defaults < the command's params file < `--ros-args --params-file` (in order) <
//! `-p name:=value` (in order). Unknown names are errors (typos do not pass silently), and the
//! result is validated ([`super::validate`]) before anyone uses it.

use std::path::{Path, PathBuf};

use serde_yaml::Value;

use super::ros_args::{ArgsError, Names, RosArgs, DEFAULT_NODE_NAME};
use super::tree::{deep_merge, dotted, undot};
use super::validate::InvalidParam;
use super::{AppParams, NodeParams, TopicMap};
use crate::reject::network_params::ModelConstant;

/// Where the parameters come from, lowest first (the defaults are below them all).
#[derive(Clone, Copy, Debug)]
pub struct Layers<'a> {
    /// The node's name and namespace: which sections of a params file and which
    /// `node:name:=value` overrides apply.
    pub names: &'a Names,
    /// The command's own `--params-file`, applied before the ROS arguments'.
    pub params_file: Option<&'a Path>,
    /// `--ros-args`: its params files, then its `-p` overrides.
    pub ros_args: &'a RosArgs,
}

/// Why the parameters could not be resolved.
#[derive(Debug, thiserror::Error)]
pub enum ResolveError {
    #[error("cannot read params file {}: {source}", path.display())]
    Read { path: PathBuf, source: std::io::Error },
    #[error("params file {}: {message}", path.display())]
    Parse { path: PathBuf, message: String },
    #[error("params file {}: no `{node_name}:` (or `/**:`) section with `ros__parameters:`", path.display())]
    NoSection { path: PathBuf, node_name: String },
    #[error("parameters: unknown parameter `{name}`, expected one of {}", expected.join(", "))]
    Unknown { name: String, expected: Vec<String> },
    /// A parameter an earlier version had, and what became of it.
    #[error("parameters: `{name}` is no parameter any more: {why}; remove it from the params file")]
    Retired { name: String, why: &'static str },
    /// A topic name earlier versions had as a parameter: remapping renames topics now.
    #[error(
        "parameters: `{name}` is no parameter any more: topics are renamed by remapping, as for every ROS node — \
         `-r {rule}` (after `node --ros-args`, or given to replay, eval and export); remove it from the params file"
    )]
    TopicRenamed { name: String, rule: String },
    /// A value of the wrong type, as serde words it.
    #[error("parameters: {message}")]
    Rejected { message: String },
    #[error(transparent)]
    Invalid(#[from] InvalidParam),
    #[error(transparent)]
    Args(#[from] ArgsError),
}

/// The parameters of `layers` over the defaults, validated.
pub fn resolve(layers: &Layers) -> Result<AppParams, ResolveError> {
    let mut overrides = Value::Mapping(Default::default());
    let files = layers.params_file.into_iter().chain(layers.ros_args.params_files.iter().map(PathBuf::as_path));
    for path in files {
        deep_merge(&mut overrides, &file_layer(path, layers.names)?);
    }
    deep_merge(&mut overrides, &override_layer(layers.ros_args, layers.names));
    nest_flat_node_keys(&mut overrides);
    refuse_topic_names(&overrides)?;
    let rejected = |e: serde_yaml::Error| ResolveError::Rejected { message: e.to_string() };
    let mut tree = serde_yaml::to_value(AppParams::default()).map_err(rejected)?;
    check_names("", &overrides, &tree)?;
    deep_merge(&mut tree, &overrides);
    let mut params: AppParams = serde_yaml::from_value(tree).map_err(rejected)?;
    // Which model constants a layer set: those are held against the model's metadata at load.
    params.localizer.network.given = ModelConstant::given_in(overrides.get("network"));
    params.topics = TopicMap::remapped(layers.names);
    params.validate()?;
    Ok(params)
}

/// Topic-name parameters of earlier versions (`topics.KEY`, `node.*_topic`), each with the
/// topic it named ([`TopicMap::remap_rule`]'s key).
const TOPIC_PARAMETERS: [(&str, &str); 7] = [
    ("image_raw_topic", "image_raw"),
    ("debug_image_topic", "debug_image"),
    ("base_pose_topic", "base_pose"),
    ("initialpose_topic", "initial_pose"),
    ("diagnostics_topic", "diagnostics"),
    ("tf_topic", "tf"),
    ("tf_static_topic", "tf_static"),
];

/// An old params file's topic name (`topics.*`, `node.*_topic`, flat or not): refused with the
/// remap rule that replaces it. The rule's FROM is relative where the node's name is, so it
/// also holds under a namespace.
fn refuse_topic_names(overrides: &Value) -> Result<(), ResolveError> {
    let text = |v: &Value| v.as_str().map_or_else(|| format!("{v:?}"), str::to_string);
    let mut found: Vec<(String, String, String)> = Vec::new();
    if let Some(topics) = overrides.get("topics") {
        let Some(map) = topics.as_mapping().filter(|m| !m.is_empty()) else {
            return Err(ResolveError::Retired {
                name: "topics".into(),
                why: "topics are renamed by remapping (`-r FROM:=TO`)",
            });
        };
        found.extend(map.iter().map(|(k, v)| (format!("topics.{}", text(k)), text(k), text(v))));
    }
    for (old, key) in TOPIC_PARAMETERS {
        for (name, value) in [
            (format!("node.{old}"), overrides.get("node").and_then(|n| n.get(old))),
            (old.to_string(), overrides.get(old)),
        ] {
            if let Some(v) = value {
                found.push((name, key.to_string(), text(v)));
            }
        }
    }
    let Some((name, key, to)) = found.into_iter().next() else { return Ok(()) };
    match TopicMap::relative().remap_rule(&key, &to) {
        Some(rule) => Err(ResolveError::TopicRenamed { name, rule }),
        None => Err(ResolveError::Unknown { name, expected: vec![] }),
    }
}

/// The CLI's parameters: its `--params-file` and `-p NAME:=VALUE` overrides, resolved as the
/// node (named [`DEFAULT_NODE_NAME`], no namespace) resolves its own.
pub fn resolve_cli<S: AsRef<str>>(params_file: Option<&Path>, overrides: &[S]) -> Result<AppParams, ResolveError> {
    resolve_command(params_file, overrides, &[] as &[&str])
}

/// A bag command's parameters: [`resolve_cli`]'s, with its `-r FROM:=TO` remaps renaming the
/// topics it reads and writes ([`AppParams::topics`]).
pub fn resolve_command<S: AsRef<str>, R: AsRef<str>>(
    params_file: Option<&Path>,
    overrides: &[S],
    remaps: &[R],
) -> Result<AppParams, ResolveError> {
    let ros_args = RosArgs::from_cli(overrides, remaps)?;
    let names = Names::new(DEFAULT_NODE_NAME, &ros_args);
    resolve(&Layers { names: &names, params_file, ros_args: &ros_args })
}

/// Parameters earlier versions had, and why they went: an old params file that sets one fails
/// with this reason rather than a bare "unknown parameter".
const RETIRED: [(&str, &str); 1] = [(
    "final_refine.ranked_iterations",
    "the search over every match in the rejector's order went with the two-pass frame path (#34); \
     the plain search over every match confirms an unsure pose instead",
)];

/// Every name in `overrides` must name a parameter of `defaults` (down to where the defaults
/// stop being mappings: below that, the value is the type's to judge).
fn check_names(prefix: &str, overrides: &Value, defaults: &Value) -> Result<(), ResolveError> {
    let (Some(over), Some(known)) = (overrides.as_mapping(), defaults.as_mapping()) else { return Ok(()) };
    for (key, value) in over {
        let name = key.as_str().map_or_else(|| format!("{key:?}"), str::to_string);
        let full = if prefix.is_empty() { name } else { format!("{prefix}.{name}") };
        match known.get(key) {
            Some(default) => check_names(&full, value, default)?,
            None => {
                if let Some((_, why)) = RETIRED.iter().find(|(retired, _)| *retired == full) {
                    return Err(ResolveError::Retired { name: full, why });
                }
                let expected = known.keys().filter_map(|k| k.as_str().map(str::to_string)).collect();
                return Err(ResolveError::Unknown { name: full, expected });
            }
        }
    }
    Ok(())
}

/// This node's parameters in one params file.
fn file_layer(path: &Path, names: &Names) -> Result<Value, ResolveError> {
    let text = std::fs::read_to_string(path).map_err(|source| ResolveError::Read { path: path.into(), source })?;
    let doc: Value =
        serde_yaml::from_str(&text).map_err(|e| ResolveError::Parse { path: path.into(), message: e.to_string() })?;
    params_section(&doc, names)
        .ok_or_else(|| ResolveError::NoSection { path: path.into(), node_name: names.node_name.clone() })
}

/// The `-p` overrides that apply to this node, as one tree; a value that is not YAML is a string.
fn override_layer(args: &RosArgs, names: &Names) -> Value {
    let mut tree = Value::Mapping(Default::default());
    for o in &args.params {
        if o.node.as_deref().is_some_and(|n| n != names.node_name) {
            continue;
        }
        let value: Value = serde_yaml::from_str(&o.value).unwrap_or_else(|_| Value::String(o.value.clone()));
        deep_merge(&mut tree, &dotted(&o.name, value));
    }
    tree
}

/// The names of the node's own parameters, from the type itself.
fn node_keys() -> Vec<String> {
    let tree = serde_yaml::to_value(NodeParams::default()).unwrap_or(Value::Null);
    let keys = tree.as_mapping().into_iter().flat_map(|m| m.keys());
    keys.filter_map(|k| k.as_str().map(str::to_string)).collect()
}

/// The node's own keys may also be given flat (`-p queue_depth:=4`): moves them under `node`,
/// where they win over nested ones from any layer.
fn nest_flat_node_keys(overrides: &mut Value) {
    let Some(top) = overrides.as_mapping_mut() else { return };
    let mut flat = Value::Mapping(Default::default());
    for key in node_keys() {
        if let Some(v) = top.remove(key.as_str()) {
            deep_merge(&mut flat, &dotted(&key, v));
        }
    }
    if flat.as_mapping().is_some_and(|f| !f.is_empty()) {
        let mut node = top.remove("node").unwrap_or(Value::Mapping(Default::default()));
        deep_merge(&mut node, &flat);
        top.insert("node".into(), node);
    }
}

/// The `ros__parameters` of this node in a ROS 2 params file: every section whose key matches
/// the node, wildcard ones (`/**`, `/cam0/*`, `/**/angle_i2p`) first, then exact ones (the bare
/// node name, `/name` or the fully qualified name); later sections override earlier ones.
fn params_section(doc: &Value, names: &Names) -> Option<Value> {
    let fq = names.fully_qualified();
    let sections = doc.as_mapping()?;
    let mut matching: Vec<(bool, &Value)> = Vec::new();
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
    let mut merged: Option<Value> = None;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::{LocalizerParams, MapQos};
    use crate::pipeline::Method;

    /// An old params file that sets a retired parameter is told why it went (#36).
    #[test]
    fn a_retired_parameter_is_named_with_why_it_went() {
        let e = resolve_cli(None, &["final_refine.ranked_iterations:=150"]).unwrap_err();
        assert!(matches!(e, ResolveError::Retired { .. }), "{e}");
        assert!(e.to_string().contains("two-pass frame path"), "{e}");
        let e = resolve_cli(None, &["final_refine.no_such_thing:=1"]).unwrap_err();
        assert!(matches!(e, ResolveError::Unknown { .. }), "{e}");
    }

    /// `topics.*` and `node.*_topic` went (#36): an old params file is told the remap rule that
    /// replaces its name.
    #[test]
    fn an_old_topic_name_is_refused_with_its_remap_rule() {
        let tmp = tempfile::tempdir().unwrap();
        let f = tmp.path().join("old.yaml");
        std::fs::write(&f, "angle_i2p:\n  ros__parameters:\n    topics:\n      correspondences: /my/matches\n")
            .unwrap();
        let e = resolve_cli::<&str>(Some(&f), &[]).unwrap_err();
        assert!(e.to_string().contains("-r matcher/correspondences:=/my/matches"), "{e}");
        let e = resolve_cli(None, &["topics.pose:=/p"]).unwrap_err();
        assert!(e.to_string().contains("-r angle_i2p/pose:=/p"), "{e}");
        for old in ["node.tf_topic:=/robot/tf", "tf_topic:=/robot/tf"] {
            let e = resolve_cli(None, &[old]).unwrap_err();
            assert!(e.to_string().contains("`-r /tf:=/robot/tf`"), "{e}");
        }
        let e = resolve_cli(None, &["initialpose_topic:=pose0"]).unwrap_err();
        assert!(e.to_string().contains("`-r initialpose:=pose0`"), "{e}");
        let e = resolve_cli(None, &["topics.posse:=/p"]).unwrap_err();
        assert!(matches!(e, ResolveError::Unknown { .. }), "{e}");
        // What replaces them: a command's remaps rename the topics it reads and writes.
        let r = resolve_command(None, &["method:=ransac"], &["/matcher/correspondences:=/my/matches"]).unwrap();
        assert_eq!(r.topics.correspondences, "/my/matches");
        assert_eq!(r.topics.pose, "/angle_i2p/pose");
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
            "-r",
            "/angle_i2p/pose:=/p",
            "-p",
            "other:seed:=1",
        ])
        .unwrap();
        let names = Names::new("angle_i2p", &a);
        let r = resolve(&Layers { names: &names, params_file: Some(&f), ros_args: &a }).unwrap();
        assert_eq!(r.localizer.method, Method::Ransac);
        assert_eq!(r.localizer.pnp.min_inliers, 7);
        assert_eq!(r.topics.pose, "/p");
        assert_eq!(r.localizer.seed, LocalizerParams::default().seed);
        assert_eq!(r.node.queue_depth, 5);
        assert!(!r.node.publish_tf);
        assert_eq!(r.node.stamp_tolerance_ns, 1000);
        // Typos are errors.
        let bad = RosArgs::parse(&["--ros-args", "-p", "methd:=ransac"]).unwrap();
        assert!(resolve(&Layers { names: &names, params_file: None, ros_args: &bad }).is_err());
        let bad = RosArgs::parse(&["--ros-args", "-p", "queue_depth:=0"]).unwrap();
        assert!(resolve(&Layers { names: &names, params_file: None, ros_args: &bad }).is_err());
        // The shipped params file is accepted as is and holds the node's defaults.
        let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("params/angle_i2p.yaml");
        let r = resolve(&Layers { names: &names, params_file: Some(&shipped), ros_args: &RosArgs::default() }).unwrap();
        assert_eq!(r.node, NodeParams::default());
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
        let r = resolve(&Layers { names: &Names::new("angle_i2p", &a), params_file: Some(&f), ros_args: &a }).unwrap();
        assert_eq!(r.localizer.pnp.min_inliers, 9);
        assert_eq!(r.localizer.pnp.threshold_px, 4.0);
        assert_eq!(r.node.queue_depth, 3);
        assert_eq!(r.node.frame_timeout_ms, 900);
        assert!(r.node.use_sim_time);
        assert_eq!(r.node.map_qos, MapQos::Volatile);
        // In /cam1 only the `/cam1/**` and `/**/angle_i2p` sections apply.
        let a = RosArgs::parse(&["--ros-args", "-r", "__ns:=/cam1"]).unwrap();
        let r = resolve(&Layers { names: &Names::new("angle_i2p", &a), params_file: Some(&f), ros_args: &a }).unwrap();
        assert_eq!(r.node.queue_depth, 7);
        assert_eq!(r.localizer.pnp.min_inliers, LocalizerParams::default().pnp.min_inliers);
        assert_eq!(r.node.frame_timeout_ms, 900);
        // A misspelt dotted key is still an error.
        std::fs::write(&f, "/**:\n  ros__parameters:\n    pnp.treshold_px: 4.0\n").unwrap();
        assert!(resolve(&Layers {
            names: &Names::new("angle_i2p", &RosArgs::default()),
            params_file: Some(&f),
            ros_args: &RosArgs::default()
        })
        .is_err());
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
