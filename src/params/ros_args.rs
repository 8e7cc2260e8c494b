//! ROS 2 command-line arguments (`--ros-args …`) and node names, as `rcl` reads them; the
//! node, the player and the CLI's `-p` overrides share them.
//!
//! Supported, as `ros2 run` passes them: `-r from:=to` / `--remap from:=to` (topic remaps,
//! `node:from:=to` for this node only, `__ns:=/ns`, `__node:=name`), `-p name:=value` /
//! `--param name:=value` (dotted names for nested parameters, YAML values), `--params-file F`,
//! and `--` (end of the ROS arguments). Anything else is an error naming the argument.

use std::path::PathBuf;

/// The node name parameters are looked up under when none is given (`-r __node:=…`).
pub const DEFAULT_NODE_NAME: &str = "angle_i2p";

/// A topic remap rule; `node` limits it to the node of that name.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Remap {
    pub node: Option<String>,
    pub from: String,
    pub to: String,
}

/// One `-p [node:]name:=value`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ParamOverride {
    /// Set for `node:name:=value`: only the node of that name takes it.
    pub node: Option<String>,
    /// Dotted parameter name, e.g. `pnp.threshold_px`.
    pub name: String,
    /// The value as written (read as YAML).
    pub value: String,
}

/// The parsed `--ros-args` section.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RosArgs {
    pub remaps: Vec<Remap>,
    /// `name:=value` parameter overrides, in order.
    pub params: Vec<ParamOverride>,
    pub params_files: Vec<PathBuf>,
    pub namespace: Option<String>,
    pub node_name: Option<String>,
    /// `--log-level LEVEL` (or `--log-level NAME:=LEVEL` for this node's logger).
    pub log_level: Option<LogLevel>,
    /// `-e`/`--enclave`: accepted; DDS security is not built in, so it has no effect (logged).
    pub enclave: Option<String>,
    /// `--enable-rosout-logs` / `--disable-rosout-logs` (the last wins); rosout is on unless disabled.
    pub rosout: Option<bool>,
    /// Accepted logging options that have no effect here (e.g. `--disable-stdout-logs`).
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
    /// The ROS arguments of a command's bare `-p NAME:=VALUE` overrides and `-r FROM:=TO`
    /// remaps, as the CLI takes them.
    pub fn from_cli<S: AsRef<str>, R: AsRef<str>>(overrides: &[S], remaps: &[R]) -> Result<Self, ArgsError> {
        let mut tokens = vec!["--ros-args"];
        for o in overrides {
            tokens.extend(["-p", o.as_ref()]);
        }
        for r in remaps {
            tokens.extend(["-r", r.as_ref()]);
        }
        Self::parse(&tokens)
    }

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
                    let (node, name, value) = split_rule("parameter", &rule)?;
                    out.params.push(ParamOverride { node, name, value });
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
                "--enable-rosout-logs" => out.rosout = Some(true),
                "--disable-rosout-logs" => out.rosout = Some(false),
                "--enable-stdout-logs"
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

#[cfg(test)]
mod tests {
    use super::*;

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
        assert_eq!(a.params, vec![ParamOverride { node: None, name: "method".into(), value: "ransac".into() }]);
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
    fn standard_ros_arguments_are_accepted_or_named() {
        let a = RosArgs::parse(&[
            "--ros-args",
            "--log-level",
            "warn",
            "-e",
            "/cam0",
            "--disable-rosout-logs",
            "--disable-stdout-logs",
            "--log-level",
            "angle_i2p:=debug",
        ])
        .unwrap();
        assert_eq!(a.log_level, Some(LogLevel::Debug));
        assert_eq!(a.enclave.as_deref(), Some("/cam0"));
        assert_eq!(a.rosout, Some(false));
        assert_eq!(a.ignored, vec!["--disable-stdout-logs".to_string()]);
        let e = RosArgs::parse(&["--ros-args", "--log-level", "loud"]).unwrap_err();
        assert!(e.to_string().contains("loud"), "{e}");
        let e = RosArgs::parse(&["--ros-args", "--enclave"]).unwrap_err();
        assert!(matches!(e, ArgsError::MissingValue { .. }), "{e}");
    }
}
