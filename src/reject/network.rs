//! The learned rejector (paper section 3.3) run with ONNX Runtime through `ort`: inputs are
//! built in Rust ([`super::inputs`]), the network scores each correspondence, and those with
//! score ≥ τ are kept.
//!
//! ONNX Runtime is loaded at start-up from `NetworkParams::onnxruntime_path`, else
//! `ORT_DYLIB_PATH`, else `.ort/libonnxruntime.so.1.31.1` (`make ort` puts it there).

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use ort::session::Session;
use ort::value::Tensor;
use serde::{Deserialize, Serialize};

use super::graph::{GraphParams, ThetaKind};
use super::inputs::{build_inputs, IndexedMap, NetworkInputs};
use super::{top_k, FrameGeometry, RejectError, Rejection, Rejector, SpectralParams, SpectralRejector};
use crate::consistency::ScaleShiftParams;

/// The library file this build expects (the `api-31` feature).
pub const ONNXRUNTIME_LIBRARY: &str = "libonnxruntime.so.1.31.1";

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
    pub theta: ThetaKind,
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

#[derive(Debug, Clone, thiserror::Error)]
pub enum NetworkError {
    #[error(
        "ONNX Runtime not found at {0}: run `make ort` (it extracts {ONNXRUNTIME_LIBRARY} from the PyPI wheel \
         onnxruntime==1.31.1 into .ort/), or set ORT_DYLIB_PATH or network.onnxruntime_path; the other methods work without it"
    )]
    MissingRuntime(String),
    #[error("ONNX Runtime at {path}: {message}")]
    Runtime { path: String, message: String },
    #[error("model {path}: {message}")]
    Model { path: String, message: String },
}

/// The process-wide ONNX Runtime environment (ort allows one per process).
fn environment(params: &NetworkParams) -> Result<ort::environment::Environment, NetworkError> {
    static ENV: OnceLock<Result<ort::environment::Environment, NetworkError>> = OnceLock::new();
    ENV.get_or_init(|| {
        let path = runtime_path(params);
        if !path.exists() {
            return Err(NetworkError::MissingRuntime(path.display().to_string()));
        }
        let err = |e: String| NetworkError::Runtime { path: path.display().to_string(), message: e };
        ort::init_from(&path).map_err(|e| err(e.to_string()))?.build().map_err(|e| err(e.to_string()))
    })
    .clone()
}

pub fn runtime_path(params: &NetworkParams) -> PathBuf {
    if !params.onnxruntime_path.is_empty() {
        return locate(Path::new(&params.onnxruntime_path));
    }
    if let Some(p) = std::env::var_os("ORT_DYLIB_PATH") {
        return PathBuf::from(p);
    }
    locate(&Path::new(".ort").join(ONNXRUNTIME_LIBRARY))
}

/// A relative path as given when it exists from the working directory, else under the source
/// tree this binary was built from: a node started from any directory (`ros2 launch`) finds the
/// shipped model and `make ort`'s runtime.
pub fn locate(path: &Path) -> PathBuf {
    if path.is_absolute() || path.exists() {
        return path.to_path_buf();
    }
    let in_tree = Path::new(env!("CARGO_MANIFEST_DIR")).join(path);
    if in_tree.exists() {
        in_tree
    } else {
        path.to_path_buf()
    }
}

/// Scores correspondences with the trained network.
pub struct NetworkRejector {
    params: NetworkParams,
    session: Session,
    spectral: SpectralRejector,
    map: Option<Arc<IndexedMap>>,
}

impl NetworkRejector {
    pub fn new(params: NetworkParams, spectral: SpectralParams) -> Result<Self, NetworkError> {
        let env = environment(&params)?;
        let model_path = locate(Path::new(&params.model_path));
        let model_err = |e: String| NetworkError::Model { path: model_path.display().to_string(), message: e };
        if !model_path.exists() {
            return Err(model_err("no such file".into()));
        }
        let session = Session::builder(&env)
            .and_then(|b| b.with_intra_threads(params.intra_threads.max(1)).map_err(Into::into))
            .and_then(|b| b.with_intra_op_spinning(false).map_err(Into::into))
            .and_then(|mut b| b.commit_from_file(&model_path))
            .map_err(|e| model_err(e.to_string()))?;
        let spectral = SpectralRejector::new(params.keypoint_spectral(spectral));
        Ok(Self { params, session, spectral, map: None })
    }

    /// The network's inputs for one frame (eq. 9 features, graphs, θ).
    pub fn inputs(&mut self, geometry: &FrameGeometry) -> NetworkInputs {
        build_inputs(geometry, self.map.as_deref(), &mut self.spectral, &self.params)
    }

    /// The network's scores for prepared inputs.
    pub fn run(&mut self, inputs: &NetworkInputs) -> Result<Vec<f32>, RejectError> {
        let n = inputs.features.len();
        let g = &inputs.graphs;
        let m = g.global_index.len();
        let fail = |e: ort::Error| RejectError::Failed(format!("network: {e}"));
        let index = |v: &[u32]| v.iter().map(|&i| i as i64).collect::<Vec<i64>>();
        let features: Vec<f32> = inputs.features.iter().flatten().copied().collect();
        let mut values = ort::inputs![
            "features" => Tensor::from_array(([n, 24], features)).map_err(fail)?,
            "local_index" => Tensor::from_array(([g.nodes, g.neighbours], index(&g.local_index))).map_err(fail)?,
            "local_theta" => Tensor::from_array(([g.nodes, g.neighbours, g.neighbours], g.local_theta.clone())).map_err(fail)?,
            "global_index" => Tensor::from_array(([m], index(&g.global_index))).map_err(fail)?,
            "global_theta" => Tensor::from_array(([m, m], g.global_theta.clone())).map_err(fail)?,
            "cross_theta" => Tensor::from_array(([n, m], g.cross_theta.clone())).map_err(fail)?,
            "matcher_score" => Tensor::from_array(([n], inputs.matcher_scores.clone())).map_err(fail)?,
        ];
        // Each model takes the inputs it declares: one without global attention (the ablation)
        // has no global ones, one trained without the matcher's confidence has no `matcher_score`.
        values.retain(|(name, _)| self.session.inputs().iter().any(|i| i.name() == name.as_ref()));
        let outputs = self.session.run(values).map_err(fail)?;
        let (_, scores) = outputs["score"].try_extract_tensor::<f32>().map_err(fail)?;
        if scores.len() != n {
            return Err(RejectError::Failed(format!(
                "network returned {} scores for {n} correspondences",
                scores.len()
            )));
        }
        Ok(scores.to_vec())
    }
}

impl Rejector for NetworkRejector {
    fn name(&self) -> &'static str {
        "angle_i2p"
    }

    fn set_map_index(&mut self, index: &Arc<IndexedMap>) {
        self.map = Some(Arc::clone(index));
    }

    fn reject(&mut self, geometry: &FrameGeometry) -> Result<Rejection, RejectError> {
        if !geometry.has_prior() {
            return Err(RejectError::MissingDepthPrior("angle_i2p"));
        }
        let inputs = self.inputs(geometry);
        let scores = self.run(&inputs)?;
        let mut kept: Vec<usize> = top_k(&scores, scores.len());
        let above = kept.iter().take_while(|&&i| f64::from(scores[i]) >= self.params.tau).count();
        kept.truncate(above.max(self.params.min_keep).min(scores.len()));
        Ok(Rejection { scores, kept })
    }
}
