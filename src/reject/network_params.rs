//! The learned rejector's parameters (`network.*`), apart from the network itself so that the
//! inputs can be built without it.

use serde::{Deserialize, Serialize};

use super::graph::GraphParams;
use super::SpectralParams;
use crate::consistency::{PairMetric, ScaleShiftParams};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NetworkParams {
    /// The trained model (ONNX, one file).
    pub model_path: String,
    /// ONNX Runtime's shared library; empty: `ORT_DYLIB_PATH`, then `.ort/` + the library name.
    pub onnxruntime_path: String,
    /// Keep correspondences with score ≥ τ …
    pub tau: f64,
    /// … but at least this many (the best ones), so PnP always has material.
    pub min_keep: usize,
    /// Intra-op threads of the session (1: one core per node instance).
    pub intra_threads: usize,
    /// K, M, the θ kind and σ_d of the graphs (must match the training export).
    pub neighbours: usize,
    pub keypoints: usize,
    pub theta: PairMetric,
    pub sigma_d: f64,
    /// Align the prior's scale and shift before building features and graphs (the paper's
    /// scale alignment); `false` is the ablation: raw prior, no eq. (8) rescaling either.
    pub align_prior: bool,
    /// Power-iteration steps of the spectral pass that ranks the keypoints (a ranking of the
    /// top M settles long before the eigenvector converges).
    pub keypoint_iterations: usize,
    /// What ranks the M keypoints of the global graph.
    pub keypoint_ranking: KeypointRanking,
}

/// How the global graph's keypoints are chosen (the paper takes P2-Net's top-M detections).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum KeypointRanking {
    /// The spectral consistency score alone.
    Spectral,
    /// Spectral score × the matcher's confidence (clamped to [0, 1]): geometric agreement and
    /// the matcher's own certainty, as a detector's score would add to it.
    #[default]
    SpectralMatcher,
}

impl Default for NetworkParams {
    fn default() -> Self {
        let g = GraphParams::default();
        Self {
            model_path: "models/angle_i2p.onnx".into(),
            onnxruntime_path: String::new(),
            tau: 0.2,
            min_keep: 12,
            intra_threads: 1,
            neighbours: g.neighbours,
            keypoints: g.keypoints,
            theta: g.theta,
            sigma_d: g.sigma_d,
            align_prior: true,
            keypoint_iterations: 4,
            keypoint_ranking: KeypointRanking::default(),
        }
    }
}

impl NetworkParams {
    /// The graphs' parameters.
    pub fn graph(&self) -> GraphParams {
        GraphParams {
            neighbours: self.neighbours,
            keypoints: self.keypoints,
            theta: self.theta,
            sigma_d: self.sigma_d,
            ..GraphParams::default()
        }
    }

    /// The spectral pass that ranks the keypoints.
    pub fn keypoint_spectral(&self, spectral: SpectralParams) -> SpectralParams {
        SpectralParams { iterations: self.keypoint_iterations, ..spectral }
    }

    /// The prior alignment the network's inputs are built with.
    pub fn alignment<'a>(&self, align: &'a ScaleShiftParams) -> Option<&'a ScaleShiftParams> {
        self.align_prior.then_some(align)
    }
}
