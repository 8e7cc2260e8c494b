//! Every parameter of angle-i2p. The core's ([`LocalizerParams`]: what [`crate::pipeline::Localizer`]
//! needs) and the edges' ([`AppParams`]: the live node, input limits, the bag commands' topic
//! names) are separate types, so that the core depends on no edge; in a params file they sit
//! side by side under `ros__parameters` (`params/angle_i2p.yaml`, the parameters a deployment
//! sets; `params/expert.yaml`, every parameter), as they always did. [`resolve`] layers the
//! sources: defaults < params file < `--ros-args` params files < `-p name:=value`.

mod node;
pub mod resolve;
pub mod ros_args;
mod topics;
pub mod tree;
pub mod validate;

use serde::{Deserialize, Serialize};

use crate::camera::PixelSpace;
use crate::limits::InputLimits;
pub use crate::pipeline::LocalizerParams;

/// How the edges read the camera ([`crate::camera`]).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CameraParams {
    /// `raw`: pixels (and the prior) of the image CameraInfo describes, undistorted with its K
    /// and D; `rectified`: pixels of the rectified image (`image_proc`), in P's camera.
    pub pixels: PixelSpace,
}

pub use node::{MapQos, MapSource, NodeParams, TfMode};
pub use resolve::{resolve, resolve_cli, resolve_command, Layers, ResolveError};
pub use ros_args::{ArgsError, LogLevel, Names, ParamOverride, Remap, RosArgs, DEFAULT_NODE_NAME};
pub use topics::TopicMap;
pub use validate::InvalidParam;

/// Every parameter of a command or of the node: the localizer's, flat beside the edges' own.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AppParams {
    /// The core's parameters; their keys sit at the top level (`method`, `pnp.*`, …).
    #[serde(flatten)]
    pub localizer: LocalizerParams,
    /// The topic names of the bag commands (`replay`, `eval`, `export`): the defaults under the
    /// command's `-r` remaps ([`TopicMap::remapped`]). Not a parameter; the live node resolves
    /// its own names under its namespace (`node::topics`).
    #[serde(skip)]
    pub topics: TopicMap,
    /// The live node: queue, frame matching, TF, diagnostics, debug image.
    pub node: NodeParams,
    /// The camera's pixel space: raw (undistorted with CameraInfo's D) or rectified (P).
    pub camera: CameraParams,
    /// How much one input may make us hold or compute ([`crate::limits`]), enforced where
    /// messages come in (bag reading, the node).
    pub limits: InputLimits,
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;

    /// The user's file (the parameters a deployment sets) and the reference of every parameter.
    const USER_FILE: &str = "params/angle_i2p.yaml";
    const EXPERT_FILE: &str = "params/expert.yaml";
    /// The most keys the user's file may hold (#36: a user needs about twenty).
    const MAX_USER_KEYS: usize = 25;

    fn shipped(file: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join(file)
    }

    fn resolve_file(path: &Path) -> Result<AppParams, ResolveError> {
        resolve_cli::<&str>(Some(path), &[])
    }

    /// The leaf keys of a shipped params file.
    fn keys_of(file: &str) -> Vec<String> {
        let text = std::fs::read_to_string(shipped(file)).unwrap();
        let doc: serde_yaml::Value = serde_yaml::from_str(&text).unwrap();
        tree::leaf_keys(&tree::undot(&doc["angle_i2p"]["ros__parameters"]))
    }

    /// Both shipped files hold the defaults: loading either changes nothing.
    #[test]
    fn shipped_params_files_match_the_defaults() {
        let defaults = serde_yaml::to_string(&AppParams::default()).unwrap();
        for file in [USER_FILE, EXPERT_FILE] {
            let from_file = resolve_file(&shipped(file)).unwrap();
            assert_eq!(serde_yaml::to_string(&from_file).unwrap(), defaults, "{file}");
        }
    }

    /// The reference file lists every parameter and only parameters; the user's file holds at
    /// most [`MAX_USER_KEYS`] of them.
    #[test]
    fn shipped_params_files_list_the_parameters() {
        let defaults = tree::leaf_keys(&serde_yaml::to_value(AppParams::default()).unwrap());
        let all = keys_of(EXPERT_FILE);
        let missing: Vec<&String> = defaults.iter().filter(|k| !all.contains(k)).collect();
        let unknown: Vec<&String> = all.iter().filter(|k| !defaults.contains(k)).collect();
        assert!(missing.is_empty(), "parameters missing from {EXPERT_FILE}: {missing:?}");
        assert!(unknown.is_empty(), "keys in {EXPERT_FILE} that are no parameter: {unknown:?}");
        assert!(defaults.len() > 100 && defaults.contains(&"pnp.prior_tolerance".to_string()), "{defaults:?}");
        let user = keys_of(USER_FILE);
        assert!(user.len() <= MAX_USER_KEYS, "{} keys in {USER_FILE}: {user:?}", user.len());
        let unknown: Vec<&String> = user.iter().filter(|k| !defaults.contains(k)).collect();
        assert!(unknown.is_empty(), "keys in {USER_FILE} that are no parameter: {unknown:?}");
    }

    #[test]
    fn unknown_keys_are_rejected() {
        let err = resolve_cli(None, &["methd:=ransac"]).unwrap_err().to_string();
        assert!(err.contains("methd"), "{err}");
        let err = resolve_cli(None, &["network.tauu:=0.4"]).unwrap_err().to_string();
        assert!(err.contains("tauu"), "a nested typo must not pass silently: {err}");
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("p.yaml");
        std::fs::write(&file, "angle_i2p:\n  ros__parameters:\n    network: {tauu: 0.4}\n").unwrap();
        let err = resolve_file(&file).unwrap_err().to_string();
        assert!(err.contains("tauu"), "{err}");
    }

    /// The localizer's keys and the edges' sections share one flat namespace: none may shadow another.
    #[test]
    fn the_localizer_and_edge_keys_do_not_collide() {
        let top = |v: serde_yaml::Value| -> Vec<String> {
            v.as_mapping().unwrap().keys().map(|k| k.as_str().unwrap().to_string()).collect()
        };
        let core = top(serde_yaml::to_value(LocalizerParams::default()).unwrap());
        let mut edges = vec!["node".to_string(), "limits".to_string()];
        edges.extend(top(serde_yaml::to_value(NodeParams::default()).unwrap()));
        assert!(core.iter().all(|k| !edges.contains(k)), "{core:?} vs {edges:?}");
    }
}
