//! Every parameter of angle-i2p, in one struct. Sources, later ones winning: defaults, the ROS 2
//! params file (`params/angle_i2p.yaml`, `angle_i2p: ros__parameters: …`), then CLI flags.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::bag::TopicMap;
use crate::consistency::ScaleShiftParams;
use crate::geometry::DepthKind;
use crate::node::NodeParams;
use crate::pipeline::{CascadeParams, FinalRefine, Method};
use crate::pnp::PnpParams;
use crate::reject::network::NetworkParams;
use crate::reject::SpectralParams;
use crate::verify::VerifyParams;

#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    /// Outlier rejection before PnP.
    pub method: Method,
    /// The fast path: a budgeted LO-RANSAC that settles easy frames before any rejection.
    pub cascade: CascadeParams,
    /// What the prior's values mean: depth, inverse depth or affine-invariant disparity.
    pub depth_kind: DepthKind,
    /// Scale-and-shift alignment of the prior.
    pub align: ScaleShiftParams,
    /// The training-free spectral rejector.
    pub spectral: SpectralParams,
    /// The learned rejector (method `angle-i2p`).
    pub network: NetworkParams,
    /// Robust PnP.
    pub pnp: PnpParams,
    /// Verification of PnP's best hypotheses against the dense depth prior.
    pub verify: VerifyParams,
    /// Last refinement on every correspondence agreeing with the pose.
    pub final_refine: FinalRefine,
    /// Seed of every random choice (results are reproducible).
    pub seed: u64,
    /// Topic names.
    pub topics: TopicMap,
    /// The live node: queue, frame matching, TF, diagnostics, debug image.
    pub node: NodeParams,
    /// How much one input may make us hold or compute ([`crate::limits`]).
    pub limits: crate::limits::InputLimits,
}

#[derive(Debug, thiserror::Error)]
pub enum ParamsError {
    #[error("cannot read params file {path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("params file {path}: {message}")]
    Parse { path: String, message: String },
}

impl Params {
    /// Reads a ROS 2 params file: the `ros__parameters` of node `angle_i2p` (or of `/**`).
    pub fn from_ros_params_file(path: &Path) -> Result<Self, ParamsError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| ParamsError::Io { path: path.display().to_string(), source })?;
        Self::from_ros_params_yaml(&text)
            .map_err(|message| ParamsError::Parse { path: path.display().to_string(), message })
    }

    pub fn from_ros_params_yaml(text: &str) -> Result<Self, String> {
        let doc: serde_yaml::Value = serde_yaml::from_str(text).map_err(|e| e.to_string())?;
        let node = ["angle_i2p", "/angle_i2p", "/**"]
            .iter()
            .find_map(|name| doc.get(*name))
            .ok_or("no `angle_i2p:` (or `/**:`) node section")?;
        let params = node.get("ros__parameters").ok_or("no `ros__parameters:` under the node")?;
        serde_yaml::from_value(params.clone()).map_err(|e| e.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_params_file_matches_the_defaults() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("params/angle_i2p.yaml");
        let from_file = Params::from_ros_params_file(&path).unwrap();
        let defaults = Params::default();
        assert_eq!(serde_yaml::to_string(&from_file).unwrap(), serde_yaml::to_string(&defaults).unwrap());
    }

    #[test]
    fn unknown_keys_are_rejected() {
        let err = Params::from_ros_params_yaml("angle_i2p:\n  ros__parameters:\n    methd: ransac\n").unwrap_err();
        assert!(err.contains("methd"), "{err}");
        let err =
            Params::from_ros_params_yaml("angle_i2p:\n  ros__parameters:\n    network: {tauu: 0.4}\n").unwrap_err();
        assert!(err.contains("tauu"), "a nested typo must not pass silently: {err}");
    }
}
