//! The learned rejector (paper section 3.3) run with ONNX Runtime through `ort`: inputs are
//! built in Rust ([`super::inputs`]), the network scores each correspondence, and those with
//! score ≥ τ are kept.
//!
//! ONNX Runtime is loaded at start-up from `NetworkParams::onnxruntime_path`, else
//! `ORT_DYLIB_PATH`, else `.ort/libonnxruntime.so.1.31.1` (`make ort` puts it there).

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use ort::session::Session;
use ort::value::Tensor;
use serde::{Deserialize, Serialize};

use super::graph::GraphParams;
use super::inputs::{build_inputs, IndexedMap, NetworkInputs};
use super::{top_k, FrameGeometry, RejectError, Rejection, Rejector, SpectralParams, SpectralRejector};
use crate::frame::MapCloud;

/// The library file this build expects (the `api-31` feature).
pub const ONNXRUNTIME_LIBRARY: &str = "libonnxruntime.so.1.31.1";

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct NetworkParams {
    /// The trained model (ONNX, one file).
    pub model_path: String,
    /// ONNX Runtime's shared library; empty: `ORT_DYLIB_PATH`, then `.ort/` + the library name.
    pub onnxruntime_path: String,
    /// Keep correspondences with score ≥ τ …
    pub tau: f32,
    /// … but at least this many (the best ones), so PnP always has material.
    pub min_keep: usize,
    /// Intra-op threads of the session (1: one core per node instance).
    pub intra_threads: usize,
    /// K, M and σ_d of the graphs (must match the training export).
    pub neighbours: usize,
    pub keypoints: usize,
    pub sigma_d: f64,
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
            sigma_d: g.sigma_d,
        }
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
        return PathBuf::from(&params.onnxruntime_path);
    }
    if let Some(p) = std::env::var_os("ORT_DYLIB_PATH") {
        return PathBuf::from(p);
    }
    Path::new(".ort").join(ONNXRUNTIME_LIBRARY)
}

/// Scores correspondences with the trained network.
pub struct NetworkRejector {
    params: NetworkParams,
    session: Session,
    spectral: SpectralRejector,
    map: Option<IndexedMap>,
}

impl NetworkRejector {
    pub fn new(params: NetworkParams, spectral: SpectralParams) -> Result<Self, NetworkError> {
        let env = environment(&params)?;
        let model_err = |e: String| NetworkError::Model { path: params.model_path.clone(), message: e };
        if !Path::new(&params.model_path).exists() {
            return Err(model_err("no such file".into()));
        }
        let session = Session::builder(&env)
            .and_then(|b| b.with_intra_threads(params.intra_threads.max(1)).map_err(Into::into))
            .and_then(|b| b.with_intra_op_spinning(false).map_err(Into::into))
            .and_then(|mut b| b.commit_from_file(&params.model_path))
            .map_err(|e| model_err(e.to_string()))?;
        Ok(Self { params, session, spectral: SpectralRejector::new(spectral), map: None })
    }

    fn graph_params(&self) -> GraphParams {
        GraphParams {
            neighbours: self.params.neighbours,
            keypoints: self.params.keypoints,
            sigma_d: self.params.sigma_d,
        }
    }

    /// The network's scores for prepared inputs.
    pub fn run(&mut self, inputs: &NetworkInputs) -> Result<Vec<f32>, RejectError> {
        let n = inputs.features.len();
        let g = &inputs.graphs;
        let m = g.global_index.len();
        let fail = |e: ort::Error| RejectError::Failed(format!("network: {e}"));
        let index = |v: &[u32]| v.iter().map(|&i| i as i64).collect::<Vec<i64>>();
        let features: Vec<f32> = inputs.features.iter().flatten().copied().collect();
        let values = ort::inputs![
            "features" => Tensor::from_array(([n, 24], features)).map_err(fail)?,
            "local_index" => Tensor::from_array(([g.nodes, g.neighbours], index(&g.local_index))).map_err(fail)?,
            "local_theta" => Tensor::from_array(([g.nodes, g.neighbours, g.neighbours], g.local_theta.clone())).map_err(fail)?,
            "global_index" => Tensor::from_array(([m], index(&g.global_index))).map_err(fail)?,
            "global_theta" => Tensor::from_array(([m, m], g.global_theta.clone())).map_err(fail)?,
            "cross_theta" => Tensor::from_array(([n, m], g.cross_theta.clone())).map_err(fail)?,
        ];
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

    fn set_map(&mut self, map: &MapCloud) {
        self.map = Some(IndexedMap::new(map.points.clone()));
    }

    fn reject(&mut self, geometry: &FrameGeometry) -> Result<Rejection, RejectError> {
        if !geometry.has_prior() {
            return Err(RejectError::MissingDepthPrior("angle_i2p"));
        }
        let graph = self.graph_params();
        let inputs = build_inputs(geometry, self.map.as_ref(), &mut self.spectral, &graph);
        let scores = self.run(&inputs)?;
        let mut kept: Vec<usize> = top_k(&scores, scores.len());
        let above = kept.iter().take_while(|&&i| scores[i] >= self.params.tau).count();
        kept.truncate(above.max(self.params.min_keep).min(scores.len()));
        Ok(Rejection { scores, kept })
    }
}
