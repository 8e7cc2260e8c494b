//! The learned rejector's parameters (`network.*`), apart from the network itself so that the
//! inputs can be built without it.

use std::collections::BTreeSet;

use serde::{Deserialize, Serialize};

use super::graph::GraphParams;
use super::SpectralParams;
use crate::consistency::ScaleShiftParams;

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
    /// K, M, the θ kind and σ_d of the graphs (model constants, like the fields below up to
    /// `missing_confidence`: see [`super::model_constants`]): their keys sit directly under
    /// `network` (`network.neighbours`, …). Unknown keys are still refused: serde checks what no
    /// field (flattened or not) took, and `params::resolve` names them first.
    #[serde(flatten)]
    pub graph: GraphParams,
    /// Align the prior's scale and shift before building features and graphs (the paper's
    /// scale alignment); `false` is the ablation: raw prior, no eq. (8) rescaling either.
    pub align_prior: bool,
    /// Power-iteration steps of the spectral pass that ranks the keypoints (a ranking of the
    /// top M settles long before the eigenvector converges).
    pub keypoint_iterations: usize,
    /// What ranks the M keypoints of the global graph.
    pub keypoint_ranking: KeypointRanking,
    /// The confidence the network reads for every match of a frame whose matcher published
    /// none (every score of the frame equal: all 0, all 1, …). Such scores say nothing within
    /// the frame, yet the network reads all 0 as "every match doubtful" and all 1 as "every
    /// match certain", neither of which its training matchers ever said; the typical
    /// confidence of those matchers (their medians: 0.07–0.29) reads as "unknown". A property
    /// of the model, not of the scene: retraining on other matchers moves it.
    pub missing_confidence: f32,
    /// The model constants a params layer gave (`params::resolve` records them; code that builds
    /// these params adds what it means to hold): the model's metadata must agree with these,
    /// and its values replace the others ([`super::model_constants::ModelConstants::resolve`]).
    #[serde(skip)]
    pub given: BTreeSet<ModelConstant>,
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
    /// Spectral score × the confidence's within-frame rank ([`super::inputs::within_frame_ranks`]):
    /// the same, blind to the matcher's calibration (with a model that takes `matcher_rank`, any
    /// increasing remap of the scores then localizes alike).
    SpectralMatcherRank,
}

impl Default for NetworkParams {
    fn default() -> Self {
        Self {
            model_path: "models/angle_i2p.onnx".into(),
            onnxruntime_path: String::new(),
            tau: 0.2,
            min_keep: 12,
            intra_threads: 1,
            graph: GraphParams::default(),
            align_prior: true,
            keypoint_iterations: 4,
            keypoint_ranking: KeypointRanking::default(),
            missing_confidence: 0.25,
            given: BTreeSet::new(),
        }
    }
}

impl NetworkParams {
    /// The spectral pass that ranks the keypoints.
    pub fn keypoint_spectral(&self, spectral: SpectralParams) -> SpectralParams {
        SpectralParams { iterations: self.keypoint_iterations, ..spectral }
    }

    /// The prior alignment the network's inputs are built with.
    pub fn alignment<'a>(&self, align: &'a ScaleShiftParams) -> Option<&'a ScaleShiftParams> {
        self.align_prior.then_some(align)
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Point2, Point3};

    use super::*;
    use crate::consistency::PairMetric;
    use crate::reject::inputs::build_inputs;
    use crate::reject::{FrameGeometry, SpectralRejector};

    #[test]
    fn graph_keys_sit_directly_under_network() {
        let keys = serde_yaml::to_value(NetworkParams::default()).unwrap();
        let keys: Vec<&str> = keys.as_mapping().unwrap().keys().filter_map(|k| k.as_str()).collect();
        for graph_key in ["neighbours", "keypoints", "theta", "sigma_d"] {
            assert!(keys.contains(&graph_key), "{graph_key} missing from {keys:?}");
        }
        assert!(!keys.iter().any(|k| *k == "graph" || k.starts_with("sigma_abs") || k.starts_with("sigma_rel")));
        let parsed: NetworkParams =
            serde_yaml::from_str("neighbours: 8\nkeypoints: 20\ntheta: distance\nsigma_d: 0.3\ntau: 0.5\n").unwrap();
        let expected = GraphParams {
            neighbours: 8,
            keypoints: 20,
            theta: PairMetric::Distance,
            sigma_d: 0.3,
            ..GraphParams::default()
        };
        assert_eq!((parsed.graph, parsed.tau), (expected, 0.5));
    }

    /// Flattening must not open a door to typos: serde itself refuses a key no field takes.
    #[test]
    fn unknown_keys_beside_the_graph_keys_are_refused() {
        let err = serde_yaml::from_str::<NetworkParams>("neighbours: 8\nneighbors: 9\n").unwrap_err().to_string();
        assert!(err.contains("neighbors"), "{err}");
        let err = serde_yaml::from_str::<NetworkParams>("sigma_abs: 0.1\n").unwrap_err().to_string();
        assert!(err.contains("sigma_abs"), "a fixed field is no parameter: {err}");
    }

    /// `-p network.neighbours:=…` and `network.keypoints` reach the graphs the network is fed.
    #[test]
    fn a_graph_key_set_by_the_user_reaches_the_graphs() {
        let resolved =
            crate::params::resolve_cli(None, &["network.neighbours:=8", "network.keypoints:=20"]).unwrap().localizer;
        assert_eq!((resolved.network.graph.neighbours, resolved.network.graph.keypoints), (8, 20));
        let map: Vec<Point3<f64>> = (0..60)
            .map(|i| Point3::new((i % 10) as f64 * 0.2, (i / 10) as f64 * 0.2, 2.0 + (i % 3) as f64 * 0.1))
            .collect();
        let geometry = FrameGeometry {
            pixels: vec![Point2::origin(); map.len()],
            image_points: map.iter().map(|p| Point3::new(p.x, p.y, p.z + 1.0)).collect(),
            matcher_scores: vec![0.5; map.len()],
            map_points: map,
            ..FrameGeometry::default()
        };
        let mut spectral = SpectralRejector::default();
        let inputs = build_inputs(&geometry, None, &mut spectral, &resolved.network);
        assert_eq!(inputs.graphs.neighbours, 8);
        assert_eq!(inputs.graphs.local_index.len(), inputs.graphs.nodes * 8);
        assert_eq!(inputs.graphs.global_index.len(), 20);
        let default = build_inputs(&geometry, None, &mut spectral, &NetworkParams::default());
        assert_eq!((default.graphs.neighbours, default.graphs.global_index.len()), (32, 60));
    }
}

/// One `network.*` parameter that is a property of the trained model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum ModelConstant {
    Neighbours,
    Keypoints,
    Theta,
    SigmaD,
    AlignPrior,
    KeypointIterations,
    KeypointRanking,
    MissingConfidence,
}

impl ModelConstant {
    pub const ALL: [Self; 8] = [
        Self::Neighbours,
        Self::Keypoints,
        Self::Theta,
        Self::SigmaD,
        Self::AlignPrior,
        Self::KeypointIterations,
        Self::KeypointRanking,
        Self::MissingConfidence,
    ];

    /// The key under `network` (and after [`METADATA_PREFIX`] in the metadata).
    pub fn name(self) -> &'static str {
        match self {
            Self::Neighbours => "neighbours",
            Self::Keypoints => "keypoints",
            Self::Theta => "theta",
            Self::SigmaD => "sigma_d",
            Self::AlignPrior => "align_prior",
            Self::KeypointIterations => "keypoint_iterations",
            Self::KeypointRanking => "keypoint_ranking",
            Self::MissingConfidence => "missing_confidence",
        }
    }

    pub(super) fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.name() == name)
    }

    /// This constant's value in `params`, as a params file (and the metadata) writes it.
    pub fn text(self, params: &NetworkParams) -> String {
        match self {
            Self::Neighbours => yaml(&params.graph.neighbours),
            Self::Keypoints => yaml(&params.graph.keypoints),
            Self::Theta => yaml(&params.graph.theta),
            Self::SigmaD => yaml(&params.graph.sigma_d),
            Self::AlignPrior => yaml(&params.align_prior),
            Self::KeypointIterations => yaml(&params.keypoint_iterations),
            Self::KeypointRanking => yaml(&params.keypoint_ranking),
            Self::MissingConfidence => yaml(&params.missing_confidence),
        }
    }

    /// Sets this constant in `params` from a metadata value.
    pub(super) fn set(self, params: &mut NetworkParams, text: &str) -> Result<(), serde_yaml::Error> {
        match self {
            Self::Neighbours => params.graph.neighbours = serde_yaml::from_str(text)?,
            Self::Keypoints => params.graph.keypoints = serde_yaml::from_str(text)?,
            Self::Theta => params.graph.theta = serde_yaml::from_str(text)?,
            Self::SigmaD => params.graph.sigma_d = serde_yaml::from_str(text)?,
            Self::AlignPrior => params.align_prior = serde_yaml::from_str(text)?,
            Self::KeypointIterations => params.keypoint_iterations = serde_yaml::from_str(text)?,
            Self::KeypointRanking => params.keypoint_ranking = serde_yaml::from_str(text)?,
            Self::MissingConfidence => params.missing_confidence = serde_yaml::from_str(text)?,
        }
        Ok(())
    }

    /// The constants a params layer names under `network` (an override tree of
    /// [`crate::params::resolve`]): the ones held against the model's.
    pub fn given_in(network: Option<&serde_yaml::Value>) -> BTreeSet<Self> {
        let keys = network.and_then(serde_yaml::Value::as_mapping).into_iter().flat_map(|m| m.keys());
        keys.filter_map(|k| k.as_str().and_then(Self::from_name)).collect()
    }
}

/// A scalar as a params file writes it (`32`, `0.2`, `angle`, `true`).
fn yaml<T: Serialize>(value: &T) -> String {
    serde_yaml::to_string(value).map(|s| s.trim_end().to_string()).unwrap_or_default()
}
